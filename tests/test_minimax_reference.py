"""The certified minimax optimiser against an independent conic reference, eq. 8, and its
certificate on sampled scenes.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from minimax_helpers import GAP, TOLERANCE, random_scene

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    PHI,
    START_ROTATION,
    Scene,
    Status,
    Trajectory,
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


@pytest.mark.parametrize(
    ("n", "count", "seed"), [(3, 16, 1), pytest.param(4, 8, 2, marks=pytest.mark.fast)]
)
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
