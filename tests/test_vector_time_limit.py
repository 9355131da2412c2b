"""``max_episode_steps`` in the batched vector envs (envs/cube_grasp/vector.py,
envs/gait/vector.py, envs/cube_grasp/mujoco_vector.py): ``gym.make_vec(id, ...,
max_episode_steps=k)`` passes it to a vector entry point, which must cut every
sub-environment's episode after k steps as Gymnasium's ``TimeLimit`` cuts each single env
under ``vectorization_mode="sync"``.

Ours and SyncVectorEnv over the TimeLimit-wrapped single envs are driven side by side with
the same seeds, masked resets and actions, through episodes that end by themselves (slips,
the trajectory's end) and episodes cut at k, in every autoreset mode, and must agree step for
step. Then an id registered with ``max_episode_steps`` in every vectorization mode, the
MuJoCo env's rollout of a cut episode, and the refused values.
"""

from __future__ import annotations

import warnings
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from vector_policies import GAIT_TURN, gait_policy, grasp_policy

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env import MinimaxExpert
from grasp_env.physics import check_trajectories

GRASP = "grasp_env/CubeGrasp-v0"
RANDOM = "grasp_env/CubeGraspRandom-v0"
GAIT = "grasp_env/CubeGait-v0"
MUJOCO = "grasp_env/CubeGraspMujoco-v0"
# The trajectories are longer than k (GRASP: 7 poses, MUJOCO: 5, GAIT: 9) or of both kinds
# (RANDOM: 2 to 10 poses), so that episodes are cut at k and end by themselves; the gait at
# k = 9, its trajectory's length, is TimeLimit's rule against the gait's own (which does not
# truncate an episode that terminated at its last pose).
SHORT = {"alpha_start_deg": -15.0, "alpha_end_deg": -9.0}  # 7 poses
RANGES = {"alpha_start_range_deg": (-12.0, -10.0), "alpha_end_range_deg": (-9.0, -3.0)}
MUJOCO_SHORT = {"alpha_start_deg": -15.0, "alpha_end_deg": -11.0}  # 5 poses
CASES = {  # id, keywords, max_episode_steps, sub-environments, steps
    "grasp": (GRASP, {"scene": {"trajectory": SHORT}}, 4, 4, 40),
    "random": (RANDOM, RANGES, 5, 4, 40),
    "gait": (GAIT, {"trajectory": GAIT_TURN}, 4, 4, 40),
    "gait-at-end": (GAIT, {"trajectory": GAIT_TURN}, 9, 4, 60),
    "mujoco": (MUJOCO, {"scene": {"trajectory": MUJOCO_SHORT}}, 3, 2, 12),
}
MODES = list(AutoresetMode)


def make_pair(env_id: str, num_envs: int, mode, k: int, **kwargs):
    """Ours (the vector entry point) and Gymnasium's SyncVectorEnv over single envs wrapped
    in TimeLimit(k) by make_vec, the same configuration."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ours = gym.make_vec(
            env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
            autoreset_mode=mode, max_episode_steps=k, **kwargs,
        )  # fmt: skip
    sync = gym.make_vec(
        env_id, num_envs=num_envs, vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": mode}, max_episode_steps=k, **kwargs,
    )  # fmt: skip
    assert isinstance(sync.unwrapped, SyncVectorEnv)
    assert not isinstance(ours.unwrapped, SyncVectorEnv)
    assert all(isinstance(env, gym.wrappers.TimeLimit) for env in sync.unwrapped.envs)
    assert ours.unwrapped.max_episode_steps == k
    return ours, sync


def phase_index(env) -> int:
    """Where the observation holds the phase, steps taken / trajectory length (1 at the
    trajectory's end)."""
    task = getattr(env.unwrapped, "task", None)
    return task.pose_size() - 1 if task is not None else env.single_observation_space.shape[0] - 1


def assert_info_equal(ours: dict, theirs: dict, key: str) -> None:
    """The masks of ``key`` equal, and its values where set."""
    count = len(ours["_alpha_deg"])
    mask = theirs.get(f"_{key}", np.zeros(count, bool))
    np.testing.assert_array_equal(ours.get(f"_{key}", np.zeros(count, bool)), mask, err_msg=key)
    if mask.any():
        np.testing.assert_array_equal(ours[key][mask], theirs[key][mask], err_msg=key)


def assert_physics_equal(ours: dict, theirs: dict, key: str, done: np.ndarray | None) -> int:
    """MuJoCo's reports (``key``, a dict of arrays): ours equal SyncVectorEnv's wherever it
    has one. ``done`` given (the rollout): ours has one for exactly the ended episodes, also
    those TimeLimit cut, where the wrapped single env can give none. Returns how many
    reports were compared."""
    count = len(ours["_alpha_deg"])
    want = theirs.get(f"_{key}", np.zeros(count, bool))
    got = ours.get(f"_{key}", np.zeros(count, bool))
    np.testing.assert_array_equal(got, want if done is None else done, err_msg=key)
    assert not (want & ~got).any(), key
    for i in np.flatnonzero(want):
        for field, value in theirs[key].items():
            if field.startswith("_"):
                continue
            assert ours[key][f"_{field}"][i], field
            if value[i] is None:
                assert ours[key][field][i] is None, field
            else:
                np.testing.assert_array_equal(
                    np.asarray(ours[key][field][i], float), np.asarray(value[i], float), field
                )
    return int(want.sum())


def assert_step_equal(ours: tuple, theirs: tuple, mode, physics: bool) -> Counter:
    """Observations, rewards, terminated and truncated equal, and the info (SAME_STEP: the
    final observations and infos too); returns the MuJoCo reports compared."""
    names = ("obs", "reward", "terminated", "truncated")
    for name, a, b in zip(names, ours[:4], theirs[:4], strict=True):
        np.testing.assert_array_equal(a, b, err_msg=name)
    info, want = ours[4], theirs[4]
    done = ours[2] | ours[3]
    compared: Counter = Counter()
    assert_info_equal(info, want, "alpha_deg")
    if physics:
        compared["physics"] += assert_physics_equal(info, want, "physics", None)
    same_step = mode == AutoresetMode.SAME_STEP
    np.testing.assert_array_equal(info.get("_final_obs"), want.get("_final_obs"))
    if same_step and "_final_obs" in want:
        for i in np.flatnonzero(want["_final_obs"]):
            np.testing.assert_array_equal(info["final_obs"][i], want["final_obs"][i])
        final, final_want = info["final_info"], want["final_info"]
        assert_info_equal(final, final_want, "alpha_deg")
        if physics:
            key = "physics_trajectory"
            compared[key] += assert_physics_equal(final, final_want, key, done)
    elif physics:
        compared["physics_trajectory"] += assert_physics_equal(
            info, want, "physics_trajectory", done
        )
    if same_step and physics:
        assert "physics_trajectory" not in info  # the ended episodes' info is final_info
    return compared


def masked_reset(ours, sync, mask: np.ndarray, seed) -> np.ndarray:
    options = {"reset_mask": mask}
    obs, _ = ours.reset(seed=seed, options=options)
    np.testing.assert_array_equal(obs, sync.reset(seed=seed, options=dict(options))[0])
    return obs


def drive(ours, sync, policy, steps: int, k: int, rng: np.random.Generator) -> Counter:
    """Both envs from the same seeds through ``steps`` steps of the same actions, equal at
    every step. Before a step: in DISABLED mode the ended sub-environments are reset with a
    mask; in every mode a random one is sometimes reset too (its step count starts again).
    Checks that no episode outlives k steps and counts how the episodes ended."""
    mode = ours.unwrapped.autoreset_mode
    physics = "Mujoco" in ours.spec.id
    phase = phase_index(ours)
    num = ours.num_envs
    seen: Counter = Counter()
    obs, _ = ours.reset(seed=7)
    np.testing.assert_array_equal(obs, sync.reset(seed=7)[0])
    ended = np.zeros(num, bool)  # ended and not reset (NEXT_STEP, DISABLED)
    t = np.zeros(num, int)  # steps into the current episodes
    for _ in range(steps):
        mask = ended.copy() if mode == AutoresetMode.DISABLED else np.zeros(num, bool)
        if rng.random() < 0.15:
            mask[rng.integers(num)] = True
        if mask.any():
            seen["mid-episode resets"] += int((mask & (t > 0) & ~ended).sum())
            obs = masked_reset(ours, sync, mask, int(rng.integers(1000)))
            t[mask], ended[mask] = 0, False
        actions = policy(obs)
        result = ours.step(actions)
        seen += assert_step_equal(result, sync.step(actions), mode, physics)
        obs, _, terminated, truncated, info = result
        t = np.where(ended if mode == AutoresetMode.NEXT_STEP else False, 0, t + 1)
        done = terminated | truncated
        assert (t[done] <= k).all() and (t <= k).all()
        finals = info.get("final_obs") if mode == AutoresetMode.SAME_STEP else obs
        for i in np.flatnonzero(done):
            at_end = finals[i][phase] == 1.0  # the trajectory's last pose
            if truncated[i] and not at_end:
                assert t[i] == k  # cut: exactly k steps
                seen["cut"] += 1
                seen["cut as it terminated"] += int(terminated[i])
            elif truncated[i] and t[i] == k:
                seen["trajectory's end at k"] += 1
                seen["terminated at the end, k"] += int(terminated[i])
            elif truncated[i]:
                seen["trajectory's end before k"] += 1
            else:
                seen["terminated before k"] += 1
        if mode == AutoresetMode.SAME_STEP:
            t[done] = 0
        ended = done & (mode != AutoresetMode.SAME_STEP)
    return seen


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.value)
@pytest.mark.parametrize("case", list(CASES))
def test_max_episode_steps_matches_sync_time_limit(case, mode):
    """Step for step SyncVectorEnv over TimeLimit-wrapped single envs, through several cut
    episodes, in every autoreset mode, with masked resets (DISABLED: every ended episode)."""
    env_id, kwargs, k, num_envs, steps = CASES[case]
    rng = np.random.default_rng(4)
    ours, sync = make_pair(env_id, num_envs, mode, k, **kwargs)
    policy = gait_policy(rng, noisy=0.1) if env_id == GAIT else grasp_policy(rng)
    seen = drive(ours, sync, policy, steps, k, rng)
    assert seen["terminated before k"] >= 1, seen
    if case == "gait-at-end":
        # TimeLimit truncates an episode that terminated at its k-th step, the gait does not
        assert seen["terminated at the end, k"] >= 1, seen
        assert seen["trajectory's end at k"] >= 2, seen
    else:
        assert seen["cut"] >= (3 if env_id == MUJOCO else 6), seen
    if case == "random":
        assert seen["trajectory's end before k"] >= 2, seen
    if case in ("grasp", "gait"):
        assert seen["cut as it terminated"] >= 1, seen
    if mode == AutoresetMode.DISABLED:
        assert seen["mid-episode resets"] >= 1, seen
    if env_id == MUJOCO:
        # every ended episode got its rollout, the cut ones too (assert_physics_equal); equal
        # to SyncVectorEnv's where it has one
        assert seen["physics_trajectory"] >= 1, seen
        assert seen["physics"] >= steps
    ours.close()
    sync.close()


def test_cut_rollout_is_the_rollout_of_the_steps_taken():
    """A MuJoCo episode cut at k: the vector entry point's ``physics_trajectory`` is the
    continuous rollout of the k grips at the k poses, which a single env under TimeLimit does
    not give but ``check_trajectories`` on its steps' ``contact_forces`` does (the recipe of
    docs/environments.md)."""
    kwargs = {"terminate_on_slip": False, "max_episode_steps": 3}
    single = gym.make(MUJOCO, **kwargs)
    vector = gym.make_vec(MUJOCO, num_envs=1, vectorization_mode="vector_entry_point", **kwargs)
    obs, _ = single.reset(seed=0)
    np.testing.assert_array_equal(vector.reset(seed=0)[0], obs[None])
    expert = MinimaxExpert()
    forces = []
    for step in range(3):
        action = expert.predict(obs)[0]
        obs, reward, terminated, truncated, info = single.step(action)
        got = vector.step(action[None])
        np.testing.assert_array_equal(got[0][0], obs)
        assert (got[1][0], got[2][0], got[3][0]) == (reward, terminated, truncated)
        assert truncated == (step == 2) and not terminated
        forces.append(info["contact_forces"])
    assert "physics_trajectory" not in info  # TimeLimit truncated it from outside
    report = got[4]["physics_trajectory"]
    assert got[4]["_physics_trajectory"][0] and len(report["pose_holds"][0]) == 3
    env = single.unwrapped
    want = check_trajectories([(env.scene, env.episode.rotations[:3], np.stack(forces), None)])
    for key, value in want[0].as_dict().items():
        if value is None:
            assert report[key][0] is None, key
        else:
            np.testing.assert_array_equal(np.asarray(report[key][0], float), value, key)
    single.close()
    vector.close()


@pytest.fixture
def limited_id():
    """CubeGrasp-v0 registered with max_episode_steps=3 (none of ours is), removed after."""
    spec = gym.spec(GRASP)
    env_id = "grasp_env_test/CubeGraspLimited-v0"
    gym.register(
        id=env_id, entry_point=spec.entry_point, vector_entry_point=spec.vector_entry_point,
        kwargs={"terminate_on_slip": False}, max_episode_steps=3,
    )  # fmt: skip
    yield env_id
    del gym.registry[env_id]


def test_registered_max_episode_steps_in_every_vectorization_mode(limited_id):
    """make_vec of an id registered with max_episode_steps (no keyword): every mode cuts at
    step 3, with the same results (the default mode is the vector entry point)."""
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (8, 2, 3)).astype(np.float32)
    runs = {}
    for mode in [None, "vector_entry_point", "sync", "async"]:
        envs = gym.make_vec(limited_id, num_envs=2, vectorization_mode=mode)
        results = [envs.reset(seed=1)[0]]
        results += [envs.step(a)[:4] for a in actions]
        envs.close()
        runs[mode] = results
        truncated = np.array([r[3] for r in results[1:]])
        want = [False, False, True, False] * 2  # NEXT_STEP: the 4th step resets
        np.testing.assert_array_equal(truncated, np.array([want, want]).T, err_msg=str(mode))
    assert type(gym.make_vec(limited_id, num_envs=2).unwrapped).__name__ == "CubeGraspVectorEnv"
    for mode, results in runs.items():
        for got, want in zip(results, runs["sync"], strict=True):
            for a, b in zip(got, want, strict=True):
                np.testing.assert_array_equal(a, b, err_msg=str(mode))


def test_minus_one_drops_the_registered_limit_as_gym_make_does(limited_id):
    """max_episode_steps=-1 is Gymnasium's "no TimeLimit" (``gym.make`` then drops an id's
    registered limit): the vector entry point reads it as no limit too, as the sync mode's
    ``gym.make`` calls do, with the same results."""
    actions = np.random.default_rng(0).uniform(-1, 1, (8, 2, 3)).astype(np.float32)
    runs = {}
    for mode in ["vector_entry_point", "sync"]:
        envs = gym.make_vec(limited_id, num_envs=2, vectorization_mode=mode, max_episode_steps=-1)
        runs[mode] = [envs.reset(seed=1)[0]] + [envs.step(a)[:4] for a in actions]
        envs.close()
        assert not any(result[3].any() for result in runs[mode][1:]), mode  # never cut at 3
    for got, want in zip(runs["vector_entry_point"], runs["sync"], strict=True):
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("value", [0, -2, 2.5, True, "3", np.float64(3.0)], ids=repr)
@pytest.mark.parametrize("env_id", [GRASP, RANDOM, GAIT, MUJOCO])
def test_bad_max_episode_steps_is_refused(env_id, value):
    with pytest.raises(ValueError, match=r"max_episode_steps must be None, -1 \(no limit\) or"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point",
                     max_episode_steps=value)  # fmt: skip


@pytest.mark.parametrize("env_id", [GRASP, RANDOM, GAIT, MUJOCO])
def test_max_episode_steps_none_and_numpy_integers(env_id):
    """None is no limit (the trajectory's end truncates); a numpy integer is a limit."""
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point",
                        max_episode_steps=None)  # fmt: skip
    assert envs.unwrapped.max_episode_steps is None
    envs.close()
    envs = gym.make_vec(
        env_id, num_envs=2, vectorization_mode="vector_entry_point", terminate_on_slip=False,
        max_episode_steps=np.int64(2),
    )  # fmt: skip
    assert envs.unwrapped.max_episode_steps == 2 and type(envs.unwrapped.max_episode_steps) is int
    envs.reset(seed=0)
    zero = np.zeros(envs.action_space.shape, np.float32)
    assert [bool(envs.step(zero)[3].all()) for _ in range(3)] == [False, True, False]
    envs.close()
