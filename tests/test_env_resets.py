"""The random grasp environment's resets read episodes drawn ahead (EpisodeStream): the same
episodes, in the same order, as drawing one at every reset."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding

from grasp_env.envs.cube_grasp import episodes
from grasp_env.envs.cube_grasp.episodes import EpisodeStream, sample_episodes


def same(a: episodes.Episode, b: episodes.Episode) -> bool:
    return all(
        np.array_equal(getattr(a, name), getattr(b, name))
        for name in ("observations", "expert_k_w", "expert_reward", "forces_w", "alphas")
    )


@pytest.mark.fast
def test_drawn_ahead_episodes_are_those_of_one_draw_per_reset():
    env = gym.make("grasp_env/CubeGraspRandom-v0").unwrapped
    env.reset(seed=7)
    seen = [env.episode]
    for _ in range(70):  # past two batches of rounds (1, 2, 4, ..., 32, 32)
        env.reset()
        seen.append(env.episode)
    rng, _ = seeding.np_random(7)
    for i, episode in enumerate(seen):
        one = sample_episodes([rng], env.sampler, env.k_max_ratio, env.min_expert_margin)
        assert same(one.episode(0), episode), f"reset {i}"


@pytest.mark.fast
def test_a_reseed_restarts_the_stream():
    env = gym.make("grasp_env/CubeGraspRandom-v0").unwrapped
    env.reset(seed=3)
    first = env.episode
    for _ in range(5):
        env.reset()
    env.reset(seed=3)
    assert same(env.episode, first)
    env.reset(seed=4)
    assert not same(env.episode, first)


def test_a_stream_without_holding_scenes_raises_at_each_reset_and_carries_on(monkeypatch):
    """Past MAX_DRAWS candidates without an episode the reset raises, as one draw per reset
    did; the next reset draws on (and raises again if nothing holds)."""
    monkeypatch.setattr(episodes, "MAX_DRAWS", 8)  # four rounds of two candidates
    env = gym.make("grasp_env/CubeGraspRandom-v0").unwrapped
    stream = EpisodeStream(env.sampler, env.k_max_ratio, np.deg2rad(44.9))  # nothing holds
    rng = np.random.default_rng(0)
    for _ in range(3):
        with pytest.raises(ValueError, match="fewer than 1 in 8 random scenes"):
            stream.next(rng)
