"""Batched numpy vector environments of the object family: N padded grasps stepped by one
compiled kernel call (:func:`~.kernels.object_batch`).

``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` returns them. Step
for step they equal N single environments reset with the seeds seed, seed + 1, ...: each
sub-environment has its own generator and episode stream (:class:`~.episodes.EpisodeStream`),
and a reset whose sub-environment has no episode ready draws the next batch of every stream
that has none, in one batch of solves (:func:`~.episodes.fill`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ...mechanics import contact_pairs
from ..cube_grasp.vector import _CubeGraspVectorEnv
from ..validation import (
    MAX_ENVS,
    action_array,
    check_autoreset_mode,
    check_integer,
    check_max_episode_steps,
    end_step,
    refuse_ended,
    split_reset_mask,
)
from .env import ObjectGraspEnv, ObjectGraspRandomEnv, _ObjectGraspEnv
from .episodes import (
    EpisodeStream,
    ObjectEpisode,
    build_episodes,
    draws_error,
    fill,
    solve_pending,
)
from .kernels import object_batch
from .scenes import ObjectScene

_STORED = (  # in object_batch's order
    "forces_w", "directions", "normals", "observations", "alphas", "expert_k_w", "expert_reward",
)  # fmt: skip
#: The most pose rows a vector env's store may hold: num_envs x (longest trajectory + 1).
MAX_STORE_ROWS = 1 << 22
_NO_CUT = np.iinfo(np.int64).max


class _ObjectGraspVectorEnv(_CubeGraspVectorEnv):
    """N object environments in numpy; see the single environment for spaces, reward, info.

    Args:
        num_envs: number of sub-environments, in [1, 2^20].
        autoreset_mode: ``NEXT_STEP`` (default), ``SAME_STEP`` (``final_obs``,
            ``final_info``; what grasp_env's SB3 adapter runs) or ``DISABLED``, as the cube's.
        max_episode_steps: None, -1 (no limit) or an integer >= 1.
        **kwargs: the single environment's keywords (not ``render_mode``: use
            ``vectorization_mode="sync"`` for frames).

    ``reset(seed=..., options={"reset_mask": mask, "scene": {...}})`` as the cube's vector
    env. The class derives from the cube's vector env so that grasp_env's SB3 adapter accepts
    it; it shares that class's seeding helpers only.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}  # noqa: RUF012
    _single: type[_ObjectGraspEnv]

    def __init__(
        self,
        num_envs: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        VectorEnv.__init__(self)
        num_envs = check_integer("num_envs", num_envs, 1, MAX_ENVS)
        mode = check_autoreset_mode(autoreset_mode)
        self.max_episode_steps = check_max_episode_steps(max_episode_steps)
        self._cut = min(self.max_episode_steps or _NO_CUT, _NO_CUT)
        if kwargs.get("render_mode") is not None:
            raise ValueError(
                "this batched vector env takes no render_mode: use gym.make_vec(...,"
                ' vectorization_mode="sync") for frames'
            )
        self.num_envs = num_envs
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.render_mode = None
        self.template = self._single(**kwargs)
        self.terminate_on_slip = self.template.terminate_on_slip
        big = self.template.max_contacts
        self._pairs = contact_pairs(big)
        self._big, self._m = big, len(self._pairs)
        default = getattr(self.template, "_default_episode", None)
        sampler = getattr(self.template, "sampler", None)
        longest = len(default) if default is not None else sampler.max_length
        if num_envs * (longest + 1) > MAX_STORE_ROWS:
            raise ValueError(
                f"num_envs x (longest trajectory + 1) = {num_envs} x {longest + 1} pose rows"
                f" exceeds the vector env's {MAX_STORE_ROWS:,}: use fewer sub-environments or"
                " a larger alpha_step_deg"
            )
        self.single_observation_space = self.template.observation_space
        self.single_action_space = self.template.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._capacity = 0
        self._arrays: dict[str, np.ndarray] = {}
        self._grow(longest + 1)
        self._rngs: list[np.random.Generator | None] = [None] * num_envs
        self._streams = (
            [
                EpisodeStream(
                    sampler, self.template.k_max_ratio, self.template.min_expert_margin, big
                )
                for _ in range(num_envs)
            ]
            if sampler is not None
            else []
        )
        self._episodes: list[ObjectEpisode | None] = [None] * num_envs
        self._counts = np.zeros(num_envs, dtype=np.int64)
        self._projections = np.zeros((num_envs, self._m, self._m))
        self._length = np.zeros(num_envs, dtype=np.int64)
        self._end = np.zeros(num_envs, dtype=np.int64)
        self._weight = np.zeros(num_envs)
        self._limit = np.zeros(num_envs)
        self._t = np.zeros(num_envs, dtype=np.int64)
        self._autoreset = np.zeros(num_envs, dtype=bool)
        self._started = False

    # -- the store -----------------------------------------------------------------------------

    def _grow(self, capacity: int) -> None:
        """Slots of ``capacity`` rows per sub-environment (their episodes are written again)."""
        big, m, count = self._big, self._m, self.num_envs * capacity
        shapes = {
            "forces_w": (big, 3), "directions": (m, 3), "normals": (big, 3),
            "observations": (self.template.layout.size,), "alphas": (), "expert_k_w": (m,),
            "expert_reward": (), "expert_gap": (),
        }  # fmt: skip
        self._arrays = {
            name: np.zeros((count, *shape), np.float32 if name == "observations" else float)
            for name, shape in shapes.items()
        }
        self._capacity = capacity
        for env, episode in enumerate(getattr(self, "_episodes", [])):
            if episode is not None:
                self._write(env, episode)

    def _write(self, env: int, episode: ObjectEpisode) -> None:
        base, length = env * self._capacity, len(episode)
        for name in ("forces_w", "directions", "normals", "alphas", "expert_k_w"):
            self._arrays[name][base : base + length] = getattr(episode, name)
        self._arrays["expert_reward"][base : base + length] = episode.expert_reward
        self._arrays["expert_gap"][base : base + length] = episode.expert_gap
        self._arrays["observations"][base : base + length + 1] = episode.observations

    def _start(self, envs: np.ndarray, scene: ObjectScene | None) -> None:
        """New episodes for sub-environments ``envs``: the scene option's, the default one or
        each stream's next."""
        if len(envs) == 0:
            return
        template = self.template
        if scene is not None:
            episode = build_episodes([scene], template.k_max_ratio, self._big)[0]
            episodes = [episode] * len(envs)
        elif not self._streams:
            episodes = [template._default_episode] * len(envs)
        else:
            streams = [self._streams[e] for e in envs]
            for stream, env in zip(streams, envs, strict=True):
                if stream.rng is not self._rng(env):
                    stream.restart(self._rng(env))
            while True:
                lacking = [s for s in self._streams if not s.queue and s.rng is not None]
                if not any(not s.queue for s in streams):
                    break
                fill(lacking)
            episodes = []
            for stream in streams:
                episode = stream.queue.popleft()
                if episode is None:
                    raise draws_error(stream.min_margin)
                episodes.append(episode)
        longest = max(len(e) for e in episodes) + 1
        if longest > self._capacity:
            self._grow(max(longest, 2 * self._capacity))
        for env, episode in zip(envs, episodes, strict=True):
            self._episodes[env] = episode
            self._write(int(env), episode)
            self._counts[env] = episode.n_contacts
            self._projections[env] = episode.projection
            self._length[env] = len(episode)
            self._weight[env] = episode.weight
            self._limit[env] = episode.limit
        self._end[envs] = np.minimum(self._length[envs], self._cut)
        self._t[envs] = 0

    def scene(self, env: int) -> Any:
        """Sub-environment ``env``'s current :class:`~grasp_env.mechanics.Scene`."""
        if not self._started:
            raise RuntimeError("call reset() first")
        return self._episodes[env].scene.scene

    def _rows(self, envs: np.ndarray | None = None) -> np.ndarray:
        envs = np.arange(self.num_envs) if envs is None else envs
        return envs * self._capacity + self._t[envs]

    # -- reset and step --------------------------------------------------------------------------

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every sub-environment (or those of ``options["reset_mask"]``); ``seed`` is
        None, an int (env i gets seed + i) or a list; ``options["scene"]`` as the single env."""
        seeds = self._seeds(seed)
        mask, options = split_reset_mask(options, self.num_envs)
        scene = self.template.scene_option(options)
        if mask is None or mask.all():
            envs = np.arange(self.num_envs)
        elif not self._started:
            raise RuntimeError(
                "the first reset() resets every sub-environment: call it without a reset_mask"
            )
        else:
            envs = np.flatnonzero(mask)
        for env in envs:
            if seeds[env] is not None:
                self._rngs[env], _ = seeding.np_random(seeds[env])
        self._start(envs, scene)
        self._autoreset[envs] = False
        self._started = True
        return self._arrays["observations"][self._rows()], {"n_contacts": self._counts.copy()}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every sub-environment (see the single env and :mod:`.kernels`)."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        refuse_ended(self.autoreset_mode, self._autoreset)
        a = action_array(actions, self.action_space.shape)
        count = self.num_envs
        restarting = np.flatnonzero(self._autoreset)
        active = ~self._autoreset
        if not np.isfinite(a).all():
            bad = np.flatnonzero(~np.isfinite(a).all(axis=1) & active)
            if bad.size:
                raise ValueError(f"actions must be finite; sub-environments {bad.tolist()} are not")
        if restarting.size:
            self._start(restarting, None)
            a = np.where(active[:, None], a, 0.0)
        self._solve_pending()
        arrays = self._arrays
        rows = self._rows()
        big, m = self._big, self._m
        observations = np.empty((count, arrays["observations"].shape[1]), np.float32)
        reward, expert_reward, gap, alpha = (np.empty(count) for _ in range(4))
        k, expert_k = np.empty((count, m)), np.empty((count, m))
        forces, equilibrating = np.empty((count, big, 3)), np.empty((count, big, 3))
        theta, margin = np.empty((count, big)), np.empty((count, big))
        object_batch(
            *(arrays[name] for name in _STORED), self._pairs, rows, a, self._counts,
            self._projections, self.template.k_max_ratio, self._weight, self._limit,
            observations, reward, k, forces, theta, margin, equilibrating, expert_k,
            expert_reward, gap, alpha,
        )  # fmt: skip
        terminated = reward < 0.0 if self.terminate_on_slip else np.zeros(count, bool)
        self._t += 1
        truncated = self._t == self._end
        info = {
            "alpha_deg": alpha,
            "theta": theta,
            "margin": margin,
            "k": k,
            "contact_forces": forces,
            "equilibrating_forces": equilibrating,
            "expert_k": expert_k,
            "expert_reward": expert_reward,
            "expert_gap": arrays["expert_gap"][rows],
            "optimality_gap": gap,
            "slip": margin < 0.0,
            "n_contacts": self._counts.copy(),
        }
        if restarting.size:
            reward[restarting] = 0.0
            terminated[restarting] = False
            truncated[restarting] = False
            self._t[restarting] = 0
            observations[restarting] = arrays["observations"][self._rows(restarting)]
            mask = active
        else:
            mask = np.ones(count, bool)
        self._autoreset = end_step(
            self.autoreset_mode, observations, info, terminated | truncated, mask, self._restart
        )
        return observations, reward, terminated, truncated, info

    def _solve_pending(self) -> None:
        """Solve the expert at the poses the sub-environments reach unsolved (random episodes
        solve what decides that they hold at reset, the rest on the way: ``solve_pending``),
        all in one batch, and copy the optimum into the store."""
        waiting = [
            e
            for e in range(self.num_envs)
            if not self._episodes[e].solved[min(self._t[e], self._length[e] - 1)]
        ]
        if not waiting:
            return
        items = [(self._episodes[e], int(self._t[e])) for e in waiting]
        spans = solve_pending(items, self.template.k_max_ratio)
        for env, (episode, _), span in zip(waiting, items, spans, strict=True):
            rows = slice(env * self._capacity + span.start, env * self._capacity + span.stop)
            self._arrays["expert_k_w"][rows] = episode.expert_k_w[span]
            self._arrays["expert_reward"][rows] = episode.expert_reward[span]
            self._arrays["expert_gap"][rows] = episode.expert_gap[span]

    def _restart(self, envs: np.ndarray) -> np.ndarray:
        self._start(envs, None)
        return self._arrays["observations"][self._rows(envs)]

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()


class ObjectGraspVectorEnv(_ObjectGraspVectorEnv):
    __doc__ = "Batched `grasp_env/ObjectGrasp-v0`.\n\n    " + (_ObjectGraspVectorEnv.__doc__ or "")
    _single = ObjectGraspEnv


class ObjectGraspRandomVectorEnv(_ObjectGraspVectorEnv):
    __doc__ = "Batched `grasp_env/ObjectGraspRandom-v0`.\n\n    " + (
        _ObjectGraspVectorEnv.__doc__ or ""
    )
    _single = ObjectGraspRandomEnv


__all__ = ["ObjectGraspRandomVectorEnv", "ObjectGraspVectorEnv"]
