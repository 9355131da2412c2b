"""The certified minimax optimiser's refusals of bad input, and what it does not read."""

from __future__ import annotations

import re

import numpy as np
import pytest
from minimax_helpers import stack_of

from grasp_env.mechanics import (
    START_ROTATION,
    Scene,
    Trajectory,
    scene_grasp,
    solve_minimax,
)


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
    # checked when a Grasp is made (tests/test_mechanics_forces.py).
    g = scene_grasp(Scene.on_faces(offsets=[[0.3, 0.1], [-0.2, 0.3], [0.1, -0.3]]), START_ROTATION)
    other = type(g)(np.zeros((3, 3)), g.normals, g.equilibrating, g.basis, np.float64(0.0))
    result, same = solve_minimax(g, 10.0), solve_minimax(other, 10.0)
    assert result.max_angle > 0.01  # a scene whose optimum is not trivially zero
    for a, b in zip(same, result, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="grasp friction_limit must be finite angles"):
        type(g)(g.positions, g.normals, g.equilibrating, g.basis, np.float64(np.nan))
