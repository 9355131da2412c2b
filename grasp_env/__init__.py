"""grasp-env: grip-force optimisation of multi-fingered grasps as Gymnasium environments.

``import grasp_env`` registers the environments (namespace ``grasp_env``)::

    import gymnasium as gym
    import grasp_env

    env = gym.make("grasp_env/CubeGrasp-v0")
    envs = gym.make_vec("grasp_env/CubeGraspRandom-v0", num_envs=64,
                        vectorization_mode="vector_entry_point")
"""

from gymnasium.envs.registration import register, registry

from .expert import MinimaxExpert

__version__ = "0.2.0"

_FOUR_FINGERS = {"faces": ("-x", "-y", "-z", "+z")}
_ENVS = {
    # id: (single class, vector class or None, kwargs)
    "CubeGrasp-v0": ("CubeGraspEnv", "CubeGraspVectorEnv", {}),
    "CubeGraspRandom-v0": ("CubeGraspRandomEnv", "CubeGraspRandomVectorEnv", {}),
    "CubeGrasp4-v0": ("CubeGraspEnv", "CubeGraspVectorEnv", _FOUR_FINGERS),
    # MuJoCo checks every step (about 13 ms): no batched vector env for these.
    "CubeGraspMujoco-v0": ("CubeGraspEnv", None, {"physics": "mujoco"}),
    "CubeGraspRandomMujoco-v0": ("CubeGraspRandomEnv", None, {"physics": "mujoco"}),
    "CubeGrasp4Mujoco-v0": ("CubeGraspEnv", None, {**_FOUR_FINGERS, "physics": "mujoco"}),
}
ENV_IDS = tuple(f"grasp_env/{name}" for name in _ENVS)

for _name, (_single, _vector, _kwargs) in _ENVS.items():
    if f"grasp_env/{_name}" not in registry:
        register(
            id=f"grasp_env/{_name}",
            entry_point=f"grasp_env.envs.cube_grasp:{_single}",
            vector_entry_point=None if _vector is None else f"grasp_env.envs.vector:{_vector}",
            kwargs=_kwargs,
        )

__all__ = ["ENV_IDS", "MinimaxExpert", "__version__"]
