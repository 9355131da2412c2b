"""Independent reference for the minimax optimiser: bisection over second-order-cone feasibility.

Test-only (cvxpy + Clarabel). theta_i <= t < 90 deg holds exactly when the tangential part of
P_i lies in the cone |P_i - (n_i . P_i) n_i| <= tan(t) (n_i . P_i) (docs/design.md §1, "Minimax"),
so the optimum is the smallest t whose cone constraints admit a k in the box. At each t we solve

    minimise s  subject to  cos t |(I - n_i n_i^T) P_i(k)| <= sin t (n_i . P_i(k)) + s,
                            |k_ij| <= k_max,  (|P_i(k)| <= f_max),

and t is feasible iff s* <= 0. The problem is built once per finger count with cvxpy Parameters
(cos t and sin t folded into the data), so each bisection step only re-solves.

With five or more contacts the pair scalars are redundant (m = n(n-1)/2 > 3n - 6), and the box
bounds the minimum-norm k of each interaction force (docs/solver.md, "Any number of
contacts"): here k is constrained to the row space of the map k -> P (N' k = 0 for a basis N of
its null space, from scipy), where it is its own minimum-norm representative.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg

try:
    import cvxpy as cp
except ImportError as error:  # a wheel install without the extra
    raise ImportError(
        'the reference solver needs cvxpy and Clarabel: pip install "grasp-env[bench]"'
    ) from error

#: Clarabel tolerances tighter than its defaults: the bisection reads the sign of s* near 0.
SOLVER_OPTIONS = {
    "tol_gap_abs": 1e-12,
    "tol_gap_rel": 1e-12,
    "tol_feas": 1e-12,
    "tol_ktratio": 1e-10,
    "max_iter": 200,
}


@dataclass
class ReferenceResult:
    """Bracket [lower, upper] around the optimal max angle (radians) and a k attaining upper.

    upper is the max angle of k itself (in the box; within the force limits to Clarabel's
    tolerance), so it is an attained value even where the bisection's last feasible t is
    not (Clarabel's tolerances are absolute: with a tiny box they move t by about 1e-9 rad).
    """

    lower: float
    upper: float
    k: np.ndarray
    not_pushing: bool
    #: the bisection's last feasible level: upper may exceed it where a finger is released
    #: (its force ~1e-12 of the load, whose direction is then rounding)
    feasible: float = np.pi / 2


class ConeBisection:
    """Minimax by bisection on t over cone feasibility, for grasps with ``n`` contacts."""

    def __init__(self, n: int, with_force_limit: bool = False) -> None:
        m = n * (n - 1) // 2
        self.n, self.m = n, m
        self.k = cp.Variable(m)
        self.s = cp.Variable()
        self.tangential = [cp.Parameter((3, m)) for _ in range(n)]  # cos t (I - n n^T) A_i
        self.tangential0 = [cp.Parameter(3) for _ in range(n)]  # cos t (I - n n^T) F_i
        self.normal = [cp.Parameter(m) for _ in range(n)]  # sin t A_i^T n_i
        self.normal0 = [cp.Parameter() for _ in range(n)]  # sin t n_i . F_i
        self.k_max = cp.Parameter(nonneg=True)
        constraints = [cp.abs(self.k) <= self.k_max]
        self.redundant = None
        if m > 3 * n - 6:  # the null space of k -> P: (m, m - rank), 3 columns or more
            self.redundant = cp.Parameter((m, m - (3 * n - 6)))
            constraints.append(self.redundant.T @ self.k == 0)
        for i in range(n):
            tangential = self.tangential[i] @ self.k + self.tangential0[i]
            normal = self.normal[i] @ self.k + self.normal0[i]
            constraints.append(cp.norm(tangential) <= normal + self.s)
        self.force_map = self.force0 = self.f_max = None
        if with_force_limit:
            self.force_map = [cp.Parameter((3, m)) for _ in range(n)]  # A_i
            self.force0 = [cp.Parameter(3) for _ in range(n)]  # F_i
            self.f_max = cp.Parameter(nonneg=True)
            for i in range(n):
                force = self.force_map[i] @ self.k + self.force0[i]
                constraints.append(cp.norm(force) <= self.f_max)
        self.problem = cp.Problem(cp.Minimize(self.s), constraints)
        assert self.problem.is_dcp(dpp=True)

    def _slack(self, t: float) -> tuple[float, np.ndarray]:
        """s*(t) and its minimiser k; +inf when the force limits admit no k at all."""
        c, s = np.cos(t), np.sin(t)
        for i in range(self.n):
            self.tangential[i].value = c * self._proj[i] @ self._maps[i]
            self.tangential0[i].value = c * self._proj[i] @ self._forces[i]
            self.normal[i].value = s * self._maps[i].T @ self._normals[i]
            self.normal0[i].value = s * float(self._normals[i] @ self._forces[i])
        with warnings.catch_warnings():
            # "solution may be inaccurate": expected at these tolerances; the bisection only
            # reads the sign of s*, far larger than the residual
            warnings.simplefilter("ignore", UserWarning)
            self.problem.solve(solver=cp.CLARABEL, **SOLVER_OPTIONS)
        if self.problem.status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            if self.problem.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
                return np.inf, np.zeros(self.m)
            raise RuntimeError(f"reference solver failed: {self.problem.status}")
        return float(self.s.value), np.array(self.k.value)

    def solve(
        self,
        equilibrating: np.ndarray,
        basis: np.ndarray,
        normals: np.ndarray,
        k_max: float,
        f_max: float | None = None,
        tol: float = 1e-10,
    ) -> ReferenceResult:
        """Bisect t in [0, pi/2] down to ``tol`` radians for one grasp (unbatched arrays).

        Forces are divided by the largest equilibrating force first, so that the solver's
        absolute tolerances mean the same for every weight.
        """
        scale = float(np.max(np.linalg.norm(equilibrating, axis=-1)))
        self._forces = equilibrating / scale
        self._maps = [basis[:, i, :].T for i in range(self.n)]  # A_i: (3, m), k -> k_ij e_ij
        self._normals = normals
        self._proj = [np.eye(3) - np.outer(v, v) for v in normals]
        self.k_max.value = k_max / scale
        if self.redundant is not None:
            force_map = np.concatenate(self._maps)  # (3n, m)
            null = scipy.linalg.null_space(force_map, rcond=1e-10)
            if null.shape[1] != self.redundant.shape[1]:
                raise ValueError(
                    f"the contacts' pair directions span {force_map.shape[1] - null.shape[1]}"
                    f" dimensions, not 3n - 6 = {3 * self.n - 6} (coplanar contacts?)"
                )
            self.redundant.value = null
        if self.f_max is not None:
            if f_max is None:
                raise ValueError("this reference was built with a force limit: pass f_max")
            self.f_max.value = f_max / scale
            for i in range(self.n):
                self.force_map[i].value = self._maps[i]
                self.force0[i].value = self._forces[i]
        lower, upper = 0.0, np.pi / 2
        slack, k = self._slack(upper)
        if slack > 0:
            return ReferenceResult(np.pi / 2, np.pi / 2, k * scale, True)
        k_upper = k
        while upper - lower > tol:
            mid = 0.5 * (lower + upper)
            slack, k = self._slack(mid)
            if slack <= 0:
                upper, k_upper = mid, k
            else:
                lower = mid
        k = np.clip(k_upper * scale, -k_max, k_max)
        forces = equilibrating + np.einsum("m,mnc->nc", k, basis)
        tangential = np.linalg.norm(np.cross(forces, normals), axis=-1)
        attained = float(np.max(np.arctan2(tangential, np.sum(forces * normals, axis=-1))))
        return ReferenceResult(lower, max(upper, attained), k, False, upper)
