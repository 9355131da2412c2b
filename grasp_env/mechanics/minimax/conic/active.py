"""The active-set method of the conic solver, its first attempt for five to eight contacts
(docs/solver.md, "Any number of contacts", "The active-set method").

The minimax epigraph in the force coordinates y (k = B y, paper eq. 4 with the minimum-norm
pair scalars), as the three- and four-finger SQP (``minimax.sqp``) solves it:

    min t  over (y, t):  theta_i(y) <= t            (eq. 2, fingers not released)
                         P_i(y) = RELEASE_PUSH n_i   (fingers released: at the cone's apex)
                         |b_j . y| <= K              (the box on the minimum-norm k)
                         |P_i(y)| <= f               (the force limits, if any)

Each step solves the QP of the linearised constraints and the convexified Lagrangian
Hessian by Goldfarb and Idnani's dual active-set method (``qp.dual_qp``: the three- and
four-finger QP's iterates, its factorisation updated row by row), with a line search on
max_i theta_i. A finger whose force falls below RELEASE_AT of the largest is
released (held at a push of RELEASE_PUSH along its normal, its angle 0); where the SQP
stops, a released finger whose rows' multipliers say that pushing lowers the largest angle
pushes again. The last QP's active rows are the sets of Newton's method on the cone
problem's KKT system (``polish``, the certificate the barrier search uses too): its
multipliers give the dual bound, computed, never assumed. Where it does not close the gap
the barrier search runs as before.
"""

from __future__ import annotations

from math import inf, pi, sqrt

import numpy as np

from ..codes import GAP_TOL
from ..fingers import evaluate, finger_derivatives, force_derivatives
from ..sqp import convexified_inverse, predicted_change, quadprog
from .codes import (
    ACTIVE_STEPS,
    ACTIVE_TOL,
    BOUND_BELOW,
    POLISH_ROUNDS,
    RELEASE_AT,
    RELEASE_PUSH,
    UNRELEASE,
    kernel,
)
from .frames import finger_forces, largest_angle, weights
from .polish import polish
from .qp import dual_qp


@kernel
def merit(y, a0, al, tau0, T, f, penalty, R, a, tau, rho, theta):
    """max theta_i over the fingers not released, plus the penalised force-limit excess."""
    evaluate(y, a0, al, tau0, T, a, tau, rho, theta)
    worst = -inf
    for i in range(al.shape[0]):
        if not R[i]:
            worst = max(worst, theta[i])
    if f < inf:
        for i in range(al.shape[0]):
            excess = sqrt(a[i] ** 2 + rho[i] ** 2) - f
            if excess > 0.0:
                worst += penalty * excess
    return worst


@kernel
def common_push(a0, al, tau0, T, box, K, y):
    """The start: the y (and the common normal force s) of least sum_i |tau_i|^2 +
    (a_i - s)^2, every finger pushing alike along its normal with no tangential force
    (exact where such a grip exists), shrunk into the box."""
    n, m = al.shape
    d = m + 1
    A = np.zeros((3 * n, d))
    rhs = np.empty(3 * n)
    for i in range(n):
        for j in range(m):
            A[3 * i, j] = al[i, j]
            A[3 * i + 1, j] = T[i, 0, j]
            A[3 * i + 2, j] = T[i, 1, j]
        A[3 * i, m] = -1.0
        rhs[3 * i] = -a0[i]
        rhs[3 * i + 1] = -tau0[i, 0]
        rhs[3 * i + 2] = -tau0[i, 1]
    M = A.T @ A
    v = A.T @ rhs
    big = 0.0
    for p in range(d):
        big = max(big, M[p, p])
    for p in range(d):
        M[p, p] += 1e-10 * big  # the least-norm solution where the rows leave y free
    x = np.linalg.solve(M, v)
    largest = 0.0
    for j in range(box.shape[0]):
        s = 0.0
        for p in range(m):
            s += box[j, p] * x[p]
        largest = max(largest, abs(s))
    shrink = min(1.0, K * (1.0 - 1e-9) / largest) if largest > 0.0 else 1.0
    for p in range(m):
        y[p] = x[p] * shrink


@kernel
def sqp(a0, al, tau0, T, box, K, f, R, y, lam, nu, mu, max_iter, tol, warm_start):
    """SQP for min t s.t. theta_i(y) <= t, |b_j . y| <= K, |P_i| <= f, from y in the box.

    Released fingers (R) are held at P_i = RELEASE_PUSH n_i (a push along the normal, so
    that their angle is 0, not undefined) by three linear rows each; a finger whose
    force falls below RELEASE_AT of the largest after a step is released. Each step solves
    min z + z^2 / 2 + d'Hd / 2 subject to theta_i + grad_i . d <= theta_max + z, the box
    rows, the linearised force limits and the released fingers' rows (H: the Lagrangian
    Hessian of the angles and the limits, convexified as ``minimax.sqp`` does; the QP by
    ``qp.dual_qp``, started from the last QP's active rows while no finger was released or
    pushed again since), then
    backtracks on the merit. Where it converges, a released finger whose multipliers say
    that pushing would lower the largest angle pushes again (twice at most). Fills lam (the angle
    multipliers, summing to 1), nu (the limits') and mu (the box rows', signed: + on
    b_j . y = K, - on -K). warm_start: each QP by ``qp.dual_qp`` from the last one's active
    rows (while no finger was released or pushed again since); else by
    ``minimax.sqp.quadprog``, cold (the attempt as it was before ``dual_qp``, bit for bit).
    Returns the steps taken, or < 0 where a QP failed."""
    n, m = al.shape
    pairs = box.shape[0]
    has_f = f < inf
    dim = m + 1
    a, tau, rho, theta = np.empty(n), np.empty((n, 2)), np.empty(n), np.empty(n)
    grads = np.zeros((n, m))
    fgrads = np.zeros((n, m))
    size = np.zeros(n)
    H = np.empty((m, m))
    Hs = np.empty((m, m))
    Hinv = np.empty((m, m))
    Lc = np.empty((m, m))
    Lic = np.empty((m, m))
    Ginv = np.zeros((dim, dim))
    c = np.zeros(dim)
    c[m] = 1.0
    most = 3 * n + 2 * pairs + (n if has_f else 0)
    C = np.empty((most, dim))
    b = np.empty(most)
    x = np.empty(dim)
    u = np.empty(most)
    y_try = np.empty(m)
    gmean = np.empty(m)
    GN = np.empty((dim, dim))
    Mq = np.empty((dim, dim))
    Lq = np.empty((dim, dim))
    vec = np.empty((7, max(dim, most)))
    was_active = np.zeros(most, dtype=np.bool_)  # the last QP's active rows
    warm = False  # whether they start the next QP (the rows the same: no release since)
    active = np.empty(dim, dtype=np.int64)
    is_active = np.empty(most, dtype=np.bool_)
    kept = np.zeros(n, dtype=np.int64)  # how often a finger pushed again after a release
    push = np.zeros((n, 3))  # the released fingers' forces, finger frame
    push[:, 0] = RELEASE_PUSH
    Ginv[m, m] = 1.0
    penalty = 1.0
    steps = max_iter
    for it in range(max_iter):
        tmax = merit(y, a0, al, tau0, T, inf, 0.0, R, a, tau, rho, theta)
        H[:, :] = 0.0
        for i in range(n):
            if not R[i]:
                finger_derivatives(False, i, lam[i], a, tau, rho, al, T, grads[i], H)
            if has_f:
                size[i] = force_derivatives(i, nu[i], a, tau, al, T, fgrads[i], H)
        if not convexified_inverse(H, grads, lam, gmean, Hs, Hinv, Lc, Lic):
            return -1
        for p in range(m):
            for q in range(m):
                Ginv[p, q] = Hinv[p, q]
        row = 0
        for i in range(n):  # released: P_i + A_i d = RELEASE_PUSH n_i (equalities first)
            if R[i]:
                for cc in range(3):
                    for j in range(m):
                        C[row, j] = al[i, j] if cc == 0 else T[i, cc - 1, j]
                    C[row, m] = 0.0
                    b[row] = RELEASE_PUSH - a[i] if cc == 0 else -tau[i, cc - 1]
                    row += 1
        meq = row
        first_angle = row
        for i in range(n):
            if not R[i]:
                for j in range(m):
                    C[row, j] = -grads[i, j]
                C[row, m] = 1.0
                b[row] = theta[i] - tmax
                row += 1
        first_box = row
        for j in range(pairs):
            v = 0.0
            for p in range(m):
                v += box[j, p] * y[p]
            for sign in (-1.0, 1.0):  # sign (b_j . (y + d)) >= -K
                for p in range(m):
                    C[row, p] = sign * box[j, p]
                C[row, m] = 0.0
                b[row] = -K - sign * v
                row += 1
        first_ball = row
        if has_f:
            for i in range(n):
                for j in range(m):
                    C[row, j] = -fgrads[i, j]
                C[row, m] = 0.0
                b[row] = size[i] - f
                row += 1
        nc = row
        guess = 0  # the QP from the last one's active rows
        for r_ in range(nc if warm else 0):
            if was_active[r_]:
                active[guess] = r_
                guess += 1
        if warm_start:
            code = dual_qp(
                Ginv, c, C, b, nc, meq, first_box, pairs, guess, dim, x, u, GN, Mq, Lq, vec,
                active, is_active,
            )  # fmt: skip
        else:  # the previous attempt's QP, bit for bit
            code = quadprog(Ginv, c, C, b, nc, meq, dim, x, u, GN, Mq, vec, active, is_active)
        if code != 0:
            return -10 - code
        was_active[:nc] = is_active[:nc]
        warm = warm_start
        total = 0.0
        for r_ in range(first_angle, first_box):
            total += u[r_]
        if total <= 0.0:
            return -3
        r_ = first_angle
        for i in range(n):
            lam[i] = 0.0
            if not R[i]:
                lam[i] = u[r_] / total
                r_ += 1
            nu[i] = u[first_ball + i] / total if has_f else 0.0
        for j in range(pairs):
            # row 2j: -(b_j . y) >= -K (held at +K); row 2j + 1: b_j . y >= -K (at -K)
            mu[j] = (u[first_box + 2 * j] - u[first_box + 2 * j + 1]) / total
        pred, now, penalty = predicted_change(theta, grads, x, R, tmax, nu, size, f, penalty, has_f)
        accepted = False
        alpha = 1.0
        for _ in range(40 if pred <= -tol else 0):
            for j in range(m):
                y_try[j] = y[j] + alpha * x[j]
            value = merit(y_try, a0, al, tau0, T, f, penalty, R, a, tau, rho, theta)
            if value <= now + 1e-4 * alpha * pred:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            # converged on these releases (or stalled): a released finger whose rows'
            # multipliers v (finger frame) lie outside the polar cone of its cone at tmax
            # would lower the largest angle by pushing (v . e < 0 for some e within tmax of
            # its normal): the worst such finger pushes again (twice at most)
            worst, back = 0.0, -1
            r_ = 0
            for i in range(n):
                if R[i]:
                    v0, v1, v2 = u[r_], u[r_ + 1], u[r_ + 2]
                    excess = sqrt(v1 * v1 + v2 * v2) * np.sin(tmax) - v0 * np.cos(tmax)
                    if kept[i] < 2 and excess > max(worst, 1e-6 * total):
                        worst, back = excess, i
                    r_ += 3
            if back < 0:
                steps = it
                break
            # it pushes with UNRELEASE of the largest force along the direction of
            # steepest descent within its cone (at tmax, across its multipliers' tangential
            # part), the others held
            evaluate(y, a0, al, tau0, T, a, tau, rho, theta)
            largest = 0.0
            for i in range(n):
                largest = max(largest, sqrt(a[i] ** 2 + rho[i] ** 2))
            r_ = 0
            for i in range(back):
                r_ += 3 if R[i] else 0
            v1, v2 = u[r_ + 1], u[r_ + 2]
            across = max(sqrt(v1 * v1 + v2 * v2), 1e-300)
            strength = UNRELEASE * largest
            push[back, 0] = strength * np.cos(tmax)
            push[back, 1] = -strength * np.sin(tmax) * v1 / across
            push[back, 2] = -strength * np.sin(tmax) * v2 / across
            hold_released(y, a0, al, tau0, T, box, K, R, push)
            push[back, 0], push[back, 1], push[back, 2] = RELEASE_PUSH, 0.0, 0.0
            R[back] = False
            warm = False
            kept[back] += 1
            lam[back] = 0.0
            continue
        y[:] = y_try
        # a finger whose force has all but vanished is released (its angle has no limit)
        largest = 0.0
        for i in range(n):
            size[i] = sqrt(a[i] ** 2 + rho[i] ** 2)
            largest = max(largest, size[i])
        released = False
        for i in range(n):
            if not R[i] and size[i] < RELEASE_AT * largest:
                R[i] = True
                warm = False
                lam[i] = 0.0
            released = released or R[i]
        # (a partial step, or rounding, moves them off their push; the QP's rounding may
        # leave a box row by up to about 1e-8 of K, which the correction puts back on it)
        if released or outside_box(y, box, K):
            hold_released(y, a0, al, tau0, T, box, K, R, push)
    return steps


@kernel
def outside_box(y, box, K):
    """Whether some row |b_j . y| exceeds K."""
    for j in range(box.shape[0]):
        v = 0.0
        for p in range(y.shape[0]):
            v += box[j, p] * y[p]
        if abs(v) > K:
            return True
    return False


@kernel
def hold_released(y, a0, al, tau0, T, box, K, R, push):
    """y moved the least (in norm) that puts every finger of R at its force push[i]
    (finger frame; RELEASE_PUSH along the normal for a released finger), with the box
    rows it has reached held at +-K; then shrunk into the box if another row left it."""
    n, m = al.shape
    pairs = box.shape[0]
    count = 0
    for i in range(n):
        count += 3 if R[i] else 0
    for j in range(pairs):
        v = 0.0
        for p in range(m):
            v += box[j, p] * y[p]
        count += 1 if abs(v) >= K * (1.0 - 1e-12) else 0
    A = np.empty((count, m))
    gap = np.empty(count)
    row = 0
    for i in range(n):
        if R[i]:
            a, t1, t2 = a0[i], tau0[i, 0], tau0[i, 1]
            for j in range(m):
                a += al[i, j] * y[j]
                t1 += T[i, 0, j] * y[j]
                t2 += T[i, 1, j] * y[j]
                A[row, j] = al[i, j]
                A[row + 1, j] = T[i, 0, j]
                A[row + 2, j] = T[i, 1, j]
            gap[row] = push[i, 0] - a
            gap[row + 1] = push[i, 1] - t1
            gap[row + 2] = push[i, 2] - t2
            row += 3
    for j in range(pairs):
        v = 0.0
        for p in range(m):
            v += box[j, p] * y[p]
        if abs(v) >= K * (1.0 - 1e-12):
            for p in range(m):
                A[row, p] = box[j, p]
            gap[row] = (K if v > 0.0 else -K) - v
            row += 1
    z = np.linalg.lstsq(A @ A.T, gap)[0]
    step = A.T @ z
    for p in range(m):
        y[p] += step[p]
    largest = 0.0
    for j in range(pairs):
        v = 0.0
        for p in range(m):
            v += box[j, p] * y[p]
        largest = max(largest, abs(v))
    if largest > K:
        for p in range(m):
            y[p] *= K / largest


@kernel
def active_search(a0, al, tau0, T, box, K, f, best, theta):
    """The active-set attempt: the SQP from the better of k = 0 and the common-push start
    to a predicted decrease of ACTIVE_TOL[0], then Newton's method on the cone problem's
    KKT system on the sets its QP ends on (:func:`certify_sqp`); where that leaves a gap,
    the SQP on to ACTIVE_TOL[1] and the polish again; where a gap is still open, the same
    from the start with the QPs of ``minimax.sqp.quadprog``, cold (the previous attempt). best moves
    to the best grip found (it holds the grip to beat on entry). Returns (lower, share):
    lower > 0 only where the polish's multipliers proved it."""
    n, m = al.shape
    pairs = box.shape[0]
    P = np.empty((n, 3))
    y = np.zeros(m)
    trial = np.empty(m)
    finger_forces(best, a0, al, tau0, T, P)
    t_best = largest_angle(P, f, theta)
    common_push(a0, al, tau0, T, box, K, trial)
    # the start: the smaller of the two largest angles (force limits ignored: the SQP's
    # merit penalises their excess)
    finger_forces(trial, a0, al, tau0, T, P)
    t_push = largest_angle(P, inf, theta)
    finger_forces(y, a0, al, tau0, T, P)
    t_zero = largest_angle(P, inf, theta)
    if t_push < t_zero:
        y[:] = trial
    start = y.copy()
    entry = best.copy()  # the grip to beat on entry
    t_entry = t_best
    grip = np.empty(m)
    R = np.zeros(n, dtype=np.bool_)
    lam = np.empty(n)
    nu = np.empty(n)
    mu = np.empty(pairs)
    lower, share = 0.0, 0.0
    # the QPs warm-started from the last step's active rows (qp.dual_qp); where that leaves
    # a gap, the attempt again from the start with its own best grip and every QP by
    # minimax.sqp.quadprog, cold: the previous attempt bit for bit (rounding sends the warm
    # SQP down another path near the optimum: of the bench's 256 seven-finger scenes with
    # force limits it alone left five uncertified that the previous attempt certifies).
    # Each bound is a proof and each grip attained, so the better of the attempts is kept:
    # no scene that the previous attempt certified goes uncertified.
    for cold in range(2):
        y[:] = start
        grip[:] = entry
        t_grip = t_entry
        R[:] = False
        lam[:] = 1.0 / n
        nu[:] = 0.0
        mu[:] = 0.0
        for tol in ACTIVE_TOL:
            # (a QP that fails leaves y where the SQP got to: the polish may still certify)
            sqp(a0, al, tau0, T, box, K, f, R, y, lam, nu, mu, ACTIVE_STEPS, tol, cold == 0)
            t_grip, low, part = certify_sqp(
                a0, al, tau0, T, box, K, f, y, R, lam, nu, mu, grip, t_grip, theta
            )
            if t_grip < t_best:
                t_best = t_grip
                best[:] = grip
            if low > lower:
                lower, share = low, part
            if lower >= t_best - GAP_TOL:
                return lower, share
    return lower, share


@kernel
def certify_sqp(a0, al, tau0, T, box, K, f, y, R, lam, nu, mu, best, t_best, theta):
    """The KKT polish on the sets the SQP's last QP ends on (the released fingers R at the
    cone's apex, fingers and limits with multipliers above 1e-6 of the largest, box rows
    with theirs), just below the best grip, in rounds while each finds a better grip (best
    and t_best follow them). Returns (t_best, lower, share)."""
    n, m = al.shape
    pairs = box.shape[0]
    P = np.empty((n, 3))
    w = np.empty(n)
    z = np.empty(m)
    trial = np.empty(m)
    z[:] = y
    finger_forces(z, a0, al, tau0, T, P)
    # (its point may exceed a force limit by more than rounding: its level then the
    # polish's, whose point meets the limits)
    t_level = largest_angle(P, inf, theta)
    t_up = largest_angle(P, f, theta)
    if t_up < t_best and not outside_box(z, box, K * (1.0 + 1e-12)):
        t_best = t_up
        best[:] = z
    if not (GAP_TOL < t_level < pi / 2):
        return t_best, 0.0, 0.0
    # the sets the QP ends on
    cone = np.zeros(n, dtype=np.int64)
    ball = np.zeros(n, dtype=np.bool_)
    fixed = np.zeros(pairs, dtype=np.int64)
    top = 0.0
    for i in range(n):
        top = max(top, lam[i], nu[i])
    for j in range(pairs):
        top = max(top, abs(mu[j]))
    for i in range(n):
        if R[i]:
            cone[i] = 2
        elif lam[i] > 1e-6 * top or theta[i] >= t_level - 1e-9:
            cone[i] = 1
        if f < inf:
            ball[i] = nu[i] > 1e-6 * top
    for j in range(pairs):
        if abs(mu[j]) > 1e-6 * top:
            fixed[j] = 1 if mu[j] > 0.0 else -1
    lower, share = 0.0, 0.0
    for _ in range(POLISH_ROUNDS):
        if t_best <= t_level:  # (else the SQP's point, beyond a limit, sets the level)
            z[:] = best
            t_level = t_best
        t = t_level - BOUND_BELOW[0]
        finger_forces(z, a0, al, tau0, T, P)
        weights(P, w)
        improved = False
        low, part = 0.0, 0.0
        for _ in range(n + 2):  # change the sets a pass
            trial[:] = z
            low, part, changed = polish(t, w, trial, a0, al, tau0, T, box, K, f, cone, ball, fixed)
            finger_forces(trial, a0, al, tau0, T, P)
            t_new = largest_angle(P, f, theta)
            if t_new < t_best:
                t_best, improved = t_new, True
                best[:] = trial
            if low > 0.0 or not changed:
                break
        if low > 0.0:
            lower, share = t, part
            break
        if not improved or t_best <= GAP_TOL:
            break
    return t_best, lower, share
