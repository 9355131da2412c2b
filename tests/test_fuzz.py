"""Fuzzing the environments' inputs: reset options, constructor keywords, seeds and actions of
the single and the vector environments, valid and not.

Every outcome must be correct or a ValueError: never another exception, never NaN. "Correct"
is checked against the mechanics (``grasp_env.mechanics``, numpy), in units of the weight w:
the observation is finite and in its space, the reward is the mechanics' reward of that action
(eq. 4 and eq. 2), the forces in ``info`` are the mechanics' forces times w, no action beats the
expert's certified optimum (``optimality_gap >= -1e-12`` rad), and the same scene at another
weight gives the same reward for the same action.

The default profile is derandomised and quick; a longer study:

    GRASP_FUZZ_EXAMPLES=5000 python -m pytest tests/test_fuzz.py -p no:cacheprovider
"""

from __future__ import annotations

import os
import warnings

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.validation import K_MAX_RATIO_RANGE, MU_RANGE, WEIGHT_RANGE
from grasp_env.mechanics import (
    FACES,
    Scene,
    friction_angles,
    net_forces,
    pose_rotation,
    scene_grasp,
)

EXAMPLES = int(os.environ.get("GRASP_FUZZ_EXAMPLES", "0"))
FUZZ = settings(
    max_examples=EXAMPLES or 40,
    derandomize=not EXAMPLES,  # the suite's runs are reproducible; a study explores
    deadline=None,
    database=None,  # nothing written into the working tree
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
FIXED, RANDOM, FOUR = (
    "grasp_env/CubeGrasp-v0",
    "grasp_env/CubeGraspRandom-v0",
    "grasp_env/CubeGrasp4-v0",
)
MAX_STEPPED = 8  # sub-environments a fuzzed vector env is stepped with, at most
GAP = 1e-12  # rad: no action may beat the certified optimum by more than rounding
SAME = 1e-12  # rad: rewards of one action on one scene at two weights

# ----------------------------------------------------------------------------- strategies

# Anything a user might pass where a number, a flag, a vector or a mapping belongs.
junk = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=3),
    st.complex_numbers(allow_nan=True, allow_infinity=True),
    st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -0.0, -1.0, 1e-300, 1e300, 5e-324]),
    st.floats(),
    st.integers(-(10**30), 10**30),
    st.lists(st.floats(), max_size=4),
    st.lists(st.booleans(), min_size=3, max_size=3),
    st.dictionaries(st.text(max_size=2), st.floats(), max_size=2),
    st.just(np.zeros((2, 2))),
    st.just(np.array(["a", "b", "c"])),
)


def log_uniform(low: float, high: float) -> st.SearchStrategy[float]:
    return st.floats(np.log10(low), np.log10(high)).map(lambda x: float(10.0**x))


def or_junk(valid: st.SearchStrategy) -> st.SearchStrategy:
    """Mostly valid values (three in four), sometimes anything (``st.one_of`` would not keep
    these odds: it favours the branch with more distinct values)."""
    return st.integers(0, 3).flatmap(lambda i: valid if i else junk)


weights = st.one_of(
    log_uniform(*WEIGHT_RANGE), st.sampled_from([*WEIGHT_RANGE, 1e-7, 2e6, 1e-160, 1e160])
)
mus = st.one_of(log_uniform(*MU_RANGE), st.sampled_from([*MU_RANGE, 0.0, 1e-4, 1e4]))
ratios = st.one_of(
    log_uniform(*K_MAX_RATIO_RANGE), st.sampled_from([*K_MAX_RATIO_RANGE, 1e-9, 1e200])
)
fraction = st.floats(-0.999, 0.999)


@st.composite
def contact_layouts(draw: st.DrawFn, faces: tuple[str, ...]) -> list[list[float]]:
    """Points on the named faces of the unit cube (possibly near an edge, or degenerate)."""
    points = []
    for face in faces:
        axis, sign = FACES[face]
        point = [draw(fraction) / 2 for _ in range(3)]
        point[axis] = sign * 0.5
        points.append(point)
    return points


@st.composite
def trajectories(draw: st.DrawFn) -> dict:
    spec = {}
    if draw(st.booleans()):
        spec["axis"] = draw(
            or_junk(
                st.lists(
                    st.one_of(st.floats(-1e3, 1e3), st.sampled_from([1e-300, 1e300])),
                    min_size=3,
                    max_size=3,
                )
            )
        )
    start = draw(st.floats(-180, 180))
    if draw(st.booleans()):
        spec["alpha_start_deg"] = draw(or_junk(st.just(start)))
    if draw(st.booleans()):
        spec["alpha_end_deg"] = draw(or_junk(st.floats(min(start, 30.0), 180)))
    if draw(st.booleans()):
        spec["alpha_step_deg"] = draw(
            or_junk(st.one_of(st.floats(0.5, 360), st.sampled_from([1e-6, 0.0, -1.0, 400.0])))
        )
    if draw(st.integers(0, 20)) == 0:
        spec[draw(st.text(max_size=3))] = 1.0  # an unknown key
    return spec


@st.composite
def scene_options(draw: st.DrawFn, faces: tuple[str, ...]) -> dict:
    """A reset option's scene: any subset of the keys, each valid or not."""
    weight = draw(weights)
    scene: dict = {}
    if draw(st.booleans()):
        scene["weight"] = draw(or_junk(st.just(weight)))
    if draw(st.booleans()):
        scene["mu"] = draw(or_junk(mus))
    if draw(st.booleans()):
        scene["contacts"] = draw(or_junk(contact_layouts(faces)))
    if draw(st.booleans()):
        scene["cg_offset"] = draw(
            or_junk(st.lists(fraction.map(lambda x: x / 2), min_size=3, max_size=3))
        )
    w = weight if isinstance(scene.get("weight"), float) else 5.0
    uniform = st.lists(st.floats(-1.0, 1.0).map(lambda x: x * w), min_size=3, max_size=3)
    # loads that cancel the weight, exactly or nearly
    cancelling = st.sampled_from([1.0, 1 - 1e-12, 1 - 1e-7, 1 - 1e-5]).map(
        lambda x: [0.0, 0.0, x * w]
    )
    load = st.integers(0, 4).flatmap(lambda i: cancelling if i == 0 else uniform)
    for key in ("extra_force", "extra_torque"):
        if draw(st.booleans()):
            scene[key] = draw(or_junk(load))
    if draw(st.booleans()):
        scene["trajectory"] = draw(or_junk(trajectories()))
    if draw(st.integers(0, 20)) == 0:
        scene[draw(st.text(max_size=3))] = 1.0
    return scene


def _cast(pair: tuple[np.ndarray, type]) -> np.ndarray:
    with np.errstate(over="ignore"):
        return pair[0].astype(pair[1])


def action_values(m: int, batch: tuple[int, ...] = ()) -> st.SearchStrategy:
    """Actions of the right shape (finite, huge, tiny, NaN, inf, integers) or anything else."""
    element = st.one_of(
        st.floats(-1.5, 1.5),
        st.floats(-1.5, 1.5),
        st.floats(allow_nan=False, allow_infinity=False),
        st.sampled_from([np.nan, np.inf, -np.inf, 1e-300, -1e300, 5e-324]),
    )
    shape = (*batch, m)
    size = int(np.prod(shape))
    right = st.lists(element, min_size=size, max_size=size).map(
        lambda values: np.array(values).reshape(shape)
    )
    typed = st.tuples(right, st.sampled_from([np.float64, np.float32, np.float16])).map(
        _cast  # huge values become inf in float32 and float16: refused like any other inf
    )
    wrong = st.one_of(
        junk,
        right.map(lambda a: a.astype(complex) + 1j),
        right.map(lambda a: a.astype(complex)),
        right.map(lambda a: a > 0),
        right.map(lambda a: a.astype(str)),
        right.map(lambda a: a[..., :-1]),
        right.map(lambda a: a[None]),
        right.map(lambda a: a.tolist()),
        st.just(np.zeros((*batch, m), int)),
    )
    return st.integers(0, 4).flatmap(lambda i: (right, right, right, typed, wrong)[i])


# ----------------------------------------------------------------------------- the oracle


def refused(call):
    """Run ``call``: its result, or None if it raised a ValueError (anything else fails)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # gymnasium's passive checker on odd actions
            result = call()
    except ValueError as error:
        assert str(error), "a ValueError must say what is wrong"
        event(f"refused: {str(error).split(' got ')[0].split(' (')[0][:60]}")
        return None
    event("accepted")
    return result


def unit_scene(scene: Scene) -> Scene:
    """The same scene with weight 1: its forces are the scene's in units of w."""
    w = scene.weight
    return Scene(
        contacts=scene.contacts,
        weight=1.0,
        mu=scene.mu,
        cg_offset=scene.cg_offset,
        extra_force=scene.extra_force / w,
        extra_torque=scene.extra_torque / w,
    )


def mechanics_step(scene: Scene, axis: np.ndarray, alpha_deg: float, action, ratio: float):
    """(reward, P / w) of an action at a pose, from grasp_env.mechanics alone."""
    g = scene_grasp(unit_scene(scene), pose_rotation(axis, np.deg2rad(alpha_deg)))
    k = np.clip(np.asarray(action, dtype=float), -1, 1) * ratio
    forces = net_forces(g.equilibrating, g.basis, k)
    return scene.friction_limit - friction_angles(forces, g.normals).max(), forces


def check_step(space, scene, axis, alpha, action, ratio, result) -> None:
    obs, reward, _, _, info = result
    assert obs.dtype == np.float32 and np.all(np.isfinite(obs)) and space.contains(obs)
    assert np.isfinite(reward)
    for key in ("theta", "margin", "k", "contact_forces", "equilibrating_forces", "expert_k"):
        assert np.all(np.isfinite(info[key])), key
    expected, forces = mechanics_step(scene, axis, alpha, np.asarray(action, float), ratio)
    assert reward == pytest.approx(expected, abs=1e-9)
    np.testing.assert_allclose(info["contact_forces"] / scene.weight, forces, atol=1e-9)
    assert np.isfinite(info["expert_reward"]) and info["optimality_gap"] >= -GAP
    assert info["optimality_gap"] == info["expert_reward"] - reward


def steps_checked(env, data, steps: int = 3) -> None:
    """Draw up to ``steps`` actions for a single environment and check every accepted step."""
    episode, m = env.episode, env.action_space.shape[0]
    # drawn first, whatever happens: the draws must not depend on the episode (a seed of None
    # makes it random)
    actions = [data.draw(action_values(m), f"action {t}") for t in range(steps)]
    pose = 0  # a refused action does not move the episode on
    for action in actions[: len(episode)]:
        result = refused(lambda a=action: env.step(a))
        if result is None:
            continue
        alpha, axis = episode.alphas[pose], episode.scenes.axis[0]
        used = np.asarray(action, float)
        check_step(env.observation_space, env.scene, axis, alpha, used, env.k_max_ratio, result)
        pose += 1
        if result[2] or result[3]:
            break


def at_weight(spec: dict, scene: Scene, weight: float) -> dict:
    """The scene option ``spec`` (whose scene is ``scene``) at another weight, every force
    scaled with it."""
    factor = weight / scene.weight
    out = {**spec, "weight": weight}
    for key in ("extra_force", "extra_torque"):
        # clipped: a load of exactly w must stay within [-w, w] after the rounding of factor
        out[key] = np.clip(getattr(scene, key) * factor, -weight, weight).tolist()
    return out


# ----------------------------------------------------------------------------- the tests


@FUZZ
@given(data=st.data())
@pytest.mark.parametrize("env_id", [FIXED, FOUR])
def test_fuzz_reset_options_and_actions(env_id, data):
    """Reset options (scenes of every kind) and actions of the single environment."""
    env = gym.make(env_id, terminate_on_slip=False).unwrapped
    faces, m = env.faces, env.action_space.shape[0]
    options = data.draw(or_junk(st.builds(dict, scene=scene_options(faces))), "options")
    if refused(lambda: env.reset(seed=0, options=options)) is None:
        return
    steps_checked(env, data)
    # scale-free: the same scene at the extreme weights, the same action, the same reward
    spec = (options.get("scene") or {}) if isinstance(options, dict) else {}
    action = np.linspace(-1, 1, m)
    env.reset(options=options)
    reward = env.step(action)[1]
    for weight in WEIGHT_RANGE:
        env.reset(options={"scene": at_weight(spec, env.scene, weight)})
        assert env.step(action)[1] == pytest.approx(reward, abs=SAME)


@FUZZ
@given(data=st.data())
def test_fuzz_random_env_keywords(data):
    """Constructor keywords and seeds of the random environment, then a few actions."""
    keywords = {
        "faces": st.one_of(
            st.sampled_from([("-x", "-y", "-z"), ("-x", "-y", "-z", "+z"), ("-x", "+x", "-y")]),
            st.lists(st.sampled_from(sorted(FACES)), max_size=5).map(tuple),
            junk,
        ),
        "contact_offset": or_junk(st.floats(0, 0.99)),
        "cg_offset_max": or_junk(st.floats(0, 0.99)),
        "weight_range": or_junk(st.tuples(weights, weights).map(sorted).map(tuple)),
        "mu_range": or_junk(st.tuples(st.floats(0.3, 3), st.floats(0.3, 3)).map(sorted).map(tuple)),
        "alpha_start_range_deg": or_junk(st.tuples(st.floats(-40, -20), st.floats(-20, -5))),
        "alpha_end_range_deg": or_junk(st.tuples(st.floats(5, 20), st.floats(20, 40))),
        "alpha_step_deg": or_junk(st.floats(1.0, 30.0)),
        "extra_force_max": or_junk(st.floats(0, 1)),
        "extra_torque_max": or_junk(st.floats(0, 1)),
        "min_expert_margin_deg": or_junk(st.floats(0, 5)),
        "k_max_ratio": or_junk(ratios),
        "terminate_on_slip": or_junk(st.booleans()),
    }
    chosen = data.draw(st.lists(st.sampled_from(sorted(keywords)), max_size=4, unique=True))
    kwargs = {key: data.draw(keywords[key], key) for key in chosen}
    env = refused(lambda: gym.make(RANDOM, **kwargs).unwrapped)
    if env is None:
        return
    seed = data.draw(or_junk(st.integers(0, 2**70)), "seed")
    if refused(lambda: env.reset(seed=seed)) is None:
        return
    assert env.episode.expert_reward.min() >= env.min_expert_margin  # only holdable scenes
    steps_checked(env, data)


@FUZZ
@given(data=st.data())
@pytest.mark.parametrize("env_id", [FIXED, RANDOM])
def test_fuzz_vector_env(env_id, data):
    """num_envs, seeds, options and batched actions of the vector environments."""
    num_envs = data.draw(or_junk(st.integers(1, 4)), "num_envs")
    venv = refused(
        lambda: (
            gym.make_vec(
                env_id, num_envs=num_envs, vectorization_mode="vector_entry_point"
            ).unwrapped
        )
    )
    if venv is None:
        return
    n = venv.num_envs
    if n > MAX_STEPPED:  # a valid, large num_envs: built; stepping it is for the benchmarks
        return
    seed = data.draw(
        st.one_of(
            or_junk(st.integers(0, 2**40)),
            st.lists(or_junk(st.integers(0, 2**40)), min_size=n, max_size=n),
            st.lists(st.integers(0, 9), min_size=n + 1, max_size=n + 1),
        ),
        "seed",
    )
    faces = venv.template.faces
    options = data.draw(st.one_of(st.none(), st.builds(dict, scene=scene_options(faces))))
    if refused(lambda: venv.reset(seed=seed, options=options)) is None:
        return
    m = venv.single_action_space.shape[0]
    for t in range(3):
        scenes = [venv.scene(e) for e in range(n)]
        axes = [_axis(venv, e) for e in range(n)]
        actions = data.draw(action_values(m, (n,)), f"actions {t}")
        result = refused(lambda a=actions: venv.step(a))
        if result is None:
            continue
        obs, reward, terminated, truncated, info = result
        for e in range(n):
            if not info["_theta"][e]:  # restarted (NEXT_STEP autoreset)
                continue
            single = (obs[e], reward[e], terminated[e], truncated[e], _row(info, e))
            check_step(
                venv.single_observation_space, scenes[e], axes[e], info["alpha_deg"][e],
                np.asarray(actions, float)[e], venv.template.k_max_ratio, single,
            )  # fmt: skip


def _axis(venv, e: int) -> np.ndarray:
    """Sub-environment e's trajectory axis (from its episode's scene arrays)."""
    if venv._scenes[e] is not None:
        scenes, index = venv._scenes[e]
        return scenes.axis[index]
    shared = venv._store.option if venv._where[e] == 1 else venv._store.default
    return shared.scenes.axis[0]


def _row(info: dict, e: int) -> dict:
    return {key: value[e] for key, value in info.items() if not key.startswith("_")}


@FUZZ
@given(data=st.data())
def test_fuzz_sb3_adapter(data):
    """The SB3 adapter: num_envs, seeds and actions."""
    from grasp_env.envs.sb3 import SB3VecEnv

    num_envs = data.draw(or_junk(st.integers(1, 3)), "num_envs")
    venv = refused(lambda: SB3VecEnv(FIXED, num_envs=num_envs))
    if venv is None or venv.num_envs > MAX_STEPPED:
        return
    seed = data.draw(or_junk(st.integers(0, 2**40)), "seed")
    if refused(lambda: venv.seed(seed)) is None:
        return
    obs = venv.reset()
    assert np.all(np.isfinite(obs))
    actions = data.draw(action_values(3, (venv.num_envs,)), "actions")
    venv.step_async(actions)
    result = refused(venv.step_wait)
    if result is not None:
        obs, rewards, _, _ = result
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rewards))
