"""The policies the vector-env tests drive with (tests/test_vector_*.py): experts perturbed in
some sub-environments, so that episodes end at different times."""

from __future__ import annotations

import numpy as np

from grasp_env import MinimaxExpert
from grasp_env.envs.gait import GaitExpert

GAIT_TURN = {"alpha_start_deg": -90.0, "alpha_end_deg": -82.0}  # 9 poses


def grasp_policy(rng: np.random.Generator):
    """The expert's grip, perturbed in some sub-environments: some slip, others carry on."""
    expert = MinimaxExpert()

    def act(obs: np.ndarray) -> np.ndarray:
        noise = rng.uniform(-0.6, 0.6, (len(obs), 3)) * (rng.random((len(obs), 1)) < 0.3)
        return np.clip(expert.predict(obs)[0] + noise, -1, 1).astype(np.float32)

    return act


def gait_policy(rng: np.random.Generator, noisy: float = 0.15):
    """The certified gait along GAIT_TURN, with random actions in a share ``noisy`` of the
    sub-environments at each step (they drop the cube or slip)."""
    expert = GaitExpert(trajectory=GAIT_TURN)

    def act(obs: np.ndarray) -> np.ndarray:
        actions = expert.predict(obs)[0]
        chosen = rng.random(len(obs)) < noisy
        actions[chosen] = rng.uniform(-1, 1, actions[chosen].shape)
        return actions.astype(np.float32)

    return act
