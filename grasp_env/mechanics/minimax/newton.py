"""Newton's method on the KKT system of the minimax for fixed active sets (the polish), the
repair of the sets, and the certificate at the polished point (finish).
"""

from __future__ import annotations

from math import inf, pi, sqrt

import numpy as np

from .certificate import certify
from .fingers import angle_arrays, apex_columns, evaluate, finger_derivatives, force_derivatives
from .jit import inline, kernel
from .linalg import (
    bordered_least_squares,
    copy_into,
    lu_solve,
    stack_copy,
    stack_empty,
    stack_large,
    stack_zeros,
    zero,
)

#: Offsets below the primal value at which the dual certificate is tried, radians.
DELTAS = (1e-11, 1e-10, 5e-10)
#: A released finger (zero force at the optimum) is held at this normal force (normalised),
#: inside its cone, so that its friction angle is well defined.
RELEASE = 1e-10
#: Newton's KKT residual that an attempt from a far start must reach within its first few
#: iterations (see polish): one that has not is rarely converging, and costs as much as the SQP.
SETTLED = 1e-4
#: Newton's KKT residual at which polish stops: the max angle is then within about as much
#: (radians) of the optimum for its sets
CONVERGED = 1e-12


@inline
def read_multipliers(x, row, S, R, Q, lam, eta, nu):
    """Unpack lam (fingers in S), eta (released fingers, 3 each) and nu (force limits in Q)
    from x, starting at ``row``, in that order; the others are zero."""
    for i in range(S.shape[0]):
        lam[i] = 0.0
        if S[i]:
            lam[i] = x[row]
            row += 1
    for i in range(R.shape[0]):
        if R[i]:
            for c in range(3):
                eta[i, c] = x[row]
                row += 1
    for i in range(Q.shape[0]):
        nu[i] = 0.0
        if Q[i]:
            nu[i] = x[row]
            row += 1


@kernel
def multiplier_estimate(a, tau, rho, al, T, S, R, Q, fixed, lam, eta, nu):
    """Least-squares KKT multipliers at a near-optimal point, to start Newton's method.

    Minimises |sum lam_i grad theta_i + sum A_i' eta_i + sum nu_i grad |P_i||^2 over the free
    k_j with sum lam_i = 1. Newton's method on the KKT system needs multipliers as good as
    its point: equal weights can be far off where a finger's force is small (its angle
    then has a large gradient and curvature)."""
    n, m = al.shape
    cols = stack_large((m, 16))  # one column per unknown multiplier, free rows only
    Hd = stack_zeros((m, m))
    g = stack_empty(m)
    nc = 0
    for i in range(n):
        if S[i]:
            finger_derivatives(True, i, 0.0, a, tau, rho, al, T, g, Hd)
            for j in range(m):
                cols[j, nc] = g[j] if fixed[j] == 0 else 0.0
            nc += 1
    ns = nc
    nc = apex_columns(al, T, R, fixed, cols, nc)
    for i in range(n):
        if Q[i]:
            force_derivatives(i, 0.0, a, tau, al, T, g, Hd)
            for j in range(m):
                cols[j, nc] = g[j] if fixed[j] == 0 else 0.0
            nc += 1
    if ns == 0:
        return
    b = stack_empty(nc + 1)
    ones = stack_empty(ns)
    ones.fill(1.0)
    if not bordered_least_squares(cols, m, nc, ones, ns, b):  # (sum lam = 1)
        return
    read_multipliers(b, 0, S, R, Q, lam, eta, nu)


@kernel
def polish(
    a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, release, max_iter, settle_by,
    a, tau, rho, theta, evaluated,
):  # fmt: skip
    """Newton's method on the KKT system of the minimax for fixed active sets; returns t.

    S: fingers with theta_i = t (multipliers lam, summing to 1); R: released fingers,
    P_i = release * n_i (the cone's apex, nudged inside; multipliers eta, 3 each, finger
    frame); Q: fingers at |P_i| = f (nu); fixed: -1/0/+1 per k_j for k_j = -K / free / +K.
    Returns -1 when the Newton matrix is singular or the iteration does not settle (within
    max_iter steps, or below SETTLED by step settle_by). a, tau, rho, theta: the angles'
    components, which hold them at the returned k when t >= 0 (the caller's next look at the
    point); evaluated: they hold them at k already (then only a fixed k_j moved onto the box
    has them evaluated again).
    """
    n, m = al.shape
    grads = stack_empty((n, m))
    fgrads = stack_empty((n, m))
    P = stack_empty(n)
    H = stack_empty((m, m))
    free = stack_empty(m, dtype=np.int64)
    for j in range(m):
        if fixed[j] != 0 and k[j] != fixed[j] * K:
            k[j] = fixed[j] * K
            evaluated = False
    nf = 0
    for j in range(m):
        if fixed[j] == 0:
            free[nf] = j
            nf += 1
    ns = 0
    nr = 0
    nq = 0
    for i in range(n):
        ns += S[i]
        nr += R[i]
        nq += Q[i]
    size = nf + ns + 3 * nr + nq + 1
    A = stack_large((size, size))
    rhs = stack_empty(size)
    if not evaluated:
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    t = -inf
    for i in range(n):
        if S[i]:
            t = max(t, theta[i])
    last = 0.0  # the previous step
    for it in range(max_iter):
        if it > 0:  # (the first pass is at the k just evaluated)
            evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        if it > 0:
            # converged: the KKT residual is below CONVERGED (steps may not be, along
            # directions in which the optimum is not unique); the gradients alone first, so
            # that the last pass costs no Hessian
            for i in range(n):
                if S[i]:
                    finger_derivatives(True, i, 0.0, a, tau, rho, al, T, grads[i], H)
                if Q[i]:
                    P[i] = force_derivatives(i, 0.0, a, tau, al, T, fgrads[i], H)
            resid = 0.0
            for i in range(n):
                if S[i]:
                    resid = max(resid, abs(theta[i] - t))
                if R[i]:
                    resid = max(resid, abs(a[i] - release), abs(tau[i, 0]), abs(tau[i, 1]))
                if Q[i]:
                    resid = max(resid, abs(P[i] - f))
            for p in range(nf):
                j = free[p]
                g = 0.0
                for i in range(n):
                    if S[i]:
                        g += lam[i] * grads[i, j]
                    if R[i]:
                        g += eta[i, 0] * al[i, j] + eta[i, 1] * T[i, 0, j] + eta[i, 2] * T[i, 1, j]
                    if Q[i]:
                        g += nu[i] * fgrads[i, j]
                resid = max(resid, abs(g))
            if resid <= CONVERGED:
                return t
            if it >= settle_by and resid > SETTLED:
                return -1.0  # not in Newton's quadratic phase yet: the caller tries otherwise
        zero(H)
        for i in range(n):
            if S[i]:
                finger_derivatives(True, i, lam[i], a, tau, rho, al, T, grads[i], H)
            if Q[i]:
                P[i] = force_derivatives(i, nu[i], a, tau, al, T, fgrads[i], H)
        big = 1e-12
        for j in range(m):
            big = max(big, abs(H[j, j]))
        for p in range(size):
            for q in range(size):
                A[p, q] = 0.0
        for p in range(nf):
            for q in range(nf):
                A[p, q] = H[free[p], free[q]]
            A[p, p] += 1e-9 * big  # flat directions (non-unique optima) stay solvable
            rhs[p] = 0.0
        # Each multiplier row gets -reg (new - old multiplier): the fixed point is unchanged,
        # and multipliers the active constraints leave undetermined (more of them than free
        # directions, e.g. every k_j on the box) stay at their previous values.
        reg = 1e-12
        row = nf
        for i in range(n):
            if S[i]:
                for p in range(nf):
                    A[p, row] = grads[i, free[p]]
                    A[row, p] = grads[i, free[p]]
                A[row, size - 1] = -1.0
                A[size - 1, row] = 1.0
                A[row, row] = -reg
                rhs[row] = t - theta[i] - reg * lam[i]
                row += 1
        for i in range(n):
            if R[i]:
                for c in range(3):
                    for p in range(nf):
                        j = free[p]
                        v = al[i, j] if c == 0 else T[i, c - 1, j]
                        A[p, row] = v
                        A[row, p] = v
                    A[row, row] = -reg
                    if c == 0:
                        rhs[row] = release - a[i] - reg * eta[i, c]
                    else:
                        rhs[row] = -tau[i, c - 1] - reg * eta[i, c]
                    row += 1
        for i in range(n):
            if Q[i]:
                for p in range(nf):
                    A[p, row] = fgrads[i, free[p]]
                    A[row, p] = fgrads[i, free[p]]
                A[row, row] = -reg
                rhs[row] = f - P[i] - reg * nu[i]
                row += 1
        rhs[size - 1] = 1.0
        if not lu_solve(A, rhs, size):
            return -1.0
        step = 0.0
        for p in range(nf):
            k[free[p]] += rhs[p]
            step = max(step, abs(rhs[p]))
        t += rhs[size - 1]
        read_multipliers(rhs, nf, S, R, Q, lam, eta, nu)
        # a step that does not move k; or, deep in the quadratic phase, one whose successor
        # (about step^3 / last^2) would be below rounding: it, and the iteration that checks
        # for it, would leave k as it is
        if it > 0 and (
            step <= 1e-15 * (1.0 + K)
            or (step <= 1e-9 * (1.0 + K) and step**3 <= 1e-15 * (1.0 + K) * last**2)
        ):
            evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
            return t
        last = step
    return -1.0


@kernel
def polish_degenerate(
    a0, al, tau0, T, K, f, k, k_in, S, R, Q, fixed, lam, eta, nu, a, tau, rho, theta
):
    """:func:`polish` once more with one constraint fewer, where the sets hold more
    equations than there are unknowns (free k_j and t): at such a degenerate optimum
    (e.g. three equal angles and two fingers at the force limit, with three k_j free) one
    of them is weakly active, its multiplier zero, and dropping it leaves the same optimum
    a regular KKT point. Tries each candidate in turn from k_in; returns t, or -1."""
    n, m = al.shape
    count = 0
    unknowns = 1
    ns = 0
    for i in range(n):
        count += S[i] + 3 * R[i] + Q[i]
        ns += S[i]
    for j in range(m):
        unknowns += fixed[j] == 0
    if count <= unknowns:
        return -1.0
    lam0 = stack_copy(lam)
    eta0 = stack_copy(eta)
    nu0 = stack_copy(nu)
    for c in range(2 * n + m):
        if c < n:
            member = S[c] and ns > 1
        elif c < 2 * n:
            member = Q[c - n]
        else:
            member = fixed[c - 2 * n] != 0
        if not member:
            continue
        side = 0
        if c < n:
            S[c] = False
        elif c < 2 * n:
            Q[c - n] = False
        else:
            side = fixed[c - 2 * n]
            fixed[c - 2 * n] = 0
        copy_into(k, k_in, m)
        copy_into(lam, lam0, n)
        copy_into(nu, nu0, n)
        for i in range(n):
            for q in range(3):
                eta[i, q] = eta0[i, q]
        t = polish(
            a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, RELEASE, 12, np.int64(12),
            a, tau, rho, theta, np.bool_(False),
        )  # fmt: skip
        if t >= 0.0:
            # a KKT point of the original sets: multipliers >= 0, the dropped one holds
            ok = True
            for i in range(n):
                ok = ok and not (S[i] and lam[i] < -1e-12) and not (Q[i] and nu[i] < -1e-12)
            if c < n:
                ok = ok and theta[c] <= t + 1e-12
            elif c < 2 * n:
                ok = ok and sqrt(a[c - n] ** 2 + rho[c - n] ** 2) <= f * (1.0 + 1e-12)
            else:
                ok = ok and abs(k[c - 2 * n]) <= K * (1.0 + 1e-12)
            if ok:
                return t
        if c < n:
            S[c] = True
        elif c < 2 * n:
            Q[c - n] = True
        else:
            fixed[c - 2 * n] = side
    copy_into(k, k_in, m)
    copy_into(lam, lam0, n)
    copy_into(nu, nu0, n)
    return -1.0


@kernel
def finish(
    a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, settle_by, a, tau, rho, theta,
    evaluated,
):  # fmt: skip
    """Polish the KKT point for the given sets, repairing them, then certify it.

    settle_by: see :func:`polish` (12, its step limit, when k starts near the optimum);
    a, tau, rho, theta and evaluated: the angles' components, as for :func:`polish`.
    Returns (t_up, lower, box_share); lower < 0 when no certificate was found.

    numba compiles a kernel once per literal argument value: the later attempts pass
    settle_by and evaluated typed (``np.int64(12)``, ``np.bool_(True)``) and share one copy
    of this kernel and of :func:`polish`; the direct attempt keeps its literals (5, True),
    whose copies three fingers solve about 10% faster with.
    """
    n, m = al.shape
    grads = stack_empty((n, m))
    fg = stack_empty(m)
    Hd = stack_zeros((m, m))
    k_in = stack_copy(k)
    for _ in range(6):
        t = polish(
            a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, RELEASE, 12, settle_by,
            a, tau, rho, theta, evaluated,
        )  # fmt: skip
        evaluated = True  # (at the polished k, whose sets the loop may change, not k)
        if t < 0.0:
            t = polish_degenerate(
                a0, al, tau0, T, K, f, k, k_in, S, R, Q, fixed, lam, eta, nu, a, tau, rho, theta
            )
        if t < 0.0:
            for j in range(m):
                k[j] = k_in[j]
            return -1.0, -1.0, 0.0
        changed = False
        # a free k_j beyond the box: fix it at the bound
        for j in range(m):
            if fixed[j] == 0 and abs(k[j]) > K:
                fixed[j] = 1 if k[j] > 0 else -1
                changed = True
        # a finger below t that the sets hold equal (negative multiplier): drop it
        worst = -1
        value = -1e-12
        for i in range(n):
            if S[i] and lam[i] < value:
                value = lam[i]
                worst = i
        if worst >= 0:
            S[worst] = False
            changed = True
        for i in range(n):
            if Q[i] and nu[i] < -1e-12:
                Q[i] = False
                changed = True
        # a fixed k_j whose multiplier pulls inwards: free it
        bound = False
        for j in range(m):
            bound = bound or fixed[j] != 0
        if bound and not changed:  # (with none fixed its gradients would go unused)
            g = stack_zeros(m)
            for i in range(n):
                if S[i]:
                    finger_derivatives(True, i, 0.0, a, tau, rho, al, T, grads[i], Hd)
                    for j in range(m):
                        g[j] += lam[i] * grads[i, j]
                if R[i]:
                    for j in range(m):
                        g[j] += (
                            eta[i, 0] * al[i, j] + eta[i, 1] * T[i, 0, j] + eta[i, 2] * T[i, 1, j]
                        )
                if Q[i]:
                    force_derivatives(i, 0.0, a, tau, al, T, fg, Hd)
                    for j in range(m):
                        g[j] += nu[i] * fg[j]
            worst = -1
            value = -1e-12
            for j in range(m):
                if fixed[j] != 0:
                    mu = -fixed[j] * g[j]
                    if mu < value:
                        value = mu
                        worst = j
            if worst >= 0:
                fixed[worst] = 0
                changed = True
        # a finger outside the sets above t: add it
        for i in range(n):
            if not S[i] and not R[i] and theta[i] > t + 1e-12:
                S[i] = True
                changed = True
            if f < inf and not Q[i] and sqrt(a[i] ** 2 + rho[i] ** 2) > f * (1.0 + 1e-12):
                Q[i] = True
                changed = True
        if not changed:
            break
    else:
        return -1.0, -1.0, 0.0
    t_up = -1.0
    for i in range(n):
        if not R[i]:
            t_up = max(t_up, theta[i])
    for i in range(n):
        if R[i]:
            t_up = max(t_up, theta[i])
    if t_up >= pi / 2:
        # beyond 90 deg the cones are not convex and this certificate does not hold
        return t_up, -1.0, 0.0
    for delta in DELTAS:
        t_low = t_up - delta
        if t_low <= 0.0:
            return t_up, 0.0, 0.0
        L, share = certify(a0, al, tau0, T, K, f, a, tau, rho, t_low, S, R, Q, fixed, lam, eta, nu)
        if L >= 0.0:
            return t_up, t_low, share
    return t_up, -1.0, 0.0


@kernel
def finish_from(a0, al, tau0, T, K, f, k, lam, eta, tol, angle_tol):
    """Read the active sets off a near-optimal point k (within ``tol``; finger i is at the
    maximum angle if within ``angle_tol[i]`` of it), then :func:`finish`."""
    n, m = al.shape
    a, tau, rho, theta = angle_arrays(n)
    S = stack_zeros(n, dtype=np.bool_)
    R = stack_zeros(n, dtype=np.bool_)
    Q = stack_zeros(n, dtype=np.bool_)
    fixed = stack_zeros(m, dtype=np.int64)
    zero(eta)
    nu = stack_zeros(n)
    evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    big = 0.0
    for i in range(n):
        big = max(big, sqrt(a[i] ** 2 + rho[i] ** 2))
    t_up = -1.0
    for i in range(n):
        R[i] = sqrt(a[i] ** 2 + rho[i] ** 2) < min(10.0 * tol, 1e-5) * big
        if not R[i]:
            t_up = max(t_up, theta[i])
    for i in range(n):
        S[i] = not R[i] and theta[i] >= t_up - angle_tol[i]
        if f < inf:
            Q[i] = sqrt(a[i] ** 2 + rho[i] ** 2) >= f * (1.0 - tol)
    for j in range(m):
        if k[j] >= K * (1.0 - tol):
            fixed[j] = 1
        elif k[j] <= -K * (1.0 - tol):
            fixed[j] = -1
    multiplier_estimate(a, tau, rho, al, T, S, R, Q, fixed, lam, eta, nu)
    return finish(
        a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, np.int64(12),
        a, tau, rho, theta, np.bool_(True),
    )  # fmt: skip


@inline
def sets_from_point(K, f, k, a, rho, Q, fixed):
    """The force-limit and box sets that a near-optimal point k touches (within 1e-6)."""
    for q in range(a.shape[0]):
        Q[q] = f < inf and sqrt(a[q] ** 2 + rho[q] ** 2) >= f * (1.0 - 1e-6)
    for j in range(k.shape[0]):
        k[j] = min(K, max(-K, k[j]))
        fixed[j] = 1 if k[j] >= K * (1.0 - 1e-6) else (-1 if k[j] <= -K * (1.0 - 1e-6) else 0)
