"""The cube grasp family: hold the paper's cube (or a random grasp of it) along a trajectory,
choosing the interaction forces at every pose; `grasp_env/CubeGrasp-v0`,
`grasp_env/CubeGraspRandom-v0`, `grasp_env/CubeGrasp4-v0` and their `...Mujoco-v0` forms.

Modules by role: ``scenes`` (scenes and their trajectories as arrays, explicit or sampled),
``episodes`` (everything precomputed at reset), ``env`` (the single environments),
``vector`` (the batched vector environments) and ``mujoco_vector`` (the vector environments
of the MuJoCo ids). The step's kernels, the observation layout and the expert are the
environments' common ones (:mod:`grasp_env.envs.kernels`, :mod:`grasp_env.envs.observation`,
:mod:`grasp_env.envs.expert`).
"""

from .env import FOUR_FINGER_FACES, CubeGraspEnv, CubeGraspRandomEnv
from .mujoco_vector import CubeGraspMujocoVectorEnv, CubeGraspRandomMujocoVectorEnv
from .vector import CubeGraspRandomVectorEnv, CubeGraspVectorEnv

__all__ = [
    "FOUR_FINGER_FACES",
    "CubeGraspEnv",
    "CubeGraspMujocoVectorEnv",
    "CubeGraspRandomEnv",
    "CubeGraspRandomMujocoVectorEnv",
    "CubeGraspRandomVectorEnv",
    "CubeGraspVectorEnv",
]
