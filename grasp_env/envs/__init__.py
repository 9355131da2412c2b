"""Gymnasium environments of the grasp, one folder per family, single and batched vector
environments, an SB3 adapter (:mod:`grasp_env.envs.sb3`) and the minimax expert as a policy.

The families: ``cube_grasp`` (the paper's cube held along a trajectory: `CubeGrasp-v0`,
`CubeGraspRandom-v0`, `CubeGrasp4-v0` and their MuJoCo forms), ``gait`` (a hand with reach
phasing fingers out and in: `CubeGait-v0`, `CubeGaitMoves-v0`) and ``object_grasp`` (any
object held by 3 to 8 contacts, padded with a mask: `ObjectGrasp-v0`,
`ObjectGraspRandom-v0`). What the families share lives here: ``observation`` (the
observation vector), ``kernels`` (the compiled step and pose geometry), ``expert`` (the
optimiser as a policy), ``spec`` (the keywords' records), ``validation`` (keyword checks) and
``sb3``.
``vector`` and ``mujoco_vector`` are the public paths of the cube grasp family's vector
environments.
"""

from .cube_grasp import (
    CubeGraspEnv,
    CubeGraspRandomEnv,
    CubeGraspRandomVectorEnv,
    CubeGraspVectorEnv,
)
from .expert import MinimaxExpert
from .observation import ObservationLayout

__all__ = [
    "CubeGraspEnv",
    "CubeGraspRandomEnv",
    "CubeGraspRandomVectorEnv",
    "CubeGraspVectorEnv",
    "MinimaxExpert",
    "ObservationLayout",
]
