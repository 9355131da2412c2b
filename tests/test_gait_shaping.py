"""Potential-based shaping of the gait's reward from the certified programme (GaitShaping), the
poses a gait can still hold (poses_held), the legal-move masks (GaitMoveMasks) and the shaped
id grasp_env/CubeGaitMovesShaped-v0 (grasp_env/envs/gait/shaping.py)."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.gait import (
    POTENTIALS,
    GaitExpert,
    GaitExpertStarts,
    GaitMoveMasks,
    GaitShaping,
    GreedyGait,
    legal_moves,
    poses_held,
    potential_table,
)

MOVES_ID = "grasp_env/CubeGaitMoves-v0"
SHAPED_ID = "grasp_env/CubeGaitMovesShaped-v0"


def moves_env() -> gym.Env:
    return gym.make(MOVES_ID)


def play(env: gym.Env, policy, steps: int | None = None):
    """(rewards, infos, terminated) of one episode of ``policy(obs, env) -> move``, cut after
    ``steps`` steps if given."""
    obs, _ = env.reset(seed=0)
    rewards, infos, terminated, truncated = [], [], False, False
    while not (terminated or truncated) and (steps is None or len(rewards) < steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs, env))
        rewards.append(reward)
        infos.append(info)
    return np.array(rewards), infos, terminated


def expert(obs, env):
    return int(GaitExpert(optimal_grip=True).predict(obs)[0])


def random_legal(seed: int):
    rng = np.random.default_rng(seed)

    def policy(obs, env):
        t, x = env.pose_state
        return int(rng.choice(np.flatnonzero(legal_moves(env.task, t, x))))

    return policy


def held_greedy(obs, env):
    """A legal move that keeps the most poses still held (the largest H of the next state
    among the moves that hold this pose)."""
    task = env.task
    held = poses_held(task)
    t, x = env.pose_state
    table = task.table
    best, arg = -1, 0
    margin = task.solution.values.margin
    for m in np.flatnonzero(legal_moves(task, t, x)):
        k = task.csr[x, m]
        if margin[t, table.loaded[k]] >= 0 and held[t + 1, table.next[k]] > best:
            best, arg = held[t + 1, table.next[k]], int(m)
    return arg


# ------------------------------------------------------------------ the potential's table


def test_poses_held_matches_the_programme_and_the_expert():
    """H[t, x] == T - t exactly where the programme's pass 1 keeps a margin >= 0 from (t, x)
    (a gait from there holds to the end); the expert's gait starts at H = 181 and loses one
    pose of H a step."""
    from grasp_env.mechanics.gait.programme import MARGIN_TOL, _programme

    env = moves_env()
    task = env.unwrapped.task
    held = poses_held(task)
    T = task.n_poses
    assert held.shape == (T + 1, len(task.table.states)) and not held.flags.writeable
    assert np.all(held[T] == 0) and held[0, task.start] == T == 181
    table, solution = task.table, task.solution
    value, *_ = _programme(
        table.states, table.ptr, table.move, table.next, table.loaded,
        solution.values.margin, solution.reach, task.start, MARGIN_TOL,
    )  # fmt: skip
    left = T - np.arange(T + 1)
    assert np.array_equal(held == left[:, None], value >= 0.0)
    assert np.all((held >= 0) & (held <= left[:, None]))
    states = solution.optimal.states
    assert np.array_equal(held[np.arange(T), states], T - np.arange(T))


@pytest.mark.parametrize("prefix_seed", [1, 2, 3])
def test_poses_held_is_what_the_environment_holds(prefix_seed):
    """From the state a random legal prefix leaves, the policy that keeps H largest holds
    exactly H poses of the environment (no slip, no lost contact)."""
    env = GaitMoveMasks(moves_env())
    task = env.task
    held = poses_held(task)
    rng = np.random.default_rng(prefix_seed)
    prefix = int(rng.integers(5, 60))
    _, infos, terminated = play(env, random_legal(prefix_seed), prefix)
    if terminated:  # the prefix dropped the cube: H said so
        assert np.any([i["slip"].any() for i in infos])
        return
    t, x = env.pose_state
    expected = int(held[t, x])
    count, done = 0, False
    while not done:
        *_, terminated, truncated, info = env.step(held_greedy(None, env))
        done = terminated or truncated
        count += not (info["slip"].any() or info["lost"].any())
        if terminated:
            break
    assert count == expected


# ------------------------------------------------------------------------------ shaping


@pytest.mark.parametrize("potential", POTENTIALS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_shaping_telescopes(potential, seed):
    """sum_t gamma^t F_t = gamma^n Phi(s_n) - Phi(s_0) over any stretch of an episode (to
    1e-9), with Phi(s_n) = 0 once it ended; reward - shaping is the env's own reward."""
    gamma, scale = 0.97, 1.3
    env = GaitShaping(moves_env(), potential, scale, gamma)
    plain = moves_env()
    phi = potential_table(env.task, potential, scale)
    steps = [None, 7, 40][seed]
    policy = random_legal(seed) if seed else expert
    rewards, infos, _ = play(env, policy, steps)
    shaping = np.array([i["shaping"] for i in infos])
    discount = gamma ** np.arange(len(shaping))
    t, x = env.pose_state
    end = infos[-1]["potential"]
    assert end == (0.0 if env.unwrapped._done else phi[t, x])
    start = phi[0, env.task.start]
    assert abs(discount @ shaping - (gamma ** len(shaping) * end - start)) < 1e-9
    unshaped = np.array([i["unshaped_reward"] for i in infos])
    np.testing.assert_allclose(rewards - shaping, unshaped, rtol=0, atol=1e-12)
    # the env's reward, unchanged: the same moves on the plain environment
    moves = [i["move"] if not i["refused"] else 0 for i in infos]
    plain.reset(seed=0)
    own = [plain.step(m)[1] for m in moves]
    np.testing.assert_array_equal(unshaped, own)


def test_the_expert_earns_the_largest_shaped_return():
    """Whole episodes: the expert's shaped return (gamma 0.99, the default potential) beats
    the greedy gait's, keeping the contacts, random legal moves and the expert that stops
    moving from 32 deg (PPO's missing choice, docs/gait.md) or from halfway."""
    gamma = 0.99

    def shaped_return(policy):
        env = GaitShaping(moves_env(), gamma=gamma)
        rewards, _, _ = play(env, policy)
        return float((gamma ** np.arange(len(rewards))) @ rewards)

    def expert_until(alpha_deg):
        def policy(obs, env):
            t, _ = env.pose_state
            return expert(obs, env) if env.task.alphas[t] < alpha_deg else 0

        return policy

    greedy = GreedyGait(optimal_grip=True)
    best = shaped_return(expert)
    others = {
        "greedy": shaped_return(lambda obs, env: int(greedy.predict(obs)[0])),
        "keep": shaped_return(lambda obs, env: 0),
        "expert to 32 deg": shaped_return(expert_until(32.0)),
        "expert to 0 deg": shaped_return(expert_until(0.0)),
        **{f"random {s}": shaped_return(random_legal(s)) for s in range(3)},
    }
    assert all(best > value + 1e-6 for value in others.values()), (best, others)


def test_the_shaping_pays_a_lost_turn_when_the_move_is_made():
    """Along the expert's gait the expert's move earns the largest shaping term of the legal
    moves at every pose, and where keeping the contacts would lose the rest of the turn, the
    keep move's term is that many poses' worth (gamma x scale per pose) below, at once."""
    env = GaitShaping(moves_env())
    task, phi, gamma = env.task, env.phi, env.gamma
    table, margin = task.table, task.solution.values.margin
    states = task.solution.optimal.states
    worst = 0
    for t in range(task.n_poses - 1):
        x = states[t]
        terms = {}
        for m in np.flatnonzero(legal_moves(task, t, x)):
            k = task.csr[x, m]
            holds = margin[t, table.loaded[k]] >= 0  # else a slip: the episode ends, Phi 0
            terms[m] = gamma * (phi[t + 1, table.next[k]] if holds else 0.0) - phi[t, x]
        chosen = gamma * phi[t + 1, states[t + 1]] - phi[t, x]
        assert chosen >= max(terms.values()) - 1e-12
        worst = max(worst, round((chosen - terms[0]) / (gamma * env.scale)))
    assert worst >= 18  # the missing choice pays off 18 poses later (docs/gait.md)


def test_the_shaped_wrapper_passes_check_env():
    from gymnasium.utils.env_checker import check_env

    for env in (GaitShaping(moves_env().unwrapped), GaitMoveMasks(moves_env().unwrapped)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "the environment is wrapped"
            check_env(env, skip_render_check=True)


def test_the_shaped_id():
    """grasp_env/CubeGaitMovesShaped-v0 is CubeGaitMoves-v0 in GaitShaping ("held", 0.99),
    its keywords passed on."""
    env = gym.make(SHAPED_ID)
    shaping = env.env.env
    assert isinstance(shaping, GaitShaping) and env.unwrapped.optimal_grip
    assert shaping.potential == "held" and shaping.gamma == 0.99
    assert shaping.scale == pytest.approx(np.deg2rad(6.966), abs=1e-5)
    other = gym.make(SHAPED_ID, potential="holds", gamma=0.9, terminate_on_slip=False)
    assert other.env.env.potential == "holds" and not other.unwrapped.terminate_on_slip
    assert other.env.env.scale == pytest.approx(shaping.scale / 0.1)
    started = gym.make(SHAPED_ID, expert_starts=1.0)
    assert isinstance(started.env.env.env, GaitExpertStarts)
    started.reset(seed=0)
    assert started.env.env.pose_state[0] >= 1
    with pytest.raises(ValueError, match=r"expert_starts must be a finite number in \[0, 1\]"):
        gym.make(SHAPED_ID, expert_starts=2.0)


# ----------------------------------------------------------------------------- the masks


def test_masks_are_the_moves_the_environment_takes():
    """legal_moves agrees with the step kernel's rule at every move of random states and
    poses, and masked random episodes are never refused."""
    from grasp_env.envs.gait.kernels import _allowed

    env = GaitMoveMasks(moves_env())
    task = env.task
    rng = np.random.default_rng(0)
    for _ in range(200):
        t, x = int(rng.integers(task.n_poses)), int(rng.integers(len(task.table.states)))
        mask = legal_moves(task, t, x)
        rule = [
            _allowed(x, t, m, task.csr, task.table.states, task.solution.reach) >= 0
            for m in range(task.n_moves)
        ]
        assert mask[0] and np.array_equal(mask, rule)
    for _ in range(3):
        _, infos, _ = play(env, lambda obs, e: int(rng.choice(np.flatnonzero(e.action_masks()))))
        assert not any(i["refused"] for i in infos)
    assert env.action_masks().all()  # the episode ended: nothing left to mask


def test_hold_masks_keep_the_pose():
    """With ``hold`` the mask is the legal moves whose loaded set holds the pose (certified
    margin >= 0), where one does: masked random episodes slip only from states where no
    allowed move holds (H = 0)."""
    env = GaitMoveMasks(moves_env(), hold=True)
    task = env.task
    held, margin = poses_held(task), task.solution.values.margin
    rng = np.random.default_rng(1)
    for _ in range(200):
        t, x = int(rng.integers(task.n_poses)), int(rng.integers(len(task.table.states)))
        legal, mask = legal_moves(task, t, x), legal_moves(task, t, x, hold=True)
        holding = legal & (margin[t, task.table.loaded[np.maximum(task.csr[x], 0)]] >= 0)
        assert np.array_equal(mask, holding if holding.any() else legal)
    for _ in range(3):
        env.reset()
        done = False
        while not done:
            t, x = env.pose_state
            move = int(rng.choice(np.flatnonzero(env.action_masks())))
            _, _, terminated, truncated, info = env.step(move)
            done = terminated or truncated
            if info["slip"].any():
                assert held[t, x] == 0
    with pytest.raises(ValueError, match="hold must be True or False"):
        GaitMoveMasks(moves_env(), hold=1)


def test_lookahead_masks_keep_the_next_pose_within_reach():
    """lookahead: of the moves that hold, those into a state whose contacts are all within
    reach at the next pose, where one is; e.g. the thumb on +y must lift at 80 deg (the last
    pose it reaches +y), where keeping it holds the pose at a larger margin."""
    task = moves_env().unwrapped.task
    table, reach = task.table, task.solution.reach
    rng = np.random.default_rng(2)
    for _ in range(300):
        t = int(rng.integers(task.n_poses - 1))
        x = int(rng.integers(len(table.states)))
        holding = legal_moves(task, t, x, hold=True)
        mask = legal_moves(task, t, x, hold=True, lookahead=True)
        moves = np.flatnonzero(holding)
        states = table.states[table.next[task.csr[x, moves]]]
        fingers = np.arange(task.n_fingers)
        kept = np.array([np.all((a < 0) | reach[t + 1, fingers, np.maximum(a, 0)]) for a in states])
        margins = task.solution.values.margin[t, table.loaded[task.csr[x, moves]]]
        expected = np.zeros_like(mask)  # nothing holds: the allowed moves, unfiltered
        expected[moves[kept] if kept.any() and np.any(margins >= 0) else moves] = True
        assert np.array_equal(mask, expected)
    x = int(table.code[int(np.dot(np.array([0, 5, 1, -1, 4]) + 1, 7 ** np.arange(5)))])
    t = int(np.flatnonzero(task.alphas == 80.0)[0])
    assert np.flatnonzero(legal_moves(task, t, x, hold=True)).tolist() == [0, 1, 12, 29]
    assert np.flatnonzero(legal_moves(task, t, x, hold=True, lookahead=True)).tolist() == [29]
    with pytest.raises(ValueError, match="set hold=True too"):
        GaitMoveMasks(moves_env(), lookahead=True)
    with pytest.raises(ValueError, match="lookahead must be True or False"):
        GaitMoveMasks(moves_env(), hold=True, lookahead="yes")


# ------------------------------------------------------------------------ expert starts


@pytest.mark.parametrize("env_id", [MOVES_ID, "grasp_env/CubeGait-v0"])
def test_expert_starts_begin_on_the_optimal_gait(env_id):
    """fraction 1: every reset hands over at a pose k in [1, T - 1] in the optimal gait's state
    there, with the observation the plain environment shows after the expert's k moves;
    the same seed, the same start; fraction 0: the first pose."""
    env = GaitExpertStarts(gym.make(env_id), fraction=1.0)
    task = env.task
    states = task.solution.optimal.states
    starts = set()
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        t, x = env.pose_state
        assert 1 <= t < task.n_poses and x == states[t]
        assert np.array_equal(obs, env.unwrapped._observation(x, t))
        assert env.reset(seed=seed)[0].tobytes() == obs.tobytes()
        starts.add(t)
    assert len(starts) > 1
    plain = GaitExpertStarts(gym.make(env_id), fraction=0.0)
    plain.reset(seed=3)
    assert plain.pose_state == (0, task.start)
    for bad in (-0.1, 1.5, float("nan"), "half"):
        with pytest.raises(ValueError, match=r"fraction must be a finite number in \[0, 1\]"):
            GaitExpertStarts(gym.make(env_id), fraction=bad)
    with pytest.raises(ValueError, match="among must be one of"):
        GaitExpertStarts(gym.make(env_id), among="random")


def test_holdable_starts_begin_where_a_gait_still_holds():
    """among="holdable": the start is a state from which a gait holds to the end (H = T - k),
    with the plain environment's observation there, and not only the optimal gait's; the
    episode then steps on from it."""
    env = GaitShaping(GaitExpertStarts(moves_env(), fraction=1.0, among="holdable"))
    task = env.task
    held, T = poses_held(task), task.n_poses
    off_gait = 0
    for seed in range(12):
        obs, _ = env.reset(seed=seed)
        t, x = env.pose_state
        assert 1 <= t < T and held[t, x] == T - t
        assert np.array_equal(obs, env.unwrapped._observation(x, t))
        off_gait += x != task.solution.optimal.states[t]
        _, _, _, _, info = env.step(expert(obs, env))
        assert env.pose_state[0] == t + 1
        assert info["shaping"] == pytest.approx(
            env.gamma * env.phi[t + 1, env.pose_state[1]] - env.phi[t, x], abs=1e-12
        )
    assert off_gait > 0


# --------------------------------------------------------------------------- refusals


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"potential": "bottleneck"}, "potential must be one of"),
        ({"potential": None}, "potential must be one of"),
        ({"scale": 0.0}, "scale must be a finite number"),
        ({"scale": -1.0}, "scale must be a finite number"),
        ({"scale": float("nan")}, "scale must be a finite number"),
        ({"scale": "1"}, "scale must be a finite number"),
        ({"gamma": 0.0}, r"gamma must be a finite number in \(0, 1\]"),
        ({"gamma": 1.5}, r"gamma must be a finite number in \(0, 1\]"),
        ({"gamma": True}, "gamma must be a finite number"),
    ],
)
def test_bad_arguments_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GaitShaping(moves_env(), **kwargs)


def test_wrong_environments_are_refused():
    with pytest.raises(ValueError, match="env must be a gait environment"):
        GaitShaping(gym.make("grasp_env/CubeGrasp-v0"))
    with pytest.raises(ValueError, match="env must be a gait environment"):
        GaitShaping("grasp_env/CubeGaitMoves-v0")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="env must act with moves alone"):
        GaitMoveMasks(gym.make("grasp_env/CubeGait-v0"))
    with pytest.raises(ValueError, match="task must be a GaitTask"):
        poses_held(None)  # type: ignore[arg-type]
    task = moves_env().unwrapped.task
    with pytest.raises(ValueError, match="potential must be one of"):
        potential_table(task, "value")
    with pytest.raises(ValueError, match="scale must be a finite number"):
        potential_table(task, "held", -2.0)


def test_the_gait_rl_study_trains_and_scores_reproducibly(tmp_path):
    """The study behind docs/gait.md's five seeds, in one rollout's worth of steps: the same
    seed gives the same policy and the same score on the unshaped environment."""
    import torch

    from grasp_env_agents.benchmarks.study_gait_rl import train

    first = train(0, 2048, tmp_path / "a")
    again = train(0, 2048, tmp_path / "b")
    assert first[:2] == again[:2] and 0 <= first[0] <= 181
    from sb3_contrib import MaskablePPO

    a, b = (MaskablePPO.load(tmp_path / d / "model.zip", device="cpu") for d in "ab")
    for x, y in zip(a.policy.parameters(), b.policy.parameters(), strict=True):
        assert torch.equal(x, y)
    assert (tmp_path / "a" / "curve.csv").read_text().startswith("steps,held")
