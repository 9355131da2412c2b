"""The solver benchmark's flop counting (benchmarks/limits.py): the interpreter that runs the
kernels' source with counted arithmetic against the closed forms counted by hand from the
kernels, and its solves against the compiled solver. No timing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasp_env.mechanics import PAPER_AXIS, Grasp, pose_rotation, scene_grasp, solve_minimax
from grasp_env.mechanics.minimax import Path
from grasp_env_agents.benchmarks import limits
from grasp_env_agents.benchmarks.bench_solver import (
    random_grasps,
    random_scene,
    stacked,
    trajectories,
)
from grasp_env_agents.benchmarks.limits import Counted, Interpreter, counted_array


def test_counted_arithmetic_counts_each_operation_once():
    interpreter = Interpreter()
    limits._Tally.current = interpreter.own["test"]
    try:
        x = Counted(3.0)
        y = (x * 2 + 1) / x - x**2  # mul, add, div, mul (the square), sub
        z = 1.0 / Counted(0.0)  # the kernels' error model: inf, no exception
        w = -abs(x)  # sign operations: not counted
    finally:
        limits._Tally.current = [0] * len(limits.KINDS)
    assert y == pytest.approx((3.0 * 2 + 1) / 3.0 - 9.0)
    assert z == math.inf and w == -3.0
    assert dict(zip(limits.KINDS, interpreter.own["test"], strict=True)) == {
        "add": 2, "mul": 2, "div": 2, "sqrt": 0, "transcendental": 0,
    }  # fmt: skip


def frame_arrays(n: int) -> tuple[np.ndarray, ...]:
    """(k, a0, al, tau0, T) of a benchmark grasp at its optimum, as Counted arrays."""
    grasps, k_max = random_grasps(n, 1, seed=n)
    optimum = solve_minimax(grasps[0], k_max[0])
    return tuple(counted_array(x) for x in limits.newton_inputs(grasps[0], optimum.k))


@pytest.mark.parametrize("n", [3, 4])
def test_leaf_kernels_match_their_closed_forms(n):
    m = n * (n - 1) // 2
    k, a0, al, tau0, T = frame_arrays(n)
    interpreter = Interpreter()
    a, rho, theta = (counted_array(np.zeros(n)) for _ in range(3))
    tau = counted_array(np.zeros((n, 2)))
    interpreter.kernel("evaluate")(k, a0, al, tau0, T, a, tau, rho, theta)
    assert min(a) > 0 and min(rho) > 0  # the closed forms' branch (atan, unit tangent)
    assert interpreter.total() == limits.evaluate_flops(n, m)
    for exact in (True, False):
        interpreter.reset()
        grad, H = counted_array(np.zeros(m)), counted_array(np.zeros((m, m)))
        interpreter.kernel("finger_derivatives")(
            exact, n - 1, Counted(0.5), a, tau, rho, al, T, grad, H
        )
        assert interpreter.total() == limits.finger_derivatives_flops(m, exact)
    rng = np.random.default_rng(n)
    for size in (1, m + n + 1, 2 * m + 2):
        A = counted_array(rng.normal(size=(size, size)) + 3 * np.eye(size))
        b = counted_array(rng.normal(size=size))
        solution = np.linalg.solve(np.array(A, float), np.array(b, float))
        interpreter.reset()
        assert interpreter.kernel("lu_solve")(A, b, size)
        assert interpreter.total() == limits.lu_solve_flops(size)
        np.testing.assert_allclose(np.array(b, float), solution, rtol=1e-10)


@pytest.mark.parametrize("n", [3, 4])
def test_interpreted_solve_is_the_compiled_one_and_its_units_add_up(n):
    m = n * (n - 1) // 2
    grasps, k_max = random_grasps(n, 2, seed=n + 10)
    interpreter = Interpreter()
    for g, K in zip(grasps, k_max, strict=True):
        interpreter.reset()
        k, lower, status, path = interpreter.solve(
            g.equilibrating, g.basis, g.normals, float(K), math.inf
        )
        compiled = solve_minimax(g, K)
        np.testing.assert_allclose(k, compiled.k, rtol=1e-12, atol=1e-12 * K)
        assert lower == pytest.approx(float(compiled.lower_bound), abs=1e-15)
        assert status == compiled.status
        assert path == limits.batch_paths([g], np.array([K]))[0]
        # evaluate's own code (its angles are the inline `angle`'s) per call: 6 m + 4 a finger
        evaluations = interpreter.calls["evaluate"]
        assert evaluations > 0
        assert sum(interpreter.own["evaluate"]) == evaluations * n * (6 * m + 4)
        # every operation belongs to exactly one kernel, and the solve's is the whole
        assert interpreter.inclusive["solve_one"] == interpreter.total()
        units = sum(interpreter.inclusive[kernel] for _, kernel, _ in limits.UNITS)
        assert 0 < units < interpreter.total()


def test_solve_count_weights_the_paths_of_the_batch():
    grasps, k_max = random_grasps(3, 24, seed=5)
    count = limits.count_solves(grasps, k_max, per_path=1)
    shares = [share for share, _ in count.paths.values()]
    assert sum(shares) == pytest.approx(1.0)
    assert count.flops == pytest.approx(sum(s * f for s, f in count.paths.values()))
    assert sum(count.kinds.values()) == pytest.approx(count.flops)
    assert count.rest > 0
    paths = limits.batch_paths(grasps, k_max)
    for code, (share, _) in count.paths.items():
        assert share == pytest.approx(np.mean(paths == code))


def test_newton_step_count_is_per_step():
    inputs = tuple(np.array(x, float) for x in frame_arrays(3))
    flops = limits.newton_step_flops(inputs)
    m, n = 3, 3
    dense = (
        limits.evaluate_flops(n, m)
        + n * limits.finger_derivatives_flops(m, True)
        + limits.lu_solve_flops(m + n + 1)
    )
    # the KKT matrix's zero blocks skip some of the elimination's row updates
    assert limits.evaluate_flops(n, m) + n * limits.finger_derivatives_flops(m, True) < flops
    assert flops < dense + 2 * m + n


def test_limit_refuses_an_unknown_mode():
    grasps, k_max = random_grasps(3, 4, seed=1)
    limit = limits.Limit(grasps, k_max, solve_minimax(grasps[0], k_max[0]).k)
    with pytest.raises(ValueError, match=r"single.*batched"):
        limit.measure("threads", 0.01)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf"])
@pytest.mark.fast
def test_bench_refuses_seconds_that_are_not_a_finite_positive_time(value, capsys):
    from grasp_env_agents.cli import main

    assert main(["bench", "solver", "--seconds", value]) == 2
    assert "--seconds must be a finite number > 0" in capsys.readouterr().err


@pytest.mark.parametrize("n", [3, 4])
def test_a_warm_interpreted_solve_is_the_compiled_one_and_costs_less(n):
    # one scene's first five poses, 1 degree apart, as the benchmark's trajectories
    scene = random_scene(np.random.default_rng(n), n)
    along = stacked([scene_grasp(scene, pose_rotation(PAPER_AXIS, np.radians(range(-15, -10))))])
    k_max = np.array([[2 * scene.weight]])
    compiled = solve_minimax(along, k_max, follows=np.arange(5) > 0)
    F, E, N = along.equilibrating[0], along.basis[0], along.normals[0]
    K = float(k_max[0, 0])
    previous = (compiled.k[0, 3], compiled.k[0, 2], compiled.angles[0, 3], F[3], E[3], N[3])
    k, lower, status, path = Interpreter().solve(F[4], E[4], N[4], K, math.inf, previous)
    assert path == Path.NEARBY  # the warm start certified it, as in the compiled batch
    np.testing.assert_allclose(k, compiled.k[0, 4], rtol=1e-12, atol=1e-12 * K)
    assert lower == pytest.approx(float(compiled.lower_bound[0, 4]), abs=1e-15)
    assert status == compiled.status[0, 4]
    cold, warm = limits.count_along(along, k_max, compiled, every=1)
    assert 0 < warm < cold


def test_a_warm_solve_keeps_the_previous_optimums_sets():
    # a benchmark trajectory on which one finger stays within 0.1 rad of the largest angle
    # without being at it: taken as active, Newton's method went to the KKT point with it
    # active (its multiplier negative) and back, two polishes and about ten steps
    along, k_max, follows = trajectories(3, seed=3)
    fields = ("positions", "normals", "equilibrating", "basis", "friction_limit")
    scene = Grasp(*(getattr(along, field)[48:49] for field in fields))
    compiled = solve_minimax(scene, k_max[48:49], follows=follows)
    below = compiled.angles[0, 5].max() - compiled.angles[0, 5]
    assert np.any((1e-3 < below) & (below < 0.1))
    F, E, N = scene.equilibrating[0], scene.basis[0], scene.normals[0]
    previous = (compiled.k[0, 4], compiled.k[0, 3], compiled.angles[0, 4], F[4], E[4], N[4])
    interpreter = Interpreter()
    *_, path = interpreter.solve(F[5], E[5], N[5], float(k_max[48, 0]), math.inf, previous)
    assert path == Path.NEARBY
    assert interpreter.calls["polish"] == 1
    steps = interpreter.edges[("polish", "lu_solve")]
    assert steps <= 2
    # the angles evaluated once after each step (at the start by finish_from, once), the
    # last time where the KKT residual (the gradients alone, no Hessian) is below CONVERGED
    assert interpreter.edges[("finish_from", "evaluate")] == 1
    assert interpreter.edges[("polish", "evaluate")] == steps


# ------------------------------------------------ the conic solver (five to eight contacts)


def conic_inputs(n: int) -> tuple:
    """barrier_steps' arguments for a random scene with n contacts, and the scene."""
    from grasp_env_agents.benchmarks import limits_conic
    from grasp_env_agents.benchmarks.general_scenes import general_scenes

    scenes = general_scenes(n, 1, seed=n)
    grasp, k_max, _ = scenes.one(0)
    return limits_conic.step_inputs(grasp, float(k_max)), scenes


def _counted(value):  # type: ignore[no-untyped-def]
    if isinstance(value, np.ndarray):
        return counted_array(value)
    return counted_array(np.array(value, float))[()]


@pytest.mark.parametrize("n", [5, 8])
def test_conic_leaf_kernels_match_their_closed_forms(n):
    from grasp_env_agents.benchmarks import limits_conic

    inputs, _ = conic_inputs(n)
    x, a0, al, tau0, T, box, K, _, ct, st, w, tb = inputs
    m, d = al.shape[1], al.shape[1] + 1
    assert m == 3 * n - 6 and box.shape[0] == n * (n - 1) // 2
    interpreter = limits_conic.ConicInterpreter()
    barrier = interpreter.kernel("barrier")
    for f in (math.inf, 50.0):  # a limit no force is near: every cone's branch inside
        for derivatives in (False, True):
            interpreter.reset()
            g, H = counted_array(np.zeros(d)), counted_array(np.zeros((d, d)))
            args = [_counted(v) for v in (x, a0, al, tau0, T, box, K, f, ct, st, w, tb)]
            value = barrier(*args, g, H, derivatives)
            assert value < math.inf  # inside the domain: the closed form's branch
            expected = limits_conic.barrier_flops(n, m, box.shape[0], f < math.inf, derivatives)
            assert interpreter.total() == expected
    rng = np.random.default_rng(n)
    for size in (1, d, 2 * d):
        A = rng.normal(size=(size, size))
        A = A @ A.T + size * np.eye(size)
        b = rng.normal(size=size)
        solution = np.linalg.solve(A, b)
        interpreter.reset()
        cb = counted_array(b)
        assert interpreter.kernel("cholesky_solve")(counted_array(A), cb)
        assert interpreter.total() == limits_conic.cholesky_flops(size)
        np.testing.assert_allclose(np.array(cb, float), solution, rtol=1e-10)
    # the rate's step: the barrier, the Jacobi scaling (d square roots and divisions, 2 d^2
    # products, d regularisations, d right-hand sides), Cholesky, the update (3 d) and the sum
    step = limits_conic.barrier_step_flops(inputs)
    dense = limits_conic.barrier_flops(n, m, box.shape[0], False, True)
    assert step == dense + limits_conic.cholesky_flops(d) + 2 * d * d + 7 * d + 1


#: A scene of general_scenes(5, ..., seed=5) whose active-set attempt leaves a gap that the
#: barrier search closes.
FALLBACK_SCENE = 17


def test_interpreted_conic_solve_is_the_compiled_one_and_its_units_add_up():
    from grasp_env_agents.benchmarks import limits_conic
    from grasp_env_agents.benchmarks.general_scenes import general_scenes

    scenes = general_scenes(5, FALLBACK_SCENE + 1, seed=5)
    m = 3 * 5 - 6
    # the first scene: the active-set attempt certifies it (its SQP, then the KKT polish),
    # no barrier level solved
    grasp, k_max, _ = scenes.one(0)
    count = limits_conic.count_conic([grasp], np.array([k_max]))
    assert count.counted == 1 and count.departed == 0  # the compiled path, interpreted
    sqp, kkt = count.units["SQP step"], count.units["KKT Newton step"]
    assert sqp >= 1 and kkt >= 1
    assert count.units["barrier Newton step"] == 0 and count.units["level"] == 0
    # the SQP's steps and the polish's are most of the solve, not all of it
    assert 0.5 * count.flops < sqp * count.sqp_step + kkt * count.kkt_step < count.flops
    assert count.svd == limits_conic.svd_flops(15, 10)
    # FALLBACK_SCENE: the attempt leaves a gap, the barrier search runs after it
    grasp, k_max, _ = scenes.one(FALLBACK_SCENE)
    count = limits_conic.count_conic([grasp], np.array([k_max]))
    assert count.counted == 1 and count.departed == 0
    steps, sqp = count.units["barrier Newton step"], count.units["SQP step"]
    kkt = count.units["KKT Newton step"]
    assert steps > 0 and count.units["level"] >= 1 and sqp >= 1
    # the attempt's steps and the barrier's (each with its line search) are most of that
    # solve, not all of it
    stepped = steps * count.barrier_step + sqp * count.sqp_step + kkt * count.kkt_step
    assert 0.5 * count.flops < stepped < count.flops
    assert count.barrier_step > limits_conic.barrier_flops(5, m, 10, False, True)
