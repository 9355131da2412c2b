"""The environments' MuJoCo check and rendering, their sampler, the expert's bad input, and the
compiled step and pose kernels against grasp_env.mechanics.
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from env_helpers import ALL_IDS, assert_same, make
from gymnasium.utils.env_checker import check_env

from grasp_env import MinimaxExpert
from grasp_env.envs import ObservationLayout
from grasp_env.mechanics import FOUR_FINGER_FACES


def test_mujoco_env_checks_every_step():
    env = make("grasp_env/CubeGraspMujoco-v0")
    expert = MinimaxExpert()
    obs, _ = env.reset(seed=0)
    for _ in range(3):  # the expert's grip holds in MuJoCo too
        obs, _, terminated, _, info = env.step(expert.predict(obs)[0])
        assert info["physics"]["holds"] and not terminated
    env.reset(seed=0)
    _, _, terminated, _, info = env.step(np.array([1.0, -1.0, 1.0], np.float32))
    assert not info["physics"]["holds"] and terminated and info["slip"].any()
    env.close()


def test_rgb_array_render():
    env = make("grasp_env/CubeGrasp-v0", render_mode="rgb_array", terminate_on_slip=False)
    env.reset(seed=0)
    first = env.render()
    env.step(np.zeros(3, np.float32))
    env.step(np.zeros(3, np.float32))
    later = env.render()
    assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3
    assert not np.array_equal(first, later)  # the cube has turned
    env.close()
    env.close()  # closing twice is harmless


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_check_env_with_its_render_check(env_id):
    """Gymnasium's check_env with its render check: rgb_array frames, and every declared mode
    made from the spec (headless, "human" warns that it draws nothing; nothing else may)."""
    env = gym.make(env_id, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", "render_mode='human' needs a display", RuntimeWarning)
        check_env(env.unwrapped)
    env.close()


def test_record_video(tmp_path):
    """Gymnasium's RecordVideo writes an episode that decodes frame by frame (the video extra)."""
    import imageio
    from gymnasium.wrappers import RecordVideo

    env = gym.make("grasp_env/CubeGrasp-v0", render_mode="rgb_array", terminate_on_slip=False)
    folder = tmp_path / "videos"  # a new folder: RecordVideo warns about an existing one
    env = RecordVideo(env, str(folder), episode_trigger=lambda _: True, disable_logger=True)
    env.reset(seed=0)
    steps = 0
    while True:
        _, _, terminated, truncated, _ = env.step(np.zeros(3, np.float32))
        steps += 1
        if terminated or truncated:
            break
    env.close()
    (video,) = folder.glob("*.mp4")
    with imageio.get_reader(str(video), "ffmpeg") as reader:
        frames = list(reader.iter_data())  # len(reader) is inf: list(reader) tries to allocate it
        fps = reader.get_meta_data()["fps"]
    assert len(frames) == steps + 1 and fps == 10  # the reset's frame, then one per step
    assert frames[0].ndim == 3 and frames[0].std() > 1.0  # a picture, not a blank frame
    assert not np.array_equal(frames[0], frames[-1])  # the cube has turned


def test_sampled_episodes_equal_fresh_builds():
    """The sampler reuses its screening solves: the episodes must equal ones built afresh."""
    from grasp_env.envs.cube_grasp.episodes import build_episodes, sample_episodes
    from grasp_env.envs.cube_grasp.scenes import SceneSampler

    sampler = SceneSampler()
    rngs = [np.random.default_rng(seed) for seed in range(20)]
    sampled = sample_episodes(rngs, sampler, 2.0, np.deg2rad(1.0))
    fresh = build_episodes(sampled.scenes, 2.0)
    # the screened poses were solved without the previous pose's optimum as a start: the same
    # optimum to rounding
    exact = {key: value for key, value in vars(sampled.poses).items() if "expert" not in key}
    assert_same(exact, {key: vars(fresh.poses)[key] for key in exact})
    np.testing.assert_allclose(sampled.poses.expert_k_w, fresh.poses.expert_k_w, atol=1e-12)
    np.testing.assert_allclose(sampled.poses.expert_reward, fresh.poses.expert_reward, atol=1e-14)
    assert np.all(sampled.worst_expert_reward() >= np.deg2rad(1.0))


@pytest.mark.fast
def test_expert_bad_input_raises():
    expert = MinimaxExpert()
    with pytest.raises(ValueError, match=r"32 \(3 fingers\) or 38"):
        expert.predict(np.zeros(30, np.float32))
    with pytest.raises(ValueError, match="finite"):
        expert.predict(np.full(32, np.nan, np.float32))
    with pytest.raises(ValueError, match=r"\(size,\) or \(batch, size\)"):
        expert.predict(np.zeros((2, 2, 32), np.float32))
    with pytest.raises(ValueError, match="k_max_ratio"):
        MinimaxExpert(k_max_ratio=-1.0)
    for size, m in ((32, 3), (38, 6)):  # an empty batch is answered, not refused
        actions, _ = expert.predict(np.zeros((0, size), np.float32))
        assert actions.shape == (0, m) and actions.dtype == np.float32


def test_step_kernel_matches_the_mechanics():
    """The compiled step (eq. 4 and eq. 2) against grasp_env.mechanics, edge cases included."""
    from grasp_env.envs.kernels import evaluate_grips
    from grasp_env.mechanics import contact_pairs, friction_angles, interaction_basis, net_forces

    rng = np.random.default_rng(0)
    count, n = 2000, 4
    positions = rng.normal(size=(count, n, 3))
    basis = interaction_basis(positions)
    pairs = contact_pairs(n)
    directions = basis[:, np.arange(6), pairs[:, 0], :]
    normals = rng.normal(size=(count, n, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    forces = rng.normal(size=(count, n, 3))
    actions = rng.uniform(-1.5, 1.5, (count, 6))
    actions[:3] = 0.0
    forces[0], forces[1], forces[2] = 2 * normals[0], -3 * normals[1], 0.0  # 0, pi, P = 0
    weight = 10.0 ** rng.uniform(-6, 6, count)  # forces are in units of w, reported in newtons
    limit = np.full(count, 0.4)
    ok, k, net, theta, margin, reward = evaluate_grips(
        forces, directions, normals, pairs, np.arange(count), actions, 1.7, weight, limit
    )
    assert ok
    np.testing.assert_allclose(k, np.clip(actions, -1, 1) * 1.7 * weight[:, None], rtol=1e-15)
    net = net / weight[:, None, None]
    unit = net_forces(forces, basis, np.clip(actions, -1, 1) * 1.7)
    np.testing.assert_allclose(net, unit, rtol=0, atol=1e-12)
    np.testing.assert_allclose(theta, friction_angles(net, normals), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(theta[:3], [[0.0] * n, [np.pi] * n, [0.0] * n])
    np.testing.assert_array_equal(margin, 0.4 - theta)
    np.testing.assert_array_equal(reward, margin.min(axis=1))


@pytest.mark.parametrize("faces", [("-x", "-y", "-z"), FOUR_FINGER_FACES])
@pytest.mark.fast
def test_pose_kernels_match_the_mechanics(faces):
    """The compiled episode geometry (and the expert's grasp from an observation) against the
    numpy mechanics: rotation (eq. 5), grasp, equilibrating forces and the observation layout."""
    from grasp_env.envs.cube_grasp.episodes import build_episodes
    from grasp_env.envs.cube_grasp.scenes import SceneSampler
    from grasp_env.mechanics import (
        contact_pairs,
        equilibrating_forces,
        grasp,
        interaction_basis,
        load_wrench,
        pose_rotation,
    )

    sampler = SceneSampler(faces=faces, extra_force_max=0.8, extra_torque_max=0.8)
    scenes = sampler.scenes(sampler.raw(np.random.default_rng(3), 50))
    poses = build_episodes(scenes, 2.0).poses
    episode = np.repeat(np.arange(len(scenes)), scenes.length)
    step = np.concatenate([np.arange(length) for length in scenes.length])
    alphas = scenes.alpha_start[episode] + scenes.alpha_step[episode] * step
    rotations = pose_rotation(scenes.axis[episode], np.deg2rad(alphas))
    wrench = load_wrench(
        scenes.weight[episode], scenes.extra_force[episode], scenes.extra_torque[episode]
    )
    relative = (scenes.contacts - scenes.cg_offset[:, None])[episode]
    limit = np.arctan(scenes.mu[episode])
    g = grasp(relative, scenes.normals[episode], rotations, wrench, limit)
    n, pairs = len(faces), contact_pairs(len(faces))
    np.testing.assert_array_equal(poses.alphas, alphas)
    np.testing.assert_array_equal(poses.limit, limit)
    np.testing.assert_allclose(poses.rotations, rotations, rtol=0, atol=1e-15)
    np.testing.assert_allclose(poses.normals, g.normals, rtol=0, atol=1e-15)
    weight = scenes.weight[episode][:, None]
    np.testing.assert_allclose(poses.forces_w, g.equilibrating / weight[..., None], atol=1e-14)
    np.testing.assert_array_equal(poses.weight, weight[:, 0])
    np.testing.assert_allclose(
        poses.directions, g.basis[:, np.arange(len(pairs)), pairs[:, 0]], rtol=0, atol=1e-15
    )
    layout = ObservationLayout(n)
    expected = np.empty((len(episode), layout.size))
    expected[:, layout.rotation] = np.concatenate([rotations[..., 0], rotations[..., 1]], 1)
    expected[:, layout.positions] = g.positions.reshape(len(episode), -1)
    expected[:, layout.normals] = g.normals.reshape(len(episode), -1)
    expected[:, layout.force] = wrench[:, :3] / weight
    expected[:, layout.torque] = wrench[:, 3:] / weight
    expected[:, layout.friction_limit] = limit
    expected[:, layout.phase] = step / scenes.length[episode]
    assert poses.observations.dtype == np.float32
    # float32 roundings of values 1e-15 apart: equal, or one float32 step (< 2.4e-7) apart
    np.testing.assert_allclose(poses.observations, expected, rtol=0, atol=2.4e-7)
    # the expert rebuilds the grasp from the observation alone
    from grasp_env.envs.kernels import observation_grasps

    obs = poses.observations.astype(float)
    positions = obs[:, layout.positions].reshape(-1, n, 3)
    forces, normals = np.empty_like(positions), np.empty_like(positions)
    basis = np.empty((len(obs), len(pairs), n, 3))
    observation_grasps(obs, pairs, forces, basis, normals)
    load = np.concatenate([obs[:, layout.force], obs[:, layout.torque]], 1)
    np.testing.assert_allclose(forces, equilibrating_forces(positions, load), rtol=0, atol=1e-13)
    np.testing.assert_allclose(basis, interaction_basis(positions), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(normals, obs[:, layout.normals].reshape(-1, n, 3))


def test_sampled_scenes_within_their_ranges():
    """Every drawn quantity stays in its documented range (the extra torque's z component once
    reused a normal draw of the axis)."""
    from grasp_env.envs.cube_grasp.scenes import SceneSampler

    sampler = SceneSampler(
        extra_force_max=0.3, extra_torque_max=0.4, cg_offset_max=0.2, contact_offset=0.5
    )
    scenes = sampler.scenes(sampler.raw(np.random.default_rng(0), 5000))
    weight = scenes.weight[:, None]
    assert np.all(np.abs(scenes.extra_force) <= 0.3 * weight)
    assert np.all(np.abs(scenes.extra_torque) <= 0.4 * weight)
    assert np.all(np.abs(scenes.extra_torque).max(0) > 0.35 * weight.max())
    assert np.all(np.abs(scenes.cg_offset) <= 0.1)
    assert np.all((scenes.weight >= 1) & (scenes.weight <= 10))
    assert np.all((scenes.mu >= 0.3) & (scenes.mu <= 1))
    np.testing.assert_allclose(np.linalg.norm(scenes.axis, axis=1), 1.0)
    assert np.all(np.abs(scenes.contacts).max(-1) == 0.5)  # on a face of the unit cube
    assert np.all(np.sort(np.abs(scenes.contacts), -1)[..., 1] <= 0.25)  # offsets <= 0.5 L / 2
