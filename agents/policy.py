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
through it.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import gymnasium as gym
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor

from grasp_env.envs.validation import DEFAULT_K_MAX_RATIO

from .features import GraspFeatures, max_friction_angle, object_frame_grasp

#: Least-squares solves per action: equal weights, then two re-weighted by 1 / |P_i|.
SOLVES = 3
#: Smallest force magnitude (units of w) a weight 1 / |P_i| is computed from.
MIN_FORCE = 1e-3
#: Ridge added to the normal equations (solved in float64), relative to their mean diagonal: k
#: stays finite even where the directions leave some squeeze free (two opposed fingers both
#: along their line), and it moves a consistent solution by < 1e-5 where it is not needed.
RIDGE = 1e-9


def force_directions(tilts: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """Unit directions d_i = (n_i + v_i) / |n_i + v_i| with v_i = tilt_i's part across n_i."""
    tangential = tilts - (tilts * normals).sum(-1, keepdim=True) * normals
    directions = normals + tangential
    return directions / torch.linalg.vector_norm(directions, dim=-1, keepdim=True)


def grip_along(
    directions: torch.Tensor,
    forces: torch.Tensor,
    basis: torch.Tensor,
    normals: torch.Tensor,
    k_max: float,
) -> torch.Tensor:
    """The k (B, m) whose finger forces F_i + sum k_ij e_ij best point along ``directions``.

    Of the :data:`SOLVES` least-squares solves it returns the one whose grip, clipped to the
    box |k_ij| <= k_max as the environment clips it, has the smallest largest friction angle:
    where the directions are inconsistent, re-weighting by 1 / |P_i| can drive a nearly
    released finger through zero to a pull (the residual across d_i is blind to the sign),
    and an earlier solve is then the better grip.

    Args:
        directions: unit directions d_i (B, n, 3).
        forces: equilibrating forces F_i (B, n, 3), in units of w.
        basis: the interaction basis e_ij (B, m, n, 3) in the same frame.
        normals: the contact normals n_i (B, n, 3) in the same frame.
        k_max: the action box (k_max / w).
    """
    dtype = forces.dtype
    directions, forces, basis = directions.double(), forces.double(), basis.double()
    # The normal equations sum_i w_i^2 B_i^T (I - d_i d_i^T) (F_i + B_i k) = 0, with B_i =
    # (e_1i ... e_mi) (3, m) so that P_i = F_i + B_i k (eq. 4), split into the parts the
    # weights multiply: B_i^T B_i and B_i^T F_i do not depend on the directions, and the
    # projections a_i = B_i^T d_i and d_i . F_i are the same for every solve (fewer, smaller
    # products than 3 x 3 projectors per finger and solve: a fit's step 7% faster).
    gram = torch.einsum("bqnc,brnc->bnqr", basis, basis)  # (B, n, m, m)
    along = torch.einsum("bqnc,bnc->bnq", basis, directions)  # a_i (B, n, m)
    matrices = gram - along[..., :, None] * along[..., None, :]  # B_i^T (I - d_i d_i^T) B_i
    loads = torch.einsum("bqnc,bnc->bnq", basis, forces) - along * (directions * forces).sum(
        -1, keepdim=True
    )  # B_i^T (I - d_i d_i^T) F_i
    eye = torch.eye(basis.shape[1], dtype=torch.float64)

    def solve(weights: torch.Tensor) -> torch.Tensor:
        """The least squares with each finger's equations weighted by ``weights`` (B, n)."""
        squared = weights**2
        normal_matrix = torch.einsum("bn,bnqr->bqr", squared, matrices)
        rhs = -torch.einsum("bn,bnq->bq", squared, loads)
        ridge = RIDGE * normal_matrix.diagonal(dim1=1, dim2=2).mean(-1)[:, None, None]
        return torch.linalg.solve(normal_matrix + ridge * eye, rhs)

    # The solves and the choice without the graph; then, where a gradient is wanted, the
    # chosen solve once more with it (the same numbers): its backward is one solve's, not all.
    with torch.no_grad():
        weights = [forces.new_ones(forces.shape[:2])]
        solves = []
        for n_solve in range(SOLVES):
            solves.append(solve(weights[-1]))
            if n_solve + 1 < SOLVES:  # the weights of the next solve: 1 / |P_i| at this grip
                net = forces + torch.einsum("bq,bqnc->bnc", solves[-1], basis)
                weights.append(1.0 / torch.linalg.vector_norm(net, dim=-1).clamp_min(MIN_FORCE))
        grips = torch.stack(solves, 1)  # (B, SOLVES, m)
        # every solve's grip at once, against the grasp broadcast over them
        angles = max_friction_angle(
            grips / k_max, forces[:, None], basis[:, None], normals.double()[:, None], k_max
        )
        best = angles.argmin(1)
        rows = torch.arange(len(grips))
    if not torch.is_grad_enabled():
        return grips[rows, best].to(dtype)
    return solve(torch.stack(weights, 1)[rows, best]).to(dtype)


class ForceDirectionHead(torch.nn.Module):
    """Latent [hidden, grasp features] -> mean action k / k_max via :func:`grip_along`."""

    def __init__(self, hidden_dim: int, n_contacts: int, k_max_ratio: float) -> None:
        super().__init__()
        self.hidden_dim = hidden_dim
        self.n_contacts = n_contacts
        self.k_max_ratio = k_max_ratio
        self.tilts = torch.nn.Linear(hidden_dim, 3 * n_contacts)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        hidden, features = latent[:, : self.hidden_dim], latent[:, self.hidden_dim :]
        forces, basis, normals = object_frame_grasp(features, self.n_contacts)
        directions = force_directions(self.tilts(hidden).reshape(normals.shape), normals)
        return grip_along(directions, forces, basis, normals, self.k_max_ratio) / self.k_max_ratio


class _LatentWithFeatures(MlpExtractor):
    """SB3's MlpExtractor whose actor latent also carries the features (the head needs them)."""

    def __init__(self, feature_dim: int, **kwargs: Any) -> None:
        super().__init__(feature_dim, **kwargs)
        self.hidden_dim = self.latent_dim_pi
        self.latent_dim_pi += feature_dim

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.policy_net(features), features], -1)


class ForceDirectionPolicy(ActorCriticPolicy):
    """SB3's actor-critic with the force-direction head (module docstring) as its mean action.

    Takes ``ActorCriticPolicy``'s arguments, plus ``k_max_ratio`` (k_max / w, the environment's
    action scale); its features are always :class:`~grasp_env_agents.features.GraspFeatures`.
    """

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
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = _LatentWithFeatures(
            self.features_dim,
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
        return {**super()._get_constructor_parameters(), "k_max_ratio": self.k_max_ratio}
