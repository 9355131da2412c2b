"""Finger frames, forces and angles, the coordinates y of the interaction forces, and the
small dense solves of the conic solver."""

from __future__ import annotations

from math import atan2, inf, sqrt

import numpy as np

from .codes import kernel


@kernel
def force_coordinates(al, T):
    """An orthonormal basis B (m, d) of the pair scalars that move a force: the row space
    of the map k -> (a_i, tau_i) (d = 3n - 6 unless the contacts are coplanar). k = B y
    is then the minimum-norm k of the interaction force y makes (for n <= 4, every k)."""
    n, m = al.shape
    M = np.empty((3 * n, m))
    for i in range(n):
        for j in range(m):
            M[3 * i, j] = al[i, j]
            M[3 * i + 1, j] = T[i, 0, j]
            M[3 * i + 2, j] = T[i, 1, j]
    _, s, vt = np.linalg.svd(M, full_matrices=False)
    rank = 0
    for value in s:
        if value > 1e-10 * s[0]:
            rank += 1
    return np.ascontiguousarray(vt[:rank].T)


@kernel
def reduced(T, box):
    """T (n, 2, m) in the coordinates y: T @ box, (n, 2, d)."""
    n = T.shape[0]
    out = np.empty((n, 2, box.shape[1]))
    for i in range(n):
        out[i] = T[i] @ box
    return out


@kernel
def finger_forces(k, a0, al, tau0, T, P):
    """P[i] = (a_i, tau_i1, tau_i2) at k: finger i's force in its frame (eq. 4)."""
    n, m = al.shape
    for i in range(n):
        a, t1, t2 = a0[i], tau0[i, 0], tau0[i, 1]
        for j in range(m):
            a += al[i, j] * k[j]
            t1 += T[i, 0, j] * k[j]
            t2 += T[i, 1, j] * k[j]
        P[i, 0], P[i, 1], P[i, 2] = a, t1, t2


@kernel
def largest_angle(P, f, theta):
    """Friction angles (eq. 2) into theta; returns max_i theta_i, or inf where a force
    exceeds its limit f (relative tolerance 1e-9: such a point is not a grip)."""
    worst = 0.0
    over = False
    for i in range(P.shape[0]):
        tangential = sqrt(P[i, 1] ** 2 + P[i, 2] ** 2)
        theta[i] = atan2(tangential, P[i, 0])
        worst = max(worst, theta[i])
        if f < inf and sqrt(P[i, 0] ** 2 + tangential**2) > f * (1.0 + 1e-9):
            over = True
    return inf if over else worst


@kernel
def level_excess(P, f, ct, st, w):
    """The least r that (k, r) needs in the cone problem at level t: an upper bound on v(t)."""
    r = -inf
    for i in range(P.shape[0]):
        tangential = sqrt(P[i, 1] ** 2 + P[i, 2] ** 2)
        r = max(r, (ct * tangential - st * P[i, 0]) / w[i])
        if f < inf:
            r = max(r, (sqrt(P[i, 0] ** 2 + tangential**2) - f) / f)
    return r


@kernel
def weights(P, w):
    """Crouzeix-Ferland-Schaible weights w_i = |P_i| (floored at 1e-6 of the load)."""
    for i in range(P.shape[0]):
        w[i] = max(sqrt(P[i, 0] ** 2 + P[i, 1] ** 2 + P[i, 2] ** 2), 1e-6)


@kernel
def start_at(y, a0, al, tau0, T, box, K, P, w, trial):
    """A barrier method's start: y moved strictly inside the box, and the weights at y."""
    finger_forces(y, a0, al, tau0, T, P)
    weights(P, w)
    largest = 0.0
    for j in range(box.shape[0]):
        v = 0.0
        for p in range(y.shape[0]):
            v += box[j, p] * y[p]
        largest = max(largest, abs(v))
    shrink = min(1.0, K * (1.0 - 1e-9) / largest) if largest > 0.0 else 1.0
    for p in range(y.shape[0]):
        trial[p] = y[p] * shrink


@kernel
def cholesky_solve(H, b):
    """Solve H x = b in place (b becomes x) by Cholesky's factorisation, overwriting H's
    lower triangle; False if H is not positive definite to working precision."""
    d = b.shape[0]
    for j in range(d):
        s = H[j, j]
        for p in range(j):
            s -= H[j, p] * H[j, p]
        if not s > 0.0:
            return False
        s = sqrt(s)
        H[j, j] = s
        for i in range(j + 1, d):
            v = H[i, j]
            for p in range(j):
                v -= H[i, p] * H[j, p]
            H[i, j] = v / s
    for i in range(d):  # L y = b
        v = b[i]
        for p in range(i):
            v -= H[i, p] * b[p]
        b[i] = v / H[i, i]
    for i in range(d - 1, -1, -1):  # L' x = y
        v = b[i]
        for p in range(i + 1, d):
            v -= H[p, i] * b[p]
        b[i] = v / H[i, i]
    return True
