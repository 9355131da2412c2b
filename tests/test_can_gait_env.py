"""The can's gait environments grasp_env/CanGait-v0 and CanGaitMoves-v0 (docs/gait.md, "The
can"): the expert reproduces the certified gait, greedy drops where the programme says, the
rules, reproducibility and the keywords' checks."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.can_gait import CanGaitExpert, CanGreedyGait

GAIT, MOVES = "grasp_env/CanGait-v0", "grasp_env/CanGaitMoves-v0"


def play(env, policy, **reset):
    obs, _ = env.reset(**reset)
    rewards, infos = [], []
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.predict(obs)[0])
        rewards.append(reward)
        infos.append(info)
        if terminated or truncated:
            return np.array(rewards), infos, terminated


@pytest.mark.parametrize(("env_id", "grip"), [(GAIT, False), (MOVES, True)])
def test_expert_keeps_the_certified_worst_margin(env_id, grip):
    env = gym.make(env_id)
    rewards, infos, terminated = play(env, CanGaitExpert(optimal_grip=grip), seed=0)
    assert not terminated and len(rewards) == 37  # 0..360 deg by 10 deg
    assert np.degrees(rewards.min()) == pytest.approx(8.893, abs=5e-4)
    expert = np.array([i["expert_reward"] for i in infos])
    np.testing.assert_allclose(rewards, expert, atol=1e-6)  # float32 grips: 1e-6 rad
    assert sum(i["move"] != 0 for i in infos) == 25  # the gait's phase changes
    assert not any(i["refused"] for i in infos)


def test_greedy_drops_at_60_deg_from_its_own_start():
    env = gym.make(GAIT).unwrapped
    greedy = env.task.solution.greedy
    start = tuple(int(a) for a in env.task.table.states[greedy.states[0]])
    env = gym.make(GAIT, start=start)
    rewards, infos, terminated = play(env, CanGreedyGait(start=start), seed=0)
    assert terminated and infos[-1]["alpha_deg"] == 60.0
    assert infos[-1]["lost"].any()
    assert rewards[-1] == pytest.approx(np.arctan(0.5) - np.pi / 2, abs=1e-12)
    np.testing.assert_allclose(rewards[:-1], greedy.margins[:6], atol=1e-6)


def test_check_env_and_make_vec_sync():
    for env_id in (GAIT, MOVES):
        env = gym.make(env_id, render_mode="rgb_array")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            check_env(env.unwrapped)
        envs = gym.make_vec(env_id, num_envs=2)  # no vector class: sync
        obs, _ = envs.reset(seed=0)
        assert obs.shape == (2, 44)
        envs.step(envs.action_space.sample())
        envs.close()


def test_refused_moves_and_reproducible_seeds():
    env = gym.make(MOVES, terminate_on_slip=False)
    task = env.unwrapped.task
    runs = []
    for _ in range(2):
        env.reset(seed=3)
        env.action_space.seed(3)
        runs.append([env.step(env.action_space.sample())[1] for _ in range(10)])
    assert runs[0] == runs[1]
    env.reset(seed=0)
    assert (task.table.states[task.start] >= 0).sum() == 4  # the optimal gait's first state
    *_, info = env.step(1)  # place finger1 beside the four loaded: allowed
    assert not info["refused"] and info["move"] == 1 and info["ages"][0] == 0
    assert info["loaded"].sum() == 4 and not info["loaded"][0]
    *_, info = env.step(0)  # five touch, four at most loaded: keep is refused ...
    assert info["refused"] and info["move"] == 1  # ... and the lowest finger is lifted
    assert info["ages"][0] == -1 and info["loaded"].sum() == 4


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"reach_deg": 0.0}, "reach_deg must be"),
        ({"reach_deg": 95.0}, "reach_deg must be"),
        ({"alpha_step_deg": -1.0}, "alpha_step_deg must be"),
        ({"max_loaded": 6}, r"max_loaded must be an integer in \[3, 5\]"),
        ({"k_max_ratio": 0.0}, "k_max_ratio must be"),
        ({"mu": -1.0}, "mu must be"),
        ({"reach_deg": 30.0}, "no gait"),
        ({"optimal_grip": 1}, "optimal_grip must be True or False"),
    ],
)
def test_keywords_are_checked(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make(GAIT, **kwargs)
