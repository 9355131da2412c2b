"""Every Gymnasium environment id, one parameterised suite (as dm_control's suite_test and
Gymnasium-Robotics' test_envs): registration, check_env, spaces, determinism, bounds, kwargs and
pickling.
"""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from env_helpers import ALL_IDS, FAST_IDS, MUJOCO_IDS, assert_same, make, rollout
from gymnasium.utils.env_checker import check_env

import grasp_env
from grasp_env import MinimaxExpert
from grasp_env.envs import ObservationLayout
from grasp_env.mechanics import FOUR_FINGER_FACES


@pytest.mark.fast
def test_registration():
    gaits = {
        "grasp_env/CubeGait-v0",
        "grasp_env/CubeGaitMoves-v0",
        "grasp_env/CubeGaitMovesShaped-v0",
    }
    gaits |= {
        "grasp_env/CanGait-v0",
        "grasp_env/CanGaitMoves-v0",
        "grasp_env/CanGaitMovesShaped-v0",
    }
    objects = {"grasp_env/ObjectGrasp-v0", "grasp_env/ObjectGraspRandom-v0"}
    assert set(FAST_IDS) | set(MUJOCO_IDS) | gaits | objects == set(grasp_env.ENV_IDS)
    for env_id in grasp_env.ENV_IDS:
        assert env_id in gym.registry
    # Code that only takes an id string can import the package through the id.
    env = gym.make("grasp_env:grasp_env/CubeGrasp-v0")
    assert env.unwrapped.spec.id == "grasp_env/CubeGrasp-v0"


@pytest.mark.parametrize("env_id", ALL_IDS)
@pytest.mark.fast
def test_gymnasium_check_env(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # Rendering needs MuJoCo's GL context and, for "human", a display: tested below.
        check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_sb3_check_env(env_id):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(env_id).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(env, warn=True, skip_render_check=True)


@pytest.mark.parametrize("env_id", ALL_IDS)
@pytest.mark.fast
def test_spaces(env_id):
    env = make(env_id)
    n = 4 if "4" in env_id else 3
    assert env.action_space == gym.spaces.Box(-1, 1, (n * (n - 1) // 2,), np.float32)
    space = env.observation_space
    assert space.dtype == np.float32 and space.shape == (ObservationLayout(n).size,)
    assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))


@pytest.mark.parametrize("env_id", ALL_IDS)
@pytest.mark.fast
def test_same_seed_same_rollout(env_id):
    steps = 12 if "Mujoco" in env_id else 80
    first = rollout(make(env_id), seed=7, steps=steps)
    second = rollout(make(env_id), seed=7, steps=steps)
    assert_same(first, second)


def test_random_env_seeds_differ():
    env = make("grasp_env/CubeGraspRandom-v0")
    a, _ = env.reset(seed=1)
    b, _ = env.reset(seed=2)
    assert not np.array_equal(a, b)


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_pickle(env_id):
    env = make(env_id)
    expert = MinimaxExpert()
    obs, _ = env.reset(seed=3)
    obs, *_ = env.step(expert.predict(obs)[0])
    clone = pickle.loads(pickle.dumps(env))
    action = expert.predict(obs)[0]
    assert_same(env.step(action), clone.step(action))
    steps = 6 if "Mujoco" in env_id else 40
    assert_same(rollout(env, 5, steps), rollout(clone, 5, steps))


@pytest.mark.parametrize("env_id", FAST_IDS)
@pytest.mark.fast
def test_observations_in_bounds_and_finite(env_id):
    """Long random rollouts, random scenes included: never out of bounds, never NaN."""
    env = make(env_id)
    space = env.observation_space
    record = rollout(env, seed=11, steps=1500)
    observations = [r if isinstance(r, np.ndarray) else r[0] for r in record]
    rewards = [r[1] for r in record if isinstance(r, tuple)]
    for obs in observations:
        assert obs.dtype == np.float32 and space.contains(obs)
    assert np.all(np.isfinite(rewards))
    for r in record:
        if isinstance(r, tuple):
            for key in ("theta", "margin", "k", "contact_forces", "expert_reward"):
                assert np.all(np.isfinite(r[4][key])), key


@pytest.mark.parametrize(
    ("kwargs", "constant"),
    [
        ({}, {"force", "torque"}),  # no extra load is drawn by default: the load is (0, 0, -1)
        ({"extra_force_max": 0.2, "extra_torque_max": 0.1}, set()),
    ],
)
def test_random_env_no_constant_observation_element(kwargs, constant):
    env = make("grasp_env/CubeGraspRandom-v0", **kwargs)
    layout = env.unwrapped.layout
    obs = np.array([env.reset(seed=s)[0] for s in range(12)])
    varies = obs.std(axis=0) > 0
    expected = np.ones(layout.size, bool)
    for name in constant:
        expected[getattr(layout, name)] = False
    expected[layout.phase] = False  # every episode starts at phase 0 ...
    np.testing.assert_array_equal(varies, expected)
    phases = [r[0][layout.phase] for r in rollout(env, 0, 40) if isinstance(r, tuple)]
    assert len(set(phases)) > 10  # ... and moves along the trajectory


def test_kwargs_accepted():
    scene = {"mu": 0.8, "weight": 2.0, "trajectory": {"alpha_start_deg": -5.0}}
    env = make("grasp_env/CubeGrasp-v0", scene=scene, k_max_ratio=1.0, terminate_on_slip=False)
    obs, _ = env.reset()
    assert obs[env.unwrapped.layout.friction_limit] == np.float32(np.arctan(0.8))
    assert len(env.unwrapped.alphas_deg) == 21
    steps = 0
    while True:
        _, _, terminated, truncated, info = env.step(np.array([1, -1, 1], np.float32))
        assert np.allclose(info["k"], [2.0, -2.0, 2.0])  # k_max = 1 x w
        assert not terminated  # slips, but does not stop
        steps += 1
        if truncated:
            break
    assert steps == 21 and info["slip"].any()

    random = make(
        "grasp_env/CubeGraspRandom-v0",
        faces=FOUR_FINGER_FACES,
        contact_offset=0.3,
        cg_offset_max=0.1,
        weight_range=(2.0, 3.0),
        mu_range=(0.8, 0.9),
        alpha_start_range_deg=(-5.0, -4.0),
        alpha_end_range_deg=(4.0, 5.0),
        alpha_step_deg=2.0,
        extra_force_max=0.1,
        extra_torque_max=0.05,
        min_expert_margin_deg=2.0,
        k_max_ratio=3.0,
    )
    for seed in range(3):
        obs, _ = random.reset(seed=seed)
        unwrapped = random.unwrapped
        scene = unwrapped.scene
        assert obs.shape == (38,) and scene.n_contacts == 4
        assert 2.0 <= scene.weight <= 3.0 and 0.8 <= scene.mu <= 0.9
        assert np.all(np.abs(scene.cg_offset) <= 0.05) and np.any(scene.extra_force != 0)
        assert 4 <= len(unwrapped.alphas_deg) <= 6
        assert unwrapped.episode.expert_reward.min() >= np.deg2rad(2.0)
        assert unwrapped.episode.weight == scene.weight
        _, _, _, _, info = random.step(np.ones(6, np.float32))
        np.testing.assert_allclose(info["k"], 3.0 * scene.weight)  # k_max = 3 w, newtons
