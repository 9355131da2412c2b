"""Starting grips: least-squares interaction scalars that make the tangential forces vanish,
every finger push alike, or one finger take a given force.
"""

from __future__ import annotations

from .jit import inline, kernel
from .linalg import lu_solve, stack_empty, stack_zeros


@kernel
def apex_start(a0, al, tau0, T, k):
    """k minimising sum_i |tau_i(k)|^2 (normal equations); False if they are singular."""
    n, m = al.shape
    M = stack_zeros((m, m))
    r = stack_zeros(m)
    for i in range(n):
        for c in range(2):
            for p in range(m):
                r[p] -= T[i, c, p] * tau0[i, c]
                for q in range(m):
                    M[p, q] += T[i, c, p] * T[i, c, q]
    ok = lu_solve(M, r, m)
    for j in range(m):
        k[j] = r[j] if ok else 0.0
    return ok


@kernel
def normal_start(a0, al, tau0, T, c, k):
    """k minimising sum_i |tau_i(k)|^2 + (a_i(k) - c)^2: every finger pushing with force c."""
    n, m = al.shape
    M = stack_zeros((m, m))
    r = stack_zeros(m)
    for i in range(n):
        for row in range(3):
            target = c - a0[i] if row == 0 else -tau0[i, row - 1]
            for p in range(m):
                vp = al[i, p] if row == 0 else T[i, row - 1, p]
                r[p] += vp * target
                for q in range(m):
                    M[p, q] += vp * (al[i, q] if row == 0 else T[i, row - 1, q])
    ok = lu_solve(M, r, m)
    for j in range(m):
        k[j] = r[j] if ok else 0.0
    return ok


@kernel
def move_force(a0, al, tau0, T, i, t0, t1, t2, k_from, k):
    """k = k_from moved (minimum norm) so that P_i = (t0, t1, t2) in finger i's frame."""
    m = al.shape[1]
    M = stack_empty((3, 3))
    y = stack_empty(3)
    for r in range(3):
        s = a0[i] if r == 0 else tau0[i, r - 1]
        for j in range(m):
            s += (al[i, j] if r == 0 else T[i, r - 1, j]) * k_from[j]
        y[r] = (t0 if r == 0 else (t1 if r == 1 else t2)) - s
        for c in range(3):
            s = 0.0
            for j in range(m):
                s += (al[i, j] if r == 0 else T[i, r - 1, j]) * (
                    al[i, j] if c == 0 else T[i, c - 1, j]
                )
            M[r, c] = s
    if not lu_solve(M, y, M.shape[0]):
        return False
    for j in range(m):
        k[j] = k_from[j] + y[0] * al[i, j] + y[1] * T[i, 0, j] + y[2] * T[i, 1, j]
    return True


@inline
def release_start(a0, al, tau0, T, K, i, release, k_from, k):
    """k = k_from moved (minimum norm) so that P_i = release * n_i; False if it leaves the box."""
    if not move_force(a0, al, tau0, T, i, release, 0.0, 0.0, k_from, k):
        return False
    for j in range(al.shape[1]):
        if abs(k[j]) > K:
            return False
    return True
