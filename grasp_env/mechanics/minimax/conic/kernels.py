"""Kernels of the conic solver: the minimax grip for any number of contacts (docs/solver.md,
"Any number of contacts").

For a level t < 90 deg, the cone problem (docs/design.md §1, "Minimax")

    v(t) = min r  over (k, r), |k_j| <= K:
           cos t |tau_i(k)| <= sin t a_i(k) + w_i r        (finger i within angle t)
           |P_i(k)| <= f (1 + r)                           (its force limit, if any)

is convex, and v(t) <= 0 exactly when some k in the box holds every finger within t and its
limit. A log-barrier method solves it (Newton's method on  tb r + barrier, tb growing), and
its central points give dual vectors in the dual cones, whatever their accuracy. Dinkelbach's
iterations on t (Crouzeix-Ferland-Schaible weights w_i = |P_i|) move t to the largest angle
of each minimiser: attained values, decreasing superlinearly to the optimum t*. The
certificate is weak duality at t_low = t* - delta: for y_i in the cones' duals the vectors
z_i (finger i's dual, world frame) and u_i (its force limit's) give

    L(t) = sum_i (z_i + u_i) . F_i - f |u_i|  -  K || sum_i A_i' (z_i + u_i) ||_1,

the minimum over the box of a function that is <= 0 at every k holding all fingers within t:
L(t_low) > 0 proves that no k does. L is computed, never assumed.

Everything is in finger frames (a_i = n_i . P_i, tau_i the tangential coordinates) and in
units of the load (the largest equilibrating force), as in the three- and four-finger solver.
"""

from __future__ import annotations

import os
from math import atan2, inf, log, pi, sqrt

import numpy as np
from numba import njit

from ..jit import register_package

register_package(os.path.dirname(__file__))

#: Accepted certificate gap, radians (as the three- and four-finger solver's GAP_TOL).
GAP_TOL = 1e-9
#: How far below the best grip a certificate is sought, radians: first within GAP_TOL, then
#: (the gap left open, status UNCERTIFIED) the nearest that a barrier's duals prove.
BOUND_BELOW = (9e-10, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
#: Barrier parameter growth per stage, and the most stages and Newton steps per centring.
GROWTH = 12.0
STAGES = 40
NEWTON_STEPS = 60
DINKELBACH_STEPS = 40
#: The barrier parameter (units of the load) past which polish() builds the certificate.
POLISH_FROM = 1e9
#: Rounds of polishing below the best grip (each may find a better one).
POLISH_ROUNDS = 6
#: A Dinkelbach level is solved until its bounds are within this fraction of each other.
LEVEL_GAP = 1e-4

# results (status codes as minimax.codes: INTERIOR, BOUNDARY, NOT_PUSHING, UNCERTIFIED)
INTERIOR = 0
BOUNDARY = 1
NOT_PUSHING = 2
UNCERTIFIED = 3
# refusals (as minimax.codes)
INVALID = -1
BAD_NORMAL = -2
BAD_LOAD = -3
BAD_K_MAX = -4
BAD_F_MAX = -5
UNIT_TOL = 1e-6
LOAD_RANGE = (1e-305, 1e305)
RATIO_RANGE = (1e-12, 1e12)

kernel = njit(cache=True, nogil=True, error_model="numpy")


@kernel
def frames(F, E, N, a0, al, tau0, T):
    """Finger frames of world-frame F (n, 3), E (m, n, 3), N (n, 3), in units of the load.

    a_i = a0_i + al_i . k is finger i's normal force, tau_i = tau0_i + T_i k its tangential
    one (two unit tangents b, c with n x b = c). Returns (scale, code): scale is the largest
    |F_i| (0 for no load), code BAD_NORMAL for a normal not of unit length, else 0.
    """
    n, m = F.shape[0], E.shape[0]
    for i in range(n):
        length = sqrt(N[i, 0] ** 2 + N[i, 1] ** 2 + N[i, 2] ** 2)
        if not abs(length - 1.0) <= UNIT_TOL:
            return 0.0, BAD_NORMAL
    big = 0.0  # |F_i| without squaring F (which under- or overflows beyond 1e+-154)
    for i in range(n):
        for c in range(3):
            big = max(big, abs(F[i, c]))
    if big == 0.0:
        return 0.0, 0
    scale = 0.0
    for i in range(n):
        s = big * sqrt((F[i, 0] / big) ** 2 + (F[i, 1] / big) ** 2 + (F[i, 2] / big) ** 2)
        scale = max(scale, s)
    for i in range(n):
        length = sqrt(N[i, 0] ** 2 + N[i, 1] ** 2 + N[i, 2] ** 2)
        nx, ny, nz = N[i, 0] / length, N[i, 1] / length, N[i, 2] / length
        if abs(nx) <= abs(ny) and abs(nx) <= abs(nz):  # b = n x (the axis least along n)
            bx, by, bz = 0.0, nz, -ny
        elif abs(ny) <= abs(nz):
            bx, by, bz = -nz, 0.0, nx
        else:
            bx, by, bz = ny, -nx, 0.0
        bn = sqrt(bx * bx + by * by + bz * bz)
        bx, by, bz = bx / bn, by / bn, bz / bn
        cx, cy, cz = ny * bz - nz * by, nz * bx - nx * bz, nx * by - ny * bx
        f0, f1, f2 = F[i, 0] / scale, F[i, 1] / scale, F[i, 2] / scale
        a0[i] = nx * f0 + ny * f1 + nz * f2
        tau0[i, 0] = bx * f0 + by * f1 + bz * f2
        tau0[i, 1] = cx * f0 + cy * f1 + cz * f2
        for j in range(m):
            e0, e1, e2 = E[j, i, 0], E[j, i, 1], E[j, i, 2]
            al[i, j] = nx * e0 + ny * e1 + nz * e2
            T[i, 0, j] = bx * e0 + by * e1 + bz * e2
            T[i, 1, j] = cx * e0 + cy * e1 + cz * e2
    return scale, 0


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
def barrier(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, g, H, derivatives):
    """tb r + the log barrier of the cone problem at x = (y, r): its value (inf outside),
    and with derivatives its gradient g and Hessian H (the second-order-cone barrier
    -log(u0^2 - |u|^2) of each finger's cone and force limit, -log of each side of the box
    |b_j . y| <= K on the minimum-norm pair scalars k = B y)."""
    n, m = al.shape
    d = m + 1
    r = x[m]
    value = tb * r
    if derivatives:
        g[:] = 0.0
        H[:, :] = 0.0
        g[m] = tb
    for j in range(box.shape[0]):  # K -+ b_j . y > 0: the minimum-norm k_j in the box
        v = 0.0
        for p in range(m):
            v += box[j, p] * x[p]
        up, low = K - v, K + v
        if up <= 0.0 or low <= 0.0:
            return inf
        value -= log(up) + log(low)
        if not derivatives:
            continue
        slope, curve = 1.0 / up - 1.0 / low, 1.0 / (up * up) + 1.0 / (low * low)
        for p in range(m):
            g[p] += slope * box[j, p]
            for q in range(p, m):
                H[p, q] += curve * box[j, p] * box[j, q]
    G = np.empty((4, d))  # the cone's coordinates' Jacobian rows
    u = np.empty(4)
    Ju = np.empty(4)
    slope = np.empty(d)
    for i in range(n):
        a, t1, t2 = a0[i], tau0[i, 0], tau0[i, 1]
        for j in range(m):
            a += al[i, j] * x[j]
            t1 += T[i, 0, j] * x[j]
            t2 += T[i, 1, j] * x[j]
        for cone in range(2 if f < inf else 1):
            if cone == 0:  # (st a + w r, ct tau) in the cone: finger i within angle t
                u[0], u[1], u[2] = st * a + w[i] * r, ct * t1, ct * t2
                rows = 3
            else:  # (f (1 + r), P_i) in the cone: |P_i| <= f (1 + r)
                u[0], u[1], u[2], u[3] = f * (1.0 + r), a, t1, t2
                rows = 4
            radius = 0.0
            for c in range(1, rows):
                radius += u[c] * u[c]
            radius = sqrt(radius)
            if not u[0] > radius:
                return inf
            D = (u[0] - radius) * (u[0] + radius)
            value -= log(D)
            if not derivatives:
                continue
            if cone == 0:
                for j in range(m):
                    G[0, j] = st * al[i, j]
                    G[1, j] = ct * T[i, 0, j]
                    G[2, j] = ct * T[i, 1, j]
                G[0, m], G[1, m], G[2, m] = w[i], 0.0, 0.0
            else:
                for j in range(m):
                    G[0, j] = 0.0
                    G[1, j] = al[i, j]
                    G[2, j] = T[i, 0, j]
                    G[3, j] = T[i, 1, j]
                G[0, m], G[1, m], G[2, m], G[3, m] = f, 0.0, 0.0, 0.0
            # -log(u' J u), J = diag(1, -1, ...): gradient -2 J u / D, Hessian
            # -2 J / D + 4 (J u)(J u)' / D^2
            Ju[0] = u[0] / D
            for c in range(1, rows):
                Ju[c] = -u[c] / D
            for p in range(d):
                gp = 0.0
                for c in range(rows):
                    gp += Ju[c] * G[c, p]
                slope[p] = gp
                g[p] -= 2.0 * gp
            for p in range(d):
                for q in range(p, d):
                    hq = -G[0, p] * G[0, q]
                    for c in range(1, rows):
                        hq += G[c, p] * G[c, q]
                    H[p, q] += 2.0 / D * hq + 4.0 * slope[p] * slope[q]
    if derivatives:
        for p in range(d):
            for q in range(p):
                H[p, q] = H[q, p]
    return value


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


@kernel
def lu_solve(A, b):
    """Solve A x = b in place (b becomes x; A is overwritten) by Gaussian elimination with
    partial pivoting; False if a pivot is below 1e-13 of A's largest entry."""
    d = b.shape[0]
    largest = 0.0
    for p in range(d):
        for q in range(d):
            largest = max(largest, abs(A[p, q]))
    if largest == 0.0:
        return False
    for j in range(d):
        pivot, best = j, abs(A[j, j])
        for i in range(j + 1, d):
            if abs(A[i, j]) > best:
                pivot, best = i, abs(A[i, j])
        if best <= 1e-13 * largest:
            return False
        if pivot != j:
            for q in range(d):
                A[j, q], A[pivot, q] = A[pivot, q], A[j, q]
            b[j], b[pivot] = b[pivot], b[j]
        for i in range(j + 1, d):
            factor = A[i, j] / A[j, j]
            if factor != 0.0:
                for q in range(j + 1, d):
                    A[i, q] -= factor * A[j, q]
                b[i] -= factor * b[j]
    for i in range(d - 1, -1, -1):
        v = b[i]
        for q in range(i + 1, d):
            v -= A[i, q] * b[q]
        b[i] = v / A[i, i]
    return True


@kernel
def centre(x, a0, al, tau0, T, box, K, f, ct, st, w, tb):
    """Newton's method on tb r + barrier from the strictly feasible x, in place, to a
    Newton decrement of 1e-10; returns the steps taken (-1 if a step failed)."""
    d = x.shape[0]
    g = np.empty(d)
    H = np.empty((d, d))
    trial = np.empty(d)
    dx = np.empty(d)
    diag = np.empty(d)
    for step in range(NEWTON_STEPS):
        value = barrier(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, g, H, True)
        # Jacobi scaling: near the optimum a box side's or a cone's curvature is 1e20 x
        # another's, and Cholesky's factorisation of the scaled matrix keeps both accurate
        for p in range(d):
            diag[p] = 1.0 / sqrt(H[p, p])
        for p in range(d):
            for q in range(d):
                H[p, q] *= diag[p] * diag[q]
            H[p, p] += 1e-14  # the box alone curves the k that no cone feels
            dx[p] = -g[p] * diag[p]
        if not cholesky_solve(H, dx):
            return -1
        for p in range(d):
            dx[p] *= diag[p]
        decrement = 0.0
        for p in range(d):
            decrement -= g[p] * dx[p]
        if not decrement > 1e-9:
            return step
        s = 1.0
        for _ in range(40):
            for p in range(d):
                trial[p] = x[p] + s * dx[p]
            new = barrier(trial, a0, al, tau0, T, box, K, f, ct, st, w, tb, g, H, False)
            if new <= value - 0.25 * s * decrement:
                break
            s *= 0.5
        else:
            return step
        x[:] = trial
    return NEWTON_STEPS


@kernel
def certificate(x, a0, al, tau0, T, box, K, f, ct, st, w, tb):
    """Weak duality at the barrier point x: (L, norm, share). The cones' dual vectors
    y = 2 J u / (tb D) lie in the (self-dual) cones at any x of the barrier's domain;
    for every k in the box, r >= L / norm, so L > 0 proves v(t) > 0. share: the box
    term's part of the bound (BOUNDARY where it carries it)."""
    n, m = al.shape
    z = np.zeros((n, 3))  # finger frame: (normal, tangent b, tangent c)
    norm = 0.0
    limit = 0.0
    r = x[m]
    for i in range(n):
        a, t1, t2 = a0[i], tau0[i, 0], tau0[i, 1]
        for j in range(m):
            a += al[i, j] * x[j]
            t1 += T[i, 0, j] * x[j]
            t2 += T[i, 1, j] * x[j]
        u0, u1, u2 = st * a + w[i] * r, ct * t1, ct * t2
        radius = sqrt(u1 * u1 + u2 * u2)
        D = (u0 - radius) * (u0 + radius)
        scale = 2.0 / (tb * D)
        y0, y1, y2 = scale * u0, -scale * u1, -scale * u2
        # (y0, y1, y2) . (st a + w r, ct tau) >= 0 on the cone: z . P <= 0 for a point
        # within angle t, with z = -(y0 st, y1 ct, y2 ct)
        z[i, 0] = -y0 * st
        z[i, 1] = -y1 * ct
        z[i, 2] = -y2 * ct
        norm += y0 * w[i]
        if f < inf:
            radius = sqrt(a * a + t1 * t1 + t2 * t2)
            D = (f * (1.0 + r) - radius) * (f * (1.0 + r) + radius)
            scale = 2.0 / (tb * D)
            # u_i = scale P_i: u . P - f |u| <= 0 on the ball
            z[i, 0] += scale * a
            z[i, 1] += scale * t1
            z[i, 2] += scale * t2
            size = scale * radius
            limit += f * size
            norm += f * size
    mu = np.empty(box.shape[0])  # the box's multipliers: its barrier's slopes / tb
    for j in range(box.shape[0]):
        v = 0.0
        for p in range(m):
            v += box[j, p] * x[p]
        mu[j] = -(1.0 / (K - v) - 1.0 / (K + v)) / tb
    value, share = dual_bound(z, limit, a0, al, tau0, T, box, K, mu)
    return value, norm, share


@kernel
def level(t, w, k, x, a0, al, tau0, T, box, K, f, decide):
    """Solve the cone problem at level t from k (inside the box) by the barrier method.

    k moves to the best point met, x = (k, r) holds the last barrier point. Returns
    (upper, lower, share, tb): v(t) <= upper (attained by k), v(t) >= lower (certified),
    and the last barrier parameter. With decide, it stops as soon as the sign of v(t) is
    known (a better grip: upper < 0; a proof that none holds at t: lower > 0); otherwise
    when the bounds are within 1% of each other.
    """
    n, m = al.shape
    ct, st = np.cos(t), np.sin(t)
    if t >= pi / 2:
        ct, st = 0.0, 1.0
    P = np.empty((n, 3))
    finger_forces(k, a0, al, tau0, T, P)
    x[:m] = k
    excess = level_excess(P, f, ct, st, w)
    margin = max(1e-3, 0.1 * abs(excess))
    x[m] = excess + margin
    nu = 2.0 * n * (2 if f < inf else 1) + 2.0 * m
    tb = nu / margin
    upper, lower, share = excess, -inf, 0.0
    for _ in range(STAGES):
        if centre(x, a0, al, tau0, T, box, K, f, ct, st, w, tb) < 0:
            break
        finger_forces(x[:m], a0, al, tau0, T, P)
        here = level_excess(P, f, ct, st, w)
        if here < upper:
            upper = here
            k[:] = x[:m]
        value, norm, part = certificate(x, a0, al, tau0, T, box, K, f, ct, st, w, tb)
        if norm > 0.0 and value / norm > lower:
            lower, share = value / norm, part
        if decide and (upper < 0.0 or lower > 0.0):
            break
        if upper - lower <= LEVEL_GAP * abs(upper) or tb > POLISH_FROM:
            break  # (beyond POLISH_FROM the barrier's duals lose digits: polish() takes over)
        tb *= GROWTH
    return upper, lower, share, tb


@kernel
def active_sets(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, cone, ball, fixed):
    """The sets at the barrier point x: fingers released (|P_i| below 1e-6 of the largest:
    cone 2), the constraints whose dual estimate is at least 1e-3 of the largest (fingers
    at the level: cone 1; at their limit: ball), k_j on the box (fixed +-1)."""
    n, m = al.shape
    r = x[m]
    P = np.empty((n, 3))
    finger_forces(x[:m], a0, al, tau0, T, P)
    sizes = np.empty(n)
    for i in range(n):
        sizes[i] = sqrt(P[i, 0] ** 2 + P[i, 1] ** 2 + P[i, 2] ** 2)
    biggest = sizes.max()
    duals = np.zeros((n, 2))
    largest = 0.0
    for i in range(n):
        if sizes[i] < 1e-6 * biggest:
            continue
        u0 = st * P[i, 0] + w[i] * r
        radius = ct * sqrt(P[i, 1] ** 2 + P[i, 2] ** 2)
        duals[i, 0] = 2.0 * u0 / (tb * (u0 - radius) * (u0 + radius)) * w[i]
        largest = max(largest, duals[i, 0])
        if f < inf:
            u0 = f * (1.0 + r)
            radius = sizes[i]
            duals[i, 1] = 2.0 * u0 / (tb * (u0 - radius) * (u0 + radius)) * f
            largest = max(largest, duals[i, 1])
    for i in range(n):
        excess = (ct * sqrt(P[i, 1] ** 2 + P[i, 2] ** 2) - st * P[i, 0]) / w[i]
        near = excess >= r - 1e-5 or duals[i, 0] >= 1e-3 * largest
        cone[i] = 2 if sizes[i] < 1e-6 * biggest else (1 if near else 0)
        ball[i] = f < inf and duals[i, 1] >= 1e-3 * largest
    for j in range(box.shape[0]):
        v = 0.0
        for p in range(m):
            v += box[j, p] * x[p]
        up, low = K - v, K + v
        fixed[j] = 0
        if min(up, low) <= 1e-6 * K or abs(1.0 / up - 1.0 / low) / tb >= 1e-3 * largest:
            fixed[j] = 1 if up < low else -1


@kernel
def weights(P, w):
    """Crouzeix-Ferland-Schaible weights w_i = |P_i| (floored at 1e-6 of the load)."""
    for i in range(P.shape[0]):
        w[i] = max(sqrt(P[i, 0] ** 2 + P[i, 1] ** 2 + P[i, 2] ** 2), 1e-6)


@kernel
def solve_one(F, E, N, K_in, f_in, k, theta):
    """The certified minimax grip of one grasp: fills k (newtons) and theta (radians);
    returns (lower, status) or a negative refusal code as the status."""
    n, m = F.shape[0], E.shape[0]
    k[:] = 0.0
    theta[:] = 0.0
    for value in F.ravel():
        if not np.isfinite(value):
            return 0.0, INVALID
    for value in E.ravel():
        if not np.isfinite(value):
            return 0.0, INVALID
    for value in N.ravel():
        if not np.isfinite(value):
            return 0.0, INVALID
    a0, al = np.empty(n), np.empty((n, m))
    tau0, T = np.empty((n, 2)), np.empty((n, 2, m))
    scale, code = frames(F, E, N, a0, al, tau0, T)
    if code != 0:
        return 0.0, code
    if scale == 0.0:
        return 0.0, INTERIOR  # no load: k = 0 holds it with every angle 0
    if not LOAD_RANGE[0] <= scale <= LOAD_RANGE[1]:
        return 0.0, BAD_LOAD
    K, f = K_in / scale, f_in / scale
    if not RATIO_RANGE[0] <= K <= RATIO_RANGE[1]:
        return 0.0, BAD_K_MAX
    if f < inf and not RATIO_RANGE[0] <= f <= RATIO_RANGE[1]:
        return 0.0, BAD_F_MAX
    # the interaction forces' coordinates y: k = box y, the minimum-norm pair scalars
    box = force_coordinates(al, T)
    pairs = m
    al, T = al @ box, reduced(T, box)
    m = box.shape[1]
    P = np.empty((n, 3))
    w = np.empty(n)
    x = np.empty(m + 1)
    trial = np.empty(m)
    cone = np.empty(n, dtype=np.int64)
    ball = np.empty(n, dtype=np.bool_)
    fixed = np.empty(pairs, dtype=np.int64)
    best = np.zeros(m)  # k = 0: the equilibrating forces alone
    finger_forces(best, a0, al, tau0, T, P)
    t_up = largest_angle(P, f, theta)
    lower, share = 0.0, 0.0
    # Dinkelbach: each minimiser's largest angle is the next level (inf: none holds yet)
    for _ in range(DINKELBACH_STEPS):
        if t_up <= GAP_TOL:
            break  # every finger within GAP_TOL of its normal: 0 bounds it
        t = min(t_up, pi / 2)
        start_at(best, a0, al, tau0, T, box, K, P, w, trial)
        upper, low, part, tb = level(t, w, trial, x, a0, al, tau0, T, box, K, f, False)
        if low > 0.0:
            # no k holds every finger within t: certified (with t = pi/2: none pushes)
            lower, share = t, part
            break
        finger_forces(trial, a0, al, tau0, T, P)
        t_new = largest_angle(P, f, theta)
        if not t_new < t_up:
            break
        progress = t_up - t_new
        t_up = t_new
        best[:] = trial
        if progress <= 1e-3 * GAP_TOL:
            break
    # the certificate just below the best grip: Newton's method on the cone problem's KKT
    # system there (the barrier's duals are rounding noise this near the optimum) gives the
    # multipliers, and its point, nearer the optimum than the barrier resolves, may be a
    # better grip (then the certificate is sought below that)
    for _ in range(POLISH_ROUNDS):
        if lower >= t_up - GAP_TOL or t_up >= pi / 2:
            break
        if t_up <= GAP_TOL:
            lower = 0.0
            break
        t = t_up - BOUND_BELOW[0]
        ct, st = np.cos(t), np.sin(t)
        start_at(best, a0, al, tau0, T, box, K, P, w, trial)
        upper, low, part, tb = level(t, w, trial, x, a0, al, tau0, T, box, K, f, True)
        improved = False
        if upper < 0.0:
            finger_forces(trial, a0, al, tau0, T, P)
            t_new = largest_angle(P, f, theta)
            if t_new < t_up:
                t_up, improved = t_new, True
                best[:] = trial
        if low > 0.0:
            lower, share = t, part
            break
        if improved:
            continue
        active_sets(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, cone, ball, fixed)
        for _ in range(n + 2):  # change the sets a pass
            trial[:] = x[:m]
            low, part, changed = polish(t, w, trial, a0, al, tau0, T, box, K, f, cone, ball, fixed)
            finger_forces(trial, a0, al, tau0, T, P)
            t_new = largest_angle(P, f, theta)
            if t_new < t_up:
                t_up, improved = t_new, True
                best[:] = trial
            if low > 0.0 or not changed:
                break
        if low > 0.0:
            lower, share = t, part
            break
        if not improved:
            break
    # none closed the gap: the best bound further below (an honest gap, UNCERTIFIED)
    for delta in BOUND_BELOW[1:]:
        if lower >= t_up - GAP_TOL or t_up >= pi / 2:
            break
        t = max(t_up - delta, 0.0)
        start_at(best, a0, al, tau0, T, box, K, P, w, trial)
        upper, low, part, tb = level(t, w, trial, x, a0, al, tau0, T, box, K, f, True)
        if low > 0.0:
            lower, share = t, part
            break
    finger_forces(best, a0, al, tau0, T, P)
    t_best = largest_angle(P, f, theta)
    for j in range(pairs):
        v = 0.0
        for p in range(m):
            v += box[j, p] * best[p]
        k[j] = v * scale
    if lower >= pi / 2 or t_best >= pi / 2:
        return min(lower, pi / 2), NOT_PUSHING
    if t_best - lower > GAP_TOL:
        return lower, UNCERTIFIED
    return lower, BOUNDARY if share > 1e-6 else INTERIOR


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


@njit(cache=True, nogil=True, error_model="numpy")
def solve_batch(F, E, N, K, f, k, theta, lower, status, start, stop):
    """:func:`solve_one` for grasps start..stop of a flat batch; releases the GIL."""
    for b in range(start, stop):
        lower[b], status[b] = solve_one(F[b], E[b], N[b], K[b], f[b], k[b], theta[b])


@kernel
def constraint_rows(x, r, a0, al, tau0, T, f, ct, st, w, cone, ball, lam, G, dr, value, hess):
    """The active constraints at (k, r) = (x, r), a row each: their values, gradients in k
    (G) and in r (dr), and sum lam_c Hessian_c in hess. cone[i]: 1 finger i at the level
    (ct |tau_i| - st a_i - w_i r = 0), 2 released at the cone's apex (three linear rows:
    -st a_i - w_i r = 0, ct tau_i = 0, where |tau_i| has no derivative); ball[i]: at its
    limit (|P_i| - f (1 + r) = 0). Returns False where a row has no derivative."""
    n, m = al.shape
    P = np.empty((n, 3))
    finger_forces(x, a0, al, tau0, T, P)
    hess[:, :] = 0.0
    c = 0
    for i in range(n):
        if cone[i] == 1:
            radius = sqrt(P[i, 1] ** 2 + P[i, 2] ** 2)
            if radius == 0.0:
                return False
            h1, h2 = P[i, 1] / radius, P[i, 2] / radius
            value[c] = ct * radius - st * P[i, 0] - w[i] * r
            dr[c] = -w[i]
            for j in range(m):
                G[c, j] = ct * (h1 * T[i, 0, j] + h2 * T[i, 1, j]) - st * al[i, j]
            # ct / |tau| T' (I - h h') T: the tangent across h
            for j in range(m):
                pj = -h2 * T[i, 0, j] + h1 * T[i, 1, j]
                for q in range(m):
                    pq = -h2 * T[i, 0, q] + h1 * T[i, 1, q]
                    hess[j, q] += lam[c] * ct / radius * pj * pq
            c += 1
        elif cone[i] == 2:
            value[c] = -st * P[i, 0] - w[i] * r
            value[c + 1] = ct * P[i, 1]
            value[c + 2] = ct * P[i, 2]
            dr[c], dr[c + 1], dr[c + 2] = -w[i], 0.0, 0.0
            for j in range(m):
                G[c, j] = -st * al[i, j]
                G[c + 1, j] = ct * T[i, 0, j]
                G[c + 2, j] = ct * T[i, 1, j]
            c += 3
        if ball[i]:
            radius = sqrt(P[i, 0] ** 2 + P[i, 1] ** 2 + P[i, 2] ** 2)
            if radius == 0.0:
                return False
            e0, e1, e2 = P[i, 0] / radius, P[i, 1] / radius, P[i, 2] / radius
            value[c] = radius - f * (1.0 + r)
            dr[c] = -f
            for j in range(m):
                G[c, j] = e0 * al[i, j] + e1 * T[i, 0, j] + e2 * T[i, 1, j]
            for j in range(m):
                for q in range(m):
                    dot = al[i, j] * al[i, q] + T[i, 0, j] * T[i, 0, q]
                    dot += T[i, 1, j] * T[i, 1, q]
                    hess[j, q] += lam[c] * (dot - G[c, j] * G[c, q]) / radius
            c += 1
    return True


@kernel
def polish(t, w, y, a0, al, tau0, T, box, K, f, cone, ball, fixed):
    """Newton's method on the KKT system of the cone problem at level t, on the sets read
    off a barrier point y (see :func:`constraint_rows`; fixed[j] = +-1: the row b_j . y held
    at +-K), with least-squares steps damped on the largest residual. Returns (L, share,
    changed): the certificate L(t) of the multipliers (projected onto the dual cones, so
    valid at any accuracy), its box share, and whether the sets changed (the member with
    the most wrongly signed multiplier dropped, or a box row polished past K added) for
    another pass. y moves to the polished point if it stays in the box."""
    n, d = al.shape
    pairs = box.shape[0]
    ct, st = np.cos(t), np.sin(t)
    rows = 0
    for i in range(n):
        rows += (1 if cone[i] == 1 else 0) + (3 if cone[i] == 2 else 0) + (1 if ball[i] else 0)
    held = 0
    for j in range(pairs):
        held += 1 if fixed[j] != 0 else 0
    rows_held = np.empty(held, dtype=np.int64)
    q = 0
    for j in range(pairs):
        if fixed[j] != 0:
            rows_held[q] = j
            q += 1
    x = np.empty(d)
    x[:] = y
    P = np.empty((n, 3))
    finger_forces(x, a0, al, tau0, T, P)
    r = level_excess(P, f, ct, st, w)
    lam = np.full(rows, 1.0 / max(rows, 1))
    mu = np.zeros(held)
    G, dr, value = np.empty((rows, d)), np.empty(rows), np.empty(rows)
    hess = np.empty((d, d))
    size = d + 1 + rows + held
    J = np.empty((size, size))
    R = np.empty(size)
    x_new, lam_new, mu_new = np.empty(d), np.empty(rows), np.empty(held)

    def residuals(x, r, lam, mu, R):  # (stationarity in y and r, rows, held box rows)
        ok = constraint_rows(
            x, r, a0, al, tau0, T, f, ct, st, w, cone, ball, lam, G, dr, value, hess
        )
        for p in range(d):
            s = 0.0
            for c in range(rows):
                s += lam[c] * G[c, p]
            for h in range(held):
                j = rows_held[h]
                s += mu[h] * fixed[j] * box[j, p]
            R[p] = s
        s = 1.0
        for c in range(rows):
            s += lam[c] * dr[c]
        R[d] = s
        for c in range(rows):
            R[d + 1 + c] = value[c]
        for h in range(held):
            j = rows_held[h]
            v = 0.0
            for p in range(d):
                v += box[j, p] * x[p]
            R[d + 1 + rows + h] = fixed[j] * v - K
        largest = 0.0
        for p in range(size):
            largest = max(largest, abs(R[p]))
        return ok, largest

    ok, residual = residuals(x, r, lam, mu, R)
    if not ok:
        return -inf, 0.0, False
    for _ in range(20):
        if residual <= 1e-15:
            break
        J[:, :] = 0.0
        for p in range(d):
            for q in range(d):
                J[p, q] = hess[p, q]
        for c in range(rows):
            row = d + 1 + c
            for p in range(d):
                J[p, row] = J[row, p] = G[c, p]
            J[d, row] = J[row, d] = dr[c]
        for h in range(held):
            row = d + 1 + rows + h
            j = rows_held[h]
            for p in range(d):
                J[p, row] = J[row, p] = fixed[j] * box[j, p]
        step = np.empty(size)
        for p in range(size):
            step[p] = -R[p]
        J_copy = J.copy()
        if not lu_solve(J_copy, step):  # singular: degenerate sets, the least-squares step
            step = np.linalg.lstsq(J, -R)[0]
        s = 1.0
        R_new = np.empty(size)
        for _ in range(30):
            for p in range(d):
                x_new[p] = x[p] + s * step[p]
            r_new = r + s * step[d]
            for c in range(rows):
                lam_new[c] = lam[c] + s * step[d + 1 + c]
            for h in range(held):
                mu_new[h] = mu[h] + s * step[d + 1 + rows + h]
            ok, new = residuals(x_new, r_new, lam_new, mu_new, R_new)
            if ok and new < residual:
                break
            s *= 0.5
        else:
            break
        x[:], r, lam[:], mu[:], R[:], residual = x_new, r_new, lam_new, mu_new, R_new, new
    constraint_rows(x, r, a0, al, tau0, T, f, ct, st, w, cone, ball, lam, G, dr, value, hess)
    largest = 0.0
    outside, side = 0.0, -1
    for j in range(pairs):
        v = 0.0
        for p in range(d):
            v += box[j, p] * x[p]
        largest = max(largest, abs(v))
        if fixed[j] == 0 and abs(v) - K > 1e-12 * K and abs(v) - K > outside:
            outside, side = abs(v) - K, j
    if largest <= K * (1.0 + 1e-12):
        # (rows held at K end there to rounding: shrunk onto the box, the forces move
        # by 1e-12 of the load)
        shrink = min(1.0, K / largest) if largest > 0.0 else 1.0
        for p in range(d):
            y[p] = x[p] * shrink
    finger_forces(x, a0, al, tau0, T, P)
    # the multipliers' certificate, in finger frames, projected onto the dual cones
    z = np.zeros((n, 3))
    limit = 0.0
    c = 0
    for i in range(n):
        if cone[i] == 1:
            weight = max(lam[c], 0.0)
            radius = sqrt(P[i, 1] ** 2 + P[i, 2] ** 2)
            z[i, 0] -= weight * st
            z[i, 1] += weight * ct * P[i, 1] / radius
            z[i, 2] += weight * ct * P[i, 2] / radius
            c += 1
        elif cone[i] == 2:
            # z = (-st y0, ct y1, ct y2) is polar to the level's cone iff y0 >= |(y1, y2)|
            y0, y1, y2 = lam[c], lam[c + 1], lam[c + 2]
            radius = sqrt(y1 * y1 + y2 * y2)
            if radius > y0:  # the nearest point of the cone y0 >= |y|
                if radius <= -y0:
                    y0 = y1 = y2 = 0.0
                else:
                    half = 0.5 * (y0 + radius)
                    y0, y1, y2 = half, half * y1 / radius, half * y2 / radius
            z[i, 0] -= st * y0
            z[i, 1] += ct * y1
            z[i, 2] += ct * y2
            c += 3
        if ball[i]:
            weight = max(lam[c], 0.0)
            radius = sqrt(P[i, 0] ** 2 + P[i, 1] ** 2 + P[i, 2] ** 2)
            for q in range(3):
                z[i, q] += weight * P[i, q] / radius
            limit += weight * f
            c += 1
    # the box's multipliers: c = sum A' z = -sum_held mu_h s_j b_j, so mu_j = -mu_h s_j
    signed = np.zeros(pairs)
    for h in range(held):
        j = rows_held[h]
        signed[j] = -max(mu[h], 0.0) * fixed[j]
    value, share = dual_bound(z, limit, a0, al, tau0, T, box, K, signed)
    # the member of the sets whose multiplier has the wrong sign most (a finger pulled to
    # the level, a box row pulled off the box) is dropped for the next pass, or a box row
    # polished past K is held there
    worst, drop = 0.0, -1
    scale = 0.0
    for c in range(rows):
        scale = max(scale, abs(lam[c]))
    c = 0
    for i in range(n):
        if cone[i] == 1:
            if lam[c] < worst:
                worst, drop = lam[c], i
            c += 1
        elif cone[i] == 2:
            c += 3
        if ball[i]:
            if lam[c] < worst:
                worst, drop = lam[c], n + i
            c += 1
    for h in range(held):
        if mu[h] < worst:
            worst, drop = mu[h], 2 * n + rows_held[h]
    changed = False
    if side >= 0:  # every box row polished past K is held there next
        for j in range(pairs):
            v = 0.0
            for p in range(d):
                v += box[j, p] * x[p]
            if fixed[j] == 0 and abs(v) - K > 1e-12 * K:
                fixed[j] = 1 if v > 0 else -1
        changed = True
    elif worst < -1e-9 * scale:
        changed = True
        if drop < n:
            cone[drop] = 0
        elif drop < 2 * n:
            ball[drop - n] = False
        else:
            fixed[drop - 2 * n] = 0
    return value, share, changed


@kernel
def dual_bound(z, limit, a0, al, tau0, T, box, K, mu):
    """L = sum_i z_i . F_i - limit + min over the box of c . y, c = sum_i A_i' z_i (finger
    frames), and the box term's share of it. For any mu, c . y = (c - B' mu) . y + mu . B y
    >= -sqrt(m) K |c - B' mu| - K |mu|_1 on the box |B y|_inf <= K (B's columns are
    orthonormal: |y| = |B y| <= sqrt(m) K): mu is the box's multipliers, and where they are
    exact the first term vanishes."""
    n, d = al.shape
    value = -limit
    total = limit
    for i in range(n):
        term = z[i, 0] * a0[i] + z[i, 1] * tau0[i, 0] + z[i, 2] * tau0[i, 1]
        value += term
        total += abs(term)
    rest = 0.0
    for p in range(d):
        c = 0.0
        for i in range(n):
            c += z[i, 0] * al[i, p] + z[i, 1] * T[i, 0, p] + z[i, 2] * T[i, 1, p]
        for j in range(box.shape[0]):
            c -= box[j, p] * mu[j]
        rest += c * c
    pairs = box.shape[0]
    term = K * sqrt(pairs) * sqrt(rest)
    for j in range(pairs):
        term += K * abs(mu[j])
    return value - term, term / max(total + term, 1e-300)
