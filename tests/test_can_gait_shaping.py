"""The gait wrappers on the coke can's turn (grasp_env/envs/gait/shaping.py on the can's
tables): the poses a gait can still hold against a brute force over gaits and against the
programme's values, the potential and the telescoping shaping, the move masks against the
hand's rules and the environment, expert starts, the id grasp_env/CanGaitMovesShaped-v0 and
the RL study's reproducibility on the can (docs/gait.md, "Learning the can's turn")."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.can_gait import CanGaitExpert
from grasp_env.envs.gait import (
    POTENTIALS,
    GaitExpertStarts,
    GaitMoveMasks,
    GaitShaping,
    expert_gait,
    legal_moves,
    poses_held,
    potential_table,
)
from grasp_env.envs.gait.shaping import _table_poses_held
from grasp_env.mechanics.gait.can import CAN_MAX_TOUCHING, CAN_MIN_LOADED, can_configs
from grasp_env.mechanics.gait.can_programme import can_states

MOVES_ID = "grasp_env/CanGaitMoves-v0"
SHAPED_ID = "grasp_env/CanGaitMovesShaped-v0"


def moves_env() -> gym.Env:
    return gym.make(MOVES_ID)


def task():
    return moves_env().unwrapped.task


def put(env: gym.Env, t: int, x: int) -> None:
    """Put the can env at pose t in state x, mid-episode."""
    env.reset(seed=0)
    env.unwrapped._t, env.unwrapped._x = t, x


def play(env: gym.Env, policy, steps: int | None = None):
    """(rewards, infos) of one episode of ``policy(obs, env) -> move`` from reset seed 0."""
    obs, _ = env.reset(seed=0)
    rewards, infos, done = [], [], False
    while not done and (steps is None or len(rewards) < steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs, env))
        rewards.append(reward)
        infos.append(info)
        done = terminated or truncated
    return np.array(rewards), infos


def random_masked(seed: int, hold: bool = False, lookahead: bool = False):
    rng = np.random.default_rng(seed)

    def policy(obs, env):
        t, x = env.unwrapped._t, env.unwrapped._x
        return int(
            rng.choice(np.flatnonzero(legal_moves(env.unwrapped.task, t, x, hold, lookahead)))
        )

    return policy


EXPERT = CanGaitExpert(optimal_grip=True)


def expert(obs, env):
    return int(EXPERT.predict(obs)[0])


# --------------------------------------------------- the poses held, against brute force


def brute_held(table, margin, t0: int, x0: int) -> int:
    """The most poses held from (t0, x0) over every gait: each whole sequence of the table's
    moves enumerated, each scored by the rules (a pose is held while no finger is past age H
    and the move's loaded configuration has margin >= 0); margin (T, C)."""
    T, H = len(margin), table.max_age
    best = 0

    def walk(t: int, x: int, held: int) -> None:
        nonlocal best
        best = max(best, held)
        if t == T or (table.states[x] > H).any():
            return
        for k in range(table.ptr[x], table.ptr[x + 1]):
            if margin[t, table.config[k]] >= 0:
                walk(t + 1, int(table.next[k]), held + 1)
            # a slip ends the gait's held poses there: its later moves do not count

    walk(t0, x0, 0)
    return best


@pytest.mark.parametrize("case", range(12))
def test_poses_held_is_the_brute_force_over_gaits(case):
    """Small can hands (3 or 4 fingers, contacts lasting 1 or 2 poses, 3 or 4 loaded, 1 to 3
    poses), integer margins with ties, zeros, slips and unusable configurations, the same at
    every pose or pose by pose: H equals the best gait's poses held from every state."""
    rng = np.random.default_rng(case)
    F = int(rng.integers(3, 5))
    H = int(rng.integers(1, 3))
    L = int(rng.integers(3, F + 1))
    T = int(rng.integers(1, 4))
    table = can_states(F, H, L)
    C = len(can_configs(F, H, L))
    per_pose = bool(case % 2)
    margin = rng.integers(-1, 3, (T if per_pose else 1, C)).astype(float)
    margin[rng.random(margin.shape) < 0.15] = -np.inf
    margin = np.broadcast_to(margin, (T, C))
    vals = np.ascontiguousarray(margin[:, table.config] if per_pose else margin[:1, table.config])
    held = _table_poses_held(table.ptr, table.next, vals, T)
    assert held.shape == (T + 1, len(table.states)) and np.all(held[T] == 0)
    xs = rng.choice(len(table.states), min(25, len(table.states)), replace=False)
    for t in range(T):
        for x in xs:
            assert held[t, x] == brute_held(table, margin, t, int(x)), (case, t, x)


def test_poses_held_matches_the_programme_and_the_expert():
    """On the can's turn (37 poses, 536,068 states): H[t, x] == T - t exactly where the
    programme's pass 1 keeps a margin >= 0 from (t, x); the expert starts at H = 37 and loses
    one a step; a state past age H holds none."""
    from grasp_env.mechanics.gait.can_programme import (
        MARGIN_TOL,
        _move_values,
        _table_programme,
    )

    env = moves_env()
    task = env.unwrapped.task
    held = poses_held(task)
    T, table = task.n_poses, task.table
    assert held.shape == (T + 1, len(table.states)) == (38, 536_068)
    assert not held.flags.writeable and held is poses_held(task)
    assert held[0, task.start] == T == 37 and np.all(held[T] == 0)
    value, *_ = _table_programme(
        table.ptr, table.move, table.next, _move_values(table, task.solution.margin), T,
        task.start, MARGIN_TOL,
    )  # fmt: skip
    left = T - np.arange(T + 1)
    assert np.array_equal(held == left[:, None], value >= 0.0)
    assert np.all((held >= 0) & (held <= left[:, None]))
    gait = expert_gait(task)
    assert gait is task.expert and gait.margin == pytest.approx(np.deg2rad(8.893), abs=1e-5)
    assert np.array_equal(held[np.arange(T), gait.states], T - np.arange(T))
    lost = np.flatnonzero(~table.ok)
    assert lost.size and np.all(held[:, lost] == 0)


def test_the_potential_is_the_poses_held():
    task_ = task()
    held = poses_held(task_)
    T = task_.n_poses
    phi = potential_table(task_, "held", 0.5)
    assert phi is potential_table(task_, "held", 0.5) and not phi.flags.writeable
    np.testing.assert_array_equal(phi[:T], 0.5 * held[:T])
    holds = potential_table(task_, "holds", 2.0)
    left = T - np.arange(T + 1)
    np.testing.assert_array_equal(holds[:T], 2.0 * (held[:T] == left[:T, None]))
    assert not phi[T].any() and not holds[T].any()


# ------------------------------------------------------------------------------ shaping


@pytest.mark.parametrize("potential", POTENTIALS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_shaping_telescopes_on_the_can(potential, seed):
    """sum_t gamma^t F_t = gamma^n Phi(s_n) - Phi(s_0) (to 1e-9), Phi(s_n) = 0 once the episode
    ended; reward - shaping is the can env's own reward for the same moves."""
    gamma, scale = 0.97, 1.3
    env = GaitShaping(moves_env(), potential, scale, gamma)
    phi = potential_table(env.task, potential, scale)
    policy = expert if seed == 0 else random_masked(seed, hold=True)
    rewards, infos = play(env, policy, [None, 30, 9][seed])
    shaping = np.array([i["shaping"] for i in infos])
    t, x = env.pose_state
    end = infos[-1]["potential"]
    assert end == (0.0 if env.unwrapped._done else phi[t, x])
    discount = gamma ** np.arange(len(shaping))
    assert abs(discount @ shaping - (gamma ** len(shaping) * end - phi[0, env.task.start])) < 1e-9
    unshaped = np.array([i["unshaped_reward"] for i in infos])
    np.testing.assert_allclose(rewards - shaping, unshaped, rtol=0, atol=1e-12)
    plain = moves_env()
    plain.reset(seed=0)
    own = [plain.step(i["move"])[1] for i in infos]
    np.testing.assert_array_equal(unshaped, own)


def test_the_expert_earns_the_most_shaping_at_every_pose():
    """Along the certified gait the expert's move earns the largest shaping term of the legal
    moves (gamma 0.99, Phi = B x poses held): no legal move leads to a state that holds more."""
    env = GaitShaping(moves_env())
    task_, phi, gamma = env.task, env.phi, env.gamma
    table, margin = task_.table, task_.solution.values.margin
    states = expert_gait(task_).states
    assert env.scale == pytest.approx(np.deg2rad(8.893), abs=1e-5)
    for t in range(task_.n_poses - 1):
        x = int(states[t])
        terms = []
        for k in range(table.ptr[x], table.ptr[x + 1]):
            holds = margin[table.config[k]] >= 0
            terms.append(gamma * (phi[t + 1, table.next[k]] if holds else 0.0) - phi[t, x])
        chosen = gamma * phi[t + 1, states[t + 1]] - phi[t, x]
        assert chosen >= max(terms) - 1e-12


def test_the_cached_grip_scores_the_certified_grip():
    """A step of CanGaitMoves-v0 looks up its configuration's score at the certified grip: at
    every step of a masked random episode the same reward, angles and k as scoring that grip
    afresh (task.score), and fresh arrays each call."""
    env = moves_env()
    task_ = env.unwrapped.task
    configs = {c: i for i, c in enumerate(task_.solution.values.configs)}
    rewards, infos = play(env, random_masked(4, hold=True), 25)
    assert len(infos) > 3
    for own, info in zip(rewards, infos, strict=True):
        if info["lost"].any():  # a contact past its reach: no grip, the slip's reward
            assert own == task_.limit - 0.5 * np.pi
            continue
        fingers = np.flatnonzero(info["loaded"]).tolist()
        config = configs[tuple((f, int(info["ages"][f])) for f in fingers)]
        reward, theta, k, _ = task_.score(fingers, info["ages"], task_.optimal_grip(config))
        assert info["certified_reward"] == task_.solution.values.margin[config]
        np.testing.assert_array_equal(info["theta"][fingers], theta)
        np.testing.assert_array_equal(info["k"], k)
        assert own == reward == task_.optimal_score(config)[0]
    cached = task_.optimal_score(config)
    cached[2][:] = 7.0
    assert not np.any(task_.optimal_score(config)[2] == 7.0)


# ----------------------------------------------------------------------------- the masks


def rule_mask(ages: np.ndarray, H: int, max_loaded: int) -> np.ndarray:
    """The moves the can's rules allow from ages (F,), written from docs/gait.md ("The can"):
    3 to max_loaded fingers carry load at the pose and at most five touch; a lift leaves the
    others loaded, a placement touches with zero force; a lost contact (age H + 1) makes every
    move void (keep alone)."""
    F = len(ages)
    touching = int((ages >= 0).sum())
    out = np.zeros(1 + F, bool)
    if (ages > H).any():
        out[0] = True
        return out
    out[0] = CAN_MIN_LOADED <= touching <= max_loaded
    for f in range(F):
        if ages[f] >= 0:
            out[1 + f] = CAN_MIN_LOADED <= touching - 1 <= max_loaded
        else:
            out[1 + f] = touching < CAN_MAX_TOUCHING and CAN_MIN_LOADED <= touching <= max_loaded
    return out


def test_masks_are_the_legal_moves_and_the_environment_takes_them():
    """legal_moves is the rules' set of moves from random states (lost ones too), and from
    states within reach the environment refuses exactly the moves it masks; masked random
    episodes are never refused, and an ended episode masks nothing."""
    env = moves_env()
    task_ = env.unwrapped.task
    table = task_.table
    rng = np.random.default_rng(0)
    for i in range(300):
        x = int(rng.integers(len(table.states)))
        t = int(rng.integers(task_.n_poses))
        mask = legal_moves(task_, t, x)
        assert np.array_equal(mask, rule_mask(table.states[x], task_.max_age, 4)), table.states[x]
        if i < 40 and table.ok[x]:
            for m in range(task_.n_moves):
                put(env, t, x)
                info = env.step(m)[4]
                assert info["refused"] == (not mask[m])
    masked = GaitMoveMasks(moves_env())
    for seed in range(3):
        rng = np.random.default_rng(seed)
        _, infos = play(
            masked, lambda obs, e, r=rng: int(r.choice(np.flatnonzero(e.action_masks())))
        )
        assert not any(i["refused"] for i in infos)
    assert masked.action_masks().all()


def test_hold_and_lookahead_masks():
    """hold: of the legal moves, those whose loaded configuration's margin is >= 0 (all legal
    ones where none is); lookahead: of those, the moves into a state whose every contact is at
    most H poses old, where one is. Masked random episodes slip only where H = 0; with the
    lookahead they never lose a contact where a gait could keep them."""
    task_ = task()
    table, margin, H = task_.table, task_.solution.values.margin, task_.max_age
    held = poses_held(task_)
    rng = np.random.default_rng(1)
    for _ in range(400):
        x = int(rng.integers(len(table.states)))
        t = int(rng.integers(task_.n_poses))
        legal = legal_moves(task_, t, x)
        hold = legal_moves(task_, t, x, hold=True)
        look = legal_moves(task_, t, x, hold=True, lookahead=True)
        ks = range(table.ptr[x], table.ptr[x + 1])
        holding = np.zeros_like(legal)
        kept = np.zeros_like(legal)
        for k in ks:
            if margin[table.config[k]] >= 0:
                holding[table.move[k]] = True
                kept[table.move[k]] = table.states[table.next[k]].max() <= H
        assert np.array_equal(hold, holding if holding.any() else legal)
        if not holding.any():
            assert np.array_equal(look, legal)
        elif t + 1 < task_.n_poses and kept.any():
            assert np.array_equal(look, kept)
        else:
            assert np.array_equal(look, holding)
    env = GaitMoveMasks(moves_env(), hold=True, lookahead=True)
    for seed in range(4):
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        done = False
        while not done:
            t, x = env.pose_state
            _, _, terminated, truncated, info = env.step(
                int(rng.choice(np.flatnonzero(env.action_masks())))
            )
            done = terminated or truncated
            if info["slip"].any():
                assert held[t, x] == 0


# ------------------------------------------------------------------------ expert starts


@pytest.mark.parametrize("among", ["expert", "holdable"])
def test_expert_starts_on_the_can(among):
    """fraction 1: a reset hands over at a pose k in [1, T - 1], on the expert's gait (or any
    state from which a gait holds to the end) with the env's own observation there; the same
    seed the same start; the episode steps on from it."""
    env = GaitShaping(GaitExpertStarts(moves_env(), fraction=1.0, among=among))
    task_ = env.task
    T, held, states = task_.n_poses, poses_held(task_), expert_gait(task_).states
    starts, off_gait = set(), 0
    for seed in range(8):
        obs, _ = env.reset(seed=seed)
        t, x = env.pose_state
        assert 1 <= t < T and held[t, x] == T - t
        if among == "expert":
            assert x == states[t]
        off_gait += x != states[t]
        assert np.array_equal(obs, task_.observation(x, t))
        assert env.reset(seed=seed)[0].tobytes() == obs.tobytes()
        starts.add(t)
        _, _, terminated, _, info = env.step(expert(obs, env))
        assert env.pose_state[0] == t + 1 and not terminated and info["unshaped_reward"] > 0
    assert len(starts) > 1
    assert (off_gait > 0) == (among == "holdable")


def test_expert_starts_with_the_grip():
    """On CanGait-v0 (grip and moves) the expert's handed-over steps use the certified grip:
    the start is the expert's state at k."""
    env = GaitExpertStarts(gym.make("grasp_env/CanGait-v0"), fraction=1.0)
    states = expert_gait(env.task).states
    for seed in range(3):
        env.reset(seed=seed)
        t, x = env.pose_state
        assert 1 <= t < env.task.n_poses and x == states[t]


# ------------------------------------------------------------------------------ the id


def test_the_shaped_can_id():
    """grasp_env/CanGaitMovesShaped-v0 is CanGaitMoves-v0 in GaitShaping ("held", 0.99, scale
    the can's bottleneck 8.893 deg), its keywords passed on; it passes check_env."""
    from gymnasium.utils.env_checker import check_env

    env = gym.make(SHAPED_ID)
    shaping = env.env.env
    assert isinstance(shaping, GaitShaping) and env.unwrapped.optimal_grip
    assert shaping.potential == "held" and shaping.gamma == 0.99
    assert shaping.scale == pytest.approx(np.deg2rad(8.893), abs=1e-5)
    other = gym.make(SHAPED_ID, potential="holds", gamma=0.9, terminate_on_slip=False)
    assert other.env.env.potential == "holds" and not other.unwrapped.terminate_on_slip
    assert other.env.env.scale == pytest.approx(shaping.scale / 0.1)
    started = gym.make(SHAPED_ID, expert_starts=1.0, starts_among="holdable")
    assert isinstance(started.env.env.env, GaitExpertStarts)
    started.reset(seed=0)
    assert started.env.env.pose_state[0] >= 1
    with pytest.raises(ValueError, match=r"expert_starts must be a finite number in \[0, 1\]"):
        gym.make(SHAPED_ID, expert_starts=-1.0)
    for wrapped in (gym.make(SHAPED_ID), GaitMoveMasks(moves_env().unwrapped, hold=True)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "the environment is wrapped"
            check_env(wrapped, skip_render_check=True)
    with pytest.raises(ValueError, match="env must act with moves alone"):
        GaitMoveMasks(gym.make("grasp_env/CanGait-v0"))
    with pytest.raises(ValueError, match=r"task must be a GaitTask .* or a CanGaitTask"):
        poses_held("can")  # type: ignore[arg-type]


def test_the_can_rl_study_trains_and_scores_reproducibly(tmp_path):
    """The study's can run in one rollout's worth of steps: the same seed gives the same
    policy and the same score on the unshaped environment; the baselines it prints."""
    import torch
    from sb3_contrib import MaskablePPO

    from grasp_env_agents.benchmarks.study_gait_rl import baselines, train

    first = train(0, 2048, tmp_path / "a", object_name="can")
    again = train(0, 2048, tmp_path / "b", object_name="can")
    assert first[:2] == again[:2] and 0 <= first[0] <= 37
    a, b = (MaskablePPO.load(tmp_path / d / "model.zip", device="cpu") for d in "ab")
    for x, y in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
        assert torch.equal(x, y)
    assert (tmp_path / "a" / "curve.csv").read_text().startswith("steps,held")
    rows = baselines("can")
    assert rows["optimal gait (certified)"][0] == 37
    assert rows["optimal gait (certified)"][1] == pytest.approx(8.893, abs=1e-3)
    assert rows["greedy gait"][0] < 37 and rows["best fixed set"][0] == -1
    with pytest.raises(ValueError, match="object_name must be one of"):
        train(0, 8, tmp_path / "c", object_name="sphere")
