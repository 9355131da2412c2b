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

from math import inf, pi

import numpy as np
from numba import njit

from ..codes import (
    BAD_F_MAX,
    BAD_K_MAX,
    BAD_LOAD,
    BOUNDARY,
    GAP_TOL,
    INTERIOR,
    INVALID,
    LOAD_RANGE,
    NOT_PUSHING,
    RATIO_RANGE,
)
from ..codes import UNCERTIFIED_STATUS as UNCERTIFIED
from ..fingers import setup
from .active import active_search
from .barrier import level
from .codes import BOUND_BELOW, CONVERGED, DINKELBACH_STEPS, POLISH_ROUNDS, kernel
from .frames import finger_forces, force_coordinates, largest_angle, reduced, start_at
from .polish import active_sets, polish


@kernel
def search(a0, al, tau0, T, box, K, f, best, theta, careful):
    """Dinkelbach's levels from k = 0, then the certificate just below the best grip (or the
    best bound further below), in the coordinates y; best moves to the best grip. careful:
    the schedule of the first solver (every level centred to LEVEL_GAP_CAREFUL, no stalled
    level cut short, the certificate from a level solved afresh), the fallback where the
    fast one (careful False) leaves a gap. best holds the start on entry (k = 0, or a grip
    found before) and the best grip on return. Returns (lower, share)."""
    n, m = al.shape
    pairs = box.shape[0]
    P = np.empty((n, 3))
    w = np.empty(n)
    x = np.empty(m + 1)
    trial = np.empty(m)
    cone = np.empty(n, dtype=np.int64)
    ball = np.empty(n, dtype=np.bool_)
    fixed = np.empty(pairs, dtype=np.int64)
    # (best: the start, k = 0 or the fast search's grip)
    finger_forces(best, a0, al, tau0, T, P)
    t_up = largest_angle(P, f, theta)
    lower, share = 0.0, 0.0
    t_last, tb_last = -1.0, 0.0  # the last level solved and its barrier parameter (x its point)
    # Dinkelbach: each minimiser's largest angle is the next level (inf: none holds yet)
    for _ in range(DINKELBACH_STEPS):
        if t_up <= GAP_TOL:
            break  # every finger within GAP_TOL of its normal: 0 bounds it
        t = min(t_up, pi / 2)
        start_at(best, a0, al, tau0, T, box, K, P, w, trial)
        upper, low, part, tb = level(t, w, trial, x, a0, al, tau0, T, box, K, f, False, careful)
        t_last, tb_last = t, tb
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
        if progress <= CONVERGED:
            break
    # the certificate just below the best grip from the last level's barrier point: its sets
    # are the optimum's once Dinkelbach has converged (else the rounds below solve a level
    # at t_up - 9e-10 afresh)
    if not careful and 0.0 < t_last < pi / 2 and lower < t_up - GAP_TOL and GAP_TOL < t_up < pi / 2:
        ct, st = np.cos(t_last), np.sin(t_last)
        active_sets(x, a0, al, tau0, T, box, K, f, ct, st, w, tb_last, cone, ball, fixed)
        t = t_up - BOUND_BELOW[0]
        for _ in range(n + 2):  # change the sets a pass
            trial[:] = x[:m]
            low, part, changed = polish(t, w, trial, a0, al, tau0, T, box, K, f, cone, ball, fixed)
            finger_forces(trial, a0, al, tau0, T, P)
            t_new = largest_angle(P, f, theta)
            if t_new < t_up:  # a better grip (the rounds below seek a certificate below it)
                t_up = t_new
                best[:] = trial
            if low > 0.0 or not changed:
                break
        if low > 0.0:
            lower, share = t, part
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
        upper, low, part, tb = level(t, w, trial, x, a0, al, tau0, T, box, K, f, True, careful)
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
        upper, low, part, tb = level(t, w, trial, x, a0, al, tau0, T, box, K, f, True, careful)
        if low > 0.0:
            lower, share = t, part
            break
    return lower, share


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
    scale, code = setup(F, E, N, a0, al, tau0, T)  # the finger frames, in units of the load
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
    # first the active-set attempt (an SQP, then the KKT polish's certificate on its sets)
    found = np.zeros(m)
    found_lower, found_share = active_search(a0, al, tau0, T, box, K, f, found, theta)
    finger_forces(found, a0, al, tau0, T, P)
    t_found = largest_angle(P, f, theta)
    if t_found < pi / 2 and t_found - found_lower <= GAP_TOL:
        for j in range(pairs):
            v = 0.0
            for p in range(m):
                v += box[j, p] * found[p]
            k[j] = v * scale
        return found_lower, BOUNDARY if found_share > 1e-6 else INTERIOR
    # not certified: the barrier search as before, its result folded with the attempt's
    best = np.zeros(m)  # k = 0: the equilibrating forces alone
    lower, share = search(a0, al, tau0, T, box, K, f, best, theta, False)
    finger_forces(best, a0, al, tau0, T, P)
    t_best = largest_angle(P, f, theta)
    # a gap left open: the careful schedule from the fast search's grip, then (a gap still
    # open) from k = 0 (the first solver's search, as it was); the best grip and the best
    # bound of them all (each bound is a proof and each grip attained, whichever search
    # found them)
    other = np.empty(m)
    for start in range(2):
        if not (lower < t_best - GAP_TOL and lower < pi / 2 and t_best < pi / 2):
            break
        if start == 0:
            other[:] = best
        else:
            other[:] = 0.0
        low, part = search(a0, al, tau0, T, box, K, f, other, theta, True)
        finger_forces(other, a0, al, tau0, T, P)
        t_other = largest_angle(P, f, theta)
        if t_other < t_best:
            t_best = t_other
            best[:] = other
        if low > lower:
            lower, share = low, part
    # (each bound is a proof and each grip attained, whichever attempt found them)
    if t_found < t_best:
        t_best = t_found
        best[:] = found
    if found_lower > lower:
        lower, share = found_lower, found_share
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


@njit(cache=True, nogil=True, error_model="numpy")
def solve_batch(F, E, N, K, f, k, theta, lower, status, start, stop):
    """:func:`solve_one` for grasps start..stop of a flat batch; releases the GIL."""
    for b in range(start, stop):
        lower[b], status[b] = solve_one(F[b], E[b], N[b], K[b], f[b], k[b], theta[b])
