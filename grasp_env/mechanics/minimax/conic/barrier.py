"""The cone problem at a level t by the log-barrier method, and the certificate of its duals
(weak duality, docs/solver.md "Any number of contacts")."""

from __future__ import annotations

from math import inf, log, pi, sqrt

import numpy as np

from .codes import (
    CENTRED,
    GROWTH,
    LEVEL_GAP,
    LEVEL_GAP_CAREFUL,
    NEWTON_STEPS,
    POLISH_FROM,
    STAGES,
    STALLED,
    kernel,
)
from .frames import cholesky_solve, finger_forces, level_excess


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
def centre(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, limit):
    """Newton's method on tb r + barrier from the strictly feasible x, in place, to a
    Newton decrement of 1e-10, in at most ``limit`` steps; returns the steps taken (-1 if a
    step failed)."""
    d = x.shape[0]
    g = np.empty(d)
    H = np.empty((d, d))
    trial = np.empty(d)
    dx = np.empty(d)
    diag = np.empty(d)
    for step in range(limit):
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
        if not decrement > CENTRED:
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
    return limit


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


@kernel
def level(t, w, k, x, a0, al, tau0, T, box, K, f, decide, careful):
    """Solve the cone problem at level t from k (inside the box) by the barrier method.

    k moves to the best point met, x = (k, r) holds the last barrier point. Returns
    (upper, lower, share, tb): v(t) <= upper (attained by k), v(t) >= lower (certified),
    and the last barrier parameter. With decide, it stops as soon as the sign of v(t) is
    known (a better grip: upper < 0; a proof that none holds at t: lower > 0); otherwise
    when the bounds are within LEVEL_GAP of each other and a centring that stalls (STALLED
    Newton steps) ends the level; careful: within LEVEL_GAP_CAREFUL, no level cut short.
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
    limit = NEWTON_STEPS if decide or careful else STALLED
    gap = LEVEL_GAP_CAREFUL if careful else LEVEL_GAP
    for _ in range(STAGES):
        steps = centre(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, limit)
        if steps < 0:
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
        if not (decide or careful) and steps >= limit:
            break  # stalled (Dinkelbach's next level needs only the point: upper's k)
        if upper - lower <= gap * abs(upper) or tb > POLISH_FROM:
            break  # (beyond POLISH_FROM the barrier's duals lose digits: polish() takes over)
        tb *= GROWTH
    return upper, lower, share, tb
