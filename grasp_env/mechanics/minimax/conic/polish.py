"""Newton's method on the cone problem's KKT system, on the sets read off a barrier point:
the multipliers of the certificate where the barrier's own duals are rounding noise."""

from __future__ import annotations

from math import inf, sqrt

import numpy as np

from ..linalg import lu_solve
from .barrier import dual_bound
from .codes import kernel
from .frames import finger_forces, level_excess


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
        if not lu_solve(J_copy, step, size):  # singular: degenerate sets, the least-squares step
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
