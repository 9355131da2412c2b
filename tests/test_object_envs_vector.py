"""The object environments' batched vector envs (grasp_env/envs/object_grasp/vector.py): step for
step the single envs, Gymnasium's autoreset modes and reset masks, and the learning stack:
grasp_env's SB3 adapter, SB3's make_vec_env (rendering), the agents' held-out evaluation and a
few thousand steps of PPO on the random id.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.object_grasp.episodes import MAX_EXPERT_GAP

EXPLICIT = "grasp_env/ObjectGrasp-v0"
RANDOM = "grasp_env/ObjectGraspRandom-v0"
KEYS = ("theta", "margin", "k", "contact_forces", "expert_k", "expert_reward", "optimality_gap")


def singles_rollout(env_id: str, kwargs: dict, seeds: list[int], actions: np.ndarray) -> dict:
    """Single envs seeded ``seeds``, stepped with ``actions`` (T, N, M) and reset when their
    episode ends (NEXT_STEP: the step after the end is a reset with reward 0)."""
    envs = [gym.make(env_id, **kwargs) for _ in seeds]
    obs = [env.reset(seed=s)[0] for env, s in zip(envs, seeds, strict=True)]
    ended = [False] * len(envs)
    out = {"obs": [np.stack(obs)], "reward": [], **{k: [] for k in KEYS}}
    for step in actions:
        rewards, row, infos = [], [], []
        for i, env in enumerate(envs):
            if ended[i]:
                o, _ = env.reset()
                rewards.append(0.0)
                ended[i] = False
                infos.append(None)
            else:
                o, r, terminated, truncated, info = env.step(step[i])
                rewards.append(r)
                ended[i] = terminated or truncated
                infos.append(info)
            row.append(o)
        out["obs"].append(np.stack(row))
        out["reward"].append(np.array(rewards))
        for key in KEYS:
            out[key].append([None if i is None else i[key] for i in infos])
    return out


@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [
        (EXPLICIT, {"object": "sphere:r=0.05", "cg_offset": (0.004, 0.0, -0.003)}),
        (RANDOM, {}),
        (RANDOM, {"terminate_on_slip": False, "contact_counts": (3, 5)}),
    ],
)
def test_the_vector_env_steps_as_single_envs(env_id: str, kwargs: dict) -> None:
    count, steps = 4, 14
    vector = gym.make_vec(env_id, num_envs=count, vectorization_mode="vector_entry_point", **kwargs)
    rng = np.random.default_rng(2)
    actions = rng.uniform(-1, 1, (steps, *vector.action_space.shape)).astype(np.float32)
    actions[::3] *= 0.05  # some grips that hold, so that episodes run on
    expected = singles_rollout(env_id, kwargs, [10 + i for i in range(count)], actions)
    obs, _ = vector.reset(seed=10)
    np.testing.assert_array_equal(obs, expected["obs"][0])
    for t in range(steps):
        obs, reward, _, _, info = vector.step(actions[t])
        np.testing.assert_array_equal(obs, expected["obs"][t + 1])
        np.testing.assert_array_equal(reward, expected["reward"][t])
        for key in KEYS:
            for i, value in enumerate(expected[key][t]):
                if value is not None:
                    np.testing.assert_array_equal(info[key][i], value, err_msg=f"{key}, step {t}")
        gap = info["optimality_gap"] + info["expert_gap"]
        assert gap[info["_optimality_gap"]].min(initial=0.0) >= -1e-12
    vector.close()


def test_same_step_autoreset_and_reset_masks() -> None:
    vector = gym.make_vec(
        RANDOM, num_envs=3, vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
    )  # fmt: skip
    first, _ = vector.reset(seed=0)
    actions = np.ones(vector.action_space.shape, np.float32)
    obs, _, terminated, truncated, info = vector.step(actions)
    ended = terminated | truncated
    assert ended.any()  # squeezing every pair at k_max slips somewhere
    for i in np.flatnonzero(ended):
        assert info["final_obs"][i].shape == first.shape[1:]
        assert info["final_info"]["optimality_gap"][i] >= -1e-12
    mask = np.array([True, False, False])
    again, _ = vector.reset(seed=5, options={"reset_mask": mask})
    np.testing.assert_array_equal(again[1:], obs[1:])
    single = gym.make(RANDOM)
    np.testing.assert_array_equal(again[0], single.reset(seed=5)[0])
    with pytest.raises(ValueError, match="reset_mask"):
        vector.reset(options={"reset_mask": np.zeros(3, bool)})


def test_disabled_autoreset_refuses_ended_episodes_and_seed_lists_seed_each() -> None:
    vector = gym.make_vec(
        RANDOM, num_envs=2, vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.DISABLED,
    )  # fmt: skip
    obs, _ = vector.reset(seed=[3, 9])
    np.testing.assert_array_equal(obs[1], gym.make(RANDOM).reset(seed=9)[0])
    ended = np.zeros(2, bool)
    while not ended.any():  # a slip, or the trajectory's end
        _, _, terminated, truncated, _ = vector.step(np.ones(vector.action_space.shape, np.float32))
        ended = terminated | truncated
    with pytest.raises(RuntimeError, match="DISABLED"):
        vector.step(np.zeros(vector.action_space.shape, np.float32))


def test_the_vector_env_refuses_render_mode_and_too_many_rows() -> None:
    with pytest.raises(ValueError, match="render_mode"):
        gym.make_vec(RANDOM, num_envs=2, vectorization_mode="vector_entry_point",
                     render_mode="rgb_array")  # fmt: skip
    with pytest.raises(ValueError, match="pose rows"):
        gym.make_vec(RANDOM, num_envs=1 << 20, vectorization_mode="vector_entry_point")


def test_sb3_adapter_and_held_out_scenes() -> None:
    from grasp_env.envs.sb3 import SB3VecEnv
    from grasp_env_agents.learning.envs import HeldOutScenes

    venv = HeldOutScenes(SB3VecEnv(RANDOM, num_envs=4, terminate_on_slip=False), seed=100)
    assert venv.get_attr("k_max_ratio") == [2.0] * 4
    assert venv.reset().shape == (4, 56)
    for _ in range(40):
        venv.step(np.zeros((4, 15), np.float32))
        if all(e.finished for e in venv.episodes):
            break
    metrics = venv.metrics()
    assert metrics["episodes"] == 4
    assert metrics["mean_gap_deg"] >= -1e-9
    assert all(np.all(np.array(e.gap) >= -MAX_EXPERT_GAP - 1e-12) for e in venv.episodes)
    venv.close()


def test_sb3_make_vec_env_renders() -> None:
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(EXPLICIT, n_envs=2, env_kwargs={"object": "can"})
    venv.reset()
    frames = venv.get_images()
    assert len(frames) == 2 and frames[0].shape == (480, 480, 3)
    venv.close()


def test_ppo_trains_on_the_random_id() -> None:
    """A few thousand steps of SB3's PPO: it runs, and its policy's reward beats the policy it
    started from on the same held-out scenes."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecMonitor

    from grasp_env.envs.sb3 import SB3VecEnv

    kwargs = {"terminate_on_slip": False, "contact_counts": (3, 4)}
    venv = VecMonitor(SB3VecEnv(RANDOM, num_envs=8, **kwargs))
    venv.seed(0)
    model = PPO(
        "MlpPolicy", venv, n_steps=64, batch_size=256, gamma=0.0, learning_rate=1e-3,
        policy_kwargs={"net_arch": [64, 64], "log_std_init": -1.0}, seed=0, device="cpu",
    )  # fmt: skip

    def score() -> float:
        evaluation = VecMonitor(SB3VecEnv(RANDOM, num_envs=8, **kwargs))
        evaluation.seed(1000)
        mean, _ = evaluate_policy(model, evaluation, n_eval_episodes=8, deterministic=True)
        evaluation.close()
        return mean

    before = score()
    model.learn(4096)
    assert model.num_timesteps >= 4096
    assert score() > before
    venv.close()
