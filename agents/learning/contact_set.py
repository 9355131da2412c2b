"""One policy for every grasp: a network over the set of contacts, any object, any n.

The general objects' environments pad a grasp of n contacts to their ``max_contacts`` N: the
observation holds N contact positions and normals with a mask, and the action the interaction
scalars of the N (N - 1) / 2 pairs (those of padded contacts unused). A policy for every grasp
must not care in which order the fingers are listed, nor how many there are.

:class:`ContactSetPolicy` (an SB3 ``ActorCriticPolicy``) reads the grasp as a set of tokens, one per
real contact, in the object's frame (the friction angles do not depend on the frame, eq. 2): the
contact's position p_i, its inward normal n_i and its equilibrating force F_i (the minimum-norm
forces that balance the load, computed from the observation in closed form), with the friction
limit, and its mechanics tokens (:mod:`.contact_set_tokens`: F_i and the paper's equal-k grip force
in the contact's frame, normal and tangential parts and friction angle), so that the network learns
a correction of the mechanics. A per-token MLP and masked self-attention layers (no positional
encoding) make each contact's latent depend on the whole set and not on the order, so the network is
equivariant to permutations of the fingers and takes any n up to N; its weights do not depend on N,
so a policy trained with one N loads into another (:func:`transfer`).

Its mean action is a force-direction head with a release gate. Each contact's latent gives
the direction of its force, d_i = (n_i + v_i) / |n_i + v_i|, and a release logit. With five or
more contacts the certified optimum usually *releases* fingers (P_i = 0 exactly: 77% of
five-contact poses release one or two, 97% of six-contact poses), and a finger the environment
finds released (``grasp_env.envs.kernels.RELEASE``) counts as angle 0, however its rounding
residue points. A direction cannot say "no force", so the head releases the contacts whose
logit is positive (at most n - 3, the most confident first, so that three contacts hold) and
the grip is the k whose forces P_i = F_i + sum k_ij e_ij (eq. 4) point best along the
directions of the others (with a weak pull of d_i . P_i towards a predicted magnitude rho_i,
which picks among the grips that seven or more contacts leave free) while the released
contacts' P_i = 0 (three equations each, weighted by :data:`RELEASE_WEIGHT`):
:func:`grip_with_release`, a weighted least squares in float64, re-weighted by 1 / |P_i| as
:mod:`grasp_env.mechanics.directions` and with its ridge (the minimum-norm k where five or
more contacts make the k_ij redundant, the k the environment plays). The expert's own grip is
representable exactly: its directions P*_i / |P*_i|, magnitudes |P*_i| and released set give
back k*. The gate is a hard choice, not differentiated: imitation trains it
(:func:`.contact_set_fit.fit_contact_set`, a cross-entropy against the expert's released
set); the directions
learn from the expert's force directions and from the reward's exact gradient
(:func:`reward_angles`, the environment's step in torch, released fingers at angle 0).
Padded contacts have no force, no normal and no pairs, and add nothing to the least squares.
The least squares is itself equivariant, so the actions of permuted fingers are the permuted
actions. The critic pools the set (a masked mean) into one value.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import partial
from typing import Any

import gymnasium as gym
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from grasp_env.envs.kernels import RELEASE
from grasp_env.envs.validation import DEFAULT_K_MAX_RATIO
from grasp_env.mechanics import contact_pairs
from grasp_env.mechanics.directions import MIN_FORCE, RIDGE, SOLVES

from .contact_set_tokens import MECHANICS, mechanics_tokens
from .policy import force_directions

#: The random objects' environment the policy is trained on.
ENV_ID = "grasp_env/ObjectGraspRandom-v0"
#: Floats per contact of the geometry: p_i, n_i and F_i in the object's frame, and the
#: friction limit.
TOKEN = 10
#: Floats per contact token: the geometry, then the mechanics tokens (F_i and the equal-k
#: grip's force in the contact's frame, :mod:`.contact_set_tokens`).
FULL_TOKEN = TOKEN + MECHANICS
#: Weight of a released contact's three equations P_i = 0 in the least squares, against the
#: held contacts' unit-weighted ones: its force is left at about RELEASE_WEIGHT^-2 of their
#: misfit, far below the environment's RELEASE threshold.
RELEASE_WEIGHT = 1e4
#: Weight of a held contact's magnitude equation d_i . P_i = rho_i against its two direction
#: equations: it only picks among the grips that the directions leave free.
MAGNITUDE_WEIGHT = 1e-3
#: The release logit's initial bias: an untrained head releases nothing.
INITIAL_RELEASE_LOGIT = -3.0
#: A contact of the expert's grip is released where |P*_i| <= RELEASE_LABEL (|F_i| +
#: sum_j |k_ij|) in the observation's float32 grasp (:func:`expert_forces`).
RELEASE_LABEL = 1e-4


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
    obs: torch.Tensor, max_contacts: int, double: bool = False
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The grasp of padded observations (B, 14 + 7N) in the object's frame, units of w and L.

    Returns the positions p_i (B, N, 3), inward normals n_i (B, N, 3), minimum-norm
    equilibrating forces F_i (B, N, 3), the mask (B, N) (1 for a real contact) and the friction
    limit (B, 1), float32 (float64 with ``double``). Padded contacts are zeros. F is
    G^+ (-(f, tau)) in closed form over the real contacts (as
    :func:`grasp_env.mechanics.equilibrating_forces`): F_i = -f / n + mu x q_i, q_i = p_i - c,
    (sum_i |q_i|^2 I - sum_i q_i q_i^T) mu = c x f - tau.
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
    out = positions, normals, forces, mask, limit
    return out if double else tuple(t.float() for t in out)


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


@dataclass(frozen=True)
class SetGrasp:
    """A batch of padded grasps in the object's frame (float64, units of w), as the reward
    sees them: the equilibrating forces F_i (B, N, 3), the interaction basis e_ij
    (B, M, N, 3), the inward normals n_i (B, N, 3), the mask (B, N) and the projection
    E^+ E (B, M, M) that the environment applies to a grip of five or more contacts (the
    minimum-norm k of the interaction force E k; the identity on the pairs in use for fewer).
    """

    forces: torch.Tensor
    basis: torch.Tensor
    normals: torch.Tensor
    mask: torch.Tensor
    projection: torch.Tensor

    def __len__(self) -> int:
        return len(self.forces)

    def __getitem__(self, index: Any) -> SetGrasp:
        return SetGrasp(*(getattr(self, f.name)[index] for f in fields(self)))


def _projection(basis: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """E^+ E (B, M, M) of padded grasps with five or more contacts, the identity on the pairs
    in use for fewer (as ``grasp_env.envs.object_grasp.episodes.projection``)."""
    batch, m, big, _ = basis.shape
    e = basis.reshape(batch, m, 3 * big).transpose(1, 2)  # (B, 3N, M), columns e_ij
    counts = mask.sum(1)
    used = basis.abs().sum((2, 3)) > 0  # pairs of two real contacts
    out = torch.diag_embed(used.to(basis.dtype))
    many = counts >= 5
    if many.any():
        out[many] = torch.linalg.pinv(e[many]) @ e[many]
    # pairs with a padded contact: exactly none (pinv leaves rounding there)
    return out * (used[:, :, None] & used[:, None, :])


def set_grasp(obs: torch.Tensor) -> SetGrasp:
    """The grasps of padded observations (B, 14 + 7N) for :func:`reward_angles`, in float64
    (the object's frame: the angles do not depend on it, eq. 2)."""
    big = max_contacts_of(obs.shape[-1])
    positions, normals, forces, mask, _ = object_frame_set(obs, big, double=True)
    basis = pair_basis(positions, mask)
    return SetGrasp(forces, basis, normals, mask, _projection(basis, mask))


def played_grip(actions: torch.Tensor, grasp: SetGrasp, k_max_ratio: float) -> torch.Tensor:
    """The grip k / w (B, M) the environment plays for ``actions`` (B, M): clipped to
    [-1, 1], times k_max / w, pairs with a padded contact at 0, and with five or more contacts
    k' = E^+ E k, scaled back into the box |k'_ij| <= k_max where it leaves it
    (``grasp_env.envs.object_grasp.kernels.object_row``)."""
    pairs = torch.as_tensor(contact_pairs(grasp.mask.shape[1]))
    used = grasp.mask[:, pairs[:, 0]] * grasp.mask[:, pairs[:, 1]]
    k = actions.double().clamp(-1.0, 1.0) * k_max_ratio * used
    many = (grasp.mask.sum(1) >= 5)[:, None]
    projected = (grasp.projection @ k[..., None])[..., 0]
    largest = projected.abs().amax(1, keepdim=True)
    scale = torch.where(largest > k_max_ratio, k_max_ratio / largest.clamp_min(1e-300), 1.0)
    return torch.where(many, projected * scale, k)


def net_forces(k: torch.Tensor, grasp: SetGrasp) -> torch.Tensor:
    """P_i / w = F_i + sum_j k_ij e_ij (eq. 4), (B, N, 3), for grips k / w (B, M)."""
    return grasp.forces + torch.einsum("bq,bqnc->bnc", k, grasp.basis)


def released_contacts(k: torch.Tensor, net: torch.Tensor, grasp: SetGrasp, ratio: float) -> Any:
    """Which real contacts (B, N) bool have |P_i| <= ``ratio`` (|F_i| + sum_j |k_ij|): with
    ratio ``RELEASE`` the environment's released fingers (``grasp_env.envs.kernels.released``)."""
    size = torch.linalg.vector_norm(grasp.forces, dim=-1) + torch.einsum(
        "bq,bqn->bn", k.abs(), torch.linalg.vector_norm(grasp.basis, dim=-1)
    )
    tiny = torch.linalg.vector_norm(net, dim=-1) <= ratio * size
    return tiny & (grasp.mask > 0.5)


def reward_angles(actions: torch.Tensor, grasp: SetGrasp, k_max_ratio: float) -> torch.Tensor:
    """The friction angles theta_i (B, N) (radians, float64) the environment gives
    ``actions`` (B, M), differentiable: :func:`played_grip`, eq. 4, and eq. 2's
    atan2(|P_i x n_i|, P_i . n_i), with a released finger's (``RELEASE``) and a padded
    contact's angle 0. The reward is theta_lim - max_i theta_i."""
    k = played_grip(actions, grasp, k_max_ratio)
    net = net_forces(k, grasp)
    released = released_contacts(k, net, grasp, RELEASE)
    normals = grasp.normals
    tangential = torch.linalg.vector_norm(torch.linalg.cross(net, normals), dim=-1)
    normal = (net * normals).sum(-1)
    counted = (grasp.mask > 0.5) & ~released
    # a finite gradient everywhere: the uncounted contacts' angles are those of (0, 1)
    theta = torch.atan2(torch.where(counted, tangential, 0.0), torch.where(counted, normal, 1.0))
    return theta


def expert_forces(
    actions: torch.Tensor, grasp: SetGrasp, k_max_ratio: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """The forces P*_i / w (B, N, 3) of the expert's ``actions`` (k* / k_max, B x M) and the
    contacts it releases (B, N) bool: |P*_i| <= :data:`RELEASE_LABEL` (|F_i| + sum_j |k_ij|).
    The observation is float32, so a force the optimum releases exactly keeps about 1e-7 of
    the forces it is made of here; the optimum's smallest loaded forces are above 1e-3."""
    k = played_grip(actions, grasp, k_max_ratio)
    net = net_forces(k, grasp)
    return net, released_contacts(k, net, grasp, RELEASE_LABEL)


class ContactSetFeatures(BaseFeaturesExtractor):
    """The set's tokens, flattened: per contact (p_i, n_i, F_i, theta_lim) in the object's
    frame and its :func:`~.contact_set_tokens.mechanics_tokens` (N x 22, computed in float64),
    then the mask (N): 23 N features, no parameters."""

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        big = max_contacts_of(observation_space.shape[0])
        super().__init__(observation_space, features_dim=(FULL_TOKEN + 1) * big)
        self.max_contacts = big

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        big = self.max_contacts
        positions, normals, forces, mask, limit = object_frame_set(observations, big, double=True)
        tokens = torch.cat(
            [
                positions,
                normals,
                forces,
                limit[:, None].expand(-1, big, 1),
                mechanics_tokens(positions, normals, forces, mask),
            ],
            -1,
        )
        return torch.cat([(tokens * mask[..., None]).flatten(1), mask], 1).float()


def split_features(features: torch.Tensor, max_contacts: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Tokens (B, N, 22) and mask (B, N) of :class:`ContactSetFeatures`' output."""
    size = FULL_TOKEN * max_contacts
    tokens = features[:, :size].reshape(len(features), max_contacts, FULL_TOKEN)
    return tokens, features[:, size:]


class SetEncoder(nn.Module):
    """Tokens (B, N, 22) -> latents (B, N, width): a per-token MLP, then ``layers`` masked
    self-attention blocks (pre-norm, no positional encoding: equivariant to the order).
    With ``mechanics`` False it reads the geometry alone (the tokens' first 10 floats)."""

    def __init__(self, width: int, layers: int, heads: int, mechanics: bool = True) -> None:
        super().__init__()
        self.inputs = FULL_TOKEN if mechanics else TOKEN
        self.embed = nn.Sequential(
            nn.Linear(self.inputs, width), nn.SiLU(), nn.Linear(width, width)
        )
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
        latent = self.embed(tokens[..., : self.inputs])
        padded = mask < 0.5
        for layer in self.blocks:
            latent = layer(latent, src_key_padding_mask=padded)
        return latent * mask[..., None]


class _SetExtractor(nn.Module):
    """SB3's ``mlp_extractor`` for the set: the actor's latent is every contact's latent with the
    features (the head needs the grasp), the critic's a masked mean of its own encoder's."""

    def __init__(
        self, max_contacts: int, width: int, layers: int, heads: int, mechanics: bool = True
    ) -> None:
        super().__init__()
        self.max_contacts, self.width = max_contacts, width
        self.actor = SetEncoder(width, layers, heads, mechanics)
        self.critic = SetEncoder(width, layers, heads, mechanics)
        self.value = nn.Sequential(nn.Linear(width, width), nn.SiLU())
        self.latent_dim_pi = max_contacts * width + (FULL_TOKEN + 1) * max_contacts
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


def release_set(logits: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The contacts (B, N) bool the head releases: real ones with a positive logit, at most
    n - 3 of them (the largest logits), so that three contacts at least carry the load."""
    candidate = (logits > 0.0) & (mask > 0.5)
    ranked = torch.where(candidate, logits, -torch.inf)
    rank = torch.argsort(torch.argsort(ranked, dim=1, descending=True), dim=1)
    allowed = (mask.sum(1, keepdim=True) - 3.0).clamp_min(0.0)
    return candidate & (rank < allowed)


def grip_with_release(
    directions: torch.Tensor,
    magnitudes: torch.Tensor,
    released: torch.Tensor,
    forces: torch.Tensor,
    basis: torch.Tensor,
    normals: torch.Tensor,
    k_max: float,
    solves: int = SOLVES,
) -> torch.Tensor:
    """The grips k / w (B, M), float64, whose forces P_i = F_i + B_i k (eq. 4) point along
    ``directions`` d_i (B, N, 3) with normal parts d_i . P_i near ``magnitudes`` (B, N) at the
    contacts that are not ``released`` (B, N) bool, and vanish at the released ones;
    differentiable in the directions and the magnitudes.

    The least squares of :mod:`grasp_env.mechanics.directions` with two more kinds of rows: a
    held contact contributes w_i (I - d_i d_i^T) P_i(k) (two equations) and
    MAGNITUDE_WEIGHT w_i (d_i . P_i(k) - rho_i) (one, weak: with seven or more contacts the
    directions leave some grips free, and the ridge alone would pick the smallest k there,
    which may leave the action box where the optimum sits on it); a released one
    w_max RELEASE_WEIGHT P_i(k) (three, w_max the largest held weight), so that its residual
    force is about RELEASE_WEIGHT^-2 of the others' misfit. The ridge RIDGE tr(A_held) / m (m
    the pairs in use, A_held the held rows' normal matrix) picks the minimum-norm k where
    five or more contacts make the k_ij redundant; the system is solved by QR of the stacked
    rows (the normal equations square its condition). The first solve weighs the held
    contacts equally, each next one by w_i = 1 / max(|P_i|, MIN_FORCE) at the previous grip;
    of the solves, the one whose grip, clipped to |k_ij| <= k_max, has the smallest largest
    friction angle (eq. 2, over the held contacts) is returned (the choice and the weights
    are not differentiated), as the minimum-norm k of its force, E^+ E k (the rounding of the
    k that make no force removed). Padded contacts (zero forces, normals, directions and pairs)
    change nothing. With the expert's directions P*_i / |P*_i|, magnitudes |P*_i| and
    released set every equation holds at k*, and k* is what it returns.
    """
    if solves < 1:
        raise ValueError(f"solves must be an integer >= 1, got {solves!r}")
    d, f, e, nn_ = (t.double() for t in (directions, forces, basis, normals))
    m = e.shape[1]
    columns = e.permute(0, 2, 3, 1)  # B_i (B, N, 3, M)
    eye = torch.eye(3, dtype=d.dtype)
    held = ~released
    across = torch.where(
        held[..., None, None], eye - d[..., :, None] * d[..., None, :], RELEASE_WEIGHT * eye
    )
    along = torch.where(held[..., None], MAGNITUDE_WEIGHT * d, 0.0)[..., None, :]
    rows = torch.cat([across, along], -2)  # (B, N, 4, 3)
    jac = rows @ columns  # (B, N, 4, M)
    target = torch.where(held, MAGNITUDE_WEIGHT * magnitudes.double(), 0.0)
    rhs_rows = (rows @ f[..., None])[..., 0]  # (B, N, 4)
    rhs_rows = torch.cat([rhs_rows[..., :3], rhs_rows[..., 3:] - target[..., None]], -1)
    used = (e.abs().sum((2, 3)) > 0).sum(1).clamp_min(1).to(d.dtype)
    batch, big = held.shape
    weights = torch.ones(batch, big, dtype=d.dtype)  # w_i (released rows: the largest w_i)
    best_k, best_cos = None, None
    for _ in range(solves):
        scaled = jac * weights[..., None, None]
        held_trace = (scaled.square() * held[..., None, None]).sum((1, 2, 3))
        ridge = torch.sqrt(RIDGE * held_trace / used)
        # the least squares by QR of the stacked rows [w_i J_i; sqrt(r) I]: the normal
        # equations' condition is squared, and their error along the k that make no force
        # (five or more contacts) would reach the action's clip
        stacked = torch.cat(
            [scaled.reshape(batch, 4 * big, m), ridge[:, None, None] * torch.eye(m, dtype=d.dtype)],
            1,
        )
        target = torch.cat(
            [-(rhs_rows * weights[..., None]).reshape(batch, 4 * big), d.new_zeros(batch, m)], 1
        )
        q, r = torch.linalg.qr(stacked)
        k = torch.linalg.solve_triangular(r, (q.transpose(1, 2) @ target[..., None]), upper=True)
        k = k[..., 0]
        with torch.no_grad():
            clipped = k.clamp(-k_max, k_max)
            net = f + torch.einsum("bq,bqnc->bnc", clipped, e)
            size = torch.linalg.vector_norm(net, dim=-1)
            cos = torch.where(size > 0, (net * nn_).sum(-1) / size.clamp_min(1e-300), 1.0)
            worst = torch.where(held & (size > 0), cos, torch.inf).amin(1)
            unclipped = f + torch.einsum("bq,bqnc->bnc", k, e)
            force = torch.linalg.vector_norm(unclipped, dim=-1).clamp_min(MIN_FORCE)
            weights = torch.where(held, 1.0 / force, 0.0)
            # a released contact's rows as strong against the strongest held contact's
            weights = torch.where(held, weights, weights.amax(1, keepdim=True))
        if best_k is None:
            best_k, best_cos = k, worst
        else:
            better = worst > best_cos
            best_k = torch.where(better[:, None], k, best_k)
            best_cos = torch.where(better, worst, best_cos)
    # the least squares leaves the k that make no force (five or more contacts) to the ridge
    # alone, so to its rounding: the minimum-norm k of the same force, E^+ E k, has none
    with torch.no_grad():
        projection = _projection(e, (nn_.abs().sum(-1) > 0).to(d.dtype))
    return (projection @ best_k[..., None])[..., 0]


class ContactSetHead(nn.Module):
    """The actor's latent -> mean action k / k_max: a direction and a release logit per
    contact, then the grip along the held contacts' directions with the released ones at
    P_i = 0 (:func:`grip_with_release`)."""

    def __init__(self, max_contacts: int, width: int, k_max_ratio: float) -> None:
        super().__init__()
        self.max_contacts, self.width, self.k_max_ratio = max_contacts, width, k_max_ratio
        self.tilts = nn.Linear(width, 3)
        self.release = nn.Linear(width, 2)  # the release logit and log rho_i

    def parts(self, latent: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The directions d_i (B, N, 3), magnitudes rho_i (B, N) (units of w), release logits
        (B, N), and the grasp the head reads: forces F_i, interaction basis, normals and mask
        (the features, not differentiated)."""
        big = self.max_contacts
        hidden = latent[:, : big * self.width].reshape(len(latent), big, self.width)
        tokens, mask = split_features(latent[:, big * self.width :].detach(), big)
        positions, normals, forces = tokens[..., :3], tokens[..., 3:6], tokens[..., 6:9]
        real = mask[..., None]
        # a padded contact gets a stand-in normal (its direction is multiplied away)
        stand_in = normals + (1.0 - real) * normals.new_tensor([0.0, 0.0, 1.0])
        directions = force_directions(self.tilts(hidden), stand_in) * real
        gate = self.release(hidden)
        logits, magnitudes = gate[..., 0], torch.exp(gate[..., 1].clamp(-20.0, 5.0)) * mask
        return directions, magnitudes, logits, forces, pair_basis(positions, mask), normals, mask

    def grip(
        self,
        directions: torch.Tensor,
        magnitudes: torch.Tensor,
        released: torch.Tensor,
        forces: torch.Tensor,
        basis: torch.Tensor,
        normals: torch.Tensor,
    ) -> torch.Tensor:
        """k / k_max (B, M) in the directions' dtype from :meth:`parts` and a released set."""
        k = grip_with_release(
            directions, magnitudes, released, forces, basis, normals, self.k_max_ratio
        )
        return (k / self.k_max_ratio).to(directions.dtype)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        directions, magnitudes, logits, forces, basis, normals, mask = self.parts(latent)
        released = release_set(logits, mask)
        return self.grip(directions, magnitudes, released, forces, basis, normals)


class ContactSetPolicy(ActorCriticPolicy):
    """SB3's actor-critic over the set of contacts (module docstring).

    Takes ``ActorCriticPolicy``'s arguments (its ``net_arch`` is not used), plus ``k_max_ratio``
    (the environment's k_max / w), ``width`` (of every token's latent), ``layers`` (attention
    blocks), ``heads`` (of each) and ``mechanics`` (whether the encoders read the mechanics
    tokens beside the geometry). Its features are always :class:`ContactSetFeatures`.
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
        mechanics: bool = True,
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
        self.mechanics = bool(mechanics)
        kwargs["features_extractor_class"] = ContactSetFeatures
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        big = self.features_extractor.max_contacts
        self.mlp_extractor = _SetExtractor(big, self.width, self.layers, self.heads, self.mechanics)

    def _build(self, lr_schedule: Any) -> None:
        super()._build(lr_schedule)
        big = self.features_extractor.max_contacts
        self.action_net = ContactSetHead(big, self.width, self.k_max_ratio)
        if self.ortho_init:  # small, so that d_i starts at n_i (a pure squeeze)
            self.action_net.apply(partial(self.init_weights, gain=0.01))
        with torch.no_grad():  # an untrained gate releases no contact
            self.action_net.release.bias[0] = INITIAL_RELEASE_LOGIT
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
            "mechanics": self.mechanics,
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
    "SetGrasp",
    "expert_forces",
    "grip_with_release",
    "max_contacts_of",
    "net_forces",
    "object_frame_set",
    "pair_basis",
    "played_grip",
    "release_set",
    "released_contacts",
    "reward_angles",
    "set_grasp",
    "transfer",
]
