"""Finger gaits: the environments CubeGait-v0 and CubeGaitMoves-v0, their experts, and the
optimal gait in MuJoCo (docs/gait.md, "The environment", "In physics")."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_TURN,
    greedy_gait,
    optimal_gait,
    site_sets,
    solve_gait,
)

# ------------------------------------------------------------------------ the environment

GAIT_ID = "grasp_env/CubeGait-v0"
MOVES_ID = "grasp_env/CubeGaitMoves-v0"


def make_gait(**kwargs):
    import gymnasium as gym

    import grasp_env  # noqa: F401  (registers the environments)

    return gym.make(GAIT_ID, **kwargs)


def play(env, policy, steps=None):
    """Rewards and infos of one episode played by ``policy(obs) -> action``."""
    obs, _ = env.reset(seed=0)
    rewards, infos = [], []
    done = False
    while not done and (steps is None or len(rewards) < steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        rewards.append(reward)
        infos.append(info)
        done = terminated or truncated
    return np.array(rewards), infos, terminated


@pytest.mark.parametrize("env_id", [GAIT_ID, MOVES_ID])
def test_gait_env_check_env(env_id):
    import warnings

    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
    assert env_id in __import__("grasp_env").ENV_IDS


def test_moves_env_grips_with_the_certified_optimum():
    """CubeGaitMoves-v0: the agent chooses the move, the environment grips with the certified
    minimax of the fingers that then carry load. Each step earns that set's certified margin
    (the solver's, to float32 rounding of the grip), a refused move keeps the contacts with
    their grip, and the expert's moves replay CubeGait-v0's expert episode exactly."""
    import gymnasium as gym

    from grasp_env.envs.gait import GaitExpert

    env = gym.make(MOVES_ID, terminate_on_slip=False)
    task = env.unwrapped.task
    values = task.solution.values
    assert env.action_space == gym.spaces.Discrete(task.n_moves)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    scored = refused = 0
    for t in range(len(PAPER_TURN)):
        # mostly keep, sometimes any move: long episodes that still change their contacts
        move = int(rng.integers(task.n_moves)) if rng.random() < 0.3 else 0
        _, reward, terminated, truncated, info = env.step(move)
        refused += info["refused"]
        if not info["lost"].any():
            loaded = tuple(sorted(int(s) for s in info["contacts"][info["loaded"]]))
            margin = values.margin[t, values.sets.index(loaded)]
            assert abs(reward - margin) < 1e-6, (t, move, reward, margin)
            scored += 1
        if terminated or truncated:
            break
    assert scored >= 20 and refused >= 1
    # the expert's moves on the moves env: the expert's episode of the full env
    expert, moves, full = GaitExpert(), GaitExpert(optimal_grip=True), make_gait()
    env = gym.make(MOVES_ID)
    (obs, _), _ = env.reset(seed=0), full.reset(seed=0)
    done = False
    while not done:
        action = expert.predict(obs)[0]
        move = moves.predict(obs)[0]
        assert move == np.argmax(action[task.n_pairs :]) and env.action_space.contains(move)
        got = env.step(move)
        want = full.step(action)
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1:4] == want[1:4]
        for key, value in want[4].items():
            np.testing.assert_array_equal(got[4][key], value)
        obs, done = got[0], got[2] or got[3]
    assert want[3] and not want[2]  # held to the end


def test_moves_env_vector_equals_single_envs_and_refuses_bad_moves():
    import gymnasium as gym

    num = 3
    envs = gym.make_vec(MOVES_ID, num_envs=num, vectorization_mode="vector_entry_point")
    singles = [gym.make(MOVES_ID) for _ in range(num)]
    obs, _ = envs.reset(seed=0)
    single_obs = [s.reset(seed=0)[0] for s in singles]
    rng = np.random.default_rng(1)
    restart = np.zeros(num, bool)
    ended = 0
    for _ in range(150):
        np.testing.assert_array_equal(obs, np.stack(single_obs))
        moves = np.where(rng.random(num) < 0.2, rng.integers(0, 31, num), 0)
        obs, reward, terminated, truncated, info = envs.step(moves)
        for i, single in enumerate(singles):
            if restart[i]:  # NEXT_STEP: this step resets it
                single_obs[i] = single.reset()[0]
                continue
            o, r, te, tr, inf = single.step(moves[i])
            assert (r, te, tr) == (reward[i], terminated[i], truncated[i])
            np.testing.assert_array_equal(inf["k"], info["k"][i])
            single_obs[i] = o
        restart = terminated | truncated
        ended += restart.sum()
    assert ended >= num  # autoresets were compared too
    for bad in (31, -1, 2.0, True, np.array([1, 2]), "3"):
        with pytest.raises(ValueError, match=r"move"):
            singles[0].reset()
            singles[0].step(bad)
    for bad in (np.array([0, 1]), np.array([0.0, 1.0, 2.0]), np.array([0, 1, 31])):
        with pytest.raises(ValueError, match=r"move"):
            envs.step(bad)


def test_gait_expert_earns_the_certified_margin():
    from grasp_env.envs.gait import GaitExpert, GreedyGait

    env = make_gait()
    solution = env.unwrapped.task.solution
    expert = GaitExpert()
    rewards, infos, terminated = play(env, lambda o: expert.predict(o)[0])
    assert len(rewards) == len(PAPER_TURN) and not terminated
    # the certified optimum, to float32 rounding of the action
    np.testing.assert_allclose(rewards, solution.optimal.margins, atol=1e-6)
    assert abs(rewards.min() - solution.optimal.margin) < 1e-6
    moves = sum(info["move"] != 0 for info in infos)
    assert moves == solution.optimal.changes and not any(info["refused"] for info in infos)
    # the greedy baseline from the same start loses a contact and drops the cube
    greedy = GreedyGait()
    rewards, infos, terminated = play(env, lambda o: greedy.predict(o)[0])
    assert terminated and rewards.min() < 0 and len(rewards) < len(PAPER_TURN)
    assert infos[-1]["lost"].any()


def test_gait_env_is_sequential():
    """A policy that never moves a finger (the best it can do at gamma = 0 wherever the
    current contacts hold) loses a contact; the expert, which plans, holds throughout."""
    env = make_gait(terminate_on_slip=False)
    task = env.unwrapped.task
    from grasp_env.envs.gait import GaitExpert

    expert = GaitExpert()

    def keep(obs):
        action = expert.predict(obs)[0]
        action[task.n_pairs :] = -1.0
        action[task.n_pairs] = 1.0  # move 0: keep
        return action

    rewards, infos, terminated = play(env, keep)
    assert terminated and infos[-1]["lost"].any()  # dropped: fewer than three fingers left
    assert np.isclose(rewards[-1], task.limit - np.pi / 2)


def test_gait_env_rules():
    env = make_gait(terminate_on_slip=False)
    task = env.unwrapped.task
    P, N = task.n_pairs, task.n_sites
    obs, _ = env.reset()
    start = task.table.states[task.start]  # three fingers touch
    assert (start >= 0).sum() == 3

    def move(m):
        action = np.zeros(P + task.n_moves, np.float32)
        action[P + m] = 1.0
        return action

    toggle = lambda f, s: 1 + f * N + s  # noqa: E731
    touching = int(np.flatnonzero(start >= 0)[0])
    _, _, _, _, info = env.step(move(toggle(touching, int(start[touching]))))
    assert info["refused"] and info["move"] == 0  # a lift would leave two fingers
    free = int(np.flatnonzero(start < 0)[0])
    taken = int(start[touching])
    _, _, _, _, info = env.step(move(toggle(free, taken)))
    assert info["refused"]  # the site is taken
    reach = task.solution.reach[2]
    far = [s for s in range(N) if not reach[free, s] and s not in start]
    if far:
        _, _, _, _, info = env.step(move(toggle(free, far[0])))
        assert info["refused"]  # out of reach
    # observation: contacts one-hot and reach flags
    obs, _ = env.reset()
    F = task.n_fingers
    width = task.pose_size()
    contacts = obs[width : width + F * N].reshape(F, N)
    for f in range(F):
        assert contacts[f].sum() == (start[f] >= 0) and (start[f] < 0 or contacts[f, start[f]])
    np.testing.assert_array_equal(obs[width + F * N :].reshape(F, N), task.solution.reach[0])


def test_gait_vector_env_equals_single_envs():
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    from grasp_env.envs.gait import GaitExpert

    expert = GaitExpert()
    num = 3
    for mode in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
        envs = gym.make_vec(
            GAIT_ID, num_envs=num, vectorization_mode="vector_entry_point",
            autoreset_mode=mode, terminate_on_slip=False,
        )  # fmt: skip
        singles = [make_gait(terminate_on_slip=False) for _ in range(num)]
        obs, _ = envs.reset(seed=0)
        single_obs = [s.reset(seed=0)[0] for s in singles]
        rng = np.random.default_rng(0)
        restart = np.zeros(num, bool)
        for _ in range(200):
            np.testing.assert_array_equal(obs, np.stack(single_obs))
            actions = expert.predict(obs)[0]
            noisy = rng.random(num) < 0.3  # some sub-environments act at random
            actions[noisy] = rng.uniform(-1, 1, actions[noisy].shape)
            obs, reward, terminated, truncated, info = envs.step(actions)
            for i, single in enumerate(singles):
                if restart[i]:  # NEXT_STEP: this step resets it
                    single_obs[i] = single.reset()[0]
                    assert reward[i] == 0
                    continue
                o, r, te, tr, inf = single.step(actions[i])
                assert r == reward[i] and te == terminated[i] and tr == truncated[i]
                np.testing.assert_array_equal(inf["theta"], info["theta"][i])
                single_obs[i] = o
                if (te or tr) and mode == AutoresetMode.SAME_STEP:
                    np.testing.assert_array_equal(info["final_obs"][i], o)
                    single_obs[i] = single.reset()[0]
            restart = (terminated | truncated) & (mode == AutoresetMode.NEXT_STEP)


def test_gait_env_other_trajectory_and_bad_keywords():
    env = make_gait(trajectory={"axis": (0, 0, 1), "alpha_start_deg": -180, "alpha_end_deg": 180})
    task = env.unwrapped.task
    assert task.n_poses == 361 and task.solution.optimal.margin > np.deg2rad(8)
    for kwargs, match in [
        ({"cone_deg": 0}, "cone_deg"),
        ({"mu": True}, "mu"),
        ({"start": (0, 0, 1, 2, -1)}, "no state"),
        ({"trajectory": {"axis": (0, 0, 0)}}, "axis"),
        ({"trajectory": "x"}, "trajectory must be a mapping"),
        ({"start": "x"}, "start must be a site"),
        ({"start": 3}, "start must be a site"),
        ({"start": (True, -1, 3, 4, -1)}, "start must be a site"),  # not converted to site 1
        ({"start": (2.7, -1, 3, 4, -1)}, "start must be a site"),
        ({"start": ("2", "-1", "3", "4", "-1")}, "start must be a site"),
        ({"start": (np.inf, -1, 3, 4, -1)}, "start must be a site"),
        ({"start": (2**70, -1, 3, 4, -1)}, "start must be a site"),
        ({"start": (5, -1, 3, 4, -1)}, r"out of reach .*\(0, 5\)"),  # finger 0 cannot push on +z
        ({"terminate_on_slip": 1}, "terminate_on_slip"),
        ({"cone_deg": 10.0}, "no gait"),
    ]:
        with pytest.raises(ValueError, match=match):
            make_gait(**kwargs)
    env = make_gait()
    env.reset()
    P = env.unwrapped.task.n_pairs
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(P))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.full(env.action_space.shape, np.nan, np.float32))
    rewards = []
    for dtype in (np.float16, np.float32, np.longdouble):  # the grasp envs' dtypes too
        env.reset()
        rewards.append(env.step(np.full(env.action_space.shape, 0.25, dtype))[1])
    assert rewards[0] == rewards[1] == rewards[2]


def test_gait_env_refusals_of_start_name_it():
    """Every refusal of ``start`` names it, the environment's and the mechanics' alike."""
    for start, match in [
        ((6, 1, 3, 4, -1), r"^start must give each of the 5 fingers a site in \[-1, 5\]"),
        ((0, 1, 3), r"^start must give each of the 5 fingers"),
        ((0, 0, 3, 4, -1), r"^start \[0, 0, 3, 4, -1\] is no state of the hand"),
        ((0, -1, -1, 4, -1), r"^start \[0, -1, -1, 4, -1\] is no state"),
        # within reach at the first pose, but every gait from it drops (the default start holds)
        ((4, 2, 3, -1, -1), r"^no gait from start \[4, 2, 3, -1, -1\] keeps three fingers"),
    ]:
        with pytest.raises(ValueError, match=match):
            make_gait(start=start)
    reach = np.ones((2, 4, 4), bool)
    margin = np.zeros((2, len(site_sets(4))))
    for start in ([2.7, 0, 1, -1], [[0, 1], [2]], [0, 1, 4, -1]):  # 2.7 is not truncated
        with pytest.raises(ValueError, match=r"^start must give each of the 4 fingers"):
            optimal_gait(margin, reach, start=start)
        with pytest.raises(ValueError, match=r"^start must give"):
            greedy_gait(margin, reach, start=start)


def test_gait_env_through_sb3_make_vec_env():
    """SB3's make_vec_env asks for render_mode="rgb_array", and the gait environment takes it;
    its observations are the single environment's."""
    from stable_baselines3.common.env_util import make_vec_env

    envs = make_vec_env(GAIT_ID, n_envs=2, seed=0)
    assert envs.render_mode == "rgb_array"
    single = make_gait()
    np.testing.assert_array_equal(envs.reset()[0], single.reset(seed=0)[0])


def test_gait_env_pickles():
    import pickle

    env = make_gait()
    env.reset(seed=1)
    action = np.zeros(env.action_space.shape, np.float32)
    clone = pickle.loads(pickle.dumps(env))
    a = env.step(action)
    b = clone.step(action)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]


# ------------------------------------------------------------------------------- physics


def test_certified_gait_holds_in_mujoco():
    """The optimal gait along alpha in [-60, 0] deg (61 poses, five phase changes: fingers
    lifted with zero force and placed with none) carried through one continuous MuJoCo
    rollout: the object stays put and the analytic verdict agrees.

    The rollout takes a Scene of at most four contacts, so it models the window's four sites
    (-x, -y, -z, +x; which finger holds a site is immaterial to the physics), each touched
    where some finger touches it."""
    from grasp_env.physics.rollout import TrajectoryChecker

    solution = solve_gait()
    gait = solution.optimal
    alphas = list(PAPER_TURN.alphas_deg)
    window = slice(alphas.index(-60.0), alphas.index(0.0) + 1)
    contacts = gait.contacts[window]
    sites = sorted({int(s) for s in contacts.ravel() if s >= 0})
    assert len(sites) == 4 and np.count_nonzero(gait.moves[window]) == 5
    finger_forces = solution.forces(gait)[window]
    forces = np.zeros((len(contacts), 4, 3))
    touching = np.zeros((len(contacts), 4), bool)
    for t, row in enumerate(contacts):
        for f, s in enumerate(row):
            if s >= 0:
                forces[t, sites.index(s)] = finger_forces[t, f]
                touching[t, sites.index(s)] = True
    assert np.any(touching & (np.linalg.norm(forces, axis=-1) == 0))  # zero-force touches
    report = TrajectoryChecker(solution.scene.scene(sites)).check(
        solution.trajectory.rotations()[window], forces, touching
    )
    assert report.predicted_holds and report.holds, report.as_dict()
    assert abs(report.margin_deg - np.rad2deg(gait.margins[window].min())) < 0.01


def test_gait_env_through_the_sb3_adapter_and_not_grasp_env_train():
    """SB3VecEnv drives the gait's vector env (PPO learns on it); grasp-env train, whose runs
    are evaluated on held-out grasp scenes, refuses it and says where it trains."""
    from stable_baselines3 import PPO

    from grasp_env.envs.sb3 import SB3VecEnv
    from grasp_env_agents.run.config import config_from_dict

    for env_id in (GAIT_ID, MOVES_ID):  # a Box action and a Discrete one
        venv = SB3VecEnv(env_id, num_envs=4)
        venv.seed(0)
        np.testing.assert_array_equal(venv.reset()[0], make_gait().reset(seed=0)[0])
        PPO("MlpPolicy", venv, n_steps=16, batch_size=64, n_epochs=1, seed=0).learn(64)
    for env_id in (GAIT_ID, MOVES_ID):
        with pytest.raises(ValueError, match="trains with rl-zoo3"):
            config_from_dict({"env_id": env_id, "total_timesteps": 64})


def test_gait_expert_refuses_observations_outside_the_space():
    """A phase outside [0, 1] is no pose of the run (a negative one indexed from the end)."""
    from grasp_env.envs.gait import GaitExpert

    expert = GaitExpert()
    env = make_gait()
    obs, _ = env.reset(seed=0)
    phase = env.unwrapped.task.pose_size() - 1
    assert env.observation_space.low[phase] == 0.0 and env.observation_space.high[phase] == 1.0
    expert.predict(obs)  # inside: fine
    for value in (-0.01, 1.5):
        bad = obs.copy()
        bad[phase] = value
        with pytest.raises(ValueError, match=r"phase \(entry \d+\) must be within \[0, 1\]"):
            expert.predict(bad)
        with pytest.raises(ValueError, match="phase"):
            expert.predict(np.stack([obs, bad]))
    bad = obs.copy()
    bad[env.unwrapped.task.pose_size() :] = 0.0  # no finger touches
    with pytest.raises(ValueError, match="no state of the hand"):
        expert.predict(bad)
