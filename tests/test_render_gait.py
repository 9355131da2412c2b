"""Every registered id renders ``rgb_array`` frames headless; the gait ids' frames in detail.

For every id in the ``grasp_env/`` namespace of Gymnasium's registry: ``gym.make(id,
render_mode="rgb_array")`` draws a picture (H, W, 3) uint8 that is not blank, Gymnasium's full
``check_env`` (its render check included) passes without a warning, and SB3's
``make_vec_env``, which asks for ``rgb_array``, makes environments that render. Then the gait
view (grasp_env.envs.gait.render): it follows the pose, shows a slip in red, names the fingers,
the vector env draws what the single one draws, and nothing loads MuJoCo until a render.

Runs headless: ``grasp_env.physics`` picks MUJOCO_GL (OSMesa or EGL) when no display is set.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import grasp_env
from grasp_env.envs.gait import GaitExpert

REGISTERED = sorted(i for i in gym.registry if i.startswith("grasp_env/"))
GAIT_IDS = [i for i in REGISTERED if "Gait" in i]
GAIT = "grasp_env/CubeGait-v0"
MOVES = "grasp_env/CubeGaitMoves-v0"


def red_pixels(image: np.ndarray) -> int:
    r, g, b = (image[..., c].astype(int) for c in range(3))
    return int(np.sum((r > 150) & (g < 90) & (b < 90)))


def cone_pixels(image: np.ndarray) -> int:
    """Pixels of the green-to-yellow cones (and arrows) of loaded fingers inside their cones:
    green above blue, which the cube, the sky and the grey free sites are not."""
    g, b = image[..., 1].astype(int), image[..., 2].astype(int)
    return int(np.sum(g > b + 20))


def assert_picture(frame: np.ndarray) -> None:
    """A (H, W, 3) uint8 picture, not a constant or nearly blank one."""
    assert isinstance(frame, np.ndarray)
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[0] >= 16, frame.shape
    assert frame.dtype == np.uint8
    assert frame.std() > 5.0
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 100


def test_the_registry_holds_every_id():
    assert set(REGISTERED) == set(grasp_env.ENV_IDS)
    assert {GAIT, MOVES} <= set(GAIT_IDS)


@pytest.mark.parametrize("env_id", REGISTERED)
def test_every_id_renders_rgb_array(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    assert "rgb_array" in env.metadata["render_modes"]
    assert env.metadata["render_fps"] > 0
    env.reset(seed=0)
    first = env.render()
    assert_picture(first)
    env.step(env.action_space.sample())
    assert_picture(env.render())
    env.close()
    env.close()  # closing twice is harmless


@pytest.mark.parametrize("env_id", REGISTERED)
def test_every_id_passes_check_env_with_its_render_check(env_id):
    """check_env makes every declared mode from the spec; headless, "human" warns that it
    draws nothing, and no other warning may come."""
    env = gym.make(env_id, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", "render_mode='human' needs a display", RuntimeWarning)
        check_env(env.unwrapped)
    env.close()


@pytest.mark.parametrize("env_id", REGISTERED)
def test_every_id_through_sb3_make_vec_env(env_id):
    """SB3's make_vec_env makes its environments with render_mode="rgb_array": they render."""
    from stable_baselines3.common.env_util import make_vec_env

    envs = make_vec_env(env_id, n_envs=2, seed=0, env_kwargs={"terminate_on_slip": False})
    assert envs.render_mode == "rgb_array"
    envs.reset()
    images = envs.get_images()
    assert len(images) == 2
    for image in images:
        assert_picture(image)
    envs.close()


# ------------------------------------------------------------------------------- the gait view


@pytest.fixture(scope="module")
def expert_frames():
    """The certified optimal gait's episode on CubeGait-v0: the reset's frame, then one a step."""
    env = gym.make(GAIT, render_mode="rgb_array")
    expert = GaitExpert()
    obs, _ = env.reset(seed=0)
    frames, rewards = [env.render()], []
    while True:
        obs, reward, terminated, truncated, _ = env.step(expert.predict(obs)[0])
        frames.append(env.render())
        rewards.append(reward)
        if terminated or truncated:
            break
    env.close()
    return frames, rewards


def test_gait_frames_follow_the_pose_and_show_a_safe_grip(expert_frames):
    frames, rewards = expert_frames
    assert len(frames) == 182  # the reset's, then the 181 poses of the paper's turn
    assert min(rewards) > 0.0  # the certified gait holds at every pose (6.97 deg)
    for frame in frames[::30]:
        assert_picture(frame)
        assert red_pixels(frame) == 0  # no finger slips
        assert cone_pixels(frame) > 500  # the cones of the loaded fingers
    first, middle = frames[1].astype(int), frames[91].astype(int)  # alpha -90 and 0 deg
    assert np.any(np.abs(first - middle) > 30, axis=-1).mean() > 0.05


def test_a_slipping_gait_grip_is_drawn_red():
    env = gym.make(GAIT, render_mode="rgb_array", terminate_on_slip=False)
    env.reset(seed=0)
    safe = env.render()
    action = np.zeros(env.action_space.shape, np.float32)
    action[:10] = 1.0  # every pair squeezed: finger1 and finger4 leave their cones
    _, reward, _, _, info = env.step(action)
    assert reward < 0.0 and info["slip"].any()
    slipping = env.render()
    assert red_pixels(safe) == 0
    assert red_pixels(slipping) > 200
    env.close()


def test_gait_caption_names_the_fingers_on_the_faces():
    from grasp_env.envs.gait.render import GaitView, resting_grips

    env = gym.make(GAIT).unwrapped
    view = GaitView(env.task, width=64, height=64)  # no MuJoCo model until a render
    contacts, forces = resting_grips(env.task, [env.task.start], [0])
    assert contacts[0].tolist() == [2, -1, 3, 4, -1]  # the optimal gait's first state
    np.testing.assert_allclose(forces[0, [1, 4]], 0.0, atol=0.0)  # the lifted carry nothing
    assert view.caption(0, contacts[0], None) == [
        "alpha -90 deg",
        "finger1 -z  finger3 +x  finger4 +y",
        "lifted: finger2, thumb",
    ]
    assert view.caption(5, [-1, 0, 2, -1, -1], np.radians(-3.0))[::2] == [
        "alpha -85 deg   margin -3.00 deg",
        "the cube drops",
    ]
    view.close()


def test_vector_gait_env_renders_the_single_env_frames():
    """A tuple of num_envs frames, each equal to the single environment's, at the reset, after
    steps (the moves env: one sub-environment lifts a finger) and after an autoreset."""
    single = gym.make(MOVES, render_mode="rgb_array", max_episode_steps=2)
    envs = gym.make_vec(
        MOVES, num_envs=2, vectorization_mode="vector_entry_point", render_mode="rgb_array",
        max_episode_steps=2,
    )  # fmt: skip
    assert envs.metadata["render_modes"] == ["rgb_array"] and envs.metadata["render_fps"] == 20
    envs.reset(seed=0)
    single.reset(seed=0)
    frames = envs.render()
    assert isinstance(frames, tuple) and len(frames) == 2
    np.testing.assert_array_equal(frames[0], single.render())
    np.testing.assert_array_equal(frames[1], frames[0])
    expert = GaitExpert(optimal_grip=True)
    obs, _ = single.reset(seed=0)
    moves = [int(expert.predict(obs)[0]), 0]
    for step in range(3):  # steps 1 and 2, then the autoreset (NEXT_STEP)
        envs.step(np.array(moves))
        frames = envs.render()
        if step == 2:
            single.reset()
            np.testing.assert_array_equal(frames[0], single.render())
            break
        obs, *_ = single.step(moves[0])
        np.testing.assert_array_equal(frames[0], single.render())
        moves = [int(expert.predict(obs)[0]), 0]
    envs.close()
    assert envs.unwrapped._view is None
    single.close()


def test_render_modes_are_checked_and_close_frees_the_view():
    with pytest.raises(ValueError, match=r"render_mode must be None or one of \['human', 'rgb_"):
        grasp_env.envs.gait.CubeGaitEnv(render_mode="ansi")
    with pytest.raises(ValueError, match="render_mode must be None or 'rgb_array'"):
        grasp_env.envs.gait.CubeGaitVectorEnv(num_envs=2, render_mode="human")
    plain = gym.make(GAIT)
    plain.reset()
    with pytest.warns(UserWarning, match="without a render_mode"):
        assert plain.render() is None
    env = gym.make(GAIT, render_mode="rgb_array")
    env.reset(seed=0)
    before = env.render()  # before the first step: the start's certified grip, at rest
    clone = pickle.loads(pickle.dumps(env.unwrapped))  # the view is not pickled: rebuilt
    np.testing.assert_array_equal(clone.render(), before)
    assert env.unwrapped._view is not None
    env.close()
    assert env.unwrapped._view is None
    clone.close()


def test_gait_env_loads_no_mujoco_until_it_renders():
    probe = (
        "import sys, gymnasium as gym, numpy as np, grasp_env\n"
        "env = gym.make('grasp_env/CubeGait-v0', render_mode='rgb_array')\n"
        "env.reset(); env.step(np.zeros(env.action_space.shape, np.float32))\n"
        "print('mujoco' in sys.modules)\n"
        "print(env.render().shape, 'mujoco' in sys.modules)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout == "False\n(480, 480, 3) True\n"
