"""A Stable-Baselines3 ``VecEnv`` over the batched vector environments.

>>> from stable_baselines3 import PPO
>>> from stable_baselines3.common.vec_env import VecMonitor
>>> from grasp_env.envs.sb3 import SB3VecEnv
>>> venv = VecMonitor(SB3VecEnv("grasp_env/CubeGraspRandom-v0", num_envs=64))
>>> model = PPO("MlpPolicy", venv).learn(10_000)

SB3 resets a sub-environment in the step its episode ends; the adapter therefore runs the vector
environment in Gymnasium's ``SAME_STEP`` autoreset mode and hands SB3 the last observation as
``info["terminal_observation"]`` and ``info["TimeLimit.truncated"]`` for bootstrapping. The
per-step infos of SB3 are kept small (one dict per sub-environment); the full batched info of
the last step (theta, margins, expert reward, optimality gap, ...) is in :attr:`last_info`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv

try:
    from stable_baselines3.common.vec_env.base_vec_env import (
        VecEnv,
        VecEnvIndices,
        VecEnvObs,
        VecEnvStepReturn,
    )
except ModuleNotFoundError as missing:  # the library installs without the learning stack
    module = (missing.name or "").split(".")[0]
    raise ImportError(
        f"grasp_env.envs.sb3 needs Stable-Baselines3 and torch ({module} is not installed): "
        'they come with the agents extra, pip install "torch==2.13.0" "grasp-env[agents]"'
    ) from missing

from .validation import check_seed


def _is_grasp_env_vector(env: Any) -> bool:
    """Whether ``env`` is one of grasp_env's batched vector environments (every family's has
    a ``template`` single environment that holds the shared configuration)."""
    return (
        isinstance(env, VectorEnv)
        and type(env).__module__.startswith("grasp_env.envs.")
        and hasattr(env, "template")
    )


class SB3VecEnv(VecEnv):
    """SB3 view of ``gym.make_vec(env_id, num_envs, vectorization_mode="vector_entry_point")``.

    Args:
        env: an environment id (``"grasp_env/CubeGrasp-v0"``, ...) or a vector environment
            made with ``autoreset_mode=AutoresetMode.SAME_STEP``.
        num_envs: number of sub-environments (with an id).
        **kwargs: keywords of the environment (with an id).
    """

    def __init__(self, env: str | VectorEnv, num_envs: int = 1, **kwargs: Any) -> None:
        if isinstance(env, str):
            env = gym.make_vec(
                env,
                num_envs=num_envs,
                vectorization_mode="vector_entry_point",
                autoreset_mode=AutoresetMode.SAME_STEP,
                **kwargs,
            )
        elif kwargs:
            raise ValueError("keywords are for an environment id, not for an existing env")
        if not _is_grasp_env_vector(getattr(env, "unwrapped", None)):
            raise ValueError(f"expected a grasp_env vector environment, got {env!r}")
        if env.metadata.get("autoreset_mode") != AutoresetMode.SAME_STEP:
            raise ValueError("the vector environment must use AutoresetMode.SAME_STEP")
        self.venv = env
        self.last_info: dict[str, Any] = {}
        self._actions: np.ndarray | None = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seeds seed, seed + 1, ... for the next reset (SB3's convention); an integer >= 0."""
        return super().seed(check_seed("seed", seed))

    def reset(self) -> VecEnvObs:
        seed: Sequence[int | None] | None = None
        if any(s is not None for s in self._seeds):
            seed = self._seeds
        options = None
        if any(self._options):
            if any(o != self._options[0] for o in self._options):
                raise ValueError("all sub-environments must get the same reset options")
            options = self._options[0]
        observations, self.last_info = self.venv.reset(seed=seed, options=options)
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, terminated, truncated, info = self.venv.step(self._actions)
        self.last_info = info
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = info["final_obs"][i]
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        return observations, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def _indices(self, indices: VecEnvIndices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Attributes of the sub-environments (they share one configuration)."""
        value = getattr(self.venv.unwrapped.template, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise NotImplementedError("the batched sub-environments share one configuration")

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **kwargs: Any
    ) -> list[Any]:
        raise NotImplementedError("the batched sub-environments are not separate objects")

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        return [False for _ in self._indices(indices)]


__all__ = ["SB3VecEnv"]
