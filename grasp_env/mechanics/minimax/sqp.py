"""The SQP method that finds the active sets: a line search on max_i theta_i over QP steps
solved by the Goldfarb-Idnani dual active-set method.
"""

from __future__ import annotations

from math import inf, sqrt

import numpy as np

from .fingers import angle_arrays, evaluate, finger_derivatives, force_derivatives
from .jit import inline, kernel
from .linalg import cholesky_inverse, lu_solve, stack_empty, stack_large, stack_zeros, zero


@inline
def merit(k, a0, al, tau0, T, f, penalty, R, a, tau, rho, theta):
    """max theta_i over the fingers not released, plus the penalised force-limit excess."""
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    worst = -inf
    for i in range(al.shape[0]):
        if not R[i]:
            worst = max(worst, theta[i])
        if f < inf:
            excess = sqrt(a[i] ** 2 + rho[i] ** 2) - f
            if excess > 0.0:
                worst += penalty * excess
    return worst


@kernel
def quadprog(Ginv, c, C, b, nc, meq, dim, x, u, GN, M, vec, active, is_active):
    """Goldfarb-Idnani dual active-set method: min 1/2 x'Gx + c'x subject to C x >= b.

    The first ``meq`` rows are equalities C x = b (their rows may be negated in place).
    ``Ginv`` is G^-1 (G positive definite). Fills x and the multipliers u (nc). The active
    set is kept explicitly and the projections are recomputed from it at each step, which
    at these sizes (dim <= 7) is as cheap as updating factorisations and simpler.
    Scratch: GN, M (dim, dim), vec (6, >= max(dim, nc)), active (dim), is_active (nc).
    Returns 0, or a positive code if the constraints are infeasible (or a limit is hit).
    """
    for i in range(dim):
        s = 0.0
        for j in range(dim):
            s -= Ginv[i, j] * c[j]
        x[i] = s
    for i in range(nc):
        u[i] = 0.0
    ua = vec[0]
    r = vec[1]
    y = vec[2]
    z = vec[3]
    cnorm = vec[4]
    sign = vec[5]
    for i in range(nc):
        is_active[i] = False
        sign[i] = 1.0
    q = 0
    for i in range(nc):
        s = 0.0
        for j in range(dim):
            s += C[i, j] * C[i, j]
        cnorm[i] = sqrt(s)
    for _ in range(4 * (nc + dim)):
        p = -1
        worst = 0.0
        for i in range(meq):
            if not is_active[i]:
                p = i
                s = -b[i]
                for j in range(dim):
                    s += C[i, j] * x[j]
                if s > 0.0:  # approach the equality from its violated side
                    b[i] = -b[i]
                    for j in range(dim):
                        C[i, j] = -C[i, j]
                    sign[i] = -1.0
                break
        for i in range(nc if p < 0 else 0):
            if not is_active[i]:
                s = -b[i]
                for j in range(dim):
                    s += C[i, j] * x[j]
                s /= cnorm[i]
                if s < worst - 1e-13 * (1.0 + abs(b[i]) / cnorm[i]):
                    worst = s
                    p = i
        if p < 0:
            for a_ in range(q):
                u[active[a_]] = ua[a_] * sign[active[a_]]
            return 0
        up = 0.0
        for _inner in range(2 * dim + 2):
            for i in range(dim):
                s = 0.0
                for j in range(dim):
                    s += Ginv[i, j] * C[p, j]
                y[i] = s
            for a_ in range(q):
                row = active[a_]
                for i in range(dim):
                    s = 0.0
                    for j in range(dim):
                        s += Ginv[i, j] * C[row, j]
                    GN[i, a_] = s
            for a_ in range(q):
                s = 0.0
                for j in range(dim):
                    s += C[active[a_], j] * y[j]
                r[a_] = s
                for b_ in range(q):
                    s = 0.0
                    for j in range(dim):
                        s += C[active[a_], j] * GN[j, b_]
                    M[a_, b_] = s
            if q > 0 and not lu_solve(M, r, q):
                return 1
            zn = 0.0
            zz = 0.0
            for i in range(dim):
                s = y[i]
                for a_ in range(q):
                    s -= GN[i, a_] * r[a_]
                z[i] = s
                zn += s * C[p, i]
                zz += s * s
            t1 = inf
            kd = -1
            for a_ in range(q):
                if active[a_] >= meq and r[a_] > 1e-14:
                    ratio = ua[a_] / r[a_]
                    if ratio < t1:
                        t1 = ratio
                        kd = a_
            sp = -b[p]
            for j in range(dim):
                sp += C[p, j] * x[j]
            if q < dim and zn > 1e-12 * cnorm[p] * sqrt(zz) and zz > 0.0:
                t2 = -sp / zn
            else:
                t2 = inf
            t = min(t1, t2)
            if t == inf:
                return 2
            for a_ in range(q):
                ua[a_] -= t * r[a_]
            up += t
            if t2 < inf:
                for i in range(dim):
                    x[i] += t * z[i]
            if t2 <= t1:
                active[q] = p
                ua[q] = up
                is_active[p] = True
                q += 1
                break
            # drop constraint kd (partial step) and continue with p
            is_active[active[kd]] = False
            for a_ in range(kd, q - 1):
                active[a_] = active[a_ + 1]
                ua[a_] = ua[a_ + 1]
            q -= 1
        else:
            return 3
    return 4


@inline
def convexified_inverse(H, grads, lam, gmean, Hs, Hinv, Lc, Lic):
    """Hinv = the inverse of H + aug sum_i lam_i (g_i - g_mean)(g_i - g_mean)' + shift I, the
    SQP's Hessian convexified, with the smallest aug and shift (of a fixed schedule) that make
    it positive definite; False where none does. The Lagrangian Hessian H is positive definite
    only on the tangent space of the active angles; the added term is constant on the QP's
    manifold of equal linearised angles (g_i the angles' gradients, g_mean their lam-weighted
    mean, into gmean), so it convexifies without moving the QP's solution."""
    n, m = grads.shape
    big = 1e-8
    for j in range(m):
        big = max(big, abs(H[j, j]))
    for j in range(m):
        gmean[j] = 0.0
        for i in range(n):
            gmean[j] += lam[i] * grads[i, j]
    shift = 1e-9 * big
    for attempt in range(16):
        aug = 0.0 if attempt == 0 else big * 10.0 ** (attempt - 1)
        if attempt > 4:
            aug = big * 1e3
            shift *= 10.0
        for p in range(m):
            for q in range(m):
                s = H[p, q]
                for i in range(n):
                    s += aug * lam[i] * (grads[i, p] - gmean[p]) * (grads[i, q] - gmean[q])
                Hs[p, q] = s
            Hs[p, p] += shift
        if cholesky_inverse(Hs, m, Hinv, Lc, Lic):
            return True
    return False


@inline
def predicted_change(theta, grads, x, R, tmax, nu, sizes, f, penalty, has_f):
    """The QP step x's predicted change of the merit, max_i (theta_i + grad_i . x) minus the
    merit now (tmax plus the penalty on force limits exceeded, |P_i| = sizes[i] > f; the
    penalty raised to twice the largest limit multiplier nu_i first). Returns (pred, the
    merit now, the penalty)."""
    n, m = grads.shape
    model = -inf
    for i in range(n):
        if not R[i]:
            s = theta[i]
            for j in range(m):
                s += grads[i, j] * x[j]
            model = max(model, s)
    now = tmax
    if has_f:
        for i in range(n):
            penalty = max(penalty, 2.0 * nu[i])
        for i in range(n):
            if sizes[i] > f:
                now += penalty * (sizes[i] - f)
    return model - now, now, penalty


@kernel
def sqp(a0, al, tau0, T, K, f, R, release, k, lam, nu, max_iter, tol):
    """SQP for min t s.t. theta_i(k) <= t, |k_j| <= K, |P_i| <= f, from k inside the box.

    Released fingers (R) are held at P_i = release * n_i (k must satisfy this on entry).
    Each step solves the QP  min z + z^2 / 2 + d'Hd / 2  subject to
    theta_i + grad_i . d <= theta_max + z, the box, the linearised force limits and the
    released fingers' A_i d = 0, with H the Lagrangian Hessian convexified, then backtracks
    on the merit max_i theta_i. Updates k, lam (the theta multipliers, summing to 1) and nu;
    returns the number of steps taken, or < 0 if a QP failed.
    """
    n, m = al.shape
    has_f = f < inf
    dim = m + 1
    nr = 0
    for i in range(n):
        nr += R[i]
    meq = 3 * nr
    nc = meq + (n - nr) + 2 * m + (n if has_f else 0)
    a, tau, rho, theta = angle_arrays(n)
    grads = stack_zeros((n, m))
    fgrads = stack_empty((n, m))
    P = stack_empty(n)
    H = stack_empty((m, m))
    Hs = stack_empty((m, m))
    Hinv = stack_empty((m, m))
    Ginv = stack_zeros((dim, dim))
    c = stack_zeros(dim)
    c[m] = 1.0
    C = stack_large((nc, dim))
    b = stack_empty(nc)
    x = stack_empty(dim)
    u = stack_empty(nc)
    k_try = stack_empty(m)
    gmean = stack_empty(m)
    Lc = stack_empty((m, m))
    Lic = stack_empty((m, m))
    GN = stack_empty((dim, dim))
    M = stack_empty((dim, dim))
    vec = stack_large((6, max(dim, nc)))
    active = stack_empty(dim, dtype=np.int64)
    is_active = stack_empty(nc, dtype=np.bool_)
    Ginv[m, m] = 1.0
    penalty = 1.0
    for it in range(max_iter):
        tmax = merit(k, a0, al, tau0, T, inf, 0.0, R, a, tau, rho, theta)
        zero(H)
        for i in range(n):
            if not R[i]:
                finger_derivatives(False, i, lam[i], a, tau, rho, al, T, grads[i], H)
            if has_f:
                P[i] = force_derivatives(i, nu[i], a, tau, al, T, fgrads[i], H)
        if not convexified_inverse(H, grads, lam, gmean, Hs, Hinv, Lc, Lic):
            return -1
        for p in range(m):
            for q in range(m):
                Ginv[p, q] = Hinv[p, q]
        row = 0
        for i in range(n):
            if R[i]:
                for cc in range(3):
                    for j in range(m):
                        C[row, j] = al[i, j] if cc == 0 else T[i, cc - 1, j]
                    C[row, m] = 0.0
                    b[row] = release - a[i] if cc == 0 else -tau[i, cc - 1]
                    row += 1
        for i in range(n):
            if not R[i]:
                for j in range(m):
                    C[row, j] = -grads[i, j]
                C[row, m] = 1.0
                b[row] = theta[i] - tmax
                row += 1
        for j in range(m):
            C[row, :] = 0.0
            C[row, j] = -1.0
            b[row] = k[j] - K
            row += 1
            C[row, :] = 0.0
            C[row, j] = 1.0
            b[row] = -K - k[j]
            row += 1
        if has_f:
            for i in range(n):
                for j in range(m):
                    C[row, j] = -fgrads[i, j]
                C[row, m] = 0.0
                b[row] = P[i] - f
                row += 1
        code = quadprog(Ginv, c, C, b, nc, meq, dim, x, u, GN, M, vec, active, is_active)
        if code != 0:
            return -10 - code
        total = 0.0
        row = meq
        for i in range(n):
            if not R[i]:
                total += u[row]
                row += 1
        if total <= 0.0:
            return -3
        row = meq
        for i in range(n):
            lam[i] = 0.0
            if not R[i]:
                lam[i] = u[row] / total
                row += 1
            if has_f:
                nu[i] = u[meq + (n - nr) + 2 * m + i] / total
        pred, now, penalty = predicted_change(theta, grads, x, R, tmax, nu, P, f, penalty, has_f)
        if pred > -tol:
            return it
        alpha = 1.0
        accepted = False
        for _ in range(40):
            for j in range(m):
                k_try[j] = min(K, max(-K, k[j] + alpha * x[j]))
            value = merit(k_try, a0, al, tau0, T, f, penalty, R, a, tau, rho, theta)
            if value <= now + 1e-4 * alpha * pred:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            return it
        for j in range(m):
            k[j] = k_try[j]
    return max_iter
