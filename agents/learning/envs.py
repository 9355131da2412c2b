"""Environments for training and evaluation: SB3 vector envs, and a fixed set of held-out scenes.

:func:`make_vec_env` gives Stable-Baselines3 a vector environment: the batched numpy one of
``grasp_env`` where the id has one (``gym.make_vec(..., vectorization_mode=
"vector_entry_point")`` behind ``grasp_env``'s SB3 adapter), else SB3's ``DummyVecEnv``.

:class:`HeldOutScenes` makes every evaluation see the same scenes: it reseeds its environments
at every ``reset()`` (SB3's ``evaluate_policy`` resets once per evaluation), and it measures
each environment's first episode: the optimality gap and margin at every step, whether the
grasp held along the whole trajectory (also reported as ``info["is_success"]``, which SB3's
``EvalCallback`` logs), and the grip force used.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecMonitor

import grasp_env  # noqa: F401  (registers the environments)

#: Seeds of the held-out scenes: far from the training seeds (a run's seed + env index).
HELD_OUT_SEED = 1_000_000
#: Seeds of the scenes whose poses give a network its input statistics (:func:`sample_poses`),
#: apart from the training and held-out seeds: the same statistics for every seed of a config.
STATISTICS_SEED = 2_000_000


def make_vec_env(env_id: str, env_kwargs: dict[str, Any], n_envs: int, seed: int) -> VecEnv:
    """``n_envs`` environments as an SB3 ``VecEnv`` with episode statistics, seeded.

    Environment i draws its episodes from seed + i. Raises ValueError for keywords the
    environment does not accept.
    """
    venv = _vec_env(env_id, env_kwargs, n_envs)
    venv.seed(seed)
    return VecMonitor(venv)


def _vec_env(env_id: str, env_kwargs: dict[str, Any], n_envs: int) -> VecEnv:
    try:
        if gym.spec(env_id).vector_entry_point is not None:
            from grasp_env.envs.sb3 import SB3VecEnv

            return SB3VecEnv(env_id, num_envs=n_envs, **env_kwargs)
        return sb3_make_vec_env(env_id, n_envs=n_envs, env_kwargs=env_kwargs)
    except (TypeError, ValueError) as error:  # an unknown keyword or a bad value, as a config's
        raise ValueError(f"env_kwargs for {env_id}: {error}") from None


@dataclass
class Episode:
    """What one held-out episode measured (angles in radians, forces in newtons)."""

    gap: list[float] = field(default_factory=list)  # optimality gap at each step
    margin: list[float] = field(default_factory=list)  # min_i (theta_lim - theta_i)
    force: list[float] = field(default_factory=list)  # sum_i |P_i|
    max_theta: list[float] = field(default_factory=list)  # max_i theta_i
    expert_max_theta: list[float] = field(default_factory=list)  # the expert's, same pose
    limit: float = 0.0  # theta_lim
    alpha_deg: list[float] = field(default_factory=list)
    k: list[np.ndarray] = field(default_factory=list)
    expert_k: list[np.ndarray] = field(default_factory=list)
    held: bool = True  # no finger slipped at any step
    finished: bool = False


class HeldOutScenes(VecEnvWrapper):
    """The same ``num_envs`` scenes at every reset, and what happened in each first episode.

    Use ``num_envs`` equal to the number of evaluation episodes: SB3's ``evaluate_policy``
    then runs exactly one episode per environment, so the scenes are those of seeds
    ``seed, seed + 1, ...``.
    """

    def __init__(self, venv: VecEnv, seed: int = HELD_OUT_SEED) -> None:
        super().__init__(venv)
        self.held_out_seed = seed
        self.episodes: list[Episode] = []

    def reset(self) -> np.ndarray:
        self.venv.seed(self.held_out_seed)
        self.episodes = [Episode() for _ in range(self.num_envs)]
        return self.venv.reset()

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        info = batched_info(self.venv, infos)
        for i, episode in enumerate(self.episodes):
            if episode.finished:
                continue
            theta = info["theta"][i]
            episode.limit = float(theta[0] + info["margin"][i][0])
            episode.gap.append(float(info["optimality_gap"][i]))
            episode.margin.append(float(rewards[i]))
            episode.force.append(float(np.linalg.norm(info["contact_forces"][i], axis=-1).sum()))
            episode.max_theta.append(float(theta.max()))
            episode.expert_max_theta.append(episode.limit - float(info["expert_reward"][i]))
            episode.alpha_deg.append(float(info["alpha_deg"][i]))
            episode.k.append(np.array(info["k"][i]))
            episode.expert_k.append(np.array(info["expert_k"][i]))
            episode.held &= not bool(np.any(info["slip"][i]))
            if dones[i]:
                episode.finished = True
                infos[i]["is_success"] = episode.held
        return obs, rewards, dones, infos

    def metrics(self) -> dict[str, float]:
        """Summary of the finished episodes: see :func:`summarise`."""
        return summarise([e for e in self.episodes if e.finished])


def batched_info(venv: VecEnv, infos: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """The step's info as arrays over environments.

    grasp_env's SB3 adapter keeps the full batched info in ``last_info`` (its per-env dicts
    stay small); other VecEnvs give one dict per environment.
    """
    info = getattr(venv, "last_info", None)
    if info is not None:
        return info
    return {key: np.array([i[key] for i in infos]) for key in infos[0]}


def summarise(episodes: list[Episode]) -> dict[str, float]:
    """Gap statistics over all steps (degrees), success rate, mean margin and grip force."""
    if not episodes:
        raise ValueError("no finished episode to summarise")
    gap = np.degrees(np.concatenate([e.gap for e in episodes]))
    return {
        "mean_gap_deg": float(gap.mean()),
        "p90_gap_deg": float(np.percentile(gap, 90)),
        "worst_gap_deg": float(gap.max()),
        "success_rate": float(np.mean([e.held for e in episodes])),
        "mean_margin_deg": float(np.degrees(np.mean(np.concatenate([e.margin for e in episodes])))),
        "mean_force": float(np.mean(np.concatenate([e.force for e in episodes]))),
        "episodes": len(episodes),
    }


def action_scale(envs: VecEnv | gym.vector.VectorEnv) -> float:
    """k_max / w of ``envs``' environments (their ``k_max_ratio``), read back from them: an
    action a is the interaction scalar k = a k_max. ``envs`` is an SB3 ``VecEnv`` or one of
    grasp_env's batched Gymnasium vector environments."""
    if isinstance(envs, VecEnv):
        return float(envs.get_attr("k_max_ratio")[0])
    return float(envs.unwrapped.template.k_max_ratio)


def make_held_out_env(
    env_id: str, env_kwargs: dict[str, Any], episodes: int, seed: int = HELD_OUT_SEED
) -> VecEnv:
    """The evaluation environment: ``episodes`` scenes, run to the end of every trajectory.

    Slips do not end evaluation episodes, so every policy is scored at every pose of the same
    trajectories; a slip still counts against its success rate. The result is
    ``VecMonitor(HeldOutScenes(...))``, wrapped like the training env (as SB3's EvalCallback
    expects); :func:`find_held_out` finds the inner wrapper.
    """
    kwargs = {**env_kwargs}
    if "terminate_on_slip" in _accepted_keywords(env_id):
        kwargs["terminate_on_slip"] = False
    return VecMonitor(HeldOutScenes(_vec_env(env_id, kwargs, episodes), seed))


def sample_poses(env_id: str, env_kwargs: dict[str, Any], scenes: int = 128) -> np.ndarray:
    """The observations at every pose of ``scenes`` trajectories (from :data:`STATISTICS_SEED`),
    (poses, size): the environment's pose distribution, for input statistics."""
    env = make_held_out_env(env_id, env_kwargs, scenes, STATISTICS_SEED)
    obs = env.reset()
    zero = np.zeros((scenes, *env.action_space.shape), env.action_space.dtype)
    poses, running = [], np.ones(scenes, bool)
    while running.any():  # the poses do not depend on the actions
        poses.append(obs[running])
        obs, _, dones, _ = env.step(zero)
        running &= ~dones
    env.close()
    return np.concatenate(poses)


def find_held_out(env: VecEnv) -> HeldOutScenes:
    """The :class:`HeldOutScenes` wrapper inside a wrapped evaluation env."""
    while not isinstance(env, HeldOutScenes):
        if not isinstance(env, VecEnvWrapper):
            raise ValueError("not a held-out evaluation env (see make_held_out_env)")
        env = env.venv
    return env


def _accepted_keywords(env_id: str) -> set[str]:
    """Constructor keywords of the environment behind ``env_id`` (empty if unknown)."""
    import inspect

    entry = gym.spec(env_id).entry_point
    if isinstance(entry, str):
        module, _, name = entry.partition(":")
        entry = getattr(__import__(module, fromlist=[name]), name)
    try:
        return set(inspect.signature(entry).parameters)
    except (TypeError, ValueError):
        return set()
