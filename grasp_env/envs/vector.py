"""The public path of the cube grasp family's vector environments (the registered ids'
``vector_entry_point`` named it): they live in :mod:`grasp_env.envs.cube_grasp.vector`."""

from .cube_grasp.vector import CubeGraspRandomVectorEnv, CubeGraspVectorEnv

__all__ = ["CubeGraspRandomVectorEnv", "CubeGraspVectorEnv"]
