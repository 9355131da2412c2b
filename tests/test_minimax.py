"""The certified minimax optimiser against an independent conic reference, and its properties."""

from __future__ import annotations

import importlib
import os
import pkgutil
import re
import subprocess
import sys
from dataclasses import fields

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    PHI,
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
from grasp_env_agents.benchmarks.reference_solver import ConeBisection
from grasp_env_agents.benchmarks.study_solver import (
    certificate_failures,
    issue_scenes,
    reference_failures,
)

DEG = np.pi / 180
TOLERANCE = 1e-6 * DEG  # the accuracy required: the optimum within 1e-6 deg of the reference
GAP = 1e-9  # radians: the certificate the solver promises


def random_scene(rng: np.random.Generator, n: int) -> tuple[Scene, float]:
    """A scene near the paper's (contact offsets up to 0.35 of the face half-width, weight 1 to
    20 N, centre-of-gravity offsets up to 0.12), and alpha (radians) in [-15, 15] deg on the
    paper's trajectory."""
    faces = PAPER_FACES if n == 3 else FOUR_FINGER_FACES
    scene = Scene.on_faces(
        faces,
        offsets=rng.uniform(-0.35, 0.35, (n, 2)),
        weight=rng.uniform(1.0, 20.0),
        cg_offset=rng.uniform(-0.12, 0.12, 3),
    )
    return scene, np.deg2rad(rng.uniform(-15.0, 15.0))


@pytest.fixture(scope="module")
def references() -> dict[tuple[int, bool], ConeBisection]:
    return {(n, limit): ConeBisection(n, limit) for n in (3, 4) for limit in (False, True)}


#: Seeded random scans of each kind, on the wide ranges of benchmarks/study_solver.py's scenes
#: (every result must be certified there, not only near the paper's scene) unless named otherwise:
#: (fingers, force limit, k_max / w range, scenes checked for certificates, of them against cvxpy)
SCANS = {
    "3 fingers": (3, False, (0.5, 3.0), 300, 6),
    "4 fingers": (4, False, (0.5, 3.0), 300, 6),
    "3 fingers, f_max": (3, True, (0.5, 3.0), 300, 8),
    "4 fingers, f_max": (4, True, (0.5, 3.0), 300, 8),
    "3 fingers, tiny box": (3, False, (1e-9, 1e-9), 100, 3),
    "4 fingers, tiny box, f_max": (4, True, (1e-9, 1e-9), 100, 3),
    "3 fingers, boundary optima": (3, False, (0.02, 0.1), 100, 4),
    "4 fingers, boundary optima, f_max": (4, True, (0.1, 0.3), 100, 4),
}


@pytest.mark.parametrize("kind", list(SCANS))
def test_scan_against_conic_reference(references, kind: str) -> None:
    """Every result certified (gap <= 1e-9 rad, or NOT_PUSHING with lower_bound = pi/2), k in
    the box and within the force limits; a subsample agrees with bisection over cone
    feasibility (Clarabel): the same status, the optimum inside its bracket, each solver's
    bound consistent with the other's."""
    n, limit, k_ratio, count, compared = SCANS[kind]
    seed = list(SCANS).index(kind)
    scenes = issue_scenes(n, count, seed, force_limit=limit, k_ratio=k_ratio)
    result = solve_minimax(scenes.grasp, scenes.k_max, scenes.f_max)
    assert certificate_failures(scenes, result) == []
    failures, largest = reference_failures(scenes, result, np.arange(compared), references)
    assert failures == []
    assert largest <= TOLERANCE
    if "boundary" in kind:  # (small boxes leave many four-finger grasps not pushing)
        boundary = result.status == Status.BOUNDARY
        assert boundary.sum() >= 10
        assert np.mean(boundary[result.status != Status.NOT_PUSHING]) > 0.5


@pytest.mark.parametrize(("n", "count", "seed"), [(3, 16, 1), (4, 8, 2)])
@pytest.mark.fast
def test_matches_conic_reference(references, n: int, count: int, seed: int) -> None:
    """The paper's neighbourhood: optimal max angle within 1e-6 deg of the cone bisection."""
    rng = np.random.default_rng(seed)
    scenes = [random_scene(rng, n) for _ in range(count)]
    rotations = pose_rotation(PAPER_AXIS, np.array([alpha for _, alpha in scenes]))
    grasps = [scene_grasp(scene, r) for (scene, _), r in zip(scenes, rotations, strict=True)]
    errors = []
    for (scene, _), g in zip(scenes, grasps, strict=True):
        result = solve_minimax(g, 2 * scene.weight)
        ref = references[n, False].solve(g.equilibrating, g.basis, g.normals, 2 * scene.weight)
        assert not ref.not_pushing and result.status != Status.NOT_PUSHING
        errors.append(result.max_angle - ref.upper)
        # both certificates are consistent: neither bound crosses the other solver's bracket
        assert result.lower_bound <= ref.upper + 1e-12
        assert result.max_angle >= ref.lower - 1e-12
        assert 0 <= result.gap <= GAP
        # k attains the optimum (a finger released at the optimum carries 1e-10 of the load
        # along its normal: its small angle is rounding-sensitive, the maximum is not)
        assert abs(g.angles(result.k).max() - result.max_angle) <= 1e-12
        np.testing.assert_allclose(result.angles, g.angles(result.k), atol=1e-4)
        assert np.all(np.abs(result.k) <= 2 * scene.weight * (1 + 1e-12))
    assert np.max(np.abs(errors)) <= TOLERANCE


def test_force_limit_never_helps() -> None:
    """A tighter force limit cannot lower the optimum."""
    scenes = issue_scenes(4, 60, 7)
    free = solve_minimax(scenes.grasp, scenes.k_max)
    limited = solve_minimax(scenes.grasp, scenes.k_max, scenes.f_max)
    pushing = limited.status != Status.NOT_PUSHING
    assert np.all(limited.max_angle[pushing] >= free.max_angle[pushing] - 1e-12)


@pytest.mark.fast
def test_not_pushing_is_certified(references) -> None:
    """A load lifting the cube cannot be held by pushing fingers with small interaction."""
    scene = Scene(extra_force=(0.0, 0.0, 3 * 5.0))
    g = scene_grasp(scene, START_ROTATION)
    result = solve_minimax(g, 0.01)
    assert result.status == Status.NOT_PUSHING
    assert result.lower_bound == np.pi / 2 and result.max_angle >= np.pi / 2
    assert references[3, False].solve(g.equilibrating, g.basis, g.normals, 0.01).not_pushing
    # with room to squeeze, the fingers push again
    result = solve_minimax(g, 10.0)
    ref = references[3, False].solve(g.equilibrating, g.basis, g.normals, 10.0)
    assert result.status == Status.BOUNDARY and abs(result.max_angle - ref.upper) <= TOLERANCE


@pytest.mark.fast
def test_force_limit_below_the_load(references) -> None:
    """No k can hold 5 N with three fingers of 0.5 N each: certified, reported as not pushing."""
    g = scene_grasp(Scene(), START_ROTATION)
    result = solve_minimax(g, 10.0, f_max=0.5)
    assert result.status == Status.NOT_PUSHING and result.lower_bound == np.pi / 2
    assert np.all(np.isfinite(result.angles)) and np.all(np.isfinite(result.k))
    assert references[3, True].solve(g.equilibrating, g.basis, g.normals, 10.0, 0.5).not_pushing


@pytest.mark.fast
def test_paper_scene_zero_angle_and_eq8() -> None:
    """The paper's scene: 0 along the trajectory, and eq. 8's k = w tan(phi) / (3 sqrt 3)."""
    g = scene_grasp(Scene(), Trajectory().rotations())
    result = solve_minimax(g, 10.0)
    assert np.all(result.max_angle <= 1e-9) and np.all(result.status == Status.INTERIOR)
    np.testing.assert_allclose(result.k[15], 1.3608, atol=5e-5)  # alpha = 0


@settings(max_examples=25, deadline=None)
@given(weight=st.floats(0.1, 100.0))
@pytest.mark.fast
def test_eq8_for_any_weight(weight: float) -> None:
    result = solve_minimax(scene_grasp(Scene(weight=weight), START_ROTATION), 2 * weight)
    np.testing.assert_allclose(result.k, weight * np.tan(PHI) / (3 * np.sqrt(3)), rtol=1e-9)
    assert result.max_angle <= 1e-9


@pytest.mark.fast
def test_box_limits_the_paper_scene() -> None:
    """Below eq. 8's k the box binds: the optimum sits on it with a positive angle."""
    result = solve_minimax(scene_grasp(Scene(), START_ROTATION), 0.5)
    assert result.status == Status.BOUNDARY
    np.testing.assert_allclose(result.k, 0.5)
    assert result.max_angle > 1e-3 and 0 <= result.gap <= GAP


scene_parameters = {
    "n": st.sampled_from([3, 4]),
    "offsets": st.lists(st.floats(-0.35, 0.35), min_size=8, max_size=8),
    "cg": st.lists(st.floats(-0.12, 0.12), min_size=3, max_size=3),
    "weight": st.floats(1.0, 20.0),
    "alpha": st.floats(-15.0, 15.0),
}


def hypothesis_scene(n, offsets, cg, weight, alpha):
    faces = PAPER_FACES if n == 3 else FOUR_FINGER_FACES
    scene = Scene.on_faces(
        faces, offsets=np.reshape(offsets, (4, 2))[:n], weight=weight, cg_offset=cg
    )
    return scene, scene_grasp(scene, pose_rotation(PAPER_AXIS, np.deg2rad(alpha)))


@settings(max_examples=40, deadline=None)
@given(**scene_parameters, seed=st.integers(0, 2**32 - 1))
@pytest.mark.fast
def test_no_sampled_k_beats_the_certificate(n, offsets, cg, weight, alpha, seed) -> None:
    _, g = hypothesis_scene(n, offsets, cg, weight, alpha)
    k_max = 2 * weight
    result = solve_minimax(g, k_max)
    assert 0 <= result.gap <= GAP
    rng = np.random.default_rng(seed)
    m = result.k.shape[-1]
    uniform = rng.uniform(-k_max, k_max, (2000, m))
    near = np.clip(result.k + rng.normal(0, 1e-3 * k_max, (2000, m)), -k_max, k_max)
    sampled = g.angles(np.concatenate([uniform, near])).max(axis=-1)
    assert sampled.min() >= result.lower_bound


@settings(max_examples=25, deadline=None)
@given(**scene_parameters, factor=st.floats(0.1, 10.0))
def test_weight_scales_k_and_keeps_angles(n, offsets, cg, weight, alpha, factor) -> None:
    _, g = hypothesis_scene(n, offsets, cg, weight, alpha)
    _, g2 = hypothesis_scene(n, offsets, cg, weight * factor, alpha)
    one = solve_minimax(g, 2 * weight)
    two = solve_minimax(g2, 2 * weight * factor)
    assert abs(two.max_angle - one.max_angle) <= 2 * GAP
    # the optimal k is unique up to flat directions of the optimum, which are rare
    np.testing.assert_allclose(g.angles(two.k / factor).max(), one.max_angle, atol=2 * GAP)
    np.testing.assert_allclose(two.k, factor * one.k, rtol=1e-6, atol=1e-6 * weight * factor)


#: Four-finger scenes the solver does not certify (docs/solver.md, "Known failure"): contacts
#: at face centres but one or two, so the optimum is degenerate. (offsets, weight, alpha deg)
UNCERTIFIED_SCENES = [
    # found by hypothesis: the optimum is 0 with a finger at 1e-7 of the load, gap 2.4e-9 rad
    ([0.0, -2.220446049250313e-16, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0625], 0.109375, 0.0),
    # the grip optimal, the bound 4.7 deg below it
    ([-0.3, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0], 1.0, -13.0),
]


@pytest.mark.xfail(strict=True, reason="known: degenerate four-finger optima (docs/solver.md)")
@pytest.mark.parametrize(("offsets", "weight", "alpha"), UNCERTIFIED_SCENES)
def test_degenerate_four_finger_optima_are_certified(offsets, weight, alpha) -> None:
    _, g = hypothesis_scene(4, offsets, [0.0, 0.0, 0.0], weight, alpha)
    assert solve_minimax(g, 2 * weight).gap <= GAP


def test_where_the_certificate_fails_the_grip_is_still_the_references(references) -> None:
    """The second uncertified scene: its gap is reported (not hidden), its grip is cvxpy's
    bisection's, and the gap is the convex relaxation's. Fingers 2 and 3 face each other
    through the centre of gravity, so releasing fingers 0 and 1 *exactly* (P = 0, the
    cones' apex) leaves a two-finger pinch at a smaller angle; the certificate bounds that
    relaxation, so its bound cannot pass the pinch, while no grip in between has those
    fingers pushing at all (the cone problem's solutions there have exactly zero force,
    which the reference's slack test, s* <= 0, reads as infeasible at s* ~ 1e-14)."""
    import cvxpy as cp

    offsets, weight, alpha = UNCERTIFIED_SCENES[1]
    _, g = hypothesis_scene(4, offsets, [0.0, 0.0, 0.0], weight, alpha)
    result = solve_minimax(g, 2.0)
    assert result.gap > 0.05 and result.status != Status.NOT_PUSHING
    reference = references[(4, False)].solve(g.equilibrating, g.basis, g.normals, 2.0)
    assert reference.upper - reference.lower < 1e-9  # cvxpy brackets this one tightly
    assert abs(result.max_angle - reference.upper) < 1e-9

    def feasible(t: float, released: tuple[int, ...]) -> np.ndarray | None:
        """A k in the box with P_i = 0 for the released fingers, the others within t."""
        k = cp.Variable(6)
        constraints = [cp.abs(k) <= 2.0]
        for i in range(4):
            force = g.equilibrating[i] + g.basis[:, i, :].T @ k
            normal = g.normals[i] @ force
            if i in released:
                constraints.append(force == 0)
            else:
                constraints.append(cp.norm(force - normal * g.normals[i]) <= np.tan(t) * normal)
        problem = cp.Problem(cp.Minimize(0), constraints)
        problem.solve(solver=cp.CLARABEL)
        return k.value if problem.status == cp.OPTIMAL else None

    pinch = np.deg2rad(13.28)  # fingers 2 and 3 alone: 13.27 deg (cvxpy bisection)
    assert feasible(pinch, released=(0, 1)) is not None
    assert feasible(np.deg2rad(13.26), released=(0, 1)) is None
    assert result.lower_bound <= pinch < result.max_angle - np.deg2rad(3)
    # between the pinch and the grip, fingers 0 and 1 can push with no force at all
    k = cp.Variable(6)
    t = np.deg2rad(15.0)
    forces = [g.equilibrating[i] + g.basis[:, i, :].T @ k for i in range(4)]
    normals = [g.normals[i] @ forces[i] for i in range(4)]
    cones = [
        cp.norm(forces[i] - normals[i] * g.normals[i]) <= np.tan(t) * normals[i] for i in range(4)
    ]
    most = cp.Problem(cp.Maximize(normals[0] + normals[1]), [cp.abs(k) <= 2.0, *cones])
    most.solve(solver=cp.CLARABEL)
    assert most.status == cp.OPTIMAL and most.value < 1e-6  # (3.4 just above the grip)


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


def stack_of(g: Grasp, count: int) -> Grasp:
    return Grasp(*(np.stack([getattr(g, f.name)] * count) for f in fields(Grasp)))


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


@pytest.mark.parametrize("weight", [1e-306, 1e308])
def test_a_load_out_of_range_is_stated_at_its_scale(weight: float) -> None:
    """Beyond the load's range the message states its true scale (|F_i| squared would under-
    or overflow and read 0 or inf)."""
    rotation = Trajectory().rotations()[3]
    unit = scene_grasp(Scene(weight=1.0), rotation).equilibrating
    scale = re.escape(f"{weight * np.linalg.norm(unit, axis=-1).max():.3g}")
    g = scene_grasp(Scene(weight=weight), rotation)
    for value in (g, stack_of(g, 2)):
        with pytest.raises(ValueError, match=rf"within \[1e-305, 1e\+305\] N, got {scale} N"):
            solve_minimax(value, weight)


@pytest.mark.fast
def test_refused_scales() -> None:
    """Values float64 cannot hold beside the load are refused, naming the argument and range."""
    g = scene_grasp(Scene(), START_ROTATION)  # the load's scale: w / 3 = 1.667 N
    with pytest.raises(ValueError, match=r"k_max must be within \[1e-12, 1e\+12\] x the load"):
        solve_minimax(g, 1e-13)
    with pytest.raises(ValueError, match=r"k_max must be within .* got 1e\+13 N"):
        solve_minimax(g, 1e13)
    with pytest.raises(ValueError, match=r"f_max must be within .* got 1e-20 N"):
        solve_minimax(g, 10.0, 1e-20)
    with pytest.raises(ValueError, match=r"grasp 1 of the flattened batch"):
        solve_minimax(stack_of(g, 2), np.array([10.0, 1e20]))
    tiny = type(g)(g.positions, g.normals, g.equilibrating * 1e-310, g.basis, g.friction_limit)
    with pytest.raises(ValueError, match=r"load's scale .* must be 0 or within \[1e-305"):
        solve_minimax(tiny, 1e-310)


@pytest.mark.parametrize("normal", [(0.0, 0.0, 0.0), (0.0, 0.0, 2.0), (0.0, 0.0, np.nan)])
@pytest.mark.fast
def test_bad_normals(normal: tuple[float, float, float]) -> None:
    g = scene_grasp(Scene(), START_ROTATION)
    normals = g.normals.copy()
    normals[1] = normal
    bad = type(g)(g.positions, normals, g.equilibrating, g.basis, g.friction_limit)
    match = "contain NaN" if np.isnan(normal[2]) else "normals must be unit vectors"
    for value in (bad, stack_of(bad, 2)):
        with pytest.raises(ValueError, match=match):
            solve_minimax(value, 10.0)


@pytest.mark.parametrize(
    "k_max", [0.0, -1.0, np.nan, np.inf, None, "ten", [1.0, None], "10", True, np.True_, [1.0, "2"]]
)
@pytest.mark.fast
def test_bad_k_max(k_max: float) -> None:
    for rotation in (START_ROTATION, np.stack([START_ROTATION] * 2)):  # one grasp, a batch
        g = scene_grasp(Scene(), rotation)
        with pytest.raises(ValueError, match=r"k_max must (be finite and > 0|broadcast)"):
            solve_minimax(g, k_max)


@pytest.mark.parametrize("f_max", [0.0, -2.0, np.nan, np.inf, "2", True])
@pytest.mark.fast
def test_bad_f_max(f_max: float) -> None:
    g = scene_grasp(Scene(), START_ROTATION)
    with pytest.raises(ValueError, match="f_max must be finite and > 0"):
        solve_minimax(g, 10.0, f_max)


@pytest.mark.fast
def test_bad_shapes_and_values() -> None:
    g = scene_grasp(Scene(), Trajectory().rotations())
    for not_a_grasp in (None, Scene(), {"equilibrating": g.equilibrating}):
        with pytest.raises(ValueError, match=r"grasp must be a Grasp \(from scene_grasp\)"):
            solve_minimax(not_a_grasp, 10.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="must broadcast to the grasp's batch shape"):
        solve_minimax(g, np.ones(5))
    with pytest.raises(ValueError, match="follows must be boolean"):
        solve_minimax(g, 10.0, follows=np.ones(31))
    with pytest.raises(ValueError, match="follows must broadcast"):
        solve_minimax(g, 10.0, follows=np.ones(5, bool))
    bad = type(g)(g.positions, g.normals, g.equilibrating * np.nan, g.basis, g.friction_limit)
    with pytest.raises(ValueError, match="contain NaN or inf"):
        solve_minimax(bad, 10.0)
    bad = type(g)(g.positions, g.normals, g.equilibrating[..., :2, :], g.basis, g.friction_limit)
    with pytest.raises(ValueError, match="shape"):
        solve_minimax(bad, 10.0)


def test_the_solver_reads_no_positions_or_friction_limit():
    # What solve_minimax's docstring says it checks are the arrays it reads; the other two are
    # checked when a Grasp is made (tests/test_mechanics.py).
    g = scene_grasp(Scene.on_faces(offsets=[[0.3, 0.1], [-0.2, 0.3], [0.1, -0.3]]), START_ROTATION)
    other = type(g)(np.zeros((3, 3)), g.normals, g.equilibrating, g.basis, np.float64(0.0))
    result, same = solve_minimax(g, 10.0), solve_minimax(other, 10.0)
    assert result.max_angle > 0.01  # a scene whose optimum is not trivially zero
    for a, b in zip(same, result, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="grasp friction_limit must be finite angles"):
        type(g)(g.positions, g.normals, g.equilibrating, g.basis, np.float64(np.nan))


CALLEE = (
    "from grasp_env.mechanics.minimax.jit import kernel\n\n\n@kernel\ndef value():\n    return {}\n"
)
CALLER = (
    "from grasp_env.mechanics.minimax.jit import entry\n\nfrom .callee import value\n\n\n"
    "@entry\ndef call():\n    return value()\n"
)
KEYED = (
    "import os\n\nfrom grasp_env.mechanics.minimax import jit\n\n"
    "jit.register_package(os.path.dirname(__file__))\n"
)


def test_kernel_cache_follows_an_edited_callee(tmp_path) -> None:
    """numba checks only the cached function's own file, but its machine code holds its
    callees' from other modules; the kernels' cache is keyed on every module of their package,
    so an edit to a callee in another module recompiles the caller (run in subprocesses, on a
    small package made with the kernels' decorators, as the solver's would take a minute)."""
    package = tmp_path / "kernels_copy"
    package.mkdir()
    (package / "__init__.py").write_text(KEYED)
    (package / "caller.py").write_text(CALLER)
    script = (
        "from kernels_copy.caller import call; "
        "print(call(), sum(call.stats.cache_hits.values()), sum(call.stats.cache_misses.values()))"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}

    def run() -> list[int]:
        done = subprocess.run(
            [sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
        return [int(word) for word in done.stdout.split()]

    (package / "callee.py").write_text(CALLEE.format(1))
    assert run() == [1, 0, 1]  # compiled
    assert run() == [1, 1, 0]  # loaded from the cache
    (package / "callee.py").write_text(CALLEE.format(2))
    assert run() == [2, 0, 1]  # the caller's file did not change, yet it is compiled again
    assert run() == [2, 1, 0]


def test_every_kernel_is_keyed_on_its_package() -> None:
    """Every compiled function of the solver's package uses the package-keyed cache."""
    from numba.core.registry import CPUDispatcher

    import grasp_env.mechanics.minimax as package
    from grasp_env.mechanics.minimax import jit

    count = 0
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        for value in vars(module).values():
            if isinstance(value, CPUDispatcher) and value.__module__ == module.__name__:
                assert isinstance(value._cache._impl.locator, jit.LOCATORS), value
                count += 1
    assert count >= 30


@pytest.mark.fast
def test_every_way_in_reaches_the_one_compiled_signature() -> None:
    """The wheel ships numba's cache of the solver's entries as warm.py compiles them; any other
    array type (a read-only view, another dtype) would compile the whole solver again, minutes
    at a user's first command. Every way of calling solve_minimax reaches those same types."""
    from grasp_env.mechanics.minimax import driver
    from grasp_env.mechanics.minimax.warm import warm

    warm()
    scene = Scene.on_faces(offsets=[[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]])
    rotations = np.stack([pose_rotation(PAPER_AXIS, np.radians(a)) for a in (-5.0, 0.0, 5.0)])
    moving = scene_grasp(scene, rotations)
    arrays = [np.array(a) for a in (moving.positions, moving.normals, moving.equilibrating)]
    arrays.append(np.array(moving.basis, dtype=np.float32))  # another dtype
    for array in arrays:
        array.flags.writeable = False
    read_only = Grasp(*arrays, friction_limit=moving.friction_limit)
    follows = np.array([False, True, True])
    frozen = follows.copy()
    frozen.flags.writeable = False
    weight = 2.0 * scene.weight
    for kwargs in (
        {},
        {"follows": follows},  # as the environments pass it: the batch's own shape
        {"follows": frozen},
        {"follows": True},
        {"f_max": np.full(3, 4.0 * scene.weight)},
    ):
        solve_minimax(moving, weight, **kwargs)
    solve_minimax(read_only, 2, follows=follows)
    solve_minimax(scene_grasp(scene, rotations[1]), weight)
    assert len(driver.solve_batch.signatures) == 1, driver.solve_batch.signatures
    assert len(driver.solve_grasp.signatures) == 1, driver.solve_grasp.signatures


def test_stack_arrays_behave_as_numpys() -> None:
    """The kernels' stack arrays (linalg.stack_*): numpy's shapes, dtypes and values, each call
    site its own memory, every item of a full room writable, and an array beyond its room
    refused (there is no heap to fall back on)."""
    from numba import njit

    from grasp_env.mechanics.minimax.linalg import (
        LARGE_ITEMS,
        VECTOR_ITEMS,
        stack_copy,
        stack_empty,
        stack_large,
        stack_zeros,
    )

    @njit
    def made(n: int, items: int, large_rows: int):  # type: ignore[no-untyped-def]
        zeros = stack_zeros((n, 3))
        flags = stack_zeros(n, dtype=np.bool_)
        counts = stack_empty(n, dtype=np.int64)
        counts.fill(7)
        other = stack_zeros((n, 3))  # another call site: not the first's memory
        other[0, 0] = 1.0
        copied = stack_copy(other)
        other[0, 0] = 2.0
        full = stack_empty(items)
        for q in range(items):
            full[q] = q
        large = stack_large((large_rows, 24))
        large[large_rows - 1, 23] = 1.0
        # (copies on the heap: a stack array must not outlive its kernel)
        return zeros.copy(), flags.copy(), counts.copy(), copied.copy(), full.sum(), large.sum()

    zeros, flags, counts, copied, total, ones = made(4, VECTOR_ITEMS, LARGE_ITEMS // 24)
    assert zeros.shape == (4, 3) and zeros.dtype == np.float64 and not zeros.any()
    assert flags.dtype == np.bool_ and not flags.any()
    assert counts.dtype == np.int64 and (counts == 7).all()
    assert copied[0, 0] == 1.0 and copied.sum() == 1.0
    assert total == sum(range(VECTOR_ITEMS)) and ones == 1.0
    with pytest.raises(ValueError, match="beyond its room"):
        made(4, VECTOR_ITEMS + 1, 1)
    with pytest.raises(ValueError, match="beyond its room"):
        made(4, 1, LARGE_ITEMS // 24 + 1)


def test_lu_solve_matches_numpy_at_every_size() -> None:
    """linalg.lu_solve solves as numpy does at every size a solve uses, pivoting where the
    leading entry is zero, and refuses a singular matrix."""
    from numba import njit

    from grasp_env.mechanics.minimax.linalg import lu_solve

    @njit
    def solve(A, b):  # type: ignore[no-untyped-def]
        A, b = A.copy(), b.copy()
        return lu_solve(A, b, A.shape[0]), b

    rng = np.random.default_rng(0)
    for size in range(2, 12):
        for _ in range(5):
            A = rng.normal(size=(size, size))
            A[0, 0] = 0.0  # the first column needs a pivot
            b = rng.normal(size=size)
            ok, x = solve(A, b)
            assert ok and np.allclose(x, np.linalg.solve(A, b), rtol=1e-10, atol=1e-12), size
        A[-1] = A[0]  # two equal rows
        assert not solve(A, b)[0], size
