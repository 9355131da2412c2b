"""PPO with a warmed-up critic, and SAC and TD3 with the force-direction head."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.logger import Logger

from grasp_env_agents.learning.algorithms import (
    ForceDirectionSACPolicy,
    ForceDirectionTD3Policy,
    WarmCriticPPO,
)
from grasp_env_agents.learning.envs import make_vec_env
from grasp_env_agents.learning.features import GraspFeatures, max_friction_angle, object_frame_grasp
from grasp_env_agents.learning.policy import ForceDirectionPolicy, force_directions, grip_along

ENV_ID = "grasp_env/CubeGraspRandom-v0"
K_MAX_RATIO = 2.0


@pytest.fixture(scope="module")
def env():
    venv = make_vec_env(ENV_ID, {"terminate_on_slip": False}, 4, 0)
    yield venv
    venv.close()


def quiet(model):
    """The model with a logger that writes nothing (without one, SB3's learn makes a
    /tmp/SB3-<date> folder)."""
    model.set_logger(Logger(None, []))
    return model


def snapshot(module: torch.nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def changed(before: list[torch.Tensor], module: torch.nn.Module) -> bool:
    return any(not torch.equal(a, b) for a, b in zip(before, module.parameters(), strict=True))


def test_warm_critic_ppo_moves_only_the_critic_during_warmup(env) -> None:
    model = quiet(
        WarmCriticPPO(
            ForceDirectionPolicy,
            env,
            critic_warmup=2,
            n_steps=16,
            batch_size=32,
            n_epochs=2,
            gamma=0.0,
            seed=0,
            device="cpu",
            policy_kwargs={"net_arch": [16], "k_max_ratio": K_MAX_RATIO},
        )
    )
    policy = model.policy
    actor = [policy.mlp_extractor.policy_net, policy.action_net]
    critic = [policy.mlp_extractor.value_net, policy.value_net]
    actor_before = [snapshot(m) for m in actor]
    log_std_before = policy.log_std.detach().clone()
    critic_before = [snapshot(m) for m in critic]
    model.learn(2 * 16 * env.num_envs)  # two rollouts: the warm-up
    assert all(not changed(b, m) for b, m in zip(actor_before, actor, strict=True))
    assert torch.equal(policy.log_std, log_std_before)
    assert any(changed(b, m) for b, m in zip(critic_before, critic, strict=True))
    assert all(p.requires_grad for p in policy.parameters())
    model.learn(16 * env.num_envs, reset_num_timesteps=False)  # the third rollout moves the actor
    assert any(changed(b, m) for b, m in zip(actor_before, actor, strict=True))


def squeeze_grip(obs: np.ndarray) -> np.ndarray:
    """The pure squeeze: every finger's force along its normal, as closely as k allows."""
    features = GraspFeatures(env_space(obs))(torch.as_tensor(obs))
    forces, basis, normals = object_frame_grasp(features, 3)
    return (grip_along(normals, forces, basis, normals, K_MAX_RATIO) / K_MAX_RATIO).numpy()


def self_critical_ppo(env, k_max_ratio: float = K_MAX_RATIO) -> WarmCriticPPO:
    # learning_rate 0: the policy after learn() is the one that collected the rollout
    return quiet(
        WarmCriticPPO(
            ForceDirectionPolicy, env, learning_rate=0.0, n_steps=16, batch_size=32,
            n_epochs=1, gamma=0.0, seed=0, device="cpu", baseline="mean_action",
            k_max_ratio=k_max_ratio,
            policy_kwargs={"net_arch": [16], "k_max_ratio": K_MAX_RATIO, "log_std_init": -4.0},
        )
    )  # fmt: skip


def test_the_mean_action_baseline_is_the_reward_of_the_policys_mean_action(env) -> None:
    model = self_critical_ppo(env)
    model.learn(16 * env.num_envs)
    buffer = model.rollout_buffer  # flattened by train(): (steps x envs, ...)
    obs = torch.as_tensor(buffer.observations)
    with torch.no_grad():
        features = model.policy.extract_features(obs, model.policy.pi_features_extractor)
        mean = model.policy.action_net(model.policy.mlp_extractor.forward_actor(features))
    forces, basis, normals = (t.double() for t in object_frame_grasp(features, 3))
    limit = features[:, -1].double()  # GraspFeatures ends with the friction limit
    expected = limit - max_friction_angle(mean.double(), forces, basis, normals, K_MAX_RATIO)
    np.testing.assert_allclose(buffer.values[:, 0], expected.numpy(), atol=1e-5)
    rewards = buffer.returns[:, 0]  # gamma = 0: the return is the reward itself
    np.testing.assert_allclose(buffer.advantages[:, 0], rewards - buffer.values[:, 0], atol=1e-6)


def test_the_mean_action_baseline_refuses_rewards_it_does_not_reproduce(env) -> None:
    model = self_critical_ppo(env, k_max_ratio=1.0)  # the environment's actions are scaled by 2
    with pytest.raises(ValueError, match="collected rewards differ"):
        model.learn(16 * env.num_envs)


def test_grip_along_returns_the_best_of_its_solves(env) -> None:
    """Where the directions are inconsistent, re-weighting can turn a nearly released finger
    into a pull: the head keeps whichever least-squares solve grips best."""
    rng = np.random.default_rng(0)
    obs = np.concatenate([env.reset() for _ in range(64)])  # 256 random scenes
    features = GraspFeatures(env_space(obs))(torch.as_tensor(obs))
    forces, basis, normals = object_frame_grasp(features, 3)
    tilts = torch.as_tensor(rng.normal(scale=0.5, size=normals.shape), dtype=normals.dtype)
    directions = force_directions(tilts, normals)

    def largest_angle(solves: int) -> np.ndarray:
        k = grip_along(directions, forces, basis, normals, K_MAX_RATIO, solves)
        return max_friction_angle(k / K_MAX_RATIO, forces, basis, normals, K_MAX_RATIO).numpy()

    best = largest_angle(3)
    for solves in (1, 2):
        assert np.all(best <= largest_angle(solves) + 1e-6)
    assert np.any(best < largest_angle(1) - 1e-3)  # re-weighting does help some scenes


def test_grip_along_solves_the_least_squares_of_the_components_across_the_directions(
    env,
) -> None:
    """One solve (equal weights) is the least squares of (I - d_i d_i^T)(F_i + B_i k) = 0 over
    all fingers, as numpy's lstsq of the stacked rows gives it."""
    rng = np.random.default_rng(1)
    obs = np.concatenate([env.reset() for _ in range(16)])
    features = GraspFeatures(env_space(obs))(torch.as_tensor(obs))
    forces, basis, normals = (t.double() for t in object_frame_grasp(features, 3))
    tilts = torch.as_tensor(rng.normal(scale=0.3, size=normals.shape))
    directions = force_directions(tilts, normals)
    k = grip_along(directions, forces, basis, normals, K_MAX_RATIO, solves=1).numpy()
    for b in range(len(k)):
        d, F, E = directions[b].numpy(), forces[b].numpy(), basis[b].numpy()  # E: (m, n, 3)
        across = np.eye(3) - d[:, :, None] * d[:, None, :]  # (n, 3, 3)
        rows = np.einsum("nij,qnj->niq", across, E).reshape(-1, E.shape[0])
        expected = np.linalg.lstsq(rows, -np.einsum("nij,nj->ni", across, F).ravel())[0]
        np.testing.assert_allclose(k[b], expected, atol=1e-7)


def random_grasps(env, scenes: int, seed: int, scale: float) -> tuple[torch.Tensor, ...]:
    """Object-frame grasps (float64) of random scenes and tilted force directions on them."""
    obs = np.concatenate([env.reset() for _ in range(scenes // env.num_envs)])
    features = GraspFeatures(env_space(obs))(torch.as_tensor(obs))
    forces, basis, normals = (t.double() for t in object_frame_grasp(features, 3))
    rng = np.random.default_rng(seed)
    tilts = torch.as_tensor(rng.normal(scale=scale, size=normals.shape))
    return force_directions(tilts, normals), forces, basis, normals


def test_grip_along_gradient_is_the_derivative_of_one_solve(env) -> None:
    """With one solve (equal weights) the grip is a smooth function of the directions: the
    compiled gradient against finite differences (torch's gradcheck)."""
    directions, forces, basis, normals = random_grasps(env, 8, seed=2, scale=0.3)

    def grip(d: torch.Tensor) -> torch.Tensor:
        return grip_along(d, forces, basis, normals, K_MAX_RATIO, solves=1)

    assert torch.autograd.gradcheck(grip, directions.requires_grad_(), eps=1e-6, atol=1e-5)


def test_grip_along_gradient_holds_the_chosen_solves_weights(env) -> None:
    """With re-weighted solves the gradient is the chosen solve's with its weights fixed: the
    same as torch's autograd through that weighted least squares, written out here."""
    directions, forces, basis, normals = random_grasps(env, 64, seed=3, scale=0.5)
    # the leaf is on the unit sphere's tangent: (I - d d^T) and its square agree only there
    tilts = torch.zeros_like(directions, requires_grad=True)
    directions = force_directions(directions + tilts, directions)
    k = grip_along(directions, forces, basis, normals, K_MAX_RATIO)
    upstream = torch.as_tensor(np.random.default_rng(4).normal(size=k.shape))
    (compiled,) = torch.autograd.grad((k * upstream).sum(), tilts, retain_graph=True)
    # the weights of the chosen solve: 1 / |P_i| at the grip before it (or 1 for the first),
    # found by matching each solve's grip to the one returned
    with torch.no_grad():
        weights = torch.ones(forces.shape[:2], dtype=torch.float64)
        chosen = torch.ones_like(weights)
        for _ in range(3):
            grip = weighted_least_squares(directions, forces, basis, weights)
            match = (grip - k).abs().amax(-1) < 1e-9
            chosen[match] = weights[match]
            net = forces + torch.einsum("bq,bqnc->bnc", grip, basis)
            weights = 1.0 / torch.linalg.vector_norm(net, dim=-1).clamp_min(1e-3)
    assert (chosen != 1).any(), "no re-weighted solve was chosen: the test would not test it"
    reference = weighted_least_squares(directions, forces, basis, chosen)
    np.testing.assert_allclose(reference.detach().numpy(), k.detach().numpy(), atol=1e-9)
    (expected,) = torch.autograd.grad((reference * upstream).sum(), tilts)
    np.testing.assert_allclose(compiled.numpy(), expected.numpy(), rtol=1e-7, atol=1e-9)


def weighted_least_squares(directions, forces, basis, weights) -> torch.Tensor:
    """argmin_k sum_i w_i^2 |(I - d_i d_i^T)(F_i + B_i k)|^2 (+ the head's ridge), in torch."""
    across = torch.eye(3, dtype=torch.float64) - directions[..., :, None] * directions[..., None, :]
    rows = torch.einsum("bnij,bqnj->bniq", across, basis) * weights[..., None, None]
    loads = torch.einsum("bnij,bnj->bni", across, forces) * weights[..., None]
    matrix = torch.einsum("bniq,bnir->bqr", rows, rows)
    ridge = 1e-9 * matrix.diagonal(dim1=1, dim2=2).mean(-1)[:, None, None]
    rhs = -torch.einsum("bniq,bni->bq", rows, loads)
    return torch.linalg.solve(matrix + ridge * torch.eye(matrix.shape[-1]), rhs)


def env_space(obs: np.ndarray):
    import gymnasium as gym

    return gym.spaces.Box(-np.inf, np.inf, obs.shape[1:], np.float32)


@pytest.mark.parametrize(
    ("algorithm", "policy"), [(TD3, ForceDirectionTD3Policy), (SAC, ForceDirectionSACPolicy)]
)
def test_off_policy_force_direction_actors_start_at_a_squeeze_learn_and_reload(
    env, tmp_path: Path, algorithm, policy
) -> None:
    model = quiet(
        algorithm(
            policy,
            env,
            learning_starts=32,
            batch_size=32,
            gamma=0.0,
            seed=0,
            device="cpu",
            policy_kwargs={"net_arch": [16], "k_max_ratio": K_MAX_RATIO},
        )
    )
    obs = env.reset()
    start, _ = model.predict(obs, deterministic=True)
    # the untrained head tilts the normals by ~1% of their length: nearly the squeeze
    assert np.allclose(start, np.clip(squeeze_grip(obs), -1, 1), atol=0.05)
    model.learn(128)
    moved, _ = model.predict(obs, deterministic=True)
    assert not np.allclose(moved, start)
    model.save(tmp_path / "model.zip")
    loaded = algorithm.load(tmp_path / "model.zip", device="cpu")
    again, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_allclose(again, moved, atol=1e-6)


def test_sac_head_refuses_gsde(env) -> None:
    with pytest.raises(ValueError, match="gSDE"):
        SAC(
            ForceDirectionSACPolicy,
            env,
            use_sde=True,
            device="cpu",
            policy_kwargs={"net_arch": [16], "k_max_ratio": K_MAX_RATIO},
        )


# --- through the config, training and model files -----------------------------------------

TINY = {
    "env_id": ENV_ID,
    "env_kwargs": {"terminate_on_slip": False},
    "n_envs": 4,
    "total_timesteps": 256,
    "eval_freq": 0,
    "eval_episodes": 4,
    "checkpoint_freq": 0,
    "policy": {"net_arch": [16], "features": "grasp", "output": "force_directions"},
}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"algo": "a2c"}, "algo"),
        ({"offpolicy": {"batch_size": 8}}, "offpolicy: the section is for algo: td3 or sac"),
        ({"algo": "td3", "imitation": {}}, "imitation: the expert teaches PPO"),
        ({"algo": "sac", "offpolicy": {"ent_coef": "learned"}}, "ent_coef"),
        ({"algo": "td3", "offpolicy": {"gradient_steps": 0}}, "gradient_steps"),
        ({"ppo": {"critic_warmup": -1}}, "critic_warmup"),
        ({"ppo": {"use_sde": 1}}, "use_sde"),
        ({"algo": "sac", "ppo": {"n_steps": 8}}, "ppo: the section is for algo: ppo"),
        ({"algo": "td3", "offpolicy": {"ent_coef": 0.1}}, "offpolicy.ent_coef is SAC's"),
        ({"algo": "sac", "offpolicy": {"action_noise": 0.1}}, "offpolicy.action_noise is TD3's"),
        ({"ppo": {"baseline": "zero"}}, "baseline"),
        ({"ppo": {"baseline": "mean_action", "gamma": 0.9}}, "exact for gamma = 0"),
        (
            {"normalize": True, "policy": {"net_arch": [16]}, "ppo": {"baseline": "mean_action"}},
            "raw observation, which normalize: true hides",
        ),
        (
            {"policy": {"net_arch": [16], "features": "grasp", "normalize_features": True}},
            "needs policy.output: force_directions and algo: ppo",
        ),
        (
            {"algo": "td3", "policy": {**TINY["policy"], "normalize_features": True}},
            "needs policy.output: force_directions and algo: ppo",
        ),
    ],
)
def test_algo_keys_are_checked(change: dict, message: str) -> None:
    from grasp_env_agents.run.config import config_from_dict

    with pytest.raises(ValueError, match=message):
        config_from_dict({**TINY, **change})


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_off_policy_run_trains_and_its_model_file_loads_safely(tmp_path: Path, algo: str) -> None:
    from grasp_env_agents.commands.train import train
    from grasp_env_agents.learning.models import load_agent
    from grasp_env_agents.run.config import config_from_dict, load_config
    from grasp_env_agents.studies.evaluation import evaluate_run

    config = config_from_dict(
        {
            **TINY,
            "algo": algo,
            "offpolicy": {"learning_starts": 64, "batch_size": 32, "buffer_size": 1024},
        }
    )
    run_dir = tmp_path / algo
    model = train(config, run_dir, progress_bar=False)
    assert type(model).__name__ == algo.upper()
    agent = load_agent(run_dir, algo)  # the safe loader knows the off-policy classes
    obs = model.get_env().reset()
    np.testing.assert_allclose(
        agent.predict(obs)[0], model.predict(obs, deterministic=True)[0], atol=1e-6
    )
    # a bare model file received from someone: its policy class says which algorithm wrote it
    shared = tmp_path / "shared.zip"
    shutil.copy(run_dir / "model.zip", shared)
    np.testing.assert_array_equal(load_agent(shared).predict(obs)[0], agent.predict(obs)[0])
    policy = type(model.policy).__name__
    with pytest.raises(ValueError, match=f"a {algo.upper()} model .*{policy}\\), not PPO"):
        load_agent(shared, "ppo")
    comparison = evaluate_run(run_dir, 4, 0)
    assert comparison.metrics["trained agent"]["episodes"] == 4
    # the run's config.yaml holds the algorithm's sections only, and reads back the same
    written = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert written["algo"] == algo and "ppo" not in written
    assert ("ent_coef" in written["offpolicy"]) == (algo == "sac")
    assert ("action_noise" in written["offpolicy"]) == (algo == "td3")
    assert load_config(run_dir / "config.yaml") == config


@pytest.mark.slow
@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_off_policy_resume_restores_weights_buffer_and_step_count(
    tmp_path: Path, monkeypatch, algo: str
) -> None:
    from grasp_env_agents.commands.train import RecordEvaluation, train
    from grasp_env_agents.learning.checkpoints import find_start
    from grasp_env_agents.learning.models import load_replay_buffer
    from grasp_env_agents.run.config import config_from_dict

    config = config_from_dict(
        {
            **TINY,
            "algo": algo,
            "eval_freq": 128,
            "checkpoint_freq": 64,
            "offpolicy": {"learning_starts": 32, "batch_size": 32, "buffer_size": 1024},
        }
    )
    run = tmp_path / "run"
    record = RecordEvaluation._on_step

    def ctrl_c_after_first_evaluation(self):
        record(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(RecordEvaluation, "_on_step", ctrl_c_after_first_evaluation)
    with pytest.raises(KeyboardInterrupt):
        train(config, run, progress_bar=False)
    folder = run / "checkpoints"
    # interrupted in the step that passed 128, before its update and its store: the weights
    # and the buffer are those of 124 steps, and so is the checkpoint's name
    assert sorted(p.name for p in folder.glob(f"{algo}_*_steps.zip")) == [
        f"{algo}_124_steps.zip",
        f"{algo}_64_steps.zip",
    ]
    # only the newest checkpoint keeps its (large) replay buffer
    (buffer_file,) = folder.glob("*_replay_buffer_*")
    assert buffer_file.name == f"{algo}_replay_buffer_124_steps.pkl"
    start = find_start(run, False, 0, algo)
    assert start.checkpoint == folder / f"{algo}_124_steps.zip" and start.model_steps == 124

    from grasp_env_agents.learning.algorithms import new_model
    from grasp_env_agents.learning.checkpoints import restore
    from grasp_env_agents.learning.envs import make_vec_env

    saved = load_replay_buffer(buffer_file)
    # every transition but the interrupted step's (SB3 stores it after the callbacks, one of
    # which raised)
    assert saved.pos == 124 // config.n_envs
    fresh = new_model(config, make_vec_env(ENV_ID, config.env_kwargs, config.n_envs, 0))
    restore(fresh, start)
    assert fresh.num_timesteps == 124
    np.testing.assert_array_equal(fresh.replay_buffer.observations, saved.observations)
    trained = load_model_from(folder / f"{algo}_124_steps.zip", algo)
    for a, b in zip(fresh.policy.parameters(), trained.policy.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    if algo == "sac":  # the entropy coefficient lives beside the weights: restored too
        torch.testing.assert_close(fresh.log_ent_coef, trained.log_ent_coef, rtol=0, atol=0)
        assert not torch.equal(fresh.log_ent_coef, torch.zeros(1))

    monkeypatch.setattr(RecordEvaluation, "_on_step", record)
    model = train(config, run, resume=True, progress_bar=False)
    assert model.num_timesteps == 256
    assert model.replay_buffer.pos == saved.pos + (256 - 124) // config.n_envs  # old and new
    with (run / "learning_curve.csv").open() as file:
        steps = [int(row["env_steps"]) for row in csv.DictReader(file)]
    assert steps == sorted(set(steps)) and steps[-1] == 256  # each evaluation once, in order


def load_model_from(path: Path, algo: str):
    from grasp_env_agents.learning.models import load_model

    return load_model(path, algo)


def test_a_replay_buffer_that_would_run_code_is_refused(tmp_path: Path) -> None:
    import os
    import pickle

    from grasp_env_agents.learning.models import load_replay_buffer

    class Payload:
        def __reduce__(self):
            return (os.system, ("touch " + str(tmp_path / "ran"),))

    path = tmp_path / "td3_replay_buffer_64_steps.pkl"
    path.write_bytes(pickle.dumps(Payload()))
    with pytest.raises(ValueError, match=r"names posix\.system.*nothing from it was run"):
        load_replay_buffer(path)
    assert not (tmp_path / "ran").exists()
    path.write_bytes(pickle.dumps({"not": "a buffer"}))
    with pytest.raises(ValueError, match="not a replay buffer"):
        load_replay_buffer(path)


def test_critic_warmup_is_counted_in_steps_so_a_resumed_model_does_not_warm_up_again(env) -> None:
    model = quiet(
        WarmCriticPPO(
            ForceDirectionPolicy,
            env,
            critic_warmup=2,
            n_steps=16,
            batch_size=32,
            n_epochs=1,
            gamma=0.0,
            seed=0,
            device="cpu",
            policy_kwargs={"net_arch": [16], "k_max_ratio": K_MAX_RATIO},
        )
    )
    model.num_timesteps = 2 * 16 * env.num_envs  # as a checkpoint after the warm-up restores it
    actor = snapshot(model.policy.action_net)
    model.learn(16 * env.num_envs, reset_num_timesteps=False)
    assert changed(actor, model.policy.action_net)


def test_ppo_keys_reach_the_model_and_a_gsde_run_loads_safely(tmp_path: Path) -> None:
    from stable_baselines3.common.distributions import StateDependentNoiseDistribution

    from grasp_env_agents.commands.train import train
    from grasp_env_agents.learning.models import load_agent
    from grasp_env_agents.run.config import config_from_dict

    config = config_from_dict(
        {
            **TINY,
            "total_timesteps": 128,
            "ppo": {
                "n_steps": 16,
                "batch_size": 32,
                "n_epochs": 1,
                "critic_warmup": 1,
                "use_sde": True,
                "sde_sample_freq": 4,
            },
        }
    )
    model = train(config, tmp_path / "run", progress_bar=False)
    assert isinstance(model, WarmCriticPPO) and model.critic_warmup == 1
    assert model.use_sde and model.sde_sample_freq == 4
    assert isinstance(model.policy.action_dist, StateDependentNoiseDistribution)
    obs = model.get_env().reset()
    mean = model.predict(obs, deterministic=True)[0]
    assert not np.allclose(model.predict(obs)[0], mean)  # gSDE's noise moves the action
    agent = load_agent(tmp_path / "run", "ppo")
    np.testing.assert_allclose(agent.predict(obs)[0], mean, atol=1e-6)


def test_normalized_features_reach_the_hidden_layers_and_a_run_loads_safely(
    tmp_path: Path,
) -> None:
    from grasp_env_agents.commands.train import train
    from grasp_env_agents.learning.envs import sample_poses
    from grasp_env_agents.learning.models import load_agent
    from grasp_env_agents.run.config import config_from_dict

    policy = {**TINY["policy"], "normalize_features": True}
    config = config_from_dict({**TINY, "policy": policy, "ppo": {"baseline": "mean_action"}})
    model = train(config, tmp_path / "run", progress_bar=False)
    extractor = model.policy.mlp_extractor
    # standardised over the environment's poses: each varying feature at mean 0 and std 1
    features = model.policy.pi_features_extractor(torch.as_tensor(sample_poses(ENV_ID, {})))
    varying = features.std(0) > 1e-6
    assert varying.sum() == 19  # of 28: R^T F_i, R^T u_ij and the friction limit; not the normals
    inputs = extractor.hidden_inputs(features).detach()
    np.testing.assert_allclose(inputs.mean(0), 0, atol=1e-5)
    np.testing.assert_allclose(inputs.std(0)[varying], 1, atol=1e-5)
    # the head still reads the grasp itself
    assert torch.equal(extractor.forward_actor(features)[:, extractor.hidden_dim :], features)
    # the statistics travel in the model file: the safe loader predicts as the model does
    obs = model.get_env().reset()
    agent = load_agent(tmp_path / "run", "ppo")
    np.testing.assert_allclose(
        agent.predict(obs)[0], model.predict(obs, deterministic=True)[0], atol=1e-6
    )
    loaded = agent.model.policy.mlp_extractor
    assert torch.equal(loaded.feature_std, extractor.feature_std)
    assert not torch.equal(loaded.feature_std, torch.ones_like(loaded.feature_std))
