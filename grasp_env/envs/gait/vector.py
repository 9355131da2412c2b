"""The batched gait environment: N sub-environments in one step-kernel call."""

from __future__ import annotations

from collections.abc import Sequence
from numbers import Integral
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..validation import (
    MAX_ENVS,
    action_array,
    check_autoreset_mode,
    check_integer,
    check_max_episode_steps,
    check_seed,
    end_step,
    refuse_ended,
    split_reset_mask,
)
from .env import GAIT_RENDER_FPS, CubeGaitEnv
from .kernels import _INFO, _step, check_moves, optimal_actions


class CubeGaitVectorEnv(VectorEnv):
    """Batched `grasp_env/CubeGait-v0`: N sub-environments stepped by one table look-up and
    one step-kernel call per set size; step for step equal to N single environments.

    Args:
        num_envs: number of sub-environments.
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (the step after an episode ends resets
            that sub-environment, ignoring its action, with reward 0), ``SAME_STEP`` (it
            resets at once; the last observation and info are in ``info["final_obs"]`` and
            ``info["final_info"]``) or ``DISABLED`` (episodes never reset by themselves:
            reset the ended ones with ``reset(options={"reset_mask": mask})``; stepping one
            that ended raises a RuntimeError). The modes' values are accepted too.
        max_episode_steps: None (the default: an episode runs to the trajectory's end) or an
            integer >= 1: each sub-environment's episode is truncated after that many steps,
            as Gymnasium's ``TimeLimit`` truncates a single environment's (truncated is True
            at that step even if the episode terminated there too; at the trajectory's end
            the gait itself truncates only episodes that did not terminate).
            ``gym.make_vec(id, ..., max_episode_steps=k)`` passes it.
        render_mode: None or ``"rgb_array"``: :meth:`render` returns a tuple of ``num_envs``
            frames, each the single environment's (one view draws them all, built on the
            first call; ``close()`` frees it). For ``"human"`` use
            ``gym.make_vec(..., vectorization_mode="sync")``.
        **kwargs: the single environment's keywords.

    ``reset(options={"reset_mask": mask})`` (a numpy bool array of shape ``(num_envs,)``), in
    every mode, returns the sub-environments where ``mask`` is True to the start (nothing is
    random) and the observations of all, as Gymnasium's ``SyncVectorEnv``.
    """

    metadata = {  # noqa: RUF012
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": ["rgb_array"],
        "render_fps": GAIT_RENDER_FPS,
    }

    def __init__(
        self,
        num_envs: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        if not (render_mode is None or render_mode == "rgb_array"):
            raise ValueError(
                "render_mode must be None or 'rgb_array' (for 'human' use"
                f' gym.make_vec(..., vectorization_mode="sync")), got {render_mode!r}'
            )
        self.num_envs = check_integer("num_envs", num_envs, 1, MAX_ENVS)
        mode = check_autoreset_mode(autoreset_mode)
        self.max_episode_steps = check_max_episode_steps(max_episode_steps)
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.render_mode = render_mode
        self.template = CubeGaitEnv(**kwargs)
        self.task = self.template.task
        self.terminate_on_slip = self.template.terminate_on_slip
        self.single_observation_space = self.template.observation_space
        self.single_action_space = self.template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        # Truncation at step _end: the trajectory's end, where the gait truncates only what did
        # not terminate, unless max_episode_steps cuts there or before (TimeLimit's rule: it
        # truncates whatever happened at that step).
        poses, cut = self.task.n_poses, self.max_episode_steps
        self._end = poses if cut is None else min(poses, cut)
        self._cut_terminated = cut is not None and cut <= poses
        self._x = np.full(self.num_envs, self.task.start, np.int64)
        self._t = np.zeros(self.num_envs, np.int64)
        # Ended episodes not reset yet: NEXT_STEP resets them at the next step, DISABLED
        # refuses to step them.
        self._autoreset = np.zeros(self.num_envs, bool)
        self._dropped = np.zeros(self.num_envs, bool)  # ended with the cube dropped
        self._started = False
        # What render() draws (kept only with a render_mode): the last step's pose, contacts
        # after its move, forces and reward, or, where _resting, the state as it is (a new
        # episode before its first step).
        F = self.task.n_fingers
        self._view: Any = None
        self._resting = np.ones(self.num_envs, bool)
        self._shown_t = np.zeros(self.num_envs, np.int64)
        self._shown_contacts = np.full((self.num_envs, F), -1, np.int64)
        self._shown_forces = np.zeros((self.num_envs, F, 3))
        self._shown_reward = np.zeros(self.num_envs)

    def _observations(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        task = self.task
        return np.concatenate(
            [task.observations[t], task.contact_obs[x], task.reach_obs[t]], axis=1
        )

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: Any = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every sub-environment (nothing is random: ``seed`` seeds ``np_random``), or
        those where ``options={"reset_mask": mask}`` is True."""
        mask, options = split_reset_mask(options, self.num_envs)
        if mask is None:
            mask = np.ones(self.num_envs, bool)
        if seed is None or isinstance(seed, Integral):
            check_seed("seed", seed)
        elif isinstance(seed, Sequence | np.ndarray) and not isinstance(seed, str | bytes):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed must list {self.num_envs} seeds, got {len(seed)}")
            for i, s in enumerate(seed):
                check_seed(f"seed[{i}]", s)
            seed = seed[int(np.argmax(mask))]  # the first reset sub-environment's
        else:
            raise ValueError(f"seed must be None, an integer >= 0 or a list, got {seed!r}")
        if options:  # None and {} are the only options besides the mask
            raise ValueError(
                f"the gait environment takes no reset options but reset_mask, got {options!r}"
            )
        if not mask.all() and not self._started:
            raise RuntimeError(
                "the first reset() resets every sub-environment: call it without a reset_mask"
            )
        if seed is not None:
            self._np_random, _ = seeding.np_random(int(seed))
        self._x[mask] = self.task.start
        self._t[mask] = 0
        self._autoreset[mask] = False
        self._dropped[mask] = False
        self._resting[mask] = True
        self._started = True
        observations = self._observations(self._x, self._t)
        # a dropped cube's last observation shows no contacts (the state is kept)
        observations[self._dropped, self.task.pose_size() : -self.task.reach_obs.shape[1]] = 0.0
        return observations, {}

    def _restart(self, envs: np.ndarray) -> np.ndarray:
        """Start new episodes in ``envs`` (SAME_STEP autoreset); their first observations."""
        self._x[envs] = self.task.start
        self._t[envs] = 0
        self._dropped[envs] = False
        self._resting[envs] = True
        return self._observations(self._x[envs], self._t[envs])

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        refuse_ended(self.autoreset_mode, self._autoreset)
        task = self.task
        if self.template.optimal_grip:
            moves = check_moves(actions, (self.num_envs,), task.n_moves)
        else:
            a = action_array(actions, self.action_space.shape)
        restarting = np.flatnonzero(self._autoreset)
        xs, t = self._x.copy(), self._t.copy()
        if restarting.size:  # NEXT_STEP: these reset and ignore their action (stepped from the
            xs[restarting] = task.start  # start with a zero action or keeping, undone below)
            t[restarting] = 0
            if self.template.optimal_grip:
                moves[restarting] = 0
            else:
                a = a.copy()
                a[restarting] = 0.0
        if self.template.optimal_grip:
            a = optimal_actions(task, xs, t, moves)
        out = _step(task, xs, t, a, self.terminate_on_slip)  # ValueError before any change
        dropped, reward, observations = out["dropped"], out["reward"], out["obs"]
        terminated = out["terminated"]
        self._t = t + 1
        truncated = self._t == self._end
        if not self._cut_terminated:
            truncated &= ~terminated
        self._x = np.where(dropped, xs, out["next"])
        info = {key: out[key] for key in _INFO}
        info.update(alpha_deg=task.alphas[t], expert_reward=task.expert_margins[t])
        mask = np.ones(self.num_envs, bool)
        if restarting.size:  # they start afresh: the first observation, nothing happened
            self._x[restarting] = task.start
            self._t[restarting] = 0
            observations[restarting] = self._observations(self._x[restarting], self._t[restarting])
            reward[restarting] = 0.0
            terminated[restarting] = False
            truncated[restarting] = False
            mask[restarting] = False
        self._dropped = dropped & terminated  # not the restarted ones
        if self.render_mode is not None:  # the restarted ones: at their start, as after reset
            self._resting[:] = ~mask
            self._shown_t[:] = t
            self._shown_contacts[:] = out["contacts"]
            self._shown_forces[:] = out["contact_forces"]
            self._shown_reward[:] = reward
        self._autoreset = end_step(
            self.autoreset_mode, observations, info, terminated | truncated, mask, self._restart
        )
        return observations, reward, terminated, truncated, info

    def render(self) -> tuple[np.ndarray, ...] | None:
        """The ``num_envs`` sub-environments' frames, each an RGB image (H, W, 3) uint8, as
        the single environment draws it (see its Rendering section)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to make_vec()")
            return None
        from .render import GaitView, resting_grips

        if self._view is None:
            self._view = GaitView(self.task, render_mode=self.render_mode)
        resting = np.flatnonzero(self._resting)
        contacts, forces = self._shown_contacts.copy(), self._shown_forces.copy()
        poses = self._shown_t.copy()
        if resting.size:
            poses[resting] = np.minimum(self._t[resting], self.task.n_poses - 1)
            contacts[resting], forces[resting] = resting_grips(
                self.task, self._x[resting], poses[resting]
            )
        return tuple(
            self._view.render(
                int(poses[e]), contacts[e], forces[e],
                None if self._resting[e] else float(self._shown_reward[e]),
            )
            for e in range(self.num_envs)
        )  # fmt: skip

    def close_extras(self, **kwargs: Any) -> None:
        """Free the view's renderer (``close()`` calls this)."""
        if self._view is not None:
            self._view.close()
            self._view = None


__all__ = ["CubeGaitVectorEnv"]
