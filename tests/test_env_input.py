"""The environments' bad input (actions, options, kwargs, ranges) and their scene options
(docs/environments.md).
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from env_helpers import FAST_IDS, assert_same, make

from grasp_env.mechanics import Scene


@pytest.mark.parametrize(
    ("action", "message"),
    [
        (np.zeros(2), r"shape \(3,\)"),
        (np.zeros((1, 3)), r"shape \(3,\)"),
        (np.array([0.0, np.nan, 0.0]), "finite"),
        (np.array([np.inf, 0.0, 0.0]), "finite"),
        (["a", "b", "c"], "finite real numbers"),
        (np.array([1j, 0, 0]), "finite real numbers"),
        ([True, False, True], "bool"),
        ([True, 0.5, 0.5], "booleans"),
    ],
)
@pytest.mark.fast
def test_bad_action_raises(action, message):
    env = gym.make("grasp_env/CubeGrasp-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(action)


def test_out_of_range_action_is_clipped():
    big, clipped = make("grasp_env/CubeGrasp-v0"), make("grasp_env/CubeGrasp-v0")
    big.reset(seed=0)
    clipped.reset(seed=0)
    result = big.step(np.array([7.0, -9.0, 0.5]))
    assert_same(result, clipped.step(np.array([1.0, -1.0, 0.5])))
    np.testing.assert_allclose(result[4]["k"], [10.0, -10.0, 5.0])


@pytest.mark.fast
def test_step_before_reset_and_after_the_end_raises():
    env = gym.make("grasp_env/CubeGrasp-v0").unwrapped
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3))
    env.reset(seed=0)
    env.step(np.ones(3))  # slips: the episode ends
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3))


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"seen": {}}, "unknown option 'seen'"),
        ({"scene": {"friction": 0.5}}, "unknown scene key 'friction'"),
        ({"scene": {"trajectory": {"steps": 3}}}, "unknown trajectory key 'steps'"),
        ({"scene": {"contacts": np.zeros((2, 3))}}, r"shape \(3, 3\)"),
        ({"scene": {"contacts": [[-0.5, 0, 0], [0, -0.5, 0], [0, 0, -0.4]]}}, "not on a face"),
        ({"scene": {"mu": 0.0}}, r"'mu' must be a finite number in \[0.001, 1000\]"),
        ({"scene": {"mu": "high"}}, "'mu' must be a finite number"),
        ({"scene": {"weight": -1.0}}, r"'weight' must be a finite number in \[1e-06, 1e\+06\]"),
        ({"scene": {"weight": True}}, "'weight' must be a finite number"),
        ({"scene": {"extra_force": [0, 0, 5 * (1 - 1e-9)]}}, "nearly cancel the weight"),
        ({"scene": {"trajectory": {"alpha_step_deg": 1e-6}}}, "at most 10000 poses"),
        ({"scene": {"trajectory": {"alpha_start_deg": "a"}}}, "'alpha_start_deg' must be"),
        ({"scene": {"cg_offset": [0.6, 0, 0]}}, "inside the box"),
        ({"scene": {"extra_force": [6.0, 0, 0]}}, "at most the weight"),
        ({"scene": {"extra_torque": [0, 0, 9.0]}}, "at most weight x edge"),
        ({"scene": {"trajectory": {"alpha_end_deg": -20.0}}}, "alpha_end_deg"),
        ({"scene": {"trajectory": {"axis": [0, 0, 0]}}}, "axis"),
        ({"scene": "paper"}, "mapping"),
        ("scene", "options must be a mapping"),
    ],
)
@pytest.mark.parametrize("env_id", ["grasp_env/CubeGrasp-v0", "grasp_env/CubeGraspRandom-v0"])
@pytest.mark.fast
def test_bad_option_raises(env_id, options, message):
    env = gym.make(env_id).unwrapped
    with pytest.raises(ValueError, match=message):
        env.reset(seed=0, options=options)


def generator_states(env) -> list:
    """The states of an environment's generators (a batched vector env's: one a sub-env)."""
    env = env.unwrapped
    return [r.bit_generator.state for r in getattr(env, "_rngs", None) or [env.np_random]]


REFUSED_OPTIONS = [{"bogus": 1}, {"scene": {"mu": 0.0}}]


@pytest.mark.parametrize("options", REFUSED_OPTIONS)
@pytest.mark.parametrize("env_id", [*FAST_IDS, "grasp_env/CubeGait-v0"])
def test_refused_reset_changes_nothing(env_id, options):
    """A reset refused for its options neither seeds nor advances the generator: the next
    reset() is the one it would have been without the refused call."""
    fresh = make(env_id)
    want = [fresh.reset(seed=5), fresh.reset()]
    env = make(env_id)
    first = env.reset(seed=5)
    with pytest.raises(ValueError, match=r"option|'mu'"):
        env.reset(seed=6, options=options)
    assert env.unwrapped.np_random_seed == 5
    assert_same([first, env.reset()], want)
    assert generator_states(env) == generator_states(fresh)


@pytest.mark.parametrize(
    "options", [*REFUSED_OPTIONS, {"scene": {"mu": 0.0}, "reset_mask": np.array([False, True])}]
)
@pytest.mark.parametrize("env_id", [*FAST_IDS, "grasp_env/CubeGait-v0"])
def test_refused_vector_reset_changes_nothing(env_id, options):
    """The same for the vector envs: no sub-environment's generator is seeded or advanced."""

    def make_vec():
        return gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")

    fresh = make_vec()
    want = [fresh.reset(seed=5), fresh.reset()]
    venv = make_vec()
    first = venv.reset(seed=5)
    with pytest.raises(ValueError, match=r"option|'mu'"):
        venv.reset(seed=[6, 7], options=options)
    assert_same([first, venv.reset()], want)
    assert generator_states(venv) == generator_states(fresh)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"k_max_ratio": 0.0}, "k_max_ratio"),
        ({"physics": "bullet"}, "physics must be"),
        ({"render_mode": "ascii"}, "render_mode must be"),
        ({"contact_offset": 1.0}, r"contact_offset must be a finite number in \[0, 1\)"),
        ({"terminate_on_slip": "no"}, "terminate_on_slip must be True or False"),
        ({"k_max_ratio": 1e200}, r"k_max_ratio must be a finite number in \[0.001, 1000\]"),
        ({"alpha_step_deg": 1e-6}, "at most 10000 poses"),
        ({"mu_range": (0.01, 0.011)}, "must lie below the largest friction limit"),
        ({"mu_range": (0.5, 0.1)}, "mu_range"),
        ({"weight_range": (0.0, 1.0)}, "weight_range"),
        ({"alpha_start_range_deg": (-10.0, 20.0)}, "below alpha_end_range_deg"),
        ({"faces": ("-x", "-x", "-z")}, "distinct"),
        ({"faces": ("-x", "-q", "-z")}, "unknown face"),
        ({"min_expert_margin_deg": 50}, "min_expert_margin_deg"),
        ({"extra_force_max": 2.0}, "extra_force_max"),
    ],
)
@pytest.mark.fast
def test_bad_kwargs_raise(kwargs, message):
    with warnings.catch_warnings(), pytest.raises(ValueError, match=message):
        warnings.simplefilter("ignore")  # gym.make's own warning about an unknown render_mode
        gym.make("grasp_env/CubeGraspRandom-v0", **kwargs)


def test_bad_fixed_env_kwargs_raise():
    with pytest.raises(ValueError, match="unknown scene key 'size'"):
        gym.make("grasp_env/CubeGrasp-v0", scene={"size": 2.0})
    with pytest.raises(ValueError, match="3 or 4 distinct faces"):
        gym.make("grasp_env/CubeGrasp-v0", faces=("-x", "-y"))


def test_impossible_ranges_raise():
    """Ranges that almost never admit a holdable scene: a clear error, soon."""
    env = gym.make(
        "grasp_env/CubeGraspRandom-v0", mu_range=(0.05, 0.051), min_expert_margin_deg=2.0
    ).unwrapped
    with pytest.raises(ValueError, match="widen mu_range"):
        env.reset(seed=0)


def test_scene_option_pins_an_episode():
    scene = {
        "contacts": [[-0.5, 0.1, -0.2], [0.0, -0.5, 0.3], [0.2, 0.1, -0.5]],
        "cg_offset": [0.05, 0.0, -0.02],
        "weight": 3.0,
        "mu": 0.9,
        "trajectory": {"axis": [0, 1, 0], "alpha_start_deg": 0, "alpha_end_deg": 4},
    }
    fixed = make("grasp_env/CubeGrasp-v0")
    random = make("grasp_env/CubeGraspRandom-v0")
    first = rollout_with_options(fixed, scene)
    assert_same(first, rollout_with_options(random, scene))
    got = fixed.unwrapped.scene
    assert got == got and got.weight == 3.0 and got.mu == 0.9
    np.testing.assert_array_equal(got.contacts, scene["contacts"])
    np.testing.assert_allclose(fixed.unwrapped.alphas_deg, [0, 1, 2, 3, 4])
    # Options hold for that episode only: the next reset is the paper's scene again.
    fixed.reset()
    assert fixed.unwrapped.scene.weight == 5.0 and len(fixed.unwrapped.alphas_deg) == 31


def rollout_with_options(env, scene):
    obs, _ = env.reset(seed=0, options={"scene": scene})
    record = [obs]
    done = False
    while not done:
        record.append(env.step(np.array([0.2, -0.1, 0.3], np.float32)))
        done = record[-1][2] or record[-1][3]
    return record


def test_scene_option_missing_keys_keep_defaults():
    env = make("grasp_env/CubeGrasp-v0", scene={"mu": 0.7})
    env.reset(options={"scene": {"weight": 8.0}})
    scene = env.unwrapped.scene
    assert scene.mu == 0.7 and scene.weight == 8.0  # the env's mu, the option's weight
    np.testing.assert_array_equal(scene.contacts, Scene().contacts)
