"""The mechanics' records as values: pickled and copied they stay read-only, and they compare
and hash by value."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_TURN,
    GaitScene,
    Scene,
    Trajectory,
    optimal_gait,
    site_sets,
    solve_gait,
)


def small_gait():
    """The optimal gait of 4 fingers on 4 sites over 2 poses: every site set usable, in reach."""
    margin = np.linspace(0.0, 0.1, 2 * len(site_sets(4))).reshape(2, -1)
    return optimal_gait(margin, np.ones((2, 4, 4), bool))


COPIES = {
    "pickle": lambda record: pickle.loads(pickle.dumps(record)),
    "deepcopy": copy.deepcopy,
    "copy": copy.copy,
}


def read_only_arrays(record) -> dict[str, bool]:
    """Each array field and whether it is read-only."""
    return {
        name: not value.flags.writeable
        for name, value in vars(record).items()
        if isinstance(value, np.ndarray)
    }


@pytest.mark.parametrize("how", COPIES)
@pytest.mark.parametrize(
    "make",
    [Scene, lambda: Scene.on_faces(offsets=[[0.3, 0.1], [-0.2, 0.3], [0.1, -0.3]]), GaitScene],
)
def test_copied_scenes_stay_read_only(make, how):
    scene = make()
    clone = COPIES[how](scene)
    assert read_only_arrays(clone) == read_only_arrays(scene)
    assert all(read_only_arrays(clone).values())
    points = clone.sites if isinstance(clone, GaitScene) else clone.contacts
    with pytest.raises(ValueError, match="read-only"):
        points[0] = 0.3  # would move a contact unchecked, its normal stale
    assert clone == scene and hash(clone) == hash(scene)


@pytest.mark.parametrize("how", COPIES)
def test_copied_gaits_keep_their_read_only_arrays(how):
    gait = small_gait()
    clone = COPIES[how](gait)
    assert read_only_arrays(clone) == read_only_arrays(gait)
    assert all(read_only_arrays(clone).values())
    assert all(read_only_arrays(clone.table).values())
    with pytest.raises(ValueError, match="read-only"):
        clone.policy[0, 0] = 1
    np.testing.assert_array_equal(clone.policy, gait.policy)
    assert clone.events() == gait.events()


@pytest.mark.parametrize(
    ("make", "other"),
    [
        (Scene, lambda: Scene(mu=0.4)),
        (Scene, lambda: Scene(cg_offset=(0.1, 0, 0))),
        (GaitScene, lambda: GaitScene(mu=0.4)),
        (GaitScene, lambda: GaitScene(sites=GaitScene().sites[:5])),
    ],
)
def test_scenes_compare_and_hash_by_value(make, other):
    assert make() == make() and not make() != make()
    assert hash(make()) == hash(make())
    assert make() in [make()] and len({make(), make()}) == 1
    assert make() != other() and other() not in {make()}
    assert make() != "a scene" and Scene() != GaitScene()


def test_equal_scenes_hash_alike_whatever_their_input_types():
    # -0.0 == 0.0 but their bytes differ; ints and floats, lists and tuples are the same numbers
    a = Scene(cg_offset=(-0.0, 0.0, 0.0), weight=5)
    b = Scene(cg_offset=[0, 0, 0], weight=5.0)
    assert a == b and hash(a) == hash(b)
    c = GaitScene(cg_offset=[0.05, 0, 0], size=1, weight=np.int64(5))
    d = GaitScene()
    assert c == d and hash(c) == hash(d)


def test_gait_scenes_store_their_numbers_immutable():
    offset = [0.05, 0.0, 0.0]
    scene = GaitScene(cg_offset=offset, size=np.float32(1.0), mu=np.float64(0.5))
    offset[0] = 0.2  # the scene's value, and its hash, cannot change under it
    assert scene.cg_offset == (0.05, 0.0, 0.0)
    assert type(scene.size) is float and type(scene.mu) is float
    assert GaitScene.on_faces(size=[1, 2, 1]).size == (1.0, 2.0, 1.0)


def test_gaits_compare_and_hash_by_value():
    a, b = small_gait(), small_gait()
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    assert a.table == b.table and hash(a.table) == hash(b.table)
    fewer = optimal_gait(np.linspace(0.0, 0.1, len(site_sets(4)))[None], np.ones((1, 4, 4), bool))
    assert a != fewer and a != "a gait"


def test_solver_records_compare_by_identity():
    # records of solver output hold batches: identity, not an ambiguous array comparison
    solution = solve_gait(trajectory=Trajectory(PAPER_TURN.axis, -10.0, 10.0, 10.0))
    grasp = solution.values.groups[0].grasp
    for record in (solution, solution.values, solution.values.groups[0], grasp):
        assert record == record and record != copy.copy(record)
    assert solution.optimal == copy.deepcopy(solution.optimal)
