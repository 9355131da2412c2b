"""The rollout engine's shortcuts (issue 17) give the same runs as the plain path."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_env.mechanics import Scene, Trajectory, scene_grasp, solve_minimax
from grasp_env.physics import SETTINGS, TrajectoryChecker
from grasp_env.physics.motion import plan_motion, plan_poses
from grasp_env.physics.simulation import PhysicsModel, simulate


@pytest.fixture(scope="module")
def paper():
    scene = Scene(mu=0.1)
    rotations = Trajectory().rotations()
    grasp = scene_grasp(scene, rotations)
    return scene, rotations, grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)


def test_batched_pose_plans_are_the_one_pose_plans(paper):
    scene, rotations, forces = paper
    forces = forces.copy()
    forces[3, 1] = 1e-6 * scene.weight * np.array([0.0, 0.0, 1.0])  # released
    contact = np.ones((len(rotations), 3), dtype=bool)
    contact[5, 2] = False
    forces[5, 2] = 0.0
    batch = plan_poses(scene, rotations, forces, contact, SETTINGS)
    for b, motion in enumerate(batch):
        alone = plan_motion(scene, rotations[b : b + 1], forces[b : b + 1], contact[b : b + 1],
                            SETTINGS)  # fmt: skip
        assert motion.settle_steps == alone.settle_steps
        for name in ("forces", "load", "contact", "pose", "rotations"):
            np.testing.assert_array_equal(getattr(motion, name), getattr(alone, name), name)
    assert not batch[3].contact[:, 1].any() and not batch[5].contact[:, 2].any()
    with pytest.raises(ValueError, match="finger 1 is out of contact at pose 4"):
        bad = contact.copy()
        bad[4, 1] = False
        plan_poses(scene, rotations, forces, bad, SETTINGS)


def test_initial_states_are_cached_but_handed_out_as_copies(paper):
    scene = paper[0]
    physics = PhysicsModel(scene, SETTINGS["timestep"], SETTINGS["settle_mu"])
    contact = np.array([True, False, True])
    first = physics.initial_state(contact)
    first[:] = np.nan
    again = physics.initial_state(contact)
    assert np.all(np.isfinite(again))
    assert not np.array_equal(again, physics.initial_state(np.ones(3, dtype=bool)))


def test_runs_of_different_lengths_share_a_batch_unchanged(paper):
    # Padded runs are measured over their own steps only: the same traces as alone.
    scene, rotations, forces = paper
    checker = TrajectoryChecker(scene)
    motions = [checker.plan(rotations[:n], forces[:n]) for n in (2, 5, 3, 5)]
    batch = simulate([(checker.physics, m) for m in motions], threads=2)
    for motion, trace in zip(motions, batch, strict=True):
        (alone,) = simulate([(checker.physics, motion)], threads=1)
        assert len(trace.slip) == len(motion)
        for name in ("qpos", "slip", "speed", "gap", "drift", "rotation", "measured"):
            np.testing.assert_array_equal(getattr(trace, name), getattr(alone, name), name)
        assert trace.diverged == alone.diverged


def test_measured_rotations_are_quaternion_matrix_bit_for_bit():
    from grasp_env.mechanics import quaternion_matrix
    from grasp_env.physics.simulation import _rotations

    rng = np.random.default_rng(3)
    quaternions = rng.normal(size=(4, 50, 4))
    quaternions[0, :10] = [1.0, 0.0, 0.0, 0.0]
    quaternions[1, :10, 1:] *= 1e-9  # near the identity, as a held grasp's
    rotations = _rotations(quaternions)
    expected = quaternion_matrix(quaternions)
    np.testing.assert_array_equal(rotations, expected)
    np.testing.assert_array_equal(np.signbit(rotations), np.signbit(expected))
    # The layout too: numpy may take another product kernel for another one.
    assert rotations.flags.c_contiguous
    np.testing.assert_array_equal(rotations @ [0.3, -0.2, 0.1], expected @ [0.3, -0.2, 0.1])
