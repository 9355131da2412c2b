"""The gait policies: the certified optimal gait (:class:`GaitExpert`) and the greedy
baseline (:class:`GreedyGait`), acting from observations."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..validation import (
    DEFAULT_K_MAX_RATIO,
    check_bool,
)
from .kernels import optimal_actions
from .tasks import _task


class _GaitPolicy:
    """Acts from observations with a move table over (pose, state) and the certified grip."""

    def __init__(
        self,
        trajectory: Mapping[str, Any] | None = None,
        mu: float = 0.5,
        cone_deg: float = 60.0,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        start: Sequence[int] | None = None,
        optimal_grip: bool = False,
    ) -> None:
        self.task = _task(trajectory, mu, cone_deg, k_max_ratio, start)
        self.optimal_grip = check_bool("optimal_grip", optimal_grip)

    def _policy(self) -> np.ndarray:
        raise NotImplementedError

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """Actions for one observation (size,) or a batch (B, size): returns (actions, None)
        (the signature of a Stable-Baselines3 model's ``predict``); with ``optimal_grip``
        the moves alone (int64), the actions of ``grasp_env/CubeGaitMoves-v0``."""
        task = self.task
        obs = np.asarray(observation, dtype=np.float64)
        size = task.pose_size() + 2 * task.n_fingers * task.n_sites
        if obs.ndim not in (1, 2) or obs.shape[-1] != size:
            raise ValueError(f"observation must be ({size},) or (batch, {size}), got {obs.shape}")
        if not np.all(np.isfinite(obs)):
            raise ValueError("observation must be finite")
        batch = obs.reshape(-1, size)
        T, F, N = task.n_poses, task.n_fingers, task.n_sites
        phase = batch[:, task.pose_size() - 1]
        if np.any((phase < 0.0) | (phase > 1.0)):  # outside the space: no pose of the run
            raise ValueError(
                f"the observation's phase (entry {task.pose_size() - 1}) must be within [0, 1],"
                f" got {phase[(phase < 0.0) | (phase > 1.0)][:5].tolist()}"
            )
        t = np.minimum(np.rint(phase * T).astype(np.int64), T - 1)
        onehot = batch[:, task.pose_size() : task.pose_size() + F * N].reshape(-1, F, N) > 0.5
        assignment = np.where(onehot.any(axis=2), onehot.argmax(axis=2), -1)
        code = ((assignment + 1) * (N + 1) ** np.arange(F)).sum(axis=1)
        x = task.table.code[code]
        if np.any(x < 0):
            raise ValueError("the observation's contacts are no state of the hand")
        moves = task.table.move[self._policy()[t, x]]
        actions = moves if self.optimal_grip else optimal_actions(task, x, t, moves)
        return (actions[0] if obs.ndim == 1 else actions), None


class GaitExpert(_GaitPolicy):
    """The certified optimal gait as a policy: from the pose (the observation's phase) and the
    hand's contacts, the dynamic programme's move (optimal from any state, not only along
    its own gait) and the certified minimax grip of the fingers that then carry load.

    Args: the gait environment's ``trajectory``, ``mu``, ``cone_deg``, ``k_max_ratio``,
    ``start`` (the same configuration shares the environment's tables) and ``optimal_grip``
    (True: it acts with the moves alone, in ``grasp_env/CubeGaitMoves-v0``).
    """

    def _policy(self) -> np.ndarray:
        return self.task.solution.optimal.policy


class GreedyGait(_GaitPolicy):
    """The greedy baseline as a policy: at each pose the move that maximises the smaller of
    this pose's margin and the best the next pose then allows, with the certified grip."""

    def _policy(self) -> np.ndarray:
        return self.task.solution.greedy.policy


__all__ = ["GaitExpert", "GreedyGait"]
