"""Shared by the tests of the Gymnasium environments (tests/test_env_*.py): the environment ids,
the friction cone's half-angle, and making, rolling out and comparing environments.
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np

import grasp_env

FAST_IDS = ["grasp_env/CubeGrasp-v0", "grasp_env/CubeGraspRandom-v0", "grasp_env/CubeGrasp4-v0"]


MUJOCO_IDS = [i for i in grasp_env.ENV_IDS if "Mujoco" in i]


ALL_IDS = FAST_IDS + MUJOCO_IDS  # MuJoCo checks take ~10 ms a step: shorter runs for those


LIMIT = float(np.arctan(0.5))


def make(env_id: str, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. the passive checker's complaints
        return gym.make(env_id, **kwargs)


def rollout(env, seed: int, steps: int, action_seed: int = 0):
    """Observations and step results of ``steps`` random steps, resetting when an episode ends."""
    rng = np.random.default_rng(action_seed)
    obs, _ = env.reset(seed=seed)
    record = [obs]
    for _ in range(steps):
        action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        record.append((obs, reward, terminated, truncated, info))
        if terminated or truncated:
            obs, _ = env.reset()
            record.append(obs)
    return record


def assert_same(a, b):
    """Equal nested data: arrays exactly, floats exactly."""
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            assert_same(a[key], b[key])
    elif isinstance(a, tuple | list):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert_same(x, y)
    else:
        np.testing.assert_array_equal(a, b)
