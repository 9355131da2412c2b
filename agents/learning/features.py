"""The grasp in the object's frame, as network inputs: an SB3 features extractor.

The observation is in the world frame, and as the object turns along its trajectory every
vector in it turns too, while the best grip does not care about the frame: friction angles
(eq. 2) and the interaction directions (eq. 4) are the same in any frame, so k* depends only on
the equilibrating forces F_i, the pair directions u_ij and the normals n_i expressed in the
object's frame, and on the friction limit. :class:`GraspFeatures` computes exactly these from
the observation, in torch: the rotation R from its first two columns, F = G^+ (-(f, tau)) (the
minimum-norm equilibrating forces, as :func:`grasp_env.mechanics.equilibrating_forces`), then
R^T F_i, R^T u_ij and R^T n_i. The network then learns a map of the grasp, not of the pose.

:func:`grasp_tensors` (the world-frame F, the interaction basis and the normals) also serves
:func:`max_friction_angle`, the environment's friction angle as a differentiable function of
the action.
"""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from grasp_env.envs.observation import ObservationLayout
from grasp_env.mechanics import contact_pairs


def grasp_tensors(
    obs: torch.Tensor, layout: ObservationLayout
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """World-frame grasp of observations (B, size), in units of the weight w.

    Returns the equilibrating forces F (B, n, 3), the interaction basis e_ij (B, m, n, 3)
    (+u_ij at contact i, -u_ij at contact j: P = F + sum k_ij e_ij, eq. 4), the inward
    normals (B, n, 3) and the rotation R (B, 3, 3).
    """
    n = layout.n_contacts
    batch = obs.shape[0]
    obs = obs.double()  # the solve below loses digits in float32
    columns = obs[:, layout.rotation].reshape(batch, 2, 3)
    third = torch.linalg.cross(columns[:, 0], columns[:, 1])
    rotation = torch.stack([columns[:, 0], columns[:, 1], third], -1)
    positions = obs[:, layout.positions].reshape(batch, n, 3)
    normals = obs[:, layout.normals].reshape(batch, n, 3)
    wrench = torch.cat([obs[:, layout.force], obs[:, layout.torque]], -1)
    # F = G^+ (-wrench) in closed form, as grasp_env.mechanics.equilibrating_forces:
    # F_i = -f / n + mu x q_i with q_i = p_i - c and (sum_i |q_i|^2 I - q_i q_i^T) mu = c x f - tau
    centroid = positions.mean(1)
    q = positions - centroid[:, None]
    qq = q.transpose(1, 2) @ q
    inertia = qq.diagonal(dim1=1, dim2=2).sum(-1)[:, None, None] * torch.eye(3, dtype=obs.dtype)
    force, torque = wrench[:, :3], wrench[:, 3:]
    rhs = torch.linalg.cross(centroid, force) - torque
    mu = torch.linalg.solve(inertia - qq, rhs)
    forces = -force[:, None] / n + torch.linalg.cross(mu[:, None].expand_as(q), q)
    pairs = torch.as_tensor(contact_pairs(n))
    delta = positions[:, pairs[:, 1]] - positions[:, pairs[:, 0]]
    u = delta / torch.linalg.vector_norm(delta, dim=-1, keepdim=True)
    basis = interaction_basis(u, n)
    return forces.float(), basis.float(), normals.float(), rotation.float()


def interaction_basis(directions: torch.Tensor, n_contacts: int) -> torch.Tensor:
    """The basis e_ij (B, m, n, 3) of eq. 4 from the unit pair directions u_ij (B, m, 3)."""
    pairs = torch.as_tensor(contact_pairs(n_contacts))
    basis = directions.new_zeros(len(directions), len(pairs), n_contacts, 3)
    rows = torch.arange(len(pairs))
    basis[:, rows, pairs[:, 0]] = directions
    basis[:, rows, pairs[:, 1]] = -directions
    return basis


def max_friction_angle(
    actions: torch.Tensor,
    forces: torch.Tensor,
    basis: torch.Tensor,
    normals: torch.Tensor,
    k_max_ratio: float,
) -> torch.Tensor:
    """max_i theta_i (radians) for actions (..., m), differentiable: eqs. 4 and 2 in torch.

    The grasp's forces (..., n, 3), basis (..., m, n, 3) and normals (..., n, 3) broadcast
    against the actions' batch. The actions are clipped to [-1, 1] and scaled by k_max / w as
    the environment does; theta_i = atan2(|P_t|, P_n) is eq. 2's angle, with a finite
    gradient along the normal.
    """
    k = actions.clamp(-1.0, 1.0) * k_max_ratio
    net = forces + torch.einsum("...q,...qnc->...nc", k, basis)
    normal = (net * normals).sum(-1)
    tangential = torch.linalg.vector_norm(net - normal[..., None] * normals, dim=-1)
    return torch.atan2(tangential, normal).amax(-1)


class GraspFeatures(BaseFeaturesExtractor):
    """Object-frame grasp features: R^T F_i, R^T u_ij, R^T n_i and the friction limit.

    For n fingers and m pairs that is 6n + 3m + 1 features (28 for three fingers).
    """

    def __init__(self, observation_space: gym.spaces.Box) -> None:
        layout = ObservationLayout.from_size(observation_space.shape[0])
        n = layout.n_contacts
        m = n * (n - 1) // 2
        super().__init__(observation_space, features_dim=6 * n + 3 * m + 1)
        self.layout = layout
        self.pairs = contact_pairs(n)

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        forces, basis, normals, rotation = grasp_tensors(observations, self.layout)
        directions = basis[:, torch.arange(len(self.pairs)), self.pairs[:, 0]]  # u_ij
        to_object = rotation.transpose(1, 2)[:, None]  # R^T, broadcast over contacts
        parts = [(to_object @ v[..., None])[..., 0] for v in (forces, directions, normals)]
        limit = observations[:, self.layout.friction_limit, None]
        return torch.cat([p.flatten(1) for p in parts] + [limit], 1)


def object_frame_grasp(
    features: torch.Tensor, n_contacts: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The object-frame F (B, n, 3), interaction basis (B, m, n, 3) and normals (B, n, 3) that
    :class:`GraspFeatures` (B, 6n + 3m + 1) hold: :func:`grasp_tensors` in the object's frame."""
    m = n_contacts * (n_contacts - 1) // 2
    forces, directions, normals = features[:, :-1].split([3 * n_contacts, 3 * m, 3 * n_contacts], 1)
    batch = len(features)
    basis = interaction_basis(directions.reshape(batch, m, 3), n_contacts)
    return forces.reshape(batch, n_contacts, 3), basis, normals.reshape(batch, n_contacts, 3)
