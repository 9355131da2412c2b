"""The numpy mechanics core: bad scenes, scene defaults, and the grip along given force
directions (docs/design.md, "Mechanics").
"""

import math
import time

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_AXIS,
    PAPER_FACES,
    Scene,
    Trajectory,
    contact_pairs,
    face_point,
    pose_rotation,
    scene_grasp,
)


def paper_contacts():
    return np.array([face_point(f) for f in PAPER_FACES])


def with_contact(i, point, contacts=None):
    contacts = paper_contacts() if contacts is None else contacts
    contacts[i] = point
    return contacts


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"contacts": with_contact(1, [-0.5, 0, 0])}, "coincide"),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0, 0, 0.5]]}, None),  # valid: a sanity row
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0.1, 0, 0]]}, "not on a face"),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0, 0.5, 0]]}, None),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0.5, 0.2, 0]]}, None),
        ({"contacts": [[-0.5, -0.1, -0.1], [0.5, 0.1, 0.1], [0, 0.5, 0.5]]}, "edge"),
        ({"contacts": [[-0.5, 0.2, 0.2], [0, -0.5, 0], [0.2, 0.2, 0.5]]}, None),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0, 0, 0.5], [0, 0, -0.5]]}, "coplanar"),
        ({"contacts": with_contact(0, [-0.6, 0, 0])}, "outside"),
        ({"contacts": with_contact(0, [-0.4, 0, 0])}, "not on a face"),
        ({"contacts": with_contact(0, [np.nan, 0, 0])}, "finite"),
        ({"contacts": np.zeros((2, 3))}, "shape"),
        ({"contacts": np.zeros((9, 3))}, "shape"),  # 3 to 8 contacts
        ({"weight": 0.0}, "weight"),
        ({"weight": -1.0}, "weight"),
        ({"weight": np.inf}, "weight"),
        ({"mu": 0.0}, "mu"),
        ({"mu": np.nan}, "mu"),
        ({"size": 0.0}, "size"),
        ({"size": [1, -1, 1]}, "size"),
        ({"cg_offset": [0.6, 0, 0]}, "inside the box"),
        ({"cg_offset": [np.inf, 0, 0]}, "finite"),
        ({"extra_force": [0, np.nan, 0]}, "finite"),
        ({"extra_torque": [0, 0, np.inf]}, "finite"),
        # the right shapes, real numbers (no string or boolean converted), documented ranges
        ({"size": (1, 2)}, r"size must be a number or 3 numbers .* got \(1, 2\)"),
        ({"size": True}, "size must be a number or 3 numbers"),
        ({"size": 1e7}, r"each in \[1e-06, 1e\+06\]"),
        ({"size": "1"}, "size must be"),
        ({"weight": "5"}, "weight must be a finite number > 0, got '5'"),
        ({"weight": True}, "weight must be a finite number > 0, got True"),
        ({"weight": np.True_}, "weight must be a finite number > 0"),
        ({"weight": [5.0]}, "weight must be a finite number > 0"),
        ({"mu": "0.5"}, "mu must be a finite number > 0"),
        ({"mu": 1j}, "mu must be a finite number > 0"),
        ({"cg_offset": (0.0, 0.0)}, r"cg_offset must be a 3-vector .* got shape \(2,\)"),
        ({"cg_offset": 0.0}, r"cg_offset must be a 3-vector .* got shape \(\)"),
        ({"cg_offset": (True, 0, 0)}, "cg_offset must be a 3-vector of finite real numbers"),
        ({"extra_force": ("0", "0", "0")}, "extra_force must be a 3-vector"),
        ({"extra_torque": None}, "extra_torque must be a 3-vector"),
        ({"contacts": [[-0.5, 0, 0], [0, -0.5, 0], [0, 0, "x"]]}, "contacts must be an"),
        ({"contacts": "abc"}, "contacts must be an"),
    ],
)
@pytest.mark.fast
def test_bad_scenes(kwargs, match):
    if match is None:
        Scene(**kwargs)  # layouts that look odd but are valid must construct
        return
    with pytest.raises(ValueError, match=match):
        Scene(**kwargs)


def test_scene_numbers_may_be_any_real_numbers_and_are_stored_as_floats():
    scene = Scene(weight=np.int64(5), mu=np.float32(0.5), size=np.array(1), cg_offset=[0, 0, 0])
    assert type(scene.weight) is float and scene.weight == 5.0
    assert type(scene.mu) is float and scene.mu == 0.5
    assert scene.size.dtype == np.float64 and scene.size.tolist() == [1.0] * 3
    offset = np.zeros(3)
    scene = Scene(cg_offset=offset)
    offset[0] = 0.1  # the scene keeps its own copy
    assert scene.cg_offset[0] == 0.0 and not scene.cg_offset.flags.writeable


def test_gait_scenes_check_their_numbers_as_scenes_do():
    from grasp_env.mechanics import GaitScene
    from grasp_env.mechanics.gait import set_values

    for kwargs, match in (
        ({"size": (1, 2)}, "size must be a number or 3 numbers"),  # was a numpy broadcast error
        ({"weight": "5"}, "weight must be a finite number > 0, got '5'"),
        ({"sites": np.eye(3).astype(bool)}, "sites must be an"),
    ):
        with pytest.raises(ValueError, match=match):
            GaitScene(**kwargs)
    rotations = Trajectory().rotations()[:2]
    with pytest.raises(ValueError, match="k_max must be a finite number > 0, got '10'"):
        set_values(GaitScene(), rotations, "10")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"rotations must be .* proper rotation"):
        set_values(GaitScene(), 2 * rotations)


@pytest.mark.fast
def test_collinear_contacts_rejected():
    # a line meets a convex box's surface in two points unless it runs along a face
    with pytest.raises(ValueError, match="collinear"):
        Scene(contacts=[[-0.5, -0.2, 0.1], [-0.5, 0.0, 0.1], [-0.5, 0.2, 0.1]])


def test_bad_face_points():
    with pytest.raises(ValueError, match="unknown face"):
        face_point("+w")
    with pytest.raises(ValueError, match="unknown face"):
        face_point(["-x"])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="size must be a number or 3 numbers"):
        face_point("-x", size=(1, 2))
    with pytest.raises(ValueError, match="face offset must be 2 finite fractions"):
        face_point("-x", ("0.1", 0.0))
    with pytest.raises(ValueError, match="faces must be a sequence of 3 or 4 face names"):
        Scene.on_faces("-x-y-z")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="offsets must be an array of shape"):
        Scene.on_faces(PAPER_FACES, offsets=[[0, 0], [0, 0], [0, True]])
    with pytest.raises(ValueError, match="offset"):
        face_point("-x", (1.0, 0.0))
    with pytest.raises(ValueError, match="offsets must have shape"):
        Scene.on_faces(PAPER_FACES, offsets=np.zeros((2, 2)))


@pytest.mark.fast
def test_scene_defaults_are_the_papers():
    scene = Scene()
    np.testing.assert_allclose(scene.contacts, [[-0.5, 0, 0], [0, -0.5, 0], [0, 0, -0.5]])
    np.testing.assert_allclose(scene.normals, np.eye(3))
    assert scene.weight == 5.0
    assert scene.friction_limit == pytest.approx(math.atan(0.5))


def test_in_parts_covers_the_batch_in_order():
    from grasp_env.mechanics import threads
    from grasp_env.mechanics.threads import in_parts

    cases = ((7, 1), (1001, 2), (1001, 3), (0, 2), (2, 5), (1001, 2), (10, 3))
    # the split learnt from the parts' timing, whatever it is: here from the calls themselves,
    # then pushed to either end (the pool starting a second late or early at 1 ns an item)
    for timing in (None, (1.0, 1e-9), (-1.0, 1e-9)):
        if timing is not None:
            threads._timing["test-parts"] = timing
        for count, parts in cases:
            done = in_parts("test-parts", count, lambda lo, hi: list(range(lo, hi)), parts)
            assert len(done) == max(1, min(parts, count))
            assert all(done) or count == 0  # no part empty
            assert [i for part in done for i in part] == list(range(count))
    # what was measured is there to read (the bench prints it), and only for split calls
    assert threads.hand_off("test-parts-unsplit") is None
    in_parts("test-parts-unsplit", 10, lambda lo, hi: None, 1)
    assert threads.hand_off("test-parts-unsplit") is None
    lag, per_item = threads.hand_off("test-parts")
    assert math.isfinite(lag) and per_item > 0
    threads._timing["test-parts"] = (1.0, 1e-9)
    assert [len(part) for part in in_parts("test-parts", 10, lambda lo, hi: range(lo, hi), 3)] == [
        8, 1, 1,
    ]  # fmt: skip
    finished = []

    def part(lo: int, hi: int) -> None:
        if lo == 0:
            raise RuntimeError("the first part fails")
        time.sleep(0.05)
        finished.append(lo)

    with pytest.raises(RuntimeError, match="first part fails"):
        in_parts("test-parts", 10, part, 2)
    assert len(finished) == 1 and finished[0] > 0  # the other part ran to its end first


def test_grip_along_realises_consistent_directions_on_a_scene():
    """The directions of the forces some grip k gives are realised by that k (float64, the
    paper's scene and a random grip inside the box)."""
    from grasp_env.mechanics import directions

    g = scene_grasp(Scene.on_faces(PAPER_FACES), pose_rotation(PAPER_AXIS, 0.2))
    k = np.array([[0.3, -0.2, 0.5]])
    net = g.forces(k[0])
    d = net / np.linalg.norm(net, axis=-1, keepdims=True)
    found, weights = directions.grip_along(
        d[None], g.equilibrating[None], g.basis[None], g.normals[None], 2.0
    )
    np.testing.assert_allclose(found, k, atol=1e-8)
    assert weights.shape == (1, 3) and np.all(weights > 0)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda a: {**a, "directions": a["directions"][:, :2]}, r"n >= 3 contacts"),
        (lambda a: {**a, "forces": a["forces"][:, :, :2]}, r"forces must have the directions"),
        (lambda a: {**a, "normals": np.full((4, 3, 3), np.nan)}, r"normals must be finite"),
        (lambda a: {**a, "basis": a["basis"][:, :, :2]}, r"basis must have shape \(4, m, 3, 3\)"),
        (lambda a: {**a, "basis": a["basis"][:, :0]}, r"with m >= 1"),
        (lambda a: {**a, "k_max": 0.0}, r"k_max must be a finite number > 0"),
        (lambda a: {**a, "solves": 0}, r"solves must be an integer >= 1"),
        (lambda a: {**a, "solves": True}, r"solves must be an integer >= 1"),
        (lambda a: {**a, "directions": "up"}, r"directions must be finite real numbers"),
    ],
)
def test_grip_along_refuses_what_its_kernel_cannot_read(change, match):
    """Shapes that do not agree would make the compiled kernel read past an array's end."""
    from grasp_env.mechanics import directions

    rng = np.random.default_rng(0)
    good = {
        "directions": rng.normal(size=(4, 3, 3)),
        "forces": rng.normal(size=(4, 3, 3)),
        "basis": rng.normal(size=(4, 3, 3, 3)),
        "normals": rng.normal(size=(4, 3, 3)),
        "k_max": 2.0,
        "solves": 3,
    }
    k, weights = directions.grip_along(**good)
    assert np.isfinite(k).all() and k.shape == (4, 3)
    with pytest.raises(ValueError, match=match):
        directions.grip_along(**change(good))
    # collinear contacts: every pair along x, and every direction too: no grip is determined
    collinear = {**good, "basis": np.zeros((4, 3, 3, 3)), "directions": np.zeros((4, 3, 3))}
    for q, (i, j) in enumerate(contact_pairs(3)):
        collinear["basis"][:, q, i, 0], collinear["basis"][:, q, j, 0] = 1.0, -1.0
    collinear["directions"][..., 0] = 1.0
    with pytest.raises(ValueError, match=r"singular for grasps \[0, 1, 2, 3\]"):
        directions.grip_along(**collinear)
    with pytest.raises(ValueError, match=r"grad_k must have shape \(4, 3\)"):
        directions.grip_along_gradient(
            good["directions"], good["forces"], good["basis"], weights, k, k[:, :2]
        )
