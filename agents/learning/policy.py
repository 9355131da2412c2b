"""An actor whose network outputs finger-force directions, and k from them by least squares.

Why: where the best grip nearly lets a finger go (|P_i| a few hundredths of the weight), that
finger's friction angle swings by degrees for errors of a few hundredths in k, so a network
that outputs k must be very precise exactly where the map observation -> k* is hardest to
fit. Friction angles are angles between forces and normals: an error in a predicted direction
is an error in angle, of the same size at every finger whatever its force.

So :class:`ForceDirectionPolicy` (an SB3 ``ActorCriticPolicy``) predicts, per finger, the
direction d_i of its contact force in the object's frame, as the normal tilted by a tangential
vector v_i: d_i = (n_i + v_i) / |n_i + v_i| (v_i = 0 is a pure squeeze, the untrained
network's output). The mean action is the grip whose forces P_i(k) = F_i + sum k_ij e_ij
(eq. 4) point best along these directions: the least squares of the components of P_i across
d_i, (I - d_i d_i^T) P_i(k) = 0, two equations per finger and linear in k. Each finger's
equations are weighted by 1 / |P_i| (re-weighted from the previous solve, starting from equal
weights), so that a residual measures the angle between P_i and d_i: the finger that nearly
lets go is then matched in angle as closely as the others. Of the solves the head returns
the one whose grip grips best (the smallest largest friction angle, the grip clipped to the
action box): the residual across d_i is blind to a force's sign, and where the directions are
inconsistent re-weighting can drive a nearly released finger through zero to a pull. The
choice is not differentiated; the gradient flows through the chosen solve. The directions
the expert's grip gives are consistent (some k realises all of them), and the least squares
returns that k exactly, so nothing is lost in what the head can express; the solve is
differentiable, so behaviour cloning, the max-friction-angle loss and PPO train the network
through it. The solves and their gradient are compiled (:mod:`grasp_env.mechanics.directions`):
in torch they were a few hundred small tensor operations per minibatch, a third of a fit's
step.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor

from grasp_env.envs.validation import DEFAULT_K_MAX_RATIO
from grasp_env.mechanics import directions as directions_module
from grasp_env.mechanics.directions import SOLVES

from .features import GraspFeatures, object_frame_grasp


def force_directions(tilts: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """Unit directions d_i = (n_i + v_i) / |n_i + v_i| with v_i = tilt_i's part across n_i."""
    tangential = tilts - (tilts * normals).sum(-1, keepdim=True) * normals
    directions = normals + tangential
    return directions / torch.linalg.vector_norm(directions, dim=-1, keepdim=True)


def _array(tensor: torch.Tensor) -> np.ndarray:
    """The tensor's values as a C-contiguous numpy array (copied to the CPU if elsewhere)."""
    return tensor.detach().cpu().contiguous().numpy()


class _GripAlong(torch.autograd.Function):
    """:func:`grasp_env.mechanics.directions.grip_along` as a torch function of the directions
    (computed on the CPU, returned on the directions' device)."""

    @staticmethod
    def forward(ctx, directions, forces, basis, normals, k_max, solves):
        grasp = [_array(t) for t in (directions, forces, basis, normals)]
        k, weights = directions_module.grip_along(*grasp, k_max, solves)
        ctx.save_for_backward(directions, forces, basis)
        ctx.grip = k, weights
        return torch.from_numpy(k).to(directions.device, directions.dtype)

    @staticmethod
    def backward(ctx, grad_k):
        if any(ctx.needs_input_grad[1:]):
            raise NotImplementedError("grip_along differentiates the directions only")
        k, weights = ctx.grip
        grasp = [_array(t) for t in ctx.saved_tensors]
        grad = directions_module.grip_along_gradient(*grasp, weights, k, _array(grad_k.double()))
        return torch.from_numpy(grad).to(grad_k.device, grad_k.dtype), *[None] * 5


def grip_along(
    directions: torch.Tensor,
    forces: torch.Tensor,
    basis: torch.Tensor,
    normals: torch.Tensor,
    k_max: float,
    solves: int = SOLVES,
) -> torch.Tensor:
    """The k (B, m) whose finger forces F_i + sum k_ij e_ij best point along ``directions``.

    Of ``solves`` least-squares solves (equal weights, then re-weighted by 1 / |P_i|) it
    returns the one whose grip, clipped to the box |k_ij| <= k_max as the environment clips
    it, has the smallest largest friction angle
    (:func:`grasp_env.mechanics.directions.grip_along`, computed in float64); differentiable
    in the directions, through the chosen solve.

    Args:
        directions: unit directions d_i (B, n, 3).
        forces: equilibrating forces F_i (B, n, 3), in units of w.
        basis: the interaction basis e_ij (B, m, n, 3) in the same frame.
        normals: the contact normals n_i (B, n, 3) in the same frame.
        k_max: the action box (k_max / w).
        solves: least-squares solves (at least 1).
    """
    return _GripAlong.apply(directions, forces, basis, normals, k_max, solves)


class ForceDirectionHead(torch.nn.Module):
    """Latent [hidden, grasp features] -> mean action k / k_max via :func:`grip_along`."""

    def __init__(self, hidden_dim: int, n_contacts: int, k_max_ratio: float) -> None:
        super().__init__()
        self.hidden_dim = hidden_dim
        self.n_contacts = n_contacts
        self.k_max_ratio = k_max_ratio
        self.tilts = torch.nn.Linear(hidden_dim, 3 * n_contacts)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        # the grasp is data (GraspFeatures has no parameters): the gradient is the directions'
        hidden, features = latent[:, : self.hidden_dim], latent[:, self.hidden_dim :].detach()
        forces, basis, normals = object_frame_grasp(features, self.n_contacts)
        directions = force_directions(self.tilts(hidden).reshape(normals.shape), normals)
        return grip_along(directions, forces, basis, normals, self.k_max_ratio) / self.k_max_ratio


class _LatentWithFeatures(MlpExtractor):
    """SB3's MlpExtractor whose actor latent also carries the features (the head needs them).

    With ``normalize_features`` the hidden layers (actor and critic) see the features
    standardised by the buffers ``feature_mean`` and ``feature_std``
    (:meth:`ForceDirectionPolicy.set_feature_statistics`); the head still reads them as they are.
    """

    def __init__(self, feature_dim: int, normalize_features: bool = False, **kwargs: Any) -> None:
        super().__init__(feature_dim, **kwargs)
        self.hidden_dim = self.latent_dim_pi
        self.latent_dim_pi += feature_dim
        self.normalize_features = normalize_features
        if normalize_features:  # buffers: saved and loaded with the weights, never trained
            self.register_buffer("feature_mean", torch.zeros(feature_dim))
            self.register_buffer("feature_std", torch.ones(feature_dim))

    def hidden_inputs(self, features: torch.Tensor) -> torch.Tensor:
        """What the hidden layers see of ``features``."""
        if not self.normalize_features:
            return features
        return (features - self.feature_mean) / self.feature_std

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.policy_net(self.hidden_inputs(features)), features], -1)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value_net(self.hidden_inputs(features))


class ForceDirectionPolicy(ActorCriticPolicy):
    """SB3's actor-critic with the force-direction head (module docstring) as its mean action.

    Takes ``ActorCriticPolicy``'s arguments, plus ``k_max_ratio`` (k_max / w, the environment's
    action scale) and ``normalize_features`` (the hidden layers' inputs standardised, once
    :meth:`set_feature_statistics` has measured them); its features are always
    :class:`~grasp_env_agents.learning.features.GraspFeatures`.
    """

    def __init__(
        self,
        observation_space: gym.spaces.Box,
        action_space: gym.spaces.Box,
        lr_schedule: Any,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        normalize_features: bool = False,
        **kwargs: Any,
    ) -> None:
        self.k_max_ratio = k_max_ratio
        self.normalize_features = normalize_features
        kwargs["features_extractor_class"] = GraspFeatures
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = _LatentWithFeatures(
            self.features_dim,
            normalize_features=self.normalize_features,
            net_arch=self.net_arch,
            activation_fn=self.activation_fn,
            device=self.device,
        )

    def _build(self, lr_schedule: Any) -> None:
        super()._build(lr_schedule)
        self.action_net = ForceDirectionHead(
            self.mlp_extractor.hidden_dim,
            self.pi_features_extractor.layout.n_contacts,
            self.k_max_ratio,
        )
        if self.ortho_init:  # as SB3 initialises its action layer: small, so d_i starts at n_i
            self.action_net.apply(partial(self.init_weights, gain=0.01))
        self.optimizer = self.optimizer_class(
            self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        parameters = {**super()._get_constructor_parameters(), "k_max_ratio": self.k_max_ratio}
        if self.normalize_features:  # files written without it load as before
            parameters["normalize_features"] = True
        return parameters

    def set_feature_statistics(self, observations: np.ndarray) -> None:
        """Standardise the hidden layers' inputs by the mean and standard deviation of the
        grasp features of ``observations`` (poses, size), for example
        :func:`grasp_env_agents.learning.envs.sample_poses`. A feature that does not vary there (the
        object-frame normals of a cube's faces) is only centred."""
        if not self.normalize_features:
            raise ValueError("set_feature_statistics needs a policy made with normalize_features")
        with torch.no_grad():
            features = self.pi_features_extractor(torch.as_tensor(observations, device=self.device))
            std = features.std(0)
            self.mlp_extractor.feature_mean.copy_(features.mean(0))
            self.mlp_extractor.feature_std.copy_(torch.where(std > 1e-6, std, 1.0))
