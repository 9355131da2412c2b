"""One policy for every grasp: a network over the set of contacts, any object, any n.

The general objects' environments pad a grasp of n contacts to their ``max_contacts`` N: the
observation holds N contact positions and normals with a mask, and the action the interaction
scalars of the N (N - 1) / 2 pairs (those of padded contacts unused). A policy for every grasp
must not care in which order the fingers are listed, nor how many there are.

:class:`ContactSetPolicy` (an SB3 ``ActorCriticPolicy``) reads the grasp as a set of tokens, one
per real contact, in the object's frame (the friction angles do not depend on the frame, eq.
2): the contact's position p_i, its inward normal n_i and its equilibrating force F_i (the
minimum-norm forces that balance the load, computed from the observation in closed form), with
the friction limit. A per-token MLP and masked self-attention layers (no positional encoding)
make each contact's latent depend on the whole set and not on the order, so the network is
equivariant to permutations of the fingers and takes any n up to N; its weights do not depend
on N, so a policy trained with one N loads into another (:func:`transfer`).

Its mean action is the force-direction head of :mod:`~.policy`: each contact's latent gives the
direction of its force, d_i = (n_i + v_i) / |n_i + v_i|, and the grip is the k whose forces
F_i + sum k_ij e_ij (eq. 4) point best along them (:func:`~.policy.grip_along`, with a ridge
that picks the minimum-norm k where five or more contacts make the k_ij redundant). Padded
contacts have no force, no normal and no pairs, and add nothing to its least squares. The
least squares is itself equivariant, so the actions of permuted fingers are the permuted
actions. The critic pools the set (a masked mean) into one value.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import gymnasium as gym
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from grasp_env.envs.validation import DEFAULT_K_MAX_RATIO
from grasp_env.mechanics import contact_pairs

from .policy import force_directions, grip_along

#: Floats per contact token: p_i, n_i and F_i in the object's frame, and the friction limit.
TOKEN = 10


def max_contacts_of(size: int) -> int:
    """N of a padded object observation of ``size`` = 14 + 7 N floats (ValueError otherwise)."""
    if size < 14 + 21 or (size - 14) % 7:
        raise ValueError(
            f"a contact-set policy reads the general objects' padded observation of 14 + 7 N"
            f" floats (N >= 3 contacts), got {size} floats"
        )
    return (size - 14) // 7


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.linalg.cross(a, b.expand_as(a) if b.dim() < a.dim() else b)


def object_frame_set(
    obs: torch.Tensor, max_contacts: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The grasp of padded observations (B, 14 + 7N) in the object's frame, units of w and L.

    Returns the positions p_i (B, N, 3), inward normals n_i (B, N, 3), minimum-norm
    equilibrating forces F_i (B, N, 3), the mask (B, N) (1 for a real contact) and the friction
    limit (B, 1). Padded contacts are zeros. F is G^+ (-(f, tau)) in closed form over the real
    contacts (as :func:`grasp_env.mechanics.equilibrating_forces`): F_i = -f / n + mu x q_i,
    q_i = p_i - c, (sum_i |q_i|^2 I - sum_i q_i q_i^T) mu = c x f - tau.
    """
    big = max_contacts
    batch = obs.shape[0]
    obs = obs.double()  # the solve loses digits in float32
    columns = obs[:, :6].reshape(batch, 2, 3)
    rotation = torch.stack([columns[:, 0], columns[:, 1], _cross(columns[:, 0], columns[:, 1])], -1)
    to_object = rotation.transpose(1, 2)
    mask = obs[:, 6 + 6 * big : 6 + 7 * big]
    world = [obs[:, 6 + 3 * big * j : 6 + 3 * big * (j + 1)].reshape(batch, big, 3) for j in (0, 1)]
    positions, normals = ((to_object[:, None] @ v[..., None])[..., 0] for v in world)
    tail = 6 + 7 * big
    force = (to_object @ obs[:, tail : tail + 3, None])[..., 0]
    torque = (to_object @ obs[:, tail + 3 : tail + 6, None])[..., 0]
    count = mask.sum(1, keepdim=True).clamp_min(1.0)
    centroid = (positions * mask[..., None]).sum(1) / count
    q = (positions - centroid[:, None]) * mask[..., None]
    qq = q.transpose(1, 2) @ q
    inertia = qq.diagonal(dim1=1, dim2=2).sum(-1)[:, None, None] * torch.eye(3, dtype=obs.dtype)
    mu = torch.linalg.solve(inertia - qq, _cross(centroid, force) - torque)
    forces = (-force[:, None] / count[..., None] + _cross(mu[:, None].expand_as(q), q)) * mask[
        ..., None
    ]
    limit = obs[:, tail + 6 : tail + 7]
    return positions.float(), normals.float(), forces.float(), mask.float(), limit.float()


def pair_basis(positions: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The interaction basis e_ij (B, M, N, 3) of eq. 4 over the pairs of
    :func:`~grasp_env.mechanics.contact_pairs` (N): +u_ij at contact i, -u_ij at j, with
    u_ij = (p_j - p_i) / |p_j - p_i|; zero for a pair with a padded contact."""
    big = positions.shape[1]
    pairs = torch.as_tensor(contact_pairs(big))
    delta = positions[:, pairs[:, 1]] - positions[:, pairs[:, 0]]
    real = (mask[:, pairs[:, 0]] * mask[:, pairs[:, 1]])[..., None]
    length = torch.linalg.vector_norm(delta, dim=-1, keepdim=True)
    u = torch.where(real > 0, delta / length.clamp_min(1e-12), 0.0)
    basis = positions.new_zeros(len(positions), len(pairs), big, 3)
    rows = torch.arange(len(pairs))
    basis[:, rows, pairs[:, 0]] = u
    basis[:, rows, pairs[:, 1]] = -u
    return basis


def set_grasp(obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The object-frame F (B, N, 3), interaction basis (B, M, N, 3) and normals (B, N, 3) of
    padded observations, for :func:`~.features.max_friction_angle` (the reward's friction
    angle, differentiable): a padded contact gets the force and normal e_z and no pairs, so
    its angle is 0 with a finite gradient (atan2 at (0, 0) has none)."""
    big = max_contacts_of(obs.shape[-1])
    positions, normals, forces, mask, _ = object_frame_set(obs, big)
    absent = (1.0 - mask)[..., None] * normals.new_tensor([0.0, 0.0, 1.0])
    return forces + absent, pair_basis(positions, mask), normals + absent


class ContactSetFeatures(BaseFeaturesExtractor):
    """The set's tokens, flattened: (p_i, n_i, F_i, theta_lim) per contact in the object's
    frame (N x 10), then the mask (N): 11 N features, no parameters."""

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        big = max_contacts_of(observation_space.shape[0])
        super().__init__(observation_space, features_dim=(TOKEN + 1) * big)
        self.max_contacts = big

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        positions, normals, forces, mask, limit = object_frame_set(observations, self.max_contacts)
        tokens = torch.cat(
            [positions, normals, forces, limit[:, None].expand(-1, self.max_contacts, 1)], -1
        )
        return torch.cat([(tokens * mask[..., None]).flatten(1), mask], 1)


def split_features(features: torch.Tensor, max_contacts: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Tokens (B, N, 10) and mask (B, N) of :class:`ContactSetFeatures`' output."""
    tokens = features[:, : TOKEN * max_contacts].reshape(len(features), max_contacts, TOKEN)
    return tokens, features[:, TOKEN * max_contacts :]


class SetEncoder(nn.Module):
    """Tokens (B, N, 10) -> latents (B, N, width): a per-token MLP, then ``layers`` masked
    self-attention blocks (pre-norm, no positional encoding: equivariant to the order)."""

    def __init__(self, width: int, layers: int, heads: int) -> None:
        super().__init__()
        self.embed = nn.Sequential(nn.Linear(TOKEN, width), nn.SiLU(), nn.Linear(width, width))
        block = partial(
            nn.TransformerEncoderLayer,
            width,
            heads,
            2 * width,
            dropout=0.0,
            activation="gelu",
            batch_first=True,
            norm_first=True,
        )
        self.blocks = nn.ModuleList(block() for _ in range(layers))

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        latent = self.embed(tokens)
        padded = mask < 0.5
        for layer in self.blocks:
            latent = layer(latent, src_key_padding_mask=padded)
        return latent * mask[..., None]


class _SetExtractor(nn.Module):
    """SB3's ``mlp_extractor`` for the set: the actor's latent is every contact's latent with the
    features (the head needs the grasp), the critic's a masked mean of its own encoder's."""

    def __init__(self, max_contacts: int, width: int, layers: int, heads: int) -> None:
        super().__init__()
        self.max_contacts, self.width = max_contacts, width
        self.actor, self.critic = SetEncoder(width, layers, heads), SetEncoder(width, layers, heads)
        self.value = nn.Sequential(nn.Linear(width, width), nn.SiLU())
        self.latent_dim_pi = max_contacts * width + (TOKEN + 1) * max_contacts
        self.latent_dim_vf = width

    @property
    def policy_net(self) -> nn.Module:
        """The actor's encoder (SB3's name for the actor's hidden layers)."""
        return self.actor

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        tokens, mask = split_features(features, self.max_contacts)
        return torch.cat([self.actor(tokens, mask).flatten(1), features], 1)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        tokens, mask = split_features(features, self.max_contacts)
        pooled = self.critic(tokens, mask).sum(1) / mask.sum(1, keepdim=True)
        return self.value(pooled)


class ContactSetHead(nn.Module):
    """The actor's latent -> mean action k / k_max: a direction per contact, then the grip
    along them (:func:`~.policy.grip_along`)."""

    def __init__(self, max_contacts: int, width: int, k_max_ratio: float) -> None:
        super().__init__()
        self.max_contacts, self.width, self.k_max_ratio = max_contacts, width, k_max_ratio
        self.tilts = nn.Linear(width, 3)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        big = self.max_contacts
        hidden = latent[:, : big * self.width].reshape(len(latent), big, self.width)
        tokens, mask = split_features(latent[:, big * self.width :].detach(), big)
        positions, normals, forces = tokens[..., :3], tokens[..., 3:6], tokens[..., 6:9]
        real = mask[..., None]
        # a padded contact gets a stand-in normal (its direction is multiplied away)
        stand_in = normals + (1.0 - real) * normals.new_tensor([0.0, 0.0, 1.0])
        directions = force_directions(self.tilts(hidden), stand_in) * real
        basis = pair_basis(positions, mask)
        k = grip_along(directions, forces, basis, normals, self.k_max_ratio)
        return k / self.k_max_ratio


class ContactSetPolicy(ActorCriticPolicy):
    """SB3's actor-critic over the set of contacts (module docstring).

    Takes ``ActorCriticPolicy``'s arguments (its ``net_arch`` is not used), plus ``k_max_ratio``
    (the environment's k_max / w), ``width`` (of every token's latent), ``layers`` (attention
    blocks) and ``heads`` (of each). Its features are always :class:`ContactSetFeatures`.
    """

    def __init__(
        self,
        observation_space: gym.spaces.Box,
        action_space: gym.spaces.Box,
        lr_schedule: Any,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        width: int = 64,
        layers: int = 2,
        heads: int = 4,
        **kwargs: Any,
    ) -> None:
        big = max_contacts_of(observation_space.shape[0])
        pairs = big * (big - 1) // 2
        if action_space.shape != (pairs,):
            raise ValueError(
                f"a contact-set policy for {big} contacts acts with their {pairs} pair scalars,"
                f" got an action space of shape {action_space.shape}"
            )
        if width % heads:
            raise ValueError(f"width ({width}) must be a multiple of heads ({heads})")
        self.k_max_ratio, self.width, self.layers, self.heads = k_max_ratio, width, layers, heads
        kwargs["features_extractor_class"] = ContactSetFeatures
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        big = self.features_extractor.max_contacts
        self.mlp_extractor = _SetExtractor(big, self.width, self.layers, self.heads)

    def _build(self, lr_schedule: Any) -> None:
        super()._build(lr_schedule)
        big = self.features_extractor.max_contacts
        self.action_net = ContactSetHead(big, self.width, self.k_max_ratio)
        if self.ortho_init:  # small, so that d_i starts at n_i (a pure squeeze)
            self.action_net.apply(partial(self.init_weights, gain=0.01))
        self.optimizer = self.optimizer_class(
            self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {
            **super()._get_constructor_parameters(),
            "k_max_ratio": self.k_max_ratio,
            "width": self.width,
            "layers": self.layers,
            "heads": self.heads,
        }


def transfer(policy: ContactSetPolicy, other: ContactSetPolicy) -> None:
    """Copy ``policy``'s network into ``other``, a contact-set policy for another N (the
    weights do not depend on N; the log-std of the actions, one per pair, is not copied)."""
    mine = {k: v for k, v in policy.state_dict().items() if k != "log_std"}
    missing, unexpected = other.load_state_dict(mine, strict=False)
    if unexpected or set(missing) - {"log_std"}:
        raise ValueError(f"not the same network: missing {missing}, unexpected {unexpected}")


__all__ = [
    "ContactSetFeatures",
    "ContactSetHead",
    "ContactSetPolicy",
    "SetEncoder",
    "max_contacts_of",
    "object_frame_set",
    "pair_basis",
    "set_grasp",
    "transfer",
]
