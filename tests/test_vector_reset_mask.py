"""Masked resets (Gymnasium's ``reset(options={"reset_mask": mask})``) and
``AutoresetMode.DISABLED`` in the batched vector envs (envs/cube_grasp/vector.py,
envs/gait/vector.py, envs/cube_grasp/mujoco_vector.py).

The reference is Gymnasium's ``SyncVectorEnv`` over the single environments
(``vectorization_mode="sync"``): the batched env and it are driven side by side with the same
seeds, masks, options and actions, through short episodes that end at different times, and
must agree step for step. Then the errors.
"""

from __future__ import annotations

import re
import warnings
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from vector_policies import GAIT_TURN, gait_policy, grasp_policy

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env import MinimaxExpert
from grasp_env.envs.gait import GaitExpert

GRASP = "grasp_env/CubeGrasp-v0"
RANDOM = "grasp_env/CubeGraspRandom-v0"
GAIT = "grasp_env/CubeGait-v0"
MUJOCO = "grasp_env/CubeGraspMujoco-v0"
# Short episodes (a few poses), so that they end often and at different times.
KWARGS = {
    GRASP: {"scene": {"trajectory": {"alpha_start_deg": -15.0, "alpha_end_deg": -9.0}}},
    RANDOM: {"alpha_start_range_deg": (-12.0, -10.0), "alpha_end_range_deg": (-9.0, -3.0)},
    GAIT: {"trajectory": GAIT_TURN},
    MUJOCO: {"scene": {"trajectory": {"alpha_start_deg": -15.0, "alpha_end_deg": -12.0}}},
}
MODES = list(AutoresetMode)


def make_vec(env_id: str, num_envs: int, mode=AutoresetMode.NEXT_STEP, **kwargs):
    """Ours (the vector entry point; Gymnasium passes its keywords, vector_kwargs are refused
    in that mode)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return gym.make_vec(
            env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
            autoreset_mode=mode, **kwargs,
        )  # fmt: skip


def make_pair(env_id: str, num_envs: int, mode, **kwargs):
    """Ours and Gymnasium's SyncVectorEnv over the single envs, the same configuration."""
    kwargs = {**KWARGS[env_id], **kwargs}
    ours = make_vec(env_id, num_envs, mode, **kwargs)
    sync = gym.make_vec(
        env_id, num_envs=num_envs, vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": mode}, **kwargs,
    )  # fmt: skip
    assert isinstance(sync.unwrapped, SyncVectorEnv)
    assert not isinstance(ours.unwrapped, SyncVectorEnv)
    assert ours.metadata["autoreset_mode"] == sync.metadata["autoreset_mode"] == mode
    return ours, sync


POLICIES = {GRASP: grasp_policy, RANDOM: grasp_policy, GAIT: gait_policy, MUJOCO: grasp_policy}


def assert_info_equal(ours: dict, theirs: dict, key: str = "theta") -> None:
    """The masks of ``key`` equal, and its values where set."""
    count = len(ours[f"_{key}"])
    mask = theirs.get(f"_{key}", np.zeros(count, bool))
    np.testing.assert_array_equal(ours[f"_{key}"], mask)
    if mask.any():
        np.testing.assert_array_equal(ours[key][mask], theirs[key][mask])


def assert_step_equal(ours: tuple, theirs: tuple, mode) -> None:
    for a, b in zip(ours[:4], theirs[:4], strict=True):
        np.testing.assert_array_equal(a, b)
    info, want = ours[4], theirs[4]
    assert_info_equal(info, want)
    np.testing.assert_array_equal(info.get("_final_obs"), want.get("_final_obs"))
    if mode == AutoresetMode.SAME_STEP and "_final_obs" in want:
        for i in np.flatnonzero(want["_final_obs"]):
            np.testing.assert_array_equal(info["final_obs"][i], want["final_obs"][i])
        assert_info_equal(info["final_info"], want["final_info"])


def masked_reset(ours, sync, mask: np.ndarray, seed, extra: dict | None = None) -> np.ndarray:
    """The same masked reset of both; our options dict (and its mask) must come back as it
    was (SyncVectorEnv pops the mask from its copy)."""
    options = {"reset_mask": mask, **(extra or {})}
    before = mask.copy()
    obs, _ = ours.reset(seed=seed, options=options)
    want, _ = sync.reset(seed=seed, options=dict(options))
    assert options.keys() == {"reset_mask", *(extra or {})} and options["reset_mask"] is mask
    np.testing.assert_array_equal(mask, before)
    np.testing.assert_array_equal(obs, want)
    return obs


def drive(ours, sync, policy, steps: int, rng: np.random.Generator, options=None) -> Counter:
    """Both envs from the same seeds through ``steps`` steps of the same actions, asserting
    equal results at every step. Before a step: in DISABLED mode the ended sub-environments
    are reset with a mask; in every mode a random subset is sometimes reset too (seeds None,
    an int or a list); ``options`` maps a step to the extra options (a mask, a scene) of a
    reset before it. Returns what happened, to check that the run covered the cases."""
    mode = ours.unwrapped.autoreset_mode
    num = ours.num_envs
    seen: Counter = Counter()
    obs, _ = ours.reset(seed=7)
    np.testing.assert_array_equal(obs, sync.reset(seed=7)[0])
    ended = np.zeros(num, bool)  # ended and not reset (NEXT_STEP, DISABLED)
    t = np.zeros(num, int)  # steps into the current episodes
    for step in range(steps):
        mask = ended.copy() if mode == AutoresetMode.DISABLED else np.zeros(num, bool)
        extra = dict((options or {}).get(step, {}))
        mask |= extra.pop("reset_mask", np.zeros(num, bool))
        if rng.random() < 0.3:
            mask[rng.integers(num)] = True
        if mask.any():
            seed = [None, int(rng.integers(1000)), rng.integers(1000, size=num).tolist()][step % 3]
            seen["resets"] += 1
            seen["mid-episode"] += bool((mask & (t > 0) & ~ended).any())
            seen["others running"] += bool((~mask & (t > 0) & ~ended).any())
            obs = masked_reset(ours, sync, mask, seed, extra)
            t[mask], ended[mask] = 0, False
        actions = policy(obs)
        result = ours.step(actions)
        assert_step_equal(result, sync.step(actions), mode)
        obs, _, terminated, truncated, _ = result
        done = terminated | truncated
        seen["ended"] += int(done.sum())
        seen["ended apart"] += bool(done.any() and not done.all())
        t = np.where(ended if mode == AutoresetMode.NEXT_STEP else False, 0, t + 1)
        if mode == AutoresetMode.SAME_STEP:
            t[done] = 0
        ended = done & (mode != AutoresetMode.SAME_STEP)
    return seen


def assert_covered(seen: Counter) -> None:
    """The run had episodes ending at different times and masked resets of sub-environments
    in mid-episode beside others that carried on."""
    assert seen["ended apart"] >= 2, seen
    assert seen["mid-episode"] >= 1 and seen["others running"] >= 2, seen


# ------------------------------------------------------------------- against SyncVectorEnv


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.value)
@pytest.mark.parametrize("env_id", [GRASP, RANDOM, GAIT])
def test_masked_resets_match_sync_vector_env(env_id, mode):
    """Every autoreset mode, masked resets at random steps (DISABLED: every ended episode is
    reset by a mask), seeds None, int and list: step for step SyncVectorEnv's results."""
    rng = np.random.default_rng(1)
    ours, sync = make_pair(env_id, 4, mode)
    seen = drive(ours, sync, POLICIES[env_id](rng), 40, rng)
    assert_covered(seen)
    assert seen["ended"] >= 8


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.value)
@pytest.mark.parametrize("env_id", [GRASP, RANDOM])
def test_masked_scene_options_match_sync_vector_env(env_id, mode):
    """A scene option reaches the masked sub-environments only; a second option while some
    still run the first keeps both (and the random episodes of the others) in the store."""
    rng = np.random.default_rng(2)
    ours, sync = make_pair(env_id, 4, mode)
    long = {"alpha_start_deg": -15.0, "alpha_end_deg": 0.0}  # 16 poses: it outlives the rest
    first = {"mu": 0.9, "trajectory": long}
    second = {"mu": 0.7, "trajectory": {**long, "alpha_end_deg": -5.0}}
    options = {
        2: {"reset_mask": np.array([True, False, False, False]), "scene": first},
        4: {"reset_mask": np.array([False, True, False, True]), "scene": second},
    }
    seen = drive(ours, sync, POLICIES[env_id](rng), 24, rng, options)
    assert_covered(seen)
    for i, env in enumerate(sync.unwrapped.envs):
        want = env.unwrapped.scene
        got = ours.unwrapped.scene(i)
        assert (got.mu, got.weight) == (want.mu, want.weight)
        np.testing.assert_array_equal(got.contacts, want.contacts)


def physics_equal(info: dict, want: dict, key: str) -> int:
    """info[key] (MuJoCo's reports, a dict of arrays) equals SyncVectorEnv's where set;
    returns how many sub-environments it covers."""
    count = len(info["_theta"])
    mask = want.get(f"_{key}", np.zeros(count, bool))
    np.testing.assert_array_equal(info.get(f"_{key}", np.zeros(count, bool)), mask)
    for i in np.flatnonzero(mask):
        for field in ("holds", "slip", "drift", "pose_holds"):
            if field in want[key]:
                np.testing.assert_array_equal(
                    np.asarray(info[key][field][i], float), np.asarray(want[key][field][i], float)
                )
    return int(mask.sum())


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.value)
def test_mujoco_masked_resets_match_sync_vector_env(mode):
    """The MuJoCo vector env: pose checks, endings and the end-of-episode rollouts equal
    SyncVectorEnv's through masked resets (its checkers and the grips of its rollouts start
    afresh for the masked sub-environments only; two scene options' checkers live at once)."""
    rng = np.random.default_rng(3)
    ours, sync = make_pair(MUJOCO, 2, mode)
    policy = POLICIES[MUJOCO](rng)
    obs = masked_reset(ours, sync, np.array([True, True]), 0)
    ended = np.zeros(2, bool)
    rollouts = 0
    scene = {"trajectory": {"alpha_start_deg": -15.0, "alpha_end_deg": -11.0}}
    resets = {
        1: (np.array([False, True]), 5, None),  # mid-episode: its grips so far are dropped
        3: (np.array([True, False]), [3, 4], {"scene": {**scene, "mu": 0.8}}),
        4: (np.array([False, True]), None, {"scene": {**scene, "mu": 0.6}}),
    }
    for step in range(9):
        mask, seed, extra = resets.get(step, (np.zeros(2, bool), None, None))
        if mode == AutoresetMode.DISABLED:
            mask = mask | ended
        if mask.any():
            obs = masked_reset(ours, sync, mask, seed, extra)
        actions = policy(obs)
        result, want = ours.step(actions), sync.step(actions)
        assert_step_equal(result, want, mode)
        obs, _, terminated, truncated, info = result
        want = want[4]
        ended = (terminated | truncated) & (mode != AutoresetMode.SAME_STEP)
        physics_equal(info, want, "physics")
        if mode == AutoresetMode.SAME_STEP:
            assert "physics_trajectory" not in info
            if "final_info" in want:
                final, final_want = info["final_info"], want["final_info"]
                physics_equal(final, final_want, "physics")
                rollouts += physics_equal(final, final_want, "physics_trajectory")
        else:
            rollouts += physics_equal(info, want, "physics_trajectory")
    assert rollouts >= 3
    ours.close()
    sync.close()


@pytest.mark.parametrize(
    "mode", [AutoresetMode.NEXT_STEP, AutoresetMode.DISABLED], ids=lambda m: m.value
)
def test_gait_masked_reset_beside_a_dropped_cube(mode):
    """A dropped cube's last observation shows no contacts (the single env keeps its state):
    a masked reset of another sub-environment returns it so, as SyncVectorEnv does."""
    ours, sync = make_pair(GAIT, 2, mode, trajectory=None, terminate_on_slip=False)
    expert = GaitExpert()
    P = ours.unwrapped.task.n_pairs
    obs = masked_reset(ours, sync, np.ones(2, bool), 0)
    for _ in range(181):
        actions = expert.predict(obs)[0]
        actions[0, P:] = -1.0
        actions[0, P] = 1.0  # sub-environment 0 never moves a finger: it loses contacts
        result = ours.step(actions)
        assert_step_equal(result, sync.step(actions), mode)
        obs, _, terminated, truncated, _ = result
        if terminated[0]:
            break
    assert terminated[0] and not (terminated[1] or truncated[1])  # dropped: the only ending
    task = ours.unwrapped.task
    contacts = slice(task.pose_size(), task.pose_size() + task.n_fingers * task.n_sites)
    assert not obs[0, contacts].any()
    obs = masked_reset(ours, sync, np.array([False, True]), None)
    assert not obs[0, contacts].any() and obs[1, contacts].sum() == 3


def test_gymnasium_wrapper_sees_the_mask():
    """Gymnasium's RecordEpisodeStatistics reads the mask after the env's reset: ours leaves
    it in the options, so the episodes left running keep their statistics."""
    venv = gym.wrappers.vector.RecordEpisodeStatistics(make_vec(GRASP, 3, **KWARGS[GRASP]))
    obs, _ = venv.reset(seed=0)
    expert = MinimaxExpert()
    for _ in range(2):
        obs = venv.step(expert.predict(obs)[0])[0]
    np.testing.assert_array_equal(venv.episode_lengths, [2, 2, 2])
    venv.reset(options={"reset_mask": np.array([False, True, False])})
    np.testing.assert_array_equal(venv.episode_lengths, [2, 0, 2])


# ------------------------------------------------------------------------------ the seeds


@pytest.mark.parametrize("env_id", [RANDOM, GRASP, GAIT])
def test_masked_reset_is_seeded_as_a_full_reset(env_id):
    """A masked reset of sub-environment 2 with seed s gives the episode that a full reset
    seeded so that it gets s gives it (an int: env i gets seed + i; a list), whatever the
    others do; the others keep their observations."""
    mask = np.array([False, False, True, False])
    runs = []
    for masked, seed in [(True, 50), (False, 50), (True, [9, 8, 61, 6]), (False, [1, 2, 61, 3])]:
        venv = make_vec(env_id, 4, **KWARGS[env_id])
        venv.action_space.seed(0)
        actions = [venv.action_space.sample() * 0.2 for _ in range(8)]
        obs, _ = venv.reset(seed=0)
        if masked:
            for a in actions[:2]:
                obs = venv.step(a[::-1])[0]
            before = obs
            obs, _ = venv.reset(seed=seed, options={"reset_mask": mask})
            np.testing.assert_array_equal(obs[~mask], before[~mask])
        else:
            obs, _ = venv.reset(seed=seed)
        run = [obs[2]]
        for a in actions:
            obs, reward, terminated, truncated, _ = venv.step(a)
            run.append((obs[2], reward[2], terminated[2], truncated[2]))
            if terminated[2] or truncated[2]:
                break
        runs.append(run)
    for one, other in [(runs[0], runs[1]), (runs[2], runs[3])]:
        assert len(one) == len(other)
        for a, b in zip(one, other, strict=True):
            for x, y in zip(a, b, strict=True):
                np.testing.assert_array_equal(x, y)
    if env_id == RANDOM:  # the seeds chose the episodes
        assert not np.array_equal(runs[0][0], runs[2][0])


# ------------------------------------------------------------------------------ the errors

ALL = [GRASP, RANDOM, GAIT, MUJOCO]


@pytest.mark.parametrize("env_id", ALL)
def test_bad_reset_masks_raise_and_change_nothing(env_id):
    """Gymnasium's checks of the mask (a numpy array; shape (num_envs,); dtype bool; at
    least one True), each naming the problem and the accepted form, before anything changes;
    a masked reset before the first reset is refused."""
    venv = make_vec(env_id, 3, **KWARGS[env_id])
    twin = make_vec(env_id, 3, **KWARGS[env_id])
    with pytest.raises(RuntimeError, match=r"first reset.*without a reset_mask"):
        venv.reset(seed=0, options={"reset_mask": np.array([True, False, False])})
    for env in (venv, twin):
        env.reset(seed=0)
    form = r"must be a numpy array of dtype bool and shape \(3,\)"
    for mask, error, problem in [
        ([True, False, True], TypeError, "got a list"),
        (np.array([True, False]), ValueError, r"got shape \(2,\)"),
        (np.ones((3, 1), bool), ValueError, r"got shape \(3, 1\)"),
        (np.array([1, 0, 1]), TypeError, "got dtype int64"),
        (np.array([1.0, 0.0, 1.0]), TypeError, "got dtype float64"),
        (np.zeros(3, bool), ValueError, "at least one of them; got all False"),
    ]:
        options = {"reset_mask": mask}
        with pytest.raises(error, match=rf"options\['reset_mask'\] {form}.*{problem}"):
            venv.reset(seed=99, options=options)
        assert options["reset_mask"] is mask
    # Nothing moved or was reseeded: the same steps and next full reset as the twin's.
    venv.action_space.seed(1)
    actions = [venv.action_space.sample() * 0.2 for _ in range(2)]
    runs = []
    for env in (venv, twin):
        runs.append([x for a in actions for x in env.step(a)[:4]] + [env.reset()[0]])
    for x, y in zip(*runs, strict=True):
        np.testing.assert_array_equal(x, y)
    venv.close()
    twin.close()


@pytest.mark.parametrize("env_id", ALL)
def test_stepping_an_ended_episode_with_autoreset_disabled_raises(env_id):
    """DISABLED: nothing resets by itself; a step with an ended episode not reset is a
    RuntimeError naming the sub-environments and the reset_mask to reset them by, raised
    before anything changes (then a masked reset lets it go on, as SyncVectorEnv)."""
    num = 3 if env_id != MUJOCO else 2
    # episodes of one length (random ones too): the sub-environment reset later ends later
    same = {"alpha_start_range_deg": (-12.0, -12.0), "alpha_end_range_deg": (-8.0, -8.0)}
    kwargs = same if env_id == RANDOM else {}
    ours, sync = make_pair(env_id, num, AutoresetMode.DISABLED, terminate_on_slip=False, **kwargs)
    policy = POLICIES[env_id](np.random.default_rng(5))
    obs = masked_reset(ours, sync, np.ones(num, bool), 0)
    steps = 0
    while True:
        if steps == 1:  # one sub-environment starts over: the others end first
            obs = masked_reset(ours, sync, np.eye(num, dtype=bool)[1], None)
        actions = policy(obs)
        result = ours.step(actions)
        assert_step_equal(result, sync.step(actions), AutoresetMode.DISABLED)
        obs, _, terminated, truncated, _ = result
        steps += 1
        if (terminated | truncated).any():
            break
    ended = terminated | truncated
    assert not ended[1] and ended.sum() == num - 1 and steps >= 3
    which = np.flatnonzero(ended).tolist()
    match = rf"sub-environments {re.escape(str(which))} have ended.*DISABLED.*reset_mask"
    for _ in range(2):  # and again: the refused step changed nothing
        with pytest.raises(RuntimeError, match=match):
            ours.step(policy(obs))
    # (SyncVectorEnv only asserts.) Reset the ended ones: sub-environment 1 carries on where
    # it was, as in SyncVectorEnv, which never took the refused steps.
    obs = masked_reset(ours, sync, ended, None)
    actions = policy(obs)
    result = ours.step(actions)
    assert_step_equal(result, sync.step(actions), AutoresetMode.DISABLED)
    assert result[3][1] or result[2][1]  # its last step, one after the others' (same lengths)
    ours.close()
    sync.close()


def test_autoreset_modes_by_value_and_bad_ones():
    """The modes' values ("NextStep", "SameStep", "Disabled") are accepted as Gymnasium's
    enum; anything else is refused with the accepted values."""
    for env_id in (GRASP, GAIT):
        venv = make_vec(env_id, 2, "Disabled", **KWARGS[env_id])
        assert venv.unwrapped.autoreset_mode is AutoresetMode.DISABLED
        assert venv.metadata["autoreset_mode"] is AutoresetMode.DISABLED
        for bad in ("DISABLED", "DisabledMode", 3, None):
            with pytest.raises(ValueError, match=r"\['NextStep', 'SameStep', 'Disabled'\]"):
                make_vec(env_id, 2, bad, **KWARGS[env_id])
