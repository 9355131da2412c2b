"""PPO with a warmed-up critic, and SAC and TD3 with the force-direction head."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3 import SAC, TD3

from grasp_env_agents.algorithms import (
    ForceDirectionSACPolicy,
    ForceDirectionTD3Policy,
    WarmCriticPPO,
)
from grasp_env_agents.envs import make_vec_env
from grasp_env_agents.features import GraspFeatures, object_frame_grasp
from grasp_env_agents.policy import ForceDirectionPolicy, grip_along

ENV_ID = "grasp_env/CubeGraspRandom-v0"
K_MAX_RATIO = 2.0


@pytest.fixture(scope="module")
def env():
    venv = make_vec_env(ENV_ID, {"terminate_on_slip": False}, 4, 0)
    yield venv
    venv.close()


def snapshot(module: torch.nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def changed(before: list[torch.Tensor], module: torch.nn.Module) -> bool:
    return any(not torch.equal(a, b) for a, b in zip(before, module.parameters(), strict=True))


def test_warm_critic_ppo_moves_only_the_critic_during_warmup(env) -> None:
    model = WarmCriticPPO(
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
    return (grip_along(normals, forces, basis) / K_MAX_RATIO).numpy()


def env_space(obs: np.ndarray):
    import gymnasium as gym

    return gym.spaces.Box(-np.inf, np.inf, obs.shape[1:], np.float32)


@pytest.mark.parametrize(
    ("algorithm", "policy"), [(TD3, ForceDirectionTD3Policy), (SAC, ForceDirectionSACPolicy)]
)
def test_off_policy_force_direction_actors_start_at_a_squeeze_learn_and_reload(
    env, tmp_path: Path, algorithm, policy
) -> None:
    model = algorithm(
        policy,
        env,
        learning_starts=32,
        batch_size=32,
        gamma=0.0,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": [16], "k_max_ratio": K_MAX_RATIO},
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
