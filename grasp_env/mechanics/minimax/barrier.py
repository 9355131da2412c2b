"""The robust fallback: the convex cone problem at a fixed t solved by a log-barrier method,
Dinkelbach iterations on t, and the certified bisection on t.
"""

from __future__ import annotations

from math import cos, inf, log, pi, sin, sqrt
from typing import NamedTuple

import numpy as np

from .certificate import certify_min_slack, dual_value, force_certificate
from .codes import GAP_TOL, INTERIOR, NOT_PUSHING
from .fingers import angle_arrays, evaluate
from .jit import kernel
from .linalg import cholesky_inverse, copy_into, stack_copy, stack_empty


class ConeProblem(NamedTuple):
    """v(t) = min s over (k, s): the finger cones cos t |tau_i| <= sin t a_i + weights_i s
    with the force limits hard, or (phase_one) the force limits |P_i| <= f + s alone."""

    t: float
    weights: np.ndarray
    phase_one: bool


@kernel
def barrier_terms(x, a0, al, tau0, T, K, f, problem, g, H, tb, derivatives):
    """Value, gradient g and Hessian H of  tb * s + barrier  at x = (k, s); inf if outside.

    With derivatives False only the value is computed (line searches). The problem
    (:class:`ConeProblem`) is the finger cones ct |tau_i| <= st a_i + w_i s with the force
    limits hard, or in phase one the force limits |P_i| <= f + s alone.
    """
    n, m = al.shape
    ct, st, wts = cos(problem.t), sin(problem.t), problem.weights
    cones = not problem.phase_one
    dim = m + 1
    s = x[m]
    val = tb * s
    if derivatives:
        for p in range(dim):
            g[p] = 0.0
            for q in range(dim):
                H[p, q] = 0.0
        g[m] = tb
    for j in range(m):
        up, lo = K - x[j], K + x[j]
        if up <= 0.0 or lo <= 0.0:
            return inf
        val -= log(up) + log(lo)
        if not derivatives:
            continue
        g[j] += 1.0 / up - 1.0 / lo
        H[j, j] += 1.0 / (up * up) + 1.0 / (lo * lo)
    dsig = stack_empty(dim)
    jv = stack_empty((3, dim))
    v = stack_empty(3)
    for i in range(n):
        a = a0[i]
        t0 = tau0[i, 0]
        t1 = tau0[i, 1]
        for j in range(m):
            a += al[i, j] * x[j]
            t0 += T[i, 0, j] * x[j]
            t1 += T[i, 1, j] * x[j]
        for kind in range(2):
            # kind 0: finger cone (unless phase one); kind 1: force ball (if a limit is set)
            if kind == 0 and cones:
                sig = st * a + wts[i] * s
                nv = 2
                v[0], v[1] = ct * t0, ct * t1
                for j in range(m):
                    dsig[j] = st * al[i, j]
                    jv[0, j] = ct * T[i, 0, j]
                    jv[1, j] = ct * T[i, 1, j]
                dsig[m] = wts[i]
                jv[0, m] = 0.0
                jv[1, m] = 0.0
            elif kind == 1 and f < inf:
                sig = f + (0.0 if cones else s)
                nv = 3
                v[0], v[1], v[2] = a, t0, t1
                for j in range(m):
                    dsig[j] = 0.0
                    jv[0, j] = al[i, j]
                    jv[1, j] = T[i, 0, j]
                    jv[2, j] = T[i, 1, j]
                dsig[m] = 0.0 if cones else 1.0
                jv[0, m] = 0.0
                jv[1, m] = 0.0
                jv[2, m] = 0.0
            else:
                continue
            vv = 0.0
            for c in range(nv):
                vv += v[c] * v[c]
            D = sig * sig - vv
            if sig <= 0.0 or D <= 0.0:
                return inf
            val -= log(D)
            if not derivatives:
                continue
            # grad(-log D) = -(2 sig dsig - 2 Jv' v) / D
            for p in range(dim):
                jtv = 0.0
                for c in range(nv):
                    jtv += jv[c, p] * v[c]
                gd = 2.0 * (sig * dsig[p] - jtv)
                g[p] -= gd / D
                for q in range(p + 1):
                    jtv_q = 0.0
                    jj = 0.0
                    for c in range(nv):
                        jtv_q += jv[c, q] * v[c]
                        jj += jv[c, p] * jv[c, q]
                    gq = 2.0 * (sig * dsig[q] - jtv_q)
                    h = 2.0 * (jj - dsig[p] * dsig[q]) / D + gd * gq / (D * D)
                    H[p, q] += h
                    if q != p:
                        H[q, p] += h
    return val


@kernel
def barrier_solve(a0, al, tau0, T, K, f, problem, x, gap, stop_below, tb0):
    """Path-following log-barrier method for  min s  over ``problem`` (a ConeProblem).

    x = (k, s) must be strictly feasible on entry; on exit it is the final iterate and the
    returned tb is the last barrier weight (duality gap about nu / tb). The weight starts
    at tb0 (large when x is a warm start near the optimum). Stops early once s < stop_below
    (phase I: a strictly feasible point is all that is needed).
    """
    n, m = al.shape
    dim = m + 1
    g = stack_empty(dim)
    H = stack_empty((dim, dim))
    Hinv = stack_empty((dim, dim))
    dx = stack_empty(dim)
    xt = stack_empty(dim)
    Lc = stack_empty((dim, dim))
    Lic = stack_empty((dim, dim))
    nu_b = 2.0 * m + 2.0 * n * (1 + (f < inf))
    tb = tb0
    for _ in range(60):
        for _ in range(50):
            val = barrier_terms(x, a0, al, tau0, T, K, f, problem, g, H, tb, True)
            if not cholesky_inverse(H, dim, Hinv, Lc, Lic):
                for p in range(dim):
                    H[p, p] += 1e-12 * (1.0 + abs(H[p, p]))
                if not cholesky_inverse(H, dim, Hinv, Lc, Lic):
                    return tb
            dec = 0.0
            for p in range(dim):
                s = 0.0
                for q in range(dim):
                    s -= Hinv[p, q] * g[q]
                dx[p] = s
                dec -= s * g[p]
            # dec = lambda^2, the squared Newton decrement: centred enough at 1e-10 (or 1e-2
            # while the barrier weight is still growing)
            if dec < 1e-10 or (dec < 1e-2 and nu_b / tb > gap):
                break
            alpha = 1.0
            for _ in range(40):
                for p in range(dim):
                    xt[p] = x[p] + alpha * dx[p]
                vt = barrier_terms(xt, a0, al, tau0, T, K, f, problem, g, H, tb, False)
                # in the quadratic region (lambda < 0.01) any feasible full step is taken:
                # the value's rounding there exceeds the predicted decrease
                if vt <= val - 0.25 * alpha * dec or (dec < 1e-4 and vt < inf):
                    break
                alpha *= 0.5
            else:
                break
            for p in range(dim):
                x[p] = xt[p]
            if x[m] < stop_below:
                return tb
        if nu_b / tb < gap:
            return tb
        tb *= 10.0
    return tb


@kernel
def barrier_duals(x, a0, al, tau0, T, K, f, t, wts, tb, z, nuv, nus):
    """Dual vectors of the centred barrier point x (phase II) for :func:`dual_value`.

    The barrier -log(sig^2 - |v|^2) of a cone |v| <= sig has the dual pair
    (2 sig, -2 v) / (tb (sig^2 - |v|^2)); in the finger frame that is
    z_i = (-l st, -ct l_v) for the finger cones and (nus, -l_v) for the force balls.
    """
    n, m = al.shape
    ct, st = cos(t), sin(t)
    s = x[m]
    for i in range(n):
        a = a0[i]
        t0 = tau0[i, 0]
        t1 = tau0[i, 1]
        for j in range(m):
            a += al[i, j] * x[j]
            t0 += T[i, 0, j] * x[j]
            t1 += T[i, 1, j] * x[j]
        sig = st * a + wts[i] * s
        v0, v1 = ct * t0, ct * t1
        D = sig * sig - v0 * v0 - v1 * v1
        lsig = 2.0 * sig / (tb * D)
        z[i, 0] = -lsig * st
        z[i, 1] = ct * 2.0 * v0 / (tb * D)
        z[i, 2] = ct * 2.0 * v1 / (tb * D)
        nus[i] = 0.0
        nuv[i, 0] = nuv[i, 1] = nuv[i, 2] = 0.0
        if f < inf:
            D = f * f - a * a - t0 * t0 - t1 * t1
            nus[i] = 2.0 * f / (tb * D)
            nuv[i, 0] = 2.0 * a / (tb * D)
            nuv[i, 1] = 2.0 * t0 / (tb * D)
            nuv[i, 2] = 2.0 * t1 / (tb * D)


@kernel
def fallback(a0, al, tau0, T, K, f, k, gap, centre):
    """Robust certified minimax: Dinkelbach iterations on t over the convex cone problem.

    At a fixed t < 90 deg, v(t) = min over (k, s) of s subject to ct |tau_i| <= st a_i + w_i s
    (box, force limits) is negative exactly when some k has every theta_i < t; each v(t) is
    solved by the barrier method. From above, t <- max_i theta_i(k_t) with the weights
    w_i = |P_i(k)| of the previous point (Crouzeix-Ferland-Schaible) converges
    superlinearly. Each barrier starts from the best point moved 1% towards a centre of the
    box and the force limits (a point on their boundary would leave Newton's method a
    Hessian too ill-conditioned to move). k (in/out) starts inside the box; centre
    (out) is that centre.
    Returns (t_up, lower, status, box_share); lower < 0 unless NOT_PUSHING is decided.
    """
    n, m = al.shape
    dim = m + 1
    x = stack_empty(dim)
    wts = stack_empty(n)
    wts.fill(1.0)
    z = stack_empty((n, 3))
    nuv = stack_empty((n, 3))
    nus = stack_empty(n)
    a, tau, rho, theta = angle_arrays(n)
    for j in range(m):
        centre[j] = 0.0  # inside the box and (when f is finite) the force limits
    inner = 1.0 - 1e-9
    for j in range(m):
        k[j] = min(K * inner, max(-K * inner, k[j]))
    if f < inf:
        # phase I: min s subject to |P_i| <= f + s, to a centred point
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        excess = -inf
        for i in range(n):
            excess = max(excess, sqrt(a[i] ** 2 + rho[i] ** 2) - f)
        for j in range(m):
            x[j] = k[j]
        x[m] = max(excess, 0.0) + f
        tb = barrier_solve(
            a0, al, tau0, T, K, f, ConeProblem(0.0, wts, True), x, 1e-4 * f, -inf, 1.0 / f
        )
        if x[m] >= -1e-9 * f:
            # the limits may admit no k: converge, then certify (k: the least excess)
            barrier_solve(
                a0, al, tau0, T, K, f, ConeProblem(0.0, wts, True), x, 1e-14 * f, -inf, tb
            )
            for j in range(m):
                k[j] = min(K * inner, max(-K * inner, x[j]))
            if x[m] >= 0.0:
                L = force_certificate(a0, al, tau0, T, K, f, k)
                return pi, (pi / 2 if L > 0.0 else 0.0), NOT_PUSHING, 0.0
        for j in range(m):
            centre[j] = x[j]
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        excess = -inf
        for i in range(n):
            excess = max(excess, sqrt(a[i] ** 2 + rho[i] ** 2) - f)
        if excess > -1e-9 * f:
            copy_into(k, centre, m)
    t_best = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    k_best = stack_copy(k)
    if t_best >= pi / 2:
        # can every finger push? v(pi/2) < 0 iff some k has all a_i > 0; the barrier's
        # duals certify v(pi/2) > 0 once its gap is below v (tried as the gap closes: at a
        # tight gap rounding spoils them)
        for j in range(m):
            x[j] = 0.99 * k[j] + 0.01 * centre[j]
        s0 = -inf
        evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        for i in range(n):
            s0 = max(s0, -a[i])
        x[m] = s0 + 1.0
        tb = 1.0
        L = -1.0
        share = 0.0
        for tight in (1e-3, 1e-5, 1e-7, 1e-9, 1e-11, 1e-13):
            tb = barrier_solve(
                a0, al, tau0, T, K, f, ConeProblem(pi / 2, wts, False), x, tight, -inf, tb
            )
            if x[m] < 0.0:
                break
            barrier_duals(x, a0, al, tau0, T, K, f, pi / 2, wts, tb, z, nuv, nus)
            L, share = dual_value(a0, al, tau0, T, K, f, pi / 2, z, nuv, nus)
            if L > 0.0:
                break
        t_try = evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        if t_try < pi / 2:
            t_best = t_try
            copy_into(k_best, x, m)
        else:
            if t_try < t_best:
                t_best = t_try
                copy_into(k, x, m)
            return t_best, (pi / 2 if L > 0.0 else 0.0), NOT_PUSHING, share
    t = t_best
    for _ in range(40):
        evaluate(k_best, a0, al, tau0, T, a, tau, rho, theta)
        big = 0.0
        for i in range(n):
            wts[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
            big = max(big, wts[i])
        ct, st = cos(t), sin(t)
        for j in range(m):
            x[j] = min(K * inner, max(-K * inner, 0.99 * k_best[j] + 0.01 * centre[j]))
        evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        s0 = -inf
        for i in range(n):
            wts[i] = max(wts[i], 1e-3 * big)
            s0 = max(s0, (ct * rho[i] - st * a[i]) / wts[i])
        x[m] = s0 + 1e-3
        barrier_solve(a0, al, tau0, T, K, f, ConeProblem(t, wts, False), x, gap, -inf, 1e3)
        t_new = evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        if t_new < t_best:
            t_best = t_new
            copy_into(k_best, x, m)
        if not (t_new < t - 0.1 * gap):
            break
        t = t_new
    copy_into(k, k_best, m)
    return t_best, -1.0, INTERIOR, 0.0


@kernel
def bisect(a0, al, tau0, T, K, f, k_best, centre, lo, hi):
    """Bisection on t over the cone problem v(t) (see :func:`fallback`), each step decided
    by the barrier's primal point (v(t) < 0: a better grip) or by a dual certificate
    (:func:`certify_min_slack`: no k reaches t). k_best (in/out) attains hi; each barrier
    starts from it moved 1% towards ``centre`` (see :func:`fallback`); returns the
    bracket (lo, hi, box_share). Steps aim just below hi first, where a near-optimal hi
    needs only one; a step that is decided neither way (rounding, at the last few 1e-10 rad)
    moves the next one down, so lo is always certified and hi always attained.
    """
    n, m = al.shape
    a, tau, rho, theta = angle_arrays(n)
    wts = stack_empty(n)
    x = stack_empty(m + 1)
    share = 0.0
    top = hi  # the next t is below top (above it, steps are undecided or attained)
    inner = 1.0 - 1e-9
    for it in range(80):
        if hi - lo <= 0.5 * GAP_TOL or top <= lo:
            break
        t = max(0.5 * (lo + top), top - (2.0**it) * 1e-10)
        evaluate(k_best, a0, al, tau0, T, a, tau, rho, theta)
        big = 0.0
        for i in range(n):
            wts[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
            big = max(big, wts[i])
        for i in range(n):
            wts[i] = max(wts[i], 1e-3 * big)
        for j in range(m):
            x[j] = min(K * inner, max(-K * inner, 0.99 * k_best[j] + 0.01 * centre[j]))
        evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
        ct, st = cos(t), sin(t)
        s0 = -inf
        for i in range(n):
            s0 = max(s0, (ct * rho[i] - st * a[i]) / wts[i])
        x[m] = s0 + 1e-3
        tb = 1e3
        decided = False
        for tight in (1e-8, 1e-11, 1e-13):
            tb = barrier_solve(
                a0, al, tau0, T, K, f, ConeProblem(t, wts, False), x, tight, -inf, tb
            )
            if x[m] < 0.0:
                t_new = evaluate(x, a0, al, tau0, T, a, tau, rho, theta)
                if t_new < hi:
                    hi = t_new
                    copy_into(k_best, x, m)
                top = min(top, hi)
                decided = True
                break
            for tol in (1e-9, 1e-11, 1e-7):
                L, box = certify_min_slack(a0, al, tau0, T, K, f, t, wts, x, tol)
                if L > 0.0:
                    lo = t
                    share = box
                    decided = True
                    break
            if decided:
                break
        if not decided:
            top = t
    return lo, hi, share
