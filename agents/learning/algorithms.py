"""The learning algorithms beside SB3's PPO: a PPO whose critic learns first, and SAC and TD3
with the force-direction head.

Every pose of a trajectory is a contextual bandit (gamma = 0: the states do not depend on the
actions), so what an algorithm needs is a precise estimate of how the reward changes with the
action at each state:

- PPO estimates it from the advantage r - V(s) of its own exploration noise. With a critic that
  has not learnt V yet, the normalised advantages are noise and the first updates move a good
  actor (a from-scratch force-direction head starts at a pure squeeze, 79% success; an imitated
  policy better still) at random. :class:`WarmCriticPPO` trains only the critic for its first
  ``critic_warmup`` rollouts, then both, as usual.
- SAC and TD3 learn Q(s, a) = E[r | s, a] by regression (gamma = 0: no bootstrap) and move the
  actor along the critic's action gradient dQ/da. :class:`ForceDirectionTD3Policy` and
  :class:`ForceDirectionSACPolicy` give them the same head as
  :class:`~grasp_env_agents.learning.policy.ForceDirectionPolicy` (each finger's force
  direction, k by least squares).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.sac.policies import Actor as SACActor
from stable_baselines3.sac.policies import SACPolicy
from stable_baselines3.td3.policies import Actor as TD3Actor
from stable_baselines3.td3.policies import TD3Policy

from grasp_env.envs.observation import ObservationLayout
from grasp_env.envs.validation import DEFAULT_K_MAX_RATIO

if TYPE_CHECKING:
    from ..run.config import TrainConfig
from .envs import action_scale, sample_poses
from .features import GraspFeatures, grasp_tensors, max_friction_angle
from .imitation import mean_action
from .policy import ForceDirectionHead, ForceDirectionPolicy

#: Hidden activations by config name (policy.activation).
ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU, "silu": torch.nn.SiLU}

#: How closely the mean-action baseline's reward function must reproduce the collected rewards
#: (radians; float32 observations reproduce them to about 1e-5).
REWARD_TOLERANCE = 1e-4

#: The SAC head's mean is atanh of the least-squares action, clamped this far inside (-1, 1).
ATANH_EDGE = 1.0 - 1e-4


class WarmCriticPPO(PPO):
    """SB3's PPO whose actor (network, head and log std) stays fixed for the first
    ``critic_warmup`` rollouts while the critic fits the value of the current policy; with
    ``baseline="mean_action"``, advantages measured against the reward of the policy's own
    mean action instead of the critic's value.

    The warm-up is counted in PPO's own steps (``num_timesteps``), which a checkpoint keeps: a
    resumed run does not warm up again.

    The mean-action baseline (self-critical, as in self-critical sequence training): with
    gamma = 0 an action's advantage is r(s, a) - b(s) for any b that does not depend on a, and
    the grasp environments' reward, the pose's min friction-angle margin, is a known function
    of the observation and the action. So b(s) = r(s, mean action) is computed exactly, where
    a critic estimates V(s) with an error (about 0.3 rad, docs/rl.md) a hundred times the
    reward change the exploration noise makes. Each rollout checks that the same function
    reproduces the rewards it collected, so another reward (a wrapper, a normalisation) is an
    error, not a wrong baseline.
    """

    def __init__(
        self,
        *args: Any,
        critic_warmup: int = 0,
        baseline: str = "critic",
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        **kwargs: Any,
    ) -> None:
        if baseline not in ("critic", "mean_action"):
            raise ValueError(f"baseline must be 'critic' or 'mean_action', got {baseline!r}")
        self.critic_warmup = critic_warmup
        self.baseline = baseline
        self.k_max_ratio = k_max_ratio  # the environment's action scale, for the baseline
        super().__init__(*args, **kwargs)

    def collect_rollouts(
        self, env: VecEnv, callback: Any, rollout_buffer: Any, n_rollout_steps: int
    ) -> bool:
        collected = super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)
        if collected and self.baseline == "mean_action":
            self._mean_action_advantages(rollout_buffer)
        return collected

    def _mean_action_advantages(self, buffer: Any) -> None:
        """Advantages r - r(s, mean action) and returns r (gamma = 0) of a collected rollout."""
        size = buffer.observations.shape[-1]
        obs = torch.as_tensor(buffer.observations.reshape(-1, size))
        layout = ObservationLayout.from_size(size)
        forces, basis, normals, _ = (t.double() for t in grasp_tensors(obs, layout))
        limit = obs[:, layout.friction_limit].double()
        actions = torch.as_tensor(buffer.actions.reshape(len(obs), -1)).double()
        with torch.no_grad():
            mean = mean_action(self.policy, obs.to(self.device)).double().cpu()
            baseline = limit - max_friction_angle(mean, forces, basis, normals, self.k_max_ratio)
            played = limit - max_friction_angle(actions, forces, basis, normals, self.k_max_ratio)
        rewards = buffer.rewards.reshape(-1)
        error = float(np.max(np.abs(played.numpy() - rewards)))
        if not error <= REWARD_TOLERANCE:
            raise ValueError(
                "ppo.baseline: mean_action needs the reward to be the pose's min friction-angle"
                f" margin computed from the observation; the collected rewards differ from it by"
                f" up to {error:.3g} rad (over {REWARD_TOLERANCE}): use ppo.baseline: critic"
            )
        buffer.values = baseline.numpy().reshape(buffer.values.shape).astype(np.float32)
        buffer.advantages = (buffer.rewards - buffer.values).astype(np.float32)
        buffer.returns = buffer.rewards.copy()

    def train(self) -> None:
        # train() follows the collection of a rollout: num_timesteps counts it already
        warming = self.num_timesteps <= self.critic_warmup * self.n_steps * self.n_envs
        actor = self.actor_parameters() if warming else []
        for parameter in actor:
            parameter.requires_grad_(False)  # Adam skips parameters without a gradient
        try:
            super().train()
        finally:
            for parameter in actor:
                parameter.requires_grad_(True)

    def actor_parameters(self) -> list[torch.nn.Parameter]:
        """What the critic's warm-up keeps fixed (the features extractor has no parameters)."""
        policy = self.policy
        parts = [policy.mlp_extractor.policy_net, policy.action_net]
        parameters = [p for part in parts for p in part.parameters()]
        if isinstance(getattr(policy, "log_std", None), torch.nn.Parameter):
            parameters.append(policy.log_std)
        return parameters


class _DirectionMean(torch.nn.Module):
    """Features -> mean action k / k_max through an MLP and the force-direction head."""

    def __init__(
        self, features_dim: int, net_arch: list[int], activation_fn: type, k_max_ratio: float
    ) -> None:
        super().__init__()
        self.hidden = torch.nn.Sequential(*create_mlp(features_dim, -1, net_arch, activation_fn))
        n_contacts = _contacts(features_dim)
        self.head = ForceDirectionHead(net_arch[-1], n_contacts, k_max_ratio)
        # small, as SB3 initialises its action layers: the untrained head is a pure squeeze
        torch.nn.init.orthogonal_(self.head.tilts.weight, gain=0.01)
        torch.nn.init.zeros_(self.head.tilts.bias)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.head(torch.cat([self.hidden(features), features], -1))


def _contacts(features_dim: int) -> int:
    """Fingers n of GraspFeatures' 6n + 3m + 1 features (m = n(n - 1)/2)."""
    for n in range(2, 9):
        if 6 * n + 3 * n * (n - 1) // 2 + 1 == features_dim:
            return n
    raise ValueError(f"{features_dim} features are not GraspFeatures' of any finger count")


class _DirectionTD3Actor(TD3Actor):
    def __init__(self, *args: Any, k_max_ratio: float = DEFAULT_K_MAX_RATIO, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.k_max_ratio = k_max_ratio
        mean = _DirectionMean(self.features_dim, self.net_arch, self.activation_fn, k_max_ratio)
        # the critic only ever saw actions in the box, so the actor stays in it
        self.mu = torch.nn.Sequential(mean, torch.nn.Hardtanh())

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "k_max_ratio": self.k_max_ratio}


class _DirectionPolicy:
    """What the off-policy force-direction policies share: the grasp features, and an actor
    of ``actor_class`` with the force-direction head (``k_max_ratio`` a constructor key)."""

    actor_class: type

    def __init__(
        self,
        observation_space: gym.spaces.Box,
        action_space: gym.spaces.Box,
        lr_schedule: Any,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        **kwargs: Any,
    ) -> None:
        self.k_max_ratio = k_max_ratio
        kwargs["features_extractor_class"] = GraspFeatures
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)  # type: ignore[call-arg]

    def make_actor(self, features_extractor: Any = None) -> Any:
        kwargs = self._update_features_extractor(self.actor_kwargs, features_extractor)  # type: ignore[attr-defined]
        return self.actor_class(**kwargs, k_max_ratio=self.k_max_ratio).to(self.device)  # type: ignore[attr-defined]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "k_max_ratio": self.k_max_ratio}  # type: ignore[misc]


class ForceDirectionTD3Policy(_DirectionPolicy, TD3Policy):
    """TD3's policy whose actor is the force-direction head on the grasp features."""

    actor_class = _DirectionTD3Actor


class _DirectionSACActor(SACActor):
    def __init__(self, *args: Any, k_max_ratio: float = DEFAULT_K_MAX_RATIO, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if self.use_sde:
            raise ValueError("SAC with policy.output: force_directions does not support gSDE")
        self.k_max_ratio = k_max_ratio
        width = self.net_arch[-1] if self.net_arch else self.features_dim
        self.mu = ForceDirectionHead(width, _contacts(self.features_dim), k_max_ratio)
        torch.nn.init.orthogonal_(self.mu.tilts.weight, gain=0.01)
        torch.nn.init.zeros_(self.mu.tilts.bias)

    def get_action_dist_params(
        self, obs: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
        features = self.extract_features(obs, self.features_extractor)
        latent = self.latent_pi(features)
        action = self.mu(torch.cat([latent, features], -1))
        # SAC squashes its Gaussian with tanh: its mean is the pre-image of the head's action
        mean = torch.atanh(action.clamp(-ATANH_EDGE, ATANH_EDGE))
        log_std = self.log_std(latent).clamp(-20, 2)  # SB3's LOG_STD_MIN, LOG_STD_MAX
        return mean, log_std, {}

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "k_max_ratio": self.k_max_ratio}


class ForceDirectionSACPolicy(_DirectionPolicy, SACPolicy):
    """SAC's policy whose Gaussian mean (before the tanh) comes from the force-direction head."""

    actor_class = _DirectionSACActor


# --- models from a config --------------------------------------------------------------------


def new_model(config: TrainConfig, env: VecEnv) -> BaseAlgorithm:
    """A fresh model of ``config.algo`` with the config's hyperparameters and network."""
    policy = config.policy
    activation = ACTIVATIONS[policy.activation]
    directions = policy.output == "force_directions"
    k_max_ratio = action_scale(env)  # the environment's own, read back from it
    if config.algo == "ppo":
        ppo = config.ppo
        model = WarmCriticPPO(
            ForceDirectionPolicy if directions else "MlpPolicy",
            env,
            critic_warmup=ppo.critic_warmup,
            baseline=ppo.baseline,
            k_max_ratio=k_max_ratio,
            # SB3's own class, not a lambda: a model file then holds a reference, not code
            learning_rate=(
                LinearSchedule(ppo.learning_rate, 0.0, 1.0)
                if ppo.lr_schedule == "linear"
                else ppo.learning_rate
            ),
            n_steps=ppo.n_steps,
            batch_size=ppo.batch_size,
            n_epochs=ppo.n_epochs,
            gamma=ppo.gamma,
            gae_lambda=ppo.gae_lambda,
            clip_range=ppo.clip_range,
            ent_coef=ppo.ent_coef,
            vf_coef=ppo.vf_coef,
            max_grad_norm=ppo.max_grad_norm,
            target_kl=ppo.target_kl,
            use_sde=ppo.use_sde,
            sde_sample_freq=ppo.sde_sample_freq,
            policy_kwargs={
                "net_arch": {"pi": list(policy.net_arch), "vf": list(policy.net_arch)},
                "activation_fn": activation,
                "log_std_init": policy.log_std_init,
                **(
                    {"features_extractor_class": GraspFeatures}
                    if policy.features == "grasp"
                    else {}
                ),
                **({"k_max_ratio": k_max_ratio} if directions else {}),
                **({"normalize_features": True} if policy.normalize_features else {}),
            },
            seed=config.seed,
            device="cpu",
            verbose=0,
        )
        if policy.normalize_features:
            model.policy.set_feature_statistics(sample_poses(config.env_id, config.env_kwargs))
        return model
    off = config.offpolicy
    assert off is not None  # an off-policy config always has the section (config.py)
    policy_kwargs: dict[str, Any] = {"net_arch": list(policy.net_arch), "activation_fn": activation}
    if directions:
        policy_kwargs["k_max_ratio"] = k_max_ratio
    elif policy.features == "grasp":
        policy_kwargs["features_extractor_class"] = GraspFeatures
    common = {
        "learning_rate": off.learning_rate,
        "buffer_size": off.buffer_size,
        "learning_starts": off.learning_starts,
        "batch_size": off.batch_size,
        "tau": off.tau,
        "gamma": off.gamma,
        "train_freq": off.train_freq,
        "gradient_steps": off.gradient_steps,
        "seed": config.seed,
        "device": "cpu",
        "verbose": 0,
    }
    m = env.action_space.shape[0]
    if config.algo == "td3":
        return TD3(
            ForceDirectionTD3Policy if directions else "MlpPolicy",
            env,
            action_noise=NormalActionNoise(np.zeros(m), np.full(m, off.action_noise)),
            policy_kwargs=policy_kwargs,
            **common,
        )
    return SAC(
        ForceDirectionSACPolicy if directions else "MlpPolicy",
        env,
        ent_coef=off.ent_coef,
        policy_kwargs=policy_kwargs,  # SAC's std is a function of the state, not log_std_init
        **common,
    )
