"""The contact-set policy's mechanics tokens: what the paper's mechanics already says about each
contact, in the contact's own frame, beside its geometry.

Per real contact i, from the observed geometry and load (float64), two forces in units of the
weight:

- the equilibrating force F_i, the minimum-norm forces F = G^+ (-(f, tau)) that balance the
  load (:func:`grasp_env.mechanics.equilibrating_forces`, the zero grip);
- the paper's equal-k grip force P^eq_i = F_i + k_eq sum_j e_ij (eq. 4 with every
  k_ij = k_eq = w tan(phi) / (3 sqrt 3), eq. 8), where sum_j e_ij is the sum over the other
  real contacts of the unit vectors from p_i towards p_j (the squeeze of every pair at once).
  With five or more contacts the environment plays E^+ E k for a grip k, the same
  interaction force, so P^eq_i is the force the equal-k grip gives there too.

Each force P enters as its normal part P . n_i, the size of its tangential part |P x n_i|,
its friction angle atan2(|P x n_i|, P . n_i) (eq. 2) and its tangential part
P - (P . n_i) n_i as a vector (in the object's frame, like the geometry): 6 floats, 12 per
contact (:data:`MECHANICS`). All of it is equivariant to the fingers' order (each contact's
token depends on the set, not on its place in it); a padded contact's token is zeros. The
network then learns a correction of the mechanics, not the whole of it.
"""

from __future__ import annotations

import math

import torch

from grasp_env.mechanics import PHI

#: The paper's equal-k grip, k_ij / w for every pair (eq. 8).
EQUAL_K = math.tan(PHI) / (3.0 * math.sqrt(3.0))
#: Floats per contact of :func:`mechanics_tokens`: two forces, 6 floats each.
MECHANICS = 12


def squeeze_directions(positions: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """sum_j e_ij at each contact, (B, N, 3): the sum over the other real contacts j of
    u = (p_j - p_i) / |p_j - p_i| (eq. 4's basis, the pair (i, j) seen from i); zeros at a
    padded contact. ``positions`` (B, N, 3), ``mask`` (B, N) with 1 for a real contact."""
    delta = positions[:, None, :, :] - positions[:, :, None, :]  # (B, i, j, 3): p_j - p_i
    length = torch.linalg.vector_norm(delta, dim=-1, keepdim=True)
    pair = (mask[:, :, None] * mask[:, None, :])[..., None] > 0.5
    pair = pair & ~torch.eye(positions.shape[1], dtype=torch.bool)[None, :, :, None]
    unit = torch.where(pair, delta / length.clamp_min(1e-300), 0.0)
    return unit.sum(2)


def contact_frame_parts(force: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """(P . n, |P x n|, atan2(|P x n|, P . n), P - (P . n) n) of forces P (B, N, 3) at unit
    normals n (B, N, 3): (B, N, 6), the friction angle of eq. 2 in radians."""
    normal = (force * normals).sum(-1, keepdim=True)
    tangential = torch.linalg.vector_norm(torch.linalg.cross(force, normals), dim=-1, keepdim=True)
    angle = torch.atan2(tangential, normal)
    return torch.cat([normal, tangential, angle, force - normal * normals], -1)


def mechanics_tokens(
    positions: torch.Tensor, normals: torch.Tensor, forces: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:
    """The mechanics tokens (B, N, :data:`MECHANICS`) of padded grasps (module docstring): the
    contact-frame parts of F_i, then of the equal-k grip's P^eq_i = F_i + k_eq sum_j e_ij,
    computed in float64 and returned in it; zeros at padded contacts. Inputs as
    :func:`~.contact_set.object_frame_set` returns them (units of w and L, any frame)."""
    p, n, f, real = (t.double() for t in (positions, normals, forces, mask))
    equal_k = f + EQUAL_K * squeeze_directions(p, real)
    tokens = torch.cat([contact_frame_parts(f, n), contact_frame_parts(equal_k, n)], -1)
    return tokens * real[..., None]


__all__ = ["EQUAL_K", "MECHANICS", "contact_frame_parts", "mechanics_tokens", "squeeze_directions"]
