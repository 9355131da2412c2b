"""The environments' vector versions against single environments, and the SB3 adapter."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from env_helpers import FAST_IDS, make
from gymnasium.vector import AutoresetMode

from grasp_env import MinimaxExpert


def step_singles(envs, actions, autoreset):
    results = []
    for env, action, restart in zip(envs, actions, autoreset, strict=True):
        if restart:
            obs, _ = env.reset()
            results.append((obs, 0.0, False, False, None))
        else:
            results.append(env.step(action))
    return results


@pytest.mark.parametrize("env_id", FAST_IDS)
@pytest.mark.fast
def test_vector_env_equals_single_envs(env_id):
    """NEXT_STEP autoreset, step for step against N single environments seeded seed + i."""
    count = 5
    venv = gym.make_vec(env_id, num_envs=count, vectorization_mode="vector_entry_point")
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    envs = [make(env_id) for _ in range(count)]
    obs, _ = venv.reset(seed=40)
    np.testing.assert_array_equal(obs, [e.reset(seed=40 + i)[0] for i, e in enumerate(envs)])
    rng = np.random.default_rng(0)
    autoreset = np.zeros(count, bool)
    restarts = 0
    for _ in range(120):
        # Small grips slip less often: long episodes and short ones both occur.
        actions = rng.uniform(-0.3, 0.3, venv.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, info = venv.step(actions)
        for i, (o, r, te, tr, single_info) in enumerate(step_singles(envs, actions, autoreset)):
            np.testing.assert_array_equal(obs[i], o)
            assert (reward[i], terminated[i], truncated[i]) == (r, te, tr)
            if single_info is None:
                assert not info["_theta"][i]
            else:
                for key, value in single_info.items():
                    assert info[f"_{key}"][i]
                    np.testing.assert_array_equal(info[key][i], value)
        autoreset = terminated | truncated
        restarts += autoreset.sum()
    assert restarts >= count  # every sub-environment has at least one 31-step episode ended


@pytest.mark.parametrize(
    ("env_id", "module"),
    [
        ("grasp_env/CubeGraspRandom-v0", "grasp_env.envs.cube_grasp.vector"),
        ("grasp_env/CubeGait-v0", "grasp_env.envs.gait.kernels"),
    ],
)
def test_vector_step_split_across_cores_equals_one_call(env_id, module, monkeypatch):
    """Large batches are stepped in parts, one a core: the very numbers of one kernel call."""
    import importlib

    count = 600  # above the split threshold, not a multiple of the cores
    runs = []
    for parallel_from in (512, count + 1):
        monkeypatch.setattr(importlib.import_module(module), "PARALLEL_FROM", parallel_from)
        venv = gym.make_vec(
            env_id, num_envs=count, vectorization_mode="vector_entry_point",
            terminate_on_slip=False,
        )  # fmt: skip
        venv.action_space.seed(3)
        steps = [venv.reset(seed=1)[0]]
        for _ in range(40):
            obs, reward, terminated, truncated, info = venv.step(venv.action_space.sample())
            steps.append((obs, reward, terminated, truncated, info["theta"], info["k"]))
        runs.append(steps)
    for one_part, parts in zip(*runs, strict=True):
        for a, b in zip(one_part, parts, strict=True):
            np.testing.assert_array_equal(a, b)


def test_vector_env_resets_in_chunks_the_same_episodes(monkeypatch):
    """Random episodes are drawn for a chunk of sub-environments at a time, and ahead for at
    most _AHEAD_ENVS (bounding a large reset's memory): the episodes, observations and
    rewards are those of one chunk, whatever is drawn ahead (none, a few, all)."""
    import grasp_env.envs.cube_grasp.vector as vector

    runs = []
    for chunk, ahead in ((vector._RESET_CHUNK, vector._AHEAD_ENVS), (3, 0), (3, 2)):
        monkeypatch.setattr(vector, "_RESET_CHUNK", chunk)
        monkeypatch.setattr(vector, "_AHEAD_ENVS", ahead)
        venv = gym.make_vec(
            "grasp_env/CubeGraspRandom-v0", num_envs=7, vectorization_mode="vector_entry_point"
        )
        venv.action_space.seed(0)
        steps = [venv.reset(seed=5)[0]]
        for _ in range(40):  # autoresets in the chunks too
            obs, reward, terminated, truncated, _ = venv.step(venv.action_space.sample())
            steps.append((obs, reward, terminated, truncated))
        runs.append(steps)
    for run in runs[1:]:
        for one, chunked in zip(runs[0], run, strict=True):
            for a, b in zip(one, chunked, strict=True):
                np.testing.assert_array_equal(a, b)


def test_vector_env_draws_episodes_ahead_as_single_envs_draw_them(monkeypatch):
    """Random episodes are drawn ahead, many sub-environments' at a time: a reset finds its
    episode drawn already, and a new seed or a scene option does what it does to a single
    environment (a new seed drops the episode drawn ahead; a scene option leaves the
    generator alone, so the next random episode is the one drawn ahead)."""
    import grasp_env.envs.cube_grasp.vector as vector
    from grasp_env.envs.cube_grasp import episodes

    calls = []
    sample = episodes.sample_episodes

    def counted(rngs, *args):
        calls.append(len(rngs))
        return sample(rngs, *args)

    monkeypatch.setattr(vector, "sample_episodes", counted)
    count, scene = 6, {"weight": 3.0, "trajectory": {"alpha_start_deg": 0, "alpha_end_deg": 3}}
    env_id = "grasp_env/CubeGraspRandom-v0"
    venv = gym.make_vec(env_id, num_envs=count, vectorization_mode="vector_entry_point")
    envs = [make(env_id) for _ in range(count)]
    rng = np.random.default_rng(1)
    mask = np.array([True, False, True, False, True, False])
    autoreset = np.zeros(count, bool)  # NEXT_STEP: ended episodes restart at the next step

    def reset(seed=None, mask=None, scene=None):
        options = {"reset_mask": mask} if mask is not None else {}
        options.update({"scene": scene} if scene is not None else {})
        obs, _ = venv.reset(seed=seed, options=options or None)
        for i, env in enumerate(envs):
            if mask is None or mask[i]:
                single = env.reset(
                    seed=None if seed is None else seed + i,
                    options=None if scene is None else {"scene": scene},
                )[0]
                np.testing.assert_array_equal(obs[i], single)
                autoreset[i] = False

    def steps(number):
        for _ in range(number):
            actions = rng.uniform(-0.3, 0.3, venv.action_space.shape).astype(np.float32)
            obs, reward, terminated, truncated, _ = venv.step(actions)
            for i, (o, r, *_) in enumerate(step_singles(envs, actions, autoreset)):
                np.testing.assert_array_equal(obs[i], o)
                assert reward[i] == r
            autoreset[:] = terminated | truncated

    reset(seed=3)
    steps(70)  # autoresets: every sub-environment has drawn episodes ahead since
    assert max(calls[1:]) > 1  # a reset drew other sub-environments' next episodes too
    reset(seed=100, mask=mask)  # new seeds: the episodes drawn ahead are dropped
    # ... and drawn again with those of the others that had none
    assert np.all(venv.unwrapped._ahead_of[~mask] >= 0)
    reset(mask=~mask, scene=scene)  # the generators are left alone
    steps(40)
    reset()  # every sub-environment's next random episode
    steps(40)
    for i, env in enumerate(envs):
        np.testing.assert_array_equal(
            venv.unwrapped.scene(i).contacts, env.unwrapped.scene.contacts
        )


def test_vector_env_same_step_autoreset():
    count = 4
    venv = gym.make_vec(
        "grasp_env/CubeGraspRandom-v0",
        num_envs=count,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    envs = [make("grasp_env/CubeGraspRandom-v0") for _ in range(count)]
    venv.reset(seed=[3, 4, 5, 6])
    for i, env in enumerate(envs):
        env.reset(seed=3 + i)
    rng = np.random.default_rng(2)
    ended = 0
    for _ in range(60):
        actions = rng.uniform(-0.3, 0.3, venv.action_space.shape).astype(np.float32)
        obs, reward, terminated, truncated, info = venv.step(actions)
        for i, env in enumerate(envs):
            o, r, te, tr, single_info = env.step(actions[i])
            assert (reward[i], terminated[i], truncated[i]) == (r, te, tr)
            if te or tr:
                ended += 1
                np.testing.assert_array_equal(info["final_obs"][i], o)
                assert info["_final_obs"][i] and not info["_theta"][i]
                np.testing.assert_array_equal(info["final_info"]["theta"][i], single_info["theta"])
                o, _ = env.reset()
            np.testing.assert_array_equal(obs[i], o)
    assert ended > 0


@pytest.mark.fast
def test_vector_env_bad_input():
    venv = gym.make_vec(
        "grasp_env/CubeGrasp-v0", num_envs=3, vectorization_mode="vector_entry_point"
    )
    with pytest.raises(RuntimeError, match="reset"):
        venv.step(np.zeros((3, 3)))
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        venv.step(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"finite; sub-environments \[1\]"):
        venv.step(np.array([[0, 0, 0], [0, np.nan, 0], [0, 0, 0]], float))
    # Nothing moved: the next valid step is the first step of the episode.
    _, _, _, _, info = venv.step(np.zeros((3, 3)))
    np.testing.assert_array_equal(info["alpha_deg"], [-15.0, -15.0, -15.0])
    with pytest.raises(ValueError, match="unknown scene key 'mass'"):
        venv.reset(options={"scene": {"mass": 1}})
    with pytest.raises(
        ValueError, match=r"physics nor render_mode: for physics make the \.\.\.Mujoco"
    ):
        gym.make_vec(
            "grasp_env/CubeGrasp-v0", num_envs=2, vectorization_mode="vector_entry_point",
            physics="mujoco",
        )  # fmt: skip


def test_vector_env_scene_option_and_long_trajectories():
    """A scene option reaches every sub-environment; longer episodes grow the store."""
    venv = gym.make_vec(
        "grasp_env/CubeGrasp-v0", num_envs=3, vectorization_mode="vector_entry_point"
    )
    single = make("grasp_env/CubeGrasp-v0")
    scene = {"mu": 0.9, "trajectory": {"alpha_start_deg": -40.0, "alpha_end_deg": 40.0}}
    obs, _ = venv.reset(seed=0, options={"scene": scene})
    first, _ = single.reset(seed=0, options={"scene": scene})
    np.testing.assert_array_equal(obs, np.stack([first] * 3))
    expert = MinimaxExpert()
    for step in range(81):
        actions = expert.predict(obs)[0]
        obs, reward, terminated, truncated, _ = venv.step(actions)
        o, r, te, tr, _ = single.step(actions[0])
        np.testing.assert_array_equal(obs[0], o)
        assert (reward[0], terminated[0], truncated[0]) == (r, te, tr)
        assert not te and tr == (step == 80)


def test_sb3_vec_env_trains():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from grasp_env.envs.sb3 import SB3VecEnv

    venv = SB3VecEnv("grasp_env/CubeGrasp-v0", num_envs=8)
    venv.seed(5)
    obs = venv.reset()
    assert obs.shape == (8, 32)
    obs, rewards, dones, infos = venv.step(np.ones((8, 3), np.float32))  # every finger slips
    assert dones.all() and rewards.dtype == np.float32
    for info in infos:
        assert info["terminal_observation"].shape == (32,)
        assert info["TimeLimit.truncated"] is False
    assert venv.last_info["slip"].all()
    model = PPO("MlpPolicy", VecMonitor(venv), n_steps=16, batch_size=64, n_epochs=1, seed=0)
    model.learn(256)
