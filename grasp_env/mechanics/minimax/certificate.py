"""Dual certificates (weak duality): L(t) > 0 proves that no k in the box has every friction
angle <= t within the force limits; see the package doc, stage 2.
"""

from __future__ import annotations

from math import cos, inf, sin, sqrt

import numpy as np

from .fingers import angle_arrays, apex_columns, evaluate, force_derivatives
from .jit import inline, kernel
from .linalg import (
    bordered_least_squares,
    lu_solve,
    stack_copy,
    stack_empty,
    stack_large,
    stack_zeros,
)


@inline
def dual_vectors(al, T, S, R, Q, ct, st, lg, direction, z, u, w):
    """Smooth fingers' dual vectors at the angle (ct, st) into z; w = sum A_i' (z_i + u_i)."""
    n, m = al.shape
    for i in range(n):
        if S[i]:
            z[i, 0] = -lg[i] * st
            z[i, 1] = lg[i] * ct * direction[i, 0]
            z[i, 2] = lg[i] * ct * direction[i, 1]
    for j in range(m):
        s = 0.0
        for i in range(n):
            if S[i] or R[i]:
                s += z[i, 0] * al[i, j] + z[i, 1] * T[i, 0, j] + z[i, 2] * T[i, 1, j]
            if Q[i]:
                s += u[i, 0] * al[i, j] + u[i, 1] * T[i, 0, j] + u[i, 2] * T[i, 1, j]
        w[j] = s


@inline
def unit_into(y, i, c0, c1):
    """y[i] = (c0, c1) / |(c0, c1)|, or (1, 0) for the zero vector (as atan2(0, 0) = 0)."""
    r = sqrt(c0 * c0 + c1 * c1)
    if r > 0.0:
        y[i, 0] = c0 / r
        y[i, 1] = c1 / r
    else:
        y[i, 0] = 1.0
        y[i, 1] = 0.0


@kernel
def certify(a0, al, tau0, T, K, f, a, tau, rho, t_low, S, R, Q, fixed, lam, eta, nu):
    """Evaluate the weak-duality certificate L(t_low) from the KKT multipliers at a point k
    (a, tau, rho: its normal and tangential components, as :func:`~.fingers.evaluate` gives
    them; every caller has just evaluated them).

    For any z_i in the polar cone of {P : theta(P) <= t} (z = l (cos t y b - sin t n),
    l >= 0, |y| <= 1) and any u_i: every k in the box with all theta_i <= t and
    |P_i| <= f satisfies sum z_i.P_i(k) + sum (u_i.P_i(k) - |u_i| f) <= 0, so
        L(t) = sum z_i.F_i + sum (u_i.F_i - |u_i| f) - K ||sum A_i' (z_i + u_i)||_1 > 0
    proves that no such k exists, i.e. the optimum is > t (>= t for L = 0).
    The KKT multipliers at the optimum t* give L(t*) = 0 only up to rounding, so the dual
    point is moved to t_low < t*: the cone directions rotate to t_low and minimum-norm
    corrections of (l_i, angle of y_i, eta_i, u_i) zero the free components of the L1 term
    again (Gauss-Newton: the angles enter non-linearly); what remains is about
    (t* - t_low) sum l_i |P_i| > 0, and the corrections cost only second-order terms
    (a dual direction off by d loses about |u_i| f d^2 / 2).
    Returns (L, box_share) where box_share is the box term's share of the certificate.
    """
    n, m = al.shape
    ct, st = cos(t_low), sin(t_low)
    z = stack_zeros((n, 3))  # dual vectors in the finger frames (normal, b, c)
    lg = stack_zeros(n)
    # each smooth finger's tangential dual direction y_i, kept as a unit vector (not an
    # angle: its corrections need no trigonometry)
    direction = stack_zeros((n, 2))
    u = stack_zeros((n, 3))  # force-limit duals nu_i P_i / |P_i|
    for i in range(n):
        Pn = sqrt(a[i] ** 2 + rho[i] ** 2)
        if S[i]:
            lg[i] = max(0.0, lam[i]) / Pn
            unit_into(direction, i, tau[i, 0], tau[i, 1])
        if Q[i]:
            scale_u = max(0.0, nu[i]) / Pn
            u[i, 0] = a[i] * scale_u
            u[i, 1] = tau[i, 0] * scale_u
            u[i, 2] = tau[i, 1] * scale_u
        if R[i]:
            for c in range(3):
                z[i, c] = eta[i, c]
    # A released finger whose dual lies on the polar cone's boundary (released and at the
    # maximum angle at once) is corrected like the smooth fingers, along that boundary, so
    # that the correction cannot push it out of the cone.
    Sm = stack_copy(S)
    Rm = stack_copy(R)
    cot = ct / max(st, 1e-300)
    for i in range(n):
        if R[i]:
            x0 = -z[i, 0]
            r = sqrt(z[i, 1] ** 2 + z[i, 2] ** 2)
            if x0 > 0.0 and r >= cot * x0 * (1.0 - 1e-6):
                Sm[i] = True
                Rm[i] = False
                lg[i] = x0 / st
                unit_into(direction, i, z[i, 1], z[i, 2])
    w = stack_zeros(m)
    free = stack_empty(m, dtype=np.int64)
    nf = 0
    for j in range(m):
        if fixed[j] == 0:
            free[nf] = j
            nf += 1
    ncols = 0
    for i in range(n):
        ncols += 2 * Sm[i] + 3 * Rm[i] + 3 * Q[i]
    J = stack_large((m, 20))
    G = stack_empty((m, m))
    y = stack_empty(m)
    for _ in range(4 if nf > 0 and ncols > 0 else 0):
        # minimum-norm correction J dc = -w_free
        dual_vectors(al, T, Sm, Rm, Q, ct, st, lg, direction, z, u, w)
        col = 0
        for i in range(n):
            if Sm[i]:
                cp, sp = direction[i, 0], direction[i, 1]
                for p in range(nf):
                    j = free[p]
                    J[p, col] = -st * al[i, j] + ct * (cp * T[i, 0, j] + sp * T[i, 1, j])
                    J[p, col + 1] = lg[i] * ct * (cp * T[i, 1, j] - sp * T[i, 0, j])
                col += 2
            for _twice in range(int(Rm[i]) + int(Q[i])):  # z_i of a released finger, then u_i
                for c in range(3):
                    for p in range(nf):
                        j = free[p]
                        J[p, col] = al[i, j] if c == 0 else T[i, c - 1, j]
                    col += 1
        big = 0.0
        residual = 0.0
        for p in range(nf):
            for q in range(nf):
                s = 0.0
                for c in range(ncols):
                    s += J[p, c] * J[q, c]
                G[p, q] = s
            big = max(big, G[p, p])
            y[p] = -w[free[p]]
            residual = max(residual, abs(y[p]))
        if K * residual <= 1e-15:
            # the box term K |w| is then 1e-4 of the certificate's margin, about
            # (t* - t_low) sum l_i |P_i| >= 1e-11 (sum l_i |P_i| = sum lam_i = 1): further
            # corrections, at rounding level, would not change the verdict
            break
        for p in range(nf):
            G[p, p] += 1e-12 * big
        if not lu_solve(G, y, nf):
            break
        col = 0
        for i in range(n):
            if Sm[i]:
                d_l = 0.0
                d_p = 0.0
                for p in range(nf):
                    d_l += J[p, col] * y[p]
                    d_p += J[p, col + 1] * y[p]
                lg[i] = max(0.0, lg[i] + d_l)
                # turned by d_p: a step d_p across it, normalised (an angle of atan(d_p))
                c0, c1 = direction[i, 0], direction[i, 1]
                unit_into(direction, i, c0 - d_p * c1, c1 + d_p * c0)
                col += 2
            if Rm[i]:
                for c in range(3):
                    for p in range(nf):
                        z[i, c] += J[p, col] * y[p]
                    col += 1
            if Q[i]:
                for c in range(3):
                    for p in range(nf):
                        u[i, c] += J[p, col] * y[p]
                    col += 1
    # released fingers' duals must lie in the polar cone |z_b,c| <= cot(t) (-z_n)
    kappa = ct / max(st, 1e-300)
    for i in range(n):
        if Rm[i]:
            x0 = -z[i, 0]
            r = sqrt(z[i, 1] ** 2 + z[i, 2] ** 2)
            if r > kappa * x0:
                if kappa * r <= -x0:
                    z[i, 0] = 0.0
                    z[i, 1] = 0.0
                    z[i, 2] = 0.0
                else:  # nearest point of the boundary ray (1, kappa) in (-z_n, |z_bc|)
                    s = (x0 + kappa * r) / (1.0 + kappa * kappa)
                    z[i, 0] = -s
                    z[i, 1] *= kappa * s / r
                    z[i, 2] *= kappa * s / r
    dual_vectors(al, T, Sm, Rm, Q, ct, st, lg, direction, z, u, w)
    value = 0.0
    size = 0.0  # the terms' magnitudes, for the box share
    for i in range(n):
        if Sm[i] or Rm[i]:
            term = z[i, 0] * a0[i] + z[i, 1] * tau0[i, 0] + z[i, 2] * tau0[i, 1]
            value += term
            size += abs(term)
        if Q[i]:
            un = sqrt(u[i, 0] ** 2 + u[i, 1] ** 2 + u[i, 2] ** 2)
            term = u[i, 0] * a0[i] + u[i, 1] * tau0[i, 0] + u[i, 2] * tau0[i, 1] - un * f
            value += term
            size += abs(term)
    box = 0.0
    for j in range(m):
        box += K * abs(w[j])
    return value - box, box / max(size + box, 1e-300)


@kernel
def dual_value(a0, al, tau0, T, K, f, t, z, nuv, nus):
    """The certificate L(t) of :func:`certify` for explicit dual vectors (finger frames).

    z_i is first projected onto the polar cone of {theta <= t} and nuv_i onto the ball
    |nuv_i| <= nus_i, so the value is a valid bound whatever the input.
    """
    n, m = al.shape
    ct, st = cos(t), sin(t)
    zz = stack_empty((n, 3))
    vv = stack_empty((n, 3))
    for i in range(n):
        # polar cone of {|tau| <= tan(t) a}: |z_bc| <= cot(t) (-z_n), in coordinates
        # (x0, r) = (-z_n, |z_bc|) the cone r <= kappa x0 with kappa = cot t
        x0 = -z[i, 0]
        r = sqrt(z[i, 1] ** 2 + z[i, 2] ** 2)
        zz[i, 0], zz[i, 1], zz[i, 2] = z[i, 0], z[i, 1], z[i, 2]
        if r * st > ct * x0:
            if ct * r <= -st * x0:
                zz[i, 0] = zz[i, 1] = zz[i, 2] = 0.0
            else:
                # nearest point of the boundary ray (st, ct) of the (x0, r) plane
                s = x0 * st + r * ct
                zz[i, 0] = -s * st
                zz[i, 1] = z[i, 1] * (s * ct / r)
                zz[i, 2] = z[i, 2] * (s * ct / r)
        r = sqrt(nuv[i, 0] ** 2 + nuv[i, 1] ** 2 + nuv[i, 2] ** 2)
        shrink = 1.0 if r <= nus[i] else nus[i] / r
        for c in range(3):
            vv[i, c] = nuv[i, c] * shrink
    value = 0.0
    size = 0.0
    for i in range(n):
        term = zz[i, 0] * a0[i] + zz[i, 1] * tau0[i, 0] + zz[i, 2] * tau0[i, 1]
        if f < inf:
            term += vv[i, 0] * a0[i] + vv[i, 1] * tau0[i, 0] + vv[i, 2] * tau0[i, 1]
            term -= nus[i] * f
        value += term
        size += abs(term)
    box = 0.0
    for j in range(m):
        w = 0.0
        for i in range(n):
            w += zz[i, 0] * al[i, j] + zz[i, 1] * T[i, 0, j] + zz[i, 2] * T[i, 1, j]
            if f < inf:
                w += vv[i, 0] * al[i, j] + vv[i, 1] * T[i, 0, j] + vv[i, 2] * T[i, 1, j]
        box += K * abs(w)
    return value - box, box / max(size + box, 1e-300)


@kernel
def force_certificate(a0, al, tau0, T, K, f, k):
    """Certificate that no k in the box has every |P_i| <= f, from the point k that
    minimises the largest excess max_i |P_i| - f: with weights nu_i >= 0 (sum 1) on the
    fingers at that maximum and v_i = P_i / |P_i|, every such k would satisfy
    sum nu_i (v_i . P_i(k) - f) <= 0, so
        L = sum nu_i (v_i . F_i - f) - K || sum nu_i A_i' v_i ||_1 > 0
    proves the limits infeasible. The nu_i are the least-squares stationarity multipliers."""
    n, m = al.shape
    a, tau, rho, theta = angle_arrays(n)
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    P = stack_empty(n)
    worst = 0.0
    for i in range(n):
        P[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
        worst = max(worst, P[i])
    Q = stack_zeros(n, dtype=np.bool_)
    fixed = stack_zeros(m, dtype=np.int64)
    for i in range(n):
        Q[i] = P[i] >= worst - 1e-6 * f
    for j in range(m):
        fixed[j] = 1 if k[j] >= K * (1.0 - 1e-6) else (-1 if k[j] <= -K * (1.0 - 1e-6) else 0)
    # least-squares multipliers: the force gradients take the place of the angles'
    grads = stack_zeros((n, m))
    Hd = stack_zeros((m, m))
    for i in range(n):
        if Q[i]:
            force_derivatives(i, 0.0, a, tau, al, T, grads[i], Hd)
    nc = 0
    for i in range(n):
        nc += Q[i]
    A = stack_zeros((nc + 1, nc + 1))
    b = stack_zeros(nc + 1)
    p = 0
    for i in range(n):
        if Q[i]:
            q = 0
            for i2 in range(n):
                if Q[i2]:
                    s = 0.0
                    for j in range(m):
                        if fixed[j] == 0:
                            s += grads[i, j] * grads[i2, j]
                    A[p, q] = s
                    q += 1
            A[p, p] += 1e-12
            A[p, nc] = 1.0
            A[nc, p] = 1.0
            p += 1
    b[nc] = 1.0
    if not lu_solve(A, b, nc + 1):
        return -1.0
    value = 0.0
    w = stack_zeros(m)
    p = 0
    for i in range(n):
        if Q[i]:
            nu = max(0.0, b[p])
            p += 1
            v0, v1, v2 = a[i] / P[i], tau[i, 0] / P[i], tau[i, 1] / P[i]
            value += nu * (v0 * a0[i] + v1 * tau0[i, 0] + v2 * tau0[i, 1] - f)
            for j in range(m):
                w[j] += nu * (v0 * al[i, j] + v1 * T[i, 0, j] + v2 * T[i, 1, j])
    for j in range(m):
        value -= K * abs(w[j])
    return value


@kernel
def certify_min_slack(a0, al, tau0, T, K, f, t, wts, x, tol):
    """The certificate L(t) (:func:`certify`) at x = (k, s), the minimiser of the cone
    problem v(t) = min s (see :func:`fallback`) with s > 0.

    Its sets are read off x (within ``tol``) and its multipliers are the least-squares
    stationarity multipliers there (sum l_i w_i = 1), so that certify's correction starts
    from the dual of v(t) and L(t) is about v(t) > 0: the barrier's own duals are spoilt by
    rounding (1 / slack) near the optimum, its primal point is not. Returns (L, box_share).
    """
    n, m = al.shape
    a, tau, rho, theta = angle_arrays(n)
    k = stack_copy(x[:m])
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    ct, st = cos(t), sin(t)
    S = stack_zeros(n, dtype=np.bool_)
    R = stack_zeros(n, dtype=np.bool_)
    Q = stack_zeros(n, dtype=np.bool_)
    fixed = stack_zeros(m, dtype=np.int64)
    P = stack_empty(n)
    big = 0.0
    for i in range(n):
        P[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
        big = max(big, P[i])
    for i in range(n):
        # a finger at the cone's apex has a dual anywhere in the polar cone (3 unknowns)
        R[i] = P[i] < 1e-6 * big
        S[i] = not R[i] and (ct * rho[i] - st * a[i]) / wts[i] >= x[m] - tol
        Q[i] = f < inf and P[i] >= f * (1.0 - tol)
    for j in range(m):
        fixed[j] = 1 if k[j] >= K * (1.0 - tol) else (-1 if k[j] <= -K * (1.0 - tol) else 0)
    # columns: d(z_i . A_i)/d l_i for the cones, A_i for the apex fingers' z_i, v_i . A_i
    # for the force limits (free rows only)
    cols = stack_large((m, 4 * n))
    nc = 0
    for i in range(n):
        if S[i]:
            u0 = tau[i, 0] / rho[i] if rho[i] > 0.0 else 1.0
            u1 = tau[i, 1] / rho[i] if rho[i] > 0.0 else 0.0
            for j in range(m):
                if fixed[j] == 0:
                    cols[j, nc] = -st * al[i, j] + ct * (u0 * T[i, 0, j] + u1 * T[i, 1, j])
            nc += 1
    ns = nc
    nc = apex_columns(al, T, R, fixed, cols, nc)
    for i in range(n):
        if Q[i]:
            for j in range(m):
                if fixed[j] == 0:
                    cols[j, nc] = (a[i] * al[i, j] + tau[i, 0] * T[i, 0, j]) / P[i]
                    cols[j, nc] += tau[i, 1] * T[i, 1, j] / P[i]
            nc += 1
    if ns == 0:
        return -1.0, 0.0
    border = stack_empty(n)
    c = 0
    for i in range(n):
        if S[i]:
            border[c] = wts[i]
            c += 1
    b = stack_empty(nc + 1)
    if not bordered_least_squares(cols, m, nc, border, ns, b):  # (sum l_i w_i = 1)
        return -1.0, 0.0
    lam = stack_zeros(n)
    nu = stack_zeros(n)
    eta = stack_zeros((n, 3))
    c = 0
    for i in range(n):
        if S[i]:
            lam[i] = b[c] * P[i]  # certify takes l_i = lam_i / |P_i|
            c += 1
    for i in range(n):
        if R[i]:
            for q in range(3):
                eta[i, q] = b[c]
                c += 1
    for i in range(n):
        if Q[i]:
            nu[i] = b[c]
            c += 1
    return certify(a0, al, tau0, T, K, f, a, tau, rho, t, S, R, Q, fixed, lam, eta, nu)
