"""The minimax optimiser as a policy: actions from observations alone (docs/design.md, "Minimax").

>>> import gymnasium as gym, grasp_env
>>> from stable_baselines3.common.evaluation import evaluate_policy
>>> env = gym.make("grasp_env/CubeGrasp-v0")
>>> mean, std = evaluate_policy(grasp_env.MinimaxExpert(), env, n_eval_episodes=1)
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..mechanics import Grasp, contact_pairs, solve_minimax
from .kernels import observation_grasps
from .observation import ObservationLayout
from .validation import DEFAULT_K_MAX_RATIO, check_k_max_ratio


class MinimaxExpert:
    """The globally optimal grip k* = argmin_k max_i theta_i, recomputed from each observation.

    The observation holds the contact positions (in units of the edge length L), the normals,
    the load (in units of the weight w and of w L) and the friction limit; from these the expert
    rebuilds the grasp in units of w and solves the minimax problem over the action box
    |k_ij| <= k_max (eq. 4 and the cone constraint of eq. 2), so its action is k* / k_max.

    The observation is float32, so the grasp it rebuilds differs from the exact one by about
    1e-7 relative: its action earns the environments' ``info["expert_reward"]`` (the certified
    optimum of the exact pose, solved when the episode starts) to within about 1e-6 rad, and
    never more than it. ``info["expert_k"]`` is the exact optimum in newtons; k_max times this
    expert's action is the optimum of the rounded grasp.

    It has the ``predict`` signature of a Stable-Baselines3 model, so
    ``stable_baselines3.common.evaluation.evaluate_policy`` runs it like a trained agent.

    Args:
        k_max_ratio: k_max / w of the environment it acts in (the environments' keyword of the
            same name, default 2).
    """

    def __init__(self, k_max_ratio: float = DEFAULT_K_MAX_RATIO) -> None:
        self.k_max_ratio = check_k_max_ratio(k_max_ratio)

    def predict(
        self,
        observation: ArrayLike,
        state: Any = None,
        episode_start: ArrayLike | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """Actions for one observation (size,) or a batch (B, size): returns (actions, None).

        ``state``, ``episode_start`` and ``deterministic`` exist for SB3 compatibility; the
        expert is deterministic and has no state.
        """
        try:
            obs = np.asarray(observation)
        except (TypeError, ValueError):  # ragged nesting
            raise ValueError(
                f"observation must be an array of numbers, got {observation!r}"
            ) from None
        if obs.dtype.kind not in "iuf":
            raise ValueError(f"observation must be real numbers, got dtype {obs.dtype}")
        if obs.ndim not in (1, 2):
            raise ValueError(f"observation must be (size,) or (batch, size), got {obs.shape}")
        actions = self.actions(obs.reshape(-1, obs.shape[-1]))
        return (actions[0] if obs.ndim == 1 else actions), None

    def actions(self, observations: np.ndarray, follows: np.ndarray | None = None) -> np.ndarray:
        """Actions (B, m) float32 in [-1, 1] for a batch of observations (B, size).

        ``follows`` (B,) bool marks observations that are the next pose of a trajectory after
        the one before them: their solves start from its optimum (see
        :func:`~grasp_env.mechanics.solve_minimax`).
        """
        layout = ObservationLayout.from_size(observations.shape[-1])
        n = layout.n_contacts
        pairs = contact_pairs(n)
        obs = np.asarray(observations, dtype=np.float64)
        check_observations(obs, layout)
        count = obs.shape[0]
        forces, normals = np.empty((count, n, 3)), np.empty((count, n, 3))
        basis = np.empty((count, len(pairs), n, 3))
        # as mechanics.equilibrating_forces and interaction_basis, in one compiled pass
        bad = observation_grasps(obs, pairs, forces, basis, normals)
        if bad >= 0:
            raise ValueError(f"observation {bad} is no grasp: its contacts are collinear")
        grasp = Grasp(
            positions=obs[:, layout.positions].reshape(count, n, 3),
            normals=normals,
            equilibrating=forces,
            basis=basis,
            friction_limit=obs[:, layout.friction_limit],
        )
        k = solve_minimax(grasp, self.k_max_ratio, follows=follows).k
        return np.clip(k / self.k_max_ratio, -1.0, 1.0).astype(np.float32)


def check_observations(obs: np.ndarray, layout: ObservationLayout) -> None:
    """Observations (B, size) that the environments can produce: finite, within the
    observation space, unit normals (a normalised observation, for one, is not)."""
    if not np.all(np.isfinite(obs)):
        raise ValueError("observation must be finite")
    low, high = layout.bounds()
    outside = np.flatnonzero(np.any((obs < low) | (obs > high), axis=1))
    if outside.size:
        raise ValueError(
            f"observation {outside[0]} lies outside the observation space (a normalised"
            " observation? the expert needs the environment's own)"
        )
    normals = obs[:, layout.normals].reshape(len(obs), layout.n_contacts, 3)
    if np.any(np.abs(np.linalg.norm(normals, axis=-1) - 1.0) > 1e-3):
        raise ValueError("observation's contact normals must be unit vectors")
