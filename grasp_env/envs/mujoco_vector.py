"""The public path of the cube grasp family's MuJoCo vector environments (the ``...Mujoco-v0``
ids' ``vector_entry_point`` named it): they live in
:mod:`grasp_env.envs.cube_grasp.mujoco_vector`."""

from .cube_grasp.mujoco_vector import (
    CubeGraspMujocoVectorEnv,
    CubeGraspRandomMujocoVectorEnv,
    trajectory_rotations,
)

__all__ = ["CubeGraspMujocoVectorEnv", "CubeGraspRandomMujocoVectorEnv", "trajectory_rotations"]
