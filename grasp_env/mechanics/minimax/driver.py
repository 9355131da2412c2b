"""The solver for one grasp (the attempts in order, each folded into the best certified
result) and the batch entry point.
"""

from __future__ import annotations

from math import cos, inf, pi, sin, sqrt
from typing import NamedTuple

import numpy as np

from .barrier import bisect, fallback
from .codes import (
    APEX,
    BAD_F_MAX,
    BAD_K_MAX,
    BAD_LOAD,
    BISECTION,
    BOUNDARY,
    DIRECT,
    FALLBACK,
    GAP_TOL,
    INTERIOR,
    INVALID,
    LOAD_RANGE,
    NEARBY,
    NOT_PUSHING,
    RATIO_RANGE,
    RELEASED,
    RESTARTED,
    SQP,
    UNCERTIFIED,
)
from .fingers import angle_arrays, evaluate, setup
from .jit import entry, inline, kernel
from .linalg import all_finite, copy_into, stack_copy, stack_empty, stack_zeros, zero
from .newton import RELEASE, finish, finish_from, sets_from_point
from .sqp import sqp
from .starts import apex_start, move_force, normal_start, release_start

#: Starting from a nearby grasp's optimum, the fingers at the maximum there are taken as the
#: maximum again if within NEAR_ANGLES of the largest friction angle (radians, about 6 deg: a
#: finger missed can leave Newton's method no KKT point, and costs the cold solve), the
#: others only if within NEW_ANGLES: a finger taken wrongly costs two polishes, one to a KKT
#: point with its multiplier negative (often 0.1 K away) and one back.
NEAR_ANGLES = 0.1
NEW_ANGLES = 1e-3
#: At a nearby optimum, the fingers within this of its largest angle are at the maximum.
HELD_ANGLES = 1e-6


class Best(NamedTuple):
    """The best certified result so far: its max angle, lower bound, status and path."""

    t: float
    lower: float
    status: int
    path: int


@inline
def fold(best, k_best, k, t_up, low, status, path):
    """Fold one attempt into the best point and the best certificate so far (a Best).

    Each attempt's certified bound is valid on its own, and only certified attempts' points
    are kept (in k_best). Returns the new Best.
    """
    t_best, lower, best_status, best_path = best.t, best.lower, best.status, best.path
    if low >= 0.0 and t_up < t_best:
        t_best = t_up
        copy_into(k_best, k, k.shape[0])
    if low > lower:
        lower = low
        best_status = status
    if t_best - lower <= GAP_TOL and best_path == UNCERTIFIED:
        best_path = path
    return Best(t_best, lower, best_status, best_path)


@inline
def closed(best):
    """Whether the best point and certificate so far are within GAP_TOL."""
    return best.t - best.lower <= GAP_TOL


@inline
def box_status(share):
    """BOUNDARY where the box term carries a share of the certificate, else INTERIOR."""
    return BOUNDARY if share > 1e-9 else INTERIOR


# The attempts after the first (try_*) run on a few grasps in a hundred: they are kernels,
# compiled once and linked into both entries, where inlined they were compiled into each
# (a cold compile of the two entries 166 -> 108 s of CPU; the same speed, bit for bit the
# same results).
@kernel
def try_releases(a0, al, tau0, T, K, f, k_sqp, best, k_best):
    """Four fingers: one of them may let go at the optimum (P_i = 0, the cone's apex),
    where theta_i is singular and the SQP stalls. Try releasing each finger, weakest first;
    where the release is almost but not quite optimal (released and at the maximum angle
    at once, its dual just outside the polar cone), give it the small force its dual asks
    for and solve with every finger active."""
    n, m = al.shape
    a, tau, rho, theta = angle_arrays(n)
    lam = stack_empty(n)
    nu = stack_zeros(n)
    eta = stack_zeros((n, 3))
    S = stack_zeros(n, dtype=np.bool_)
    R = stack_zeros(n, dtype=np.bool_)
    Q = stack_zeros(n, dtype=np.bool_)
    fixed = stack_zeros(m, dtype=np.int64)
    k = stack_empty(m)
    k_rel = stack_empty(m)
    tight = stack_empty(n)
    tight.fill(1e-6)
    evaluate(k_sqp, a0, al, tau0, T, a, tau, rho, theta)
    order = stack_empty(n, dtype=np.int64)  # fingers by |P_i|, smallest first
    for q in range(n):
        order[q] = q
        size_q = a[q] ** 2 + rho[q] ** 2
        p = q
        while p > 0 and a[order[p - 1]] ** 2 + rho[order[p - 1]] ** 2 > size_q:
            order[p] = order[p - 1]
            p -= 1
        order[p] = q
    for attempt in range(n):
        i = order[attempt]
        for q in range(n):
            R[q] = q == i
            lam[q] = 1.0 / (n - 1) if q != i else 0.0
            nu[q] = 0.0
        if not release_start(a0, al, tau0, T, K, i, RELEASE, k_sqp, k):
            continue
        if sqp(a0, al, tau0, T, K, f, R, RELEASE, k, lam, nu, 60, 1e-8) < 0:
            continue
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, tight)
        best = fold(best, k_best, k, t_up, low, box_status(share), RELEASED)
        if closed(best):
            return best
        if t_up < 0.0 or t_up >= pi / 2:
            continue
        copy_into(k_rel, k, m)
        evaluate(k_rel, a0, al, tau0, T, a, tau, rho, theta)
        typical = 0.0
        for q in range(n):
            typical += sqrt(a[q] ** 2 + rho[q] ** 2) / n
        er = sqrt(eta[i, 1] ** 2 + eta[i, 2] ** 2)
        y0 = eta[i, 1] / er if er > 0.0 else 1.0
        y1 = eta[i, 2] / er if er > 0.0 else 0.0
        ct, st = cos(t_up), sin(t_up)
        for eps in (1e-3, 1e-2):
            size = eps * typical
            move_force(a0, al, tau0, T, i, size * ct, size * st * y0, size * st * y1, k_rel, k)
            for q in range(n):
                S[q] = True
                R[q] = False
                lam[q] = 1.0 / n
            evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
            sets_from_point(K, f, k, a, rho, Q, fixed)  # (which may move k onto the box)
            t_up, low, share = finish(
                a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, np.int64(12),
                a, tau, rho, theta, np.bool_(False),
            )  # fmt: skip
            best = fold(best, k_best, k, t_up, low, box_status(share), RELEASED)
            if closed(best):
                return best
    return best


@kernel
def try_push(a0, al, tau0, T, K, f, k_sqp, best, k_best):
    """Four fingers: the SQP may stall where a finger's force vanishes without that being
    optimal; restart it with the weakest finger pushing along its normal."""
    n, m = al.shape
    a, tau, rho, theta = angle_arrays(n)
    lam = stack_empty(n)
    nu = stack_zeros(n)
    eta = stack_zeros((n, 3))
    R = stack_zeros(n, dtype=np.bool_)
    k = stack_empty(m)
    tight = stack_empty(n)
    tight.fill(1e-6)
    evaluate(k_sqp, a0, al, tau0, T, a, tau, rho, theta)
    typical = 0.0
    weakest = 0
    for q in range(n):
        size_q = sqrt(a[q] ** 2 + rho[q] ** 2)
        typical += size_q / n
        if size_q < sqrt(a[weakest] ** 2 + rho[weakest] ** 2):
            weakest = q
    for push in (1.0, 4.0):
        for q in range(n):
            lam[q] = 1.0 / n
            nu[q] = 0.0
        move_force(a0, al, tau0, T, weakest, push * typical, 0.0, 0.0, k_sqp, k)
        for j in range(m):
            k[j] = min(K, max(-K, k[j]))
        if sqp(a0, al, tau0, T, K, f, R, 0.0, k, lam, nu, 60, 1e-8) < 0:
            continue
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, tight)
        best = fold(best, k_best, k, t_up, low, box_status(share), RESTARTED)
        if closed(best):
            return best
    return best


@kernel
def try_fallback(a0, al, tau0, T, K, f, k_start, best, k_best):
    """The robust primal of :func:`fallback`, then the KKT certificate, then bisection;
    returns the new Best."""
    n = al.shape[0]
    k = stack_copy(k_start)
    lam = stack_empty(n)
    lam.fill(1.0 / n)
    eta = stack_zeros((n, 3))
    centre = stack_empty(k.shape[0])
    t_up, low, status, share = fallback(a0, al, tau0, T, K, f, k, 1e-11, centre)
    best = fold(best, k_best, k, t_up, max(low, 0.0), status, FALLBACK)
    if status == NOT_PUSHING and t_up >= pi:
        copy_into(k_best, k, k.shape[0])  # no k meets the force limits: k exceeds them least
    if closed(best) or status == NOT_PUSHING:
        return best
    k_fallback = stack_copy(k)
    within = stack_empty(n)
    for tol in (1e-6, 1e-5, 1e-4, 1e-3):
        # the barrier's point is near-optimal to about 1e-8; degenerate optima (a finger
        # with almost no force) need looser tolerances to read the active sets off it
        copy_into(k, k_fallback, k.shape[0])
        within.fill(tol)
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, tol, within)
        best = fold(best, k_best, k, t_up, low, box_status(share), FALLBACK)
        if closed(best):
            return best
    # the certified bisection, from the best point so far and the best bound
    a, tau, rho, theta = angle_arrays(n)
    copy_into(k, k_fallback, k.shape[0])
    t_up = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
    if best.t < t_up:
        copy_into(k, k_best, k.shape[0])
        t_up = best.t
    lo, hi, share = bisect(a0, al, tau0, T, K, f, k, centre, max(best.lower, 0.0), t_up)
    return fold(best, k_best, k, hi, lo, box_status(share), BISECTION)


@kernel
def try_weak_finger(
    F_near, E_near, N_near, a0, al, tau0, T, K, f, scale, k_near, within, best, k_best
):
    """Four fingers along a trajectory: where the nearby optimum nearly releases a finger, its
    small force's direction swings from pose to pose (at most 0.07 rad at one optimum, 0.91
    with the same k a degree later, measured), so k_near is no start; start instead where
    that finger keeps the force (finger frame) it had at the nearby optimum. Returns the new
    Best."""
    n, m = al.shape
    a0_near = stack_empty(n)
    al_near = stack_empty((n, m))
    tau0_near = stack_empty((n, 2))
    T_near = stack_empty((n, 2, m))
    scale_near, code = setup(F_near, E_near, N_near, a0_near, al_near, tau0_near, T_near)
    if code != 0 or scale_near == 0.0:
        return best
    a, tau, rho, theta = angle_arrays(n)
    k = stack_empty(m)
    for j in range(m):
        k[j] = k_near[j] / scale_near
    evaluate(k, a0_near, al_near, tau0_near, T_near, a, tau, rho, theta)
    weak = 0
    largest = 0.0
    for i in range(n):
        size = a[i] ** 2 + rho[i] ** 2
        largest = max(largest, size)
        if size < a[weak] ** 2 + rho[weak] ** 2:
            weak = i
    if a[weak] ** 2 + rho[weak] ** 2 >= 0.01 * largest:
        return best  # no weak finger (below a tenth of the largest force)
    ratio = scale_near / scale
    k_from = stack_empty(m)
    for j in range(m):
        k_from[j] = min(K, max(-K, k_near[j] / scale))
    if not move_force(
        a0,
        al,
        tau0,
        T,
        weak,
        a[weak] * ratio,
        tau[weak, 0] * ratio,
        tau[weak, 1] * ratio,
        k_from,
        k,
    ):
        return best
    for j in range(m):
        k[j] = min(K, max(-K, k[j]))
    lam = stack_empty(n)
    lam.fill(1.0 / n)
    eta = stack_zeros((n, 3))
    t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, within)
    return fold(best, k_best, k, t_up, low, box_status(share), NEARBY)


@inline
def solve_one(
    F,
    E,
    N,
    K_in,
    f_in,
    k,
    theta,
    k_near,
    k_before,
    theta_near,
    near,
    secant,
    F_near,
    E_near,
    N_near,
):
    """Certified minimax for one grasp; fills k and theta, returns (lower, status, path).

    near: k_near (newtons) is the optimum of a nearby grasp (the previous pose of a
    trajectory), theta_near its friction angles: Newton's method starts there, with the
    sets it has there, first; with secant, k_before is the optimum of the pose before
    that, and the start is extrapolated along the secant, 2 k_near - k_before (an error
    second-order in the step, not first: 13% fewer operations a warm solve with three
    fingers, 26% with four). F_near, E_near, N_near: the nearby grasp (see
    :func:`try_weak_finger`).
    path: the attempt that certified the result (codes.Path, diagnostic), or a negative
    code for an input refused (INVALID: NaN or inf; BAD_*: see codes).
    """
    n = F.shape[0]
    m = E.shape[0]
    for j in range(m):
        k[j] = 0.0
    for i in range(n):
        theta[i] = 0.0
    if not (all_finite(F) and all_finite(E) and all_finite(N)):
        return 0.0, INTERIOR, INVALID
    a0 = stack_empty(n)
    al = stack_empty((n, m))
    tau0 = stack_empty((n, 2))
    T = stack_empty((n, 2, m))
    scale, code = setup(F, E, N, a0, al, tau0, T)
    if code != 0:
        return 0.0, INTERIOR, code
    if scale == 0.0:
        # no load: k = 0 holds it with no force at all (every angle 0, the least possible)
        return 0.0, INTERIOR, APEX
    if not LOAD_RANGE[0] <= scale <= LOAD_RANGE[1]:
        return 0.0, INTERIOR, BAD_LOAD
    # the rest works in units of the load: the friction angles do not depend on its scale
    K = K_in / scale
    f = f_in / scale
    if not RATIO_RANGE[0] <= K <= RATIO_RANGE[1]:
        return 0.0, INTERIOR, BAD_K_MAX
    if f < inf and not RATIO_RANGE[0] <= f <= RATIO_RANGE[1]:
        return 0.0, INTERIOR, BAD_F_MAX
    a = stack_empty(n)
    tau = stack_empty((n, 2))
    rho = stack_empty(n)
    lam = stack_empty(n)
    lam.fill(1.0 / n)
    nu = stack_zeros(n)
    eta = stack_zeros((n, 3))
    R = stack_zeros(n, dtype=np.bool_)
    S = stack_empty(n, dtype=np.bool_)
    S.fill(True)
    Q = stack_zeros(n, dtype=np.bool_)
    fixed = stack_zeros(m, dtype=np.int64)
    best = Best(inf, 0.0, INTERIOR, UNCERTIFIED)
    k_best = stack_empty(m)
    done = False
    if near:
        # a step along a trajectory moves the optimum a little and its sets rarely
        for j in range(m):
            step = k_near[j] - k_before[j] if secant else 0.0
            k[j] = min(K, max(-K, (k_near[j] + step) / scale))
        top = -inf
        for i in range(n):
            top = max(top, theta_near[i])
        within = stack_empty(n)
        for i in range(n):
            within[i] = NEAR_ANGLES if theta_near[i] >= top - HELD_ANGLES else NEW_ANGLES
        t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, within)
        best = fold(best, k_best, k, t_up, low, box_status(share), NEARBY)
        done = closed(best)
        if not done and n == 4:
            best = try_weak_finger(
                F_near, E_near, N_near, a0, al, tau0, T, K, f, scale, k_near, within, best, k_best
            )
            done = closed(best)
        if not done:  # start afresh (finish_from set lam and eta; its nu is its own)
            zero(eta)
            for i in range(n):
                lam[i] = 1.0 / n
    k_start = k_best  # (unused when the nearby optimum is certified)
    if not done:
        # start: the k that minimises the tangential forces (exact when they can all vanish)
        apex_start(a0, al, tau0, T, k)
        for j in range(m):
            k[j] = min(K, max(-K, k[j]))
        t_up = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        if n == 4 and f == inf:
            # four fingers: also try every finger pushing with a common normal force; the best
            # start saves the SQP about a quarter of its steps
            k_try = stack_empty(m)
            for c in (1.0, 2.0, 4.0):
                normal_start(a0, al, tau0, T, c, k_try)
                for j in range(m):
                    k_try[j] = min(K, max(-K, k_try[j]))
                t_try = evaluate(k_try, a0, al, tau0, T, a, tau, rho, theta)
                if t_try < t_up:
                    t_up = t_try
                    copy_into(k, k_try, m)
            t_up = evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        feasible = True
        for i in range(n):
            feasible = feasible and sqrt(a[i] ** 2 + rho[i] ** 2) <= f
        k_start = stack_copy(k)
        if best.t == inf or (feasible and t_up < best.t):
            copy_into(k_best, k, m)  # the best point so far (fold keeps certified ones only)
            if feasible:
                best = Best(t_up, best.lower, best.status, best.path)
        if feasible and t_up <= GAP_TOL:
            # every finger along its normal: 0 is attained, 0 is the bound
            best = Best(best.t, best.lower, best.status, APEX)
            done = True
    if not done and n == 3 and f == inf:
        # Newton on the KKT system straight from the start with every finger at the maximum
        # (the typical optimum): cheap, and certified like any other attempt; given up
        # early where Newton is not converging (then the SQP costs less than finishing)
        for j in range(m):
            fixed[j] = 1 if k[j] >= K else (-1 if k[j] <= -K else 0)
        t_up, low, share = finish(
            a0, al, tau0, T, K, f, k, S, R, Q, fixed, lam, eta, nu, 5, a, tau, rho, theta, True
        )
        best = fold(best, k_best, k, t_up, low, box_status(share), DIRECT)
        done = closed(best)
    k_sqp = stack_copy(k_start)
    if not done:
        for i in range(n):
            lam[i] = 1.0 / n
        tight = stack_empty(n)
        tight.fill(1e-6)
        steps = sqp(a0, al, tau0, T, K, f, R, 0.0, k_sqp, lam, nu, 60, 1e-8)
        if steps >= 0 or n == 4:
            copy_into(k, k_sqp, m)
            t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, tight)
            best = fold(best, k_best, k, t_up, low, box_status(share), SQP)
            done = closed(best)
        if not done and steps >= 0:
            # not certified from a point 1e-8 from optimal: converge further, read sets again
            steps = sqp(a0, al, tau0, T, K, f, R, 0.0, k_sqp, lam, nu, 60, 1e-14)
            if steps >= 0:
                copy_into(k, k_sqp, m)
                t_up, low, share = finish_from(a0, al, tau0, T, K, f, k, lam, eta, 1e-6, tight)
                best = fold(best, k_best, k, t_up, low, box_status(share), SQP)
                done = closed(best)
    if not done and n == 4:
        best = try_releases(a0, al, tau0, T, K, f, k_sqp, best, k_best)
        done = closed(best)
    if not done and n == 4:
        best = try_push(a0, al, tau0, T, K, f, k_sqp, best, k_best)
        done = closed(best)
    if not done:
        best = try_fallback(a0, al, tau0, T, K, f, k_start, best, k_best)
    t_best = evaluate(k_best, a0, al, tau0, T, a, tau, rho, theta)
    excess = False
    for i in range(n):
        excess = excess or sqrt(a[i] ** 2 + rho[i] ** 2) > f * (1.0 + 1e-9)
    if excess and best.lower < pi / 2 and best.path != FALLBACK:
        # the best point exceeds the force limits, so its certificate says nothing about
        # them (where no k meets them, any bound holds): the fallback decides whether some
        # k does (its phase one), with a certificate if none does
        best = try_fallback(a0, al, tau0, T, K, f, stack_copy(k_best), best, k_best)
        t_best = evaluate(k_best, a0, al, tau0, T, a, tau, rho, theta)
        excess = False
        for i in range(n):
            excess = excess or sqrt(a[i] ** 2 + rho[i] ** 2) > f * (1.0 + 1e-9)
    for j in range(m):
        k[j] = k_best[j] * scale
    status = best.status
    if t_best >= pi / 2 or excess:
        # no k keeps every finger pushing (or meets the force limits; k then exceeds them
        # least): certified when lower == pi / 2
        status = NOT_PUSHING
    return best.lower, status, best.path


@entry
def solve_batch(F, E, N, K, f, k, theta, lower, status, path, follows, start, stop):
    """:func:`solve_one` for grasps start..stop of a flat batch (B, ...); releases the GIL.

    follows[b]: grasp b is near grasp b - 1 (the next pose of a trajectory), whose optimum
    (if solved in this call and not NOT_PUSHING) is its first start, extrapolated from grasp
    b - 2's where b - 1 follows it too, with the active sets its angles show.
    """
    for b in range(start, stop):
        near = follows[b] and b > start and path[b - 1] >= 0 and status[b - 1] != NOT_PUSHING
        secant = near and follows[b - 1] and b - 1 > start and path[b - 2] >= 0
        secant = secant and status[b - 2] != NOT_PUSHING
        c = max(b - 1, 0)  # the nearby grasp
        lower[b], status[b], path[b] = solve_one(
            F[b],
            E[b],
            N[b],
            K[b],
            f[b],
            k[b],
            theta[b],
            k[c],
            k[max(b - 2, 0)],
            theta[c],
            near,
            secant,
            F[c],
            E[c],
            N[c],
        )


@entry
def solve_grasp(F, E, N, K, f, k, theta):
    """:func:`solve_one` for one grasp, on its own: returns (max angle, lower, status, path).

    The entry of a single solve: a batch of one through :func:`solve_batch` made five arrays
    and passed eleven, and took 1.2x as long a call.
    """
    lower, status, path = solve_one(F, E, N, K, f, k, theta, k, k, theta, False, False, F, E, N)
    worst = theta[0]  # (theta.max() would need numba's runtime, see jit.py)
    for i in range(1, theta.shape[0]):
        worst = max(worst, theta[i])
    return worst, lower, status, path
