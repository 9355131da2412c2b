"""The certified minimax optimiser's batches: batched equals single, a forked child, following
poses, zero load, and any size and weight.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest
from minimax_helpers import GAP, random_scene, stack_of

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    START_ROTATION,
    Grasp,
    Scene,
    Status,
    Trajectory,
    grasp,
    load_wrench,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)


@pytest.mark.fast
def test_batched_equals_single() -> None:
    rng = np.random.default_rng(5)
    scene, _ = random_scene(rng, 3)
    rotations = pose_rotation(PAPER_AXIS, np.deg2rad(np.linspace(-15, 15, 6))).reshape(2, 3, 3, 3)
    g = scene_grasp(scene, rotations)
    batch = solve_minimax(g, 2 * scene.weight)
    assert batch.k.shape == (2, 3, 3) and batch.angles.shape == (2, 3, 3)
    assert batch.lower_bound.shape == batch.status.shape == (2, 3)
    for index in np.ndindex(2, 3):
        single = solve_minimax(scene_grasp(scene, rotations[index]), 2 * scene.weight)
        np.testing.assert_array_equal(single.k, batch.k[index])
        assert single.status == batch.status[index]
    # k_max broadcasts against the batch
    per_pose = solve_minimax(g, np.full((2, 3), 2 * scene.weight))
    np.testing.assert_array_equal(per_pose.k, batch.k)


def _solve_in_child(g: Grasp, k_max: float, out) -> None:
    out.put(solve_minimax(g, k_max).k)


def test_a_forked_child_solves_batches() -> None:
    """SubprocVecEnv and Ray fork workers: a batch big enough for the solver's threads must be
    solved in the child too (the parent's pool has no threads there)."""
    import multiprocessing

    rng = np.random.default_rng(6)
    scene, _ = random_scene(rng, 3)
    g = scene_grasp(scene, pose_rotation(PAPER_AXIS, np.deg2rad(np.linspace(-15, 15, 256))))
    parent = solve_minimax(g, 2 * scene.weight).k  # the parent's pool now has its threads
    context = multiprocessing.get_context("fork")
    out = context.Queue()
    child = context.Process(target=_solve_in_child, args=(g, 2 * scene.weight, out))
    child.start()
    try:
        k = out.get(timeout=60)
    finally:
        child.join(10)
        if child.is_alive():
            child.kill()
    np.testing.assert_array_equal(k, parent)


@pytest.mark.parametrize(("n", "f_max"), [(3, None), (3, 12.0), (4, None)])
@pytest.mark.fast
def test_following_poses_reach_the_same_certified_optima(n: int, f_max: float | None) -> None:
    """Warm starts along trajectories change where the solver starts, not what it certifies;
    and the results do not depend on how the batch is split between threads."""
    rng = np.random.default_rng(11 + n)
    rotations = pose_rotation(PAPER_AXIS, np.deg2rad(np.arange(-15.0, 16.0)))
    scenes = [random_scene(rng, n)[0] for _ in range(6)]
    poses = [scene_grasp(s, rotations) for s in scenes]
    g = Grasp(*(np.stack([getattr(p, f.name) for p in poses]) for f in fields(Grasp)))
    k_max = np.array([2 * s.weight for s in scenes])[:, None]
    follows = np.arange(len(rotations)) > 0
    cold = solve_minimax(g, k_max, f_max)
    warm = solve_minimax(g, k_max, f_max, follows=follows)
    np.testing.assert_array_equal(warm.status, cold.status)
    np.testing.assert_allclose(warm.max_angle, cold.max_angle, rtol=0, atol=GAP)
    assert np.all(warm.gap <= GAP) and np.all(warm.gap >= 0)
    for e, scene in enumerate(scenes):  # one trajectory at a time: no threads
        alone = solve_minimax(scene_grasp(scene, rotations), k_max[e], f_max, follows=follows)
        np.testing.assert_array_equal(alone.k, warm.k[e])


@pytest.mark.parametrize(("n", "f_max"), [(3, None), (3, 1.0), (4, None), (4, 1.0)])
@pytest.mark.fast
def test_zero_load(n: int, f_max: float | None) -> None:
    """No load at all: k = 0 holds it with no force, every angle 0, certified; nothing NaN."""
    scene = Scene.on_faces(PAPER_FACES if n == 3 else FOUR_FINGER_FACES)
    g = grasp(scene.relative_contacts(), scene.normals, START_ROTATION, load_wrench(0.0), 0.5)
    for result in (solve_minimax(g, 1.0, f_max), solve_minimax(stack_of(g, 3), 1.0, f_max)):
        for array in (result.k, result.angles, result.lower_bound):
            assert np.all(np.isfinite(array))
        assert np.all(result.k == 0) and np.all(result.max_angle == 0)
        assert np.all(result.gap == 0) and np.all(result.status == Status.INTERIOR)


@pytest.mark.parametrize("n", [3, 4])
def test_any_weight_gives_the_same_angles(n: int) -> None:
    """Weights from 1e-300 to 1e300 N with k_max and f_max in proportion: the same angles
    (the solver works in units of the load; squaring the forces would under- or overflow)."""
    rng = np.random.default_rng(30 + n)
    faces = PAPER_FACES if n == 3 else FOUR_FINGER_FACES
    offsets, cg = rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(-0.1, 0.1, 3)
    rotation = pose_rotation(PAPER_AXIS, 0.2)

    def solve(weight: float, f_ratio: float | None) -> object:
        scene = Scene.on_faces(faces, offsets=offsets, weight=weight, cg_offset=cg)
        f_max = None if f_ratio is None else f_ratio * weight
        return solve_minimax(scene_grasp(scene, rotation), 2 * weight, f_max)

    free = solve(1.0, None)
    scene = Scene.on_faces(faces, offsets=offsets, cg_offset=cg, weight=1.0)
    binding = 0.9 * np.linalg.norm(scene_grasp(scene, rotation).forces(free.k), axis=-1).max()
    for f_ratio in (None, binding):
        unit = solve(1.0, f_ratio)
        assert unit.status != Status.NOT_PUSHING and unit.gap <= GAP
        for weight in 10.0 ** np.arange(-300, 301, 50):
            result = solve(weight, f_ratio)
            assert result.status == unit.status and 0 <= result.gap <= GAP
            np.testing.assert_allclose(result.angles, unit.angles, rtol=0, atol=2 * GAP)
            np.testing.assert_allclose(result.k / weight, unit.k, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("n", [3, 4])
def test_any_size_and_weight_give_the_same_optimum(n: int) -> None:
    """Boxes of 1e-6 to 1e6 m with loads of 1e-300 to 1e300 N: the unit scene's optimum, to
    rounding (the equilibrating forces are computed in units of the contacts' spread and of
    the load; in metres and newtons they were wrong at the extremes, yet certified)."""
    rng = np.random.default_rng(40 + n)
    faces = PAPER_FACES if n == 3 else FOUR_FINGER_FACES
    offsets, cg = rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(-0.1, 0.1, 3)
    rotation = Trajectory().rotations()[rng.integers(31)]

    def solve(size: float, weight: float) -> object:
        scene = Scene.on_faces(
            faces, offsets=offsets, size=size, weight=weight, cg_offset=cg * size
        )
        return solve_minimax(scene_grasp(scene, rotation), 2 * weight)

    unit = solve(1.0, 1.0)
    assert unit.max_angle > 0.05 and unit.gap <= GAP  # a scene whose optimum is not trivial
    for size in 10.0 ** np.arange(-6, 7, 2):
        for weight in 10.0 ** np.arange(-300, 301, 100):
            result = solve(size, weight)
            assert result.status == unit.status and 0 <= result.gap <= GAP
            np.testing.assert_allclose(result.angles, unit.angles, rtol=0, atol=1e-12)
