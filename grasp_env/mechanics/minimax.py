"""The minimax grip: k* = argmin over the box |k_ij| <= k_max of max_i theta_i(k) (DESIGN.md §1).

INTERIM implementation (SLSQP, local, no certificate) that fixes the public API; to be replaced
by the certified batched solver.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize

from .forces import Grasp, friction_angles, net_forces


class Status(IntEnum):
    """Where the optimum lies."""

    INTERIOR = 0  #: optimum strictly inside the box
    BOUNDARY = 1  #: optimum on the box boundary: the interaction forces would grow further
    NOT_PUSHING = 2  #: no k in the box keeps every finger pushing (some angle >= 90 deg)


@dataclass(frozen=True)
class MinimaxResult:
    """Solution of the minimax problem, batched like the grasp.

    Attributes:
        k: (..., m) optimal interaction scalars.
        angles: (..., n) friction angles at k, radians.
        max_angle: (...) max_i angles, an upper bound on the optimum attained by k.
        lower_bound: (...) certified lower bound: no k in the box has a smaller max angle.
        status: (...) :class:`Status` codes.
    """

    k: np.ndarray
    angles: np.ndarray
    max_angle: np.ndarray
    lower_bound: np.ndarray
    status: np.ndarray

    @property
    def gap(self) -> np.ndarray:
        """Certificate gap max_angle - lower_bound, radians."""
        return self.max_angle - self.lower_bound


def solve_minimax(grasp: Grasp, k_max: ArrayLike, f_max: ArrayLike | None = None) -> MinimaxResult:
    """Globally minimise the largest friction angle over |k_ij| <= k_max (and |P_i| <= f_max)."""
    F, E, N = grasp.equilibrating, grasp.basis, grasp.normals
    batch = F.shape[:-2]
    m = E.shape[-3]
    k_max = np.broadcast_to(np.asarray(k_max, dtype=float), batch)
    f_lim = None if f_max is None else np.broadcast_to(np.asarray(f_max, dtype=float), batch)
    ks = np.zeros((*batch, m))
    for idx in np.ndindex(*batch):
        f, e, n, kk = F[idx], E[idx], N[idx], k_max[idx]

        def worst(x, f=f, e=e, n=n):
            return friction_angles(net_forces(f, e, x[:m]), n)

        cons = [{"type": "ineq", "fun": lambda x, worst=worst: x[m] - worst(x)}]
        if f_lim is not None:
            cons.append(
                {
                    "type": "ineq",
                    "fun": lambda x, f=f, e=e, lim=f_lim[idx]: (
                        lim - np.linalg.norm(net_forces(f, e, x[:m]), axis=-1)
                    ),
                }
            )
        x0 = np.zeros(m + 1)
        x0[m] = worst(x0).max()
        res = minimize(
            lambda x: x[m],
            x0,
            constraints=cons,
            bounds=[(-kk, kk)] * m + [(0, np.pi)],
            method="SLSQP",
            options={"ftol": 1e-12, "maxiter": 500},
        )
        ks[idx] = np.clip(res.x[:m], -kk, kk)
    angles = friction_angles(net_forces(F, E, ks), N)
    max_angle = angles.max(axis=-1)
    on_box = np.any(np.abs(ks) >= k_max[..., None] * (1 - 1e-9), axis=-1)
    status = np.where(max_angle >= np.pi / 2, Status.NOT_PUSHING, np.where(on_box, 1, 0))
    return MinimaxResult(ks, angles, max_angle, np.zeros(batch), status.astype(np.int8))
