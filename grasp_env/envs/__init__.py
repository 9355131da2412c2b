"""Gymnasium environments of the grasp: single and batched vector environments, an SB3 adapter
(:mod:`grasp_env.envs.sb3`) and the minimax expert as a policy.

Modules by role: ``observation`` (the observation vector), ``scenes`` (scenes and their
trajectories as arrays, explicit or sampled), ``episodes`` (everything precomputed at reset),
``kernels`` (the compiled step and pose geometry), ``expert`` (the optimiser as a policy),
``validation`` (keyword checks), ``cube_grasp`` (the single environments) and ``vector``.
"""

from .cube_grasp import CubeGraspEnv, CubeGraspRandomEnv
from .expert import MinimaxExpert
from .observation import ObservationLayout
from .vector import CubeGraspRandomVectorEnv, CubeGraspVectorEnv

__all__ = [
    "CubeGraspEnv",
    "CubeGraspRandomEnv",
    "CubeGraspRandomVectorEnv",
    "CubeGraspVectorEnv",
    "MinimaxExpert",
    "ObservationLayout",
]
