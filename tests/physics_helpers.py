"""Shared by the MuJoCo physics tests (tests/test_physics_*.py): force sets at a chosen
friction angle, the paper's grips along its trajectory and a short gait."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_AXIS,
    PHI,
    Scene,
    Trajectory,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)
from grasp_env_agents.studies.agreement import (
    force_set_k,
)


def forces_at_angle(scene: Scene, alpha_deg: float, angle_deg: float, seed: int = 0):
    """A force set on ``scene`` whose max friction angle is ``angle_deg`` exactly."""
    rotation = pose_rotation(PAPER_AXIS, np.radians(alpha_deg))
    grasp = scene_grasp(scene, rotation)
    optimum = solve_minimax(grasp, 2 * scene.weight)
    target = np.radians(angle_deg)
    k = force_set_k(
        grasp, optimum.k, np.array([target]), np.random.default_rng(seed), 4 * scene.weight
    )[0]
    assert np.all(np.isfinite(k)), "no force set found at the target angle"
    assert np.degrees(grasp.angles(k).max()) == pytest.approx(angle_deg, abs=1e-9)
    return rotation, grasp.forces(k)


def paper_grips(mu: float):
    """The paper's scene at ``mu`` along its trajectory: the optimum and the equal-k grip."""
    scene = Scene(mu=mu)
    rotations = Trajectory().rotations()
    grasp = scene_grasp(scene, rotations)
    optimum = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    equal_k = grasp.forces(scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(3))
    return scene, rotations, optimum, equal_k


#: A short gait for the tests: the paper's axis from -15 to 15 deg, one window, one finger
#: placed (at alpha = -9 deg).
SHORT_GAIT = (Trajectory(tuple(PAPER_AXIS), -15.0, 15.0, 1.0),)
