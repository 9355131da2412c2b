"""Reference policies for the comparison, with Stable-Baselines3's ``predict`` signature.

- :func:`equal_k_policy`: the paper's symmetric grip, every k_ij = w tan(phi) / (3 sqrt 3)
  (eq. 8, optimal at alpha = 0 of the paper's scene), held whatever the pose.
- ``ConstantPolicy(zeros)``: no interaction force; the fingers apply the equilibrating forces.
- :class:`RandomPolicy`: uniform actions in [-1, 1]^m from a seeded generator.
- :class:`TrainedAgent`: an SB3 model, with its observation normalisation if it has one.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from grasp_env.mechanics import PHI


class ConstantPolicy:
    """The same action whatever the observation."""

    def __init__(self, action: ArrayLike) -> None:
        self.action = np.asarray(action, dtype=np.float32)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        obs = np.asarray(observation)
        shape = (*obs.shape[:-1], self.action.size)
        return np.broadcast_to(self.action, shape).copy(), None


def equal_k_policy(m: int, k_max_ratio: float) -> ConstantPolicy:
    """k_ij = w tan(phi) / (3 sqrt 3) for all m pairs (eq. 8), as actions k / k_max.

    k_max = k_max_ratio x w, so the action is the same for every weight.
    """
    return ConstantPolicy(np.full(m, np.tan(PHI) / (3 * np.sqrt(3)) / k_max_ratio))


class RandomPolicy:
    """Uniform random actions in [-1, 1]^m, reproducible from ``seed``."""

    def __init__(self, m: int, seed: int = 0) -> None:
        self.m = m
        self.rng = np.random.default_rng(seed)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        obs = np.asarray(observation)
        shape = (*obs.shape[:-1], self.m)
        return self.rng.uniform(-1.0, 1.0, shape).astype(np.float32), None


class TrainedAgent:
    """A trained SB3 model acting on raw observations (normalised here if it was trained so)."""

    def __init__(self, model: BaseAlgorithm, normalizer: VecNormalize | None = None) -> None:
        self.model = model
        self.normalizer = normalizer

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        if self.normalizer is not None:
            observation = self.normalizer.normalize_obs(observation)
        return self.model.predict(observation, state, episode_start, deterministic)
