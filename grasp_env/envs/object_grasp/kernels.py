"""The step of the object environments: eq. 4 and eq. 2 on padded grasps, compiled.

A grasp of n real contacts is stored padded to N contacts and M = N (N - 1) / 2 pairs
(:mod:`.episodes`). The action's scalars of pairs with a padding contact are ignored; the
others give k = clip(a, -1, 1) k_max. With five or more contacts the pair directions are
redundant and the expert's box bounds the minimum-norm k of the interaction force E k
(docs/solver.md, "Any number of contacts"), so the step uses k' = E^+ E k, scaled back into
the box |k'_ij| <= k_max where it leaves it (k' k_max / max |k'_ij|): every grip of the box,
the expert's k* among them, is its own k', so no action earns more than the expert. For n <= 4
k' = k. Padding contacts report theta 0, margin theta_lim and no force.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..kernels import RELEASE, released

_kernel = numba.njit(cache=True, nogil=True, error_model="numpy")


@_kernel
def object_row(
    forces, directions, normals, pairs, row, actions, b, n, project, k_max_ratio, w, limit,
    k, net, theta, margin, unit, grip,
):  # fmt: skip
    """One (pose ``row``, action ``actions[b]``) pair of a grasp of ``n`` real contacts;
    ``project`` (M, M) is E^+ E. Fills ``k[b]`` (newtons), ``net[b]`` (newtons), ``theta[b]``
    and ``margin[b]``, using ``unit`` (N, 3) and ``grip`` (M,) as scratch; returns (finite,
    reward), reward = min_i margin_i over the real contacts."""
    big = forces.shape[1]
    m = directions.shape[1]
    finite = True
    for q in range(m):
        a = actions[b, q]
        if not math.isfinite(a):
            finite = False
        grip[q] = min(max(a, -1.0), 1.0) * k_max_ratio if pairs[q, 1] < n else 0.0
    if n >= 5:  # the minimum-norm k of the force E k, back in the box
        largest = 0.0
        for q in range(m):
            v = 0.0
            for r in range(m):
                v += project[q, r] * grip[r]
            k[b, q] = v
            largest = max(largest, abs(v))
        scale = k_max_ratio / largest if largest > k_max_ratio else 1.0
        for q in range(m):
            grip[q] = k[b, q] * scale
    for i in range(big):
        for c in range(3):
            unit[i, c] = forces[row, i, c]
    for q in range(m):
        kq = grip[q]
        k[b, q] = kq * w
        if kq == 0.0:
            continue
        i = pairs[q, 0]
        j = pairs[q, 1]
        for c in range(3):
            v = kq * directions[row, q, c]
            unit[i, c] += v
            unit[j, c] -= v
    small = (2.01 * RELEASE * (n - 1) * k_max_ratio) ** 2  # as grip_row's, n - 1 pairs a finger
    worst = np.inf
    for i in range(big):
        px, py, pz = unit[i, 0], unit[i, 1], unit[i, 2]
        net[b, i, 0], net[b, i, 1], net[b, i, 2] = px * w, py * w, pz * w
        if i >= n:
            theta[b, i] = 0.0
            margin[b, i] = limit
            continue
        tiny = px * px + py * py + pz * pz <= small
        if tiny and released(forces[row, i], k[b], w, pairs, i, unit[i]):
            theta[b, i] = 0.0
            margin[b, i] = limit
            worst = min(worst, limit)
            continue
        nx, ny, nz = normals[row, i, 0], normals[row, i, 1], normals[row, i, 2]
        cx = py * nz - pz * ny
        cy = pz * nx - px * nz
        cz = px * ny - py * nx
        tangential = math.sqrt(cx * cx + cy * cy + cz * cz)
        normal = px * nx + py * ny + pz * nz
        if normal > 0.0:
            t = math.atan(tangential / normal)
        elif tangential > 0.0:
            t = 0.5 * math.pi + math.atan(-normal / tangential)
        else:
            t = 0.0
        theta[b, i] = t
        margin[b, i] = limit - t
        worst = min(worst, limit - t)
    return finite, worst


@_kernel
def object_batch(
    forces, directions, normals, observations, alphas, expert_k, expert_reward, pairs, rows,
    actions, counts, projections, k_max_ratio, weight, limit,
    next_obs, reward, k, net, theta, margin, equilibrating, expert_k_out, expert_out, gap, alpha,
):  # fmt: skip
    """The vector step: :func:`object_row` for every sub-environment b (its pose ``rows[b]``
    of the store, ``counts[b]`` real contacts, ``projections[b]``), and the rest of its
    results in the same pass (as :func:`grasp_env.envs.kernels.step_batch`). Returns False if
    an action of a sub-environment is not finite."""
    big = forces.shape[1]
    m = directions.shape[1]
    unit = np.empty((big, 3))
    grip = np.empty(m)
    ok = True
    for b in range(rows.shape[0]):
        row = rows[b]
        w = weight[b]
        finite, r = object_row(
            forces, directions, normals, pairs, row, actions, b, counts[b], projections[b],
            k_max_ratio, w, limit[b], k, net, theta, margin, unit, grip,
        )  # fmt: skip
        ok &= finite
        reward[b] = r
        best = expert_reward[row]
        expert_out[b] = best
        gap[b] = best - r
        alpha[b] = alphas[row]
        for i in range(big):
            for c in range(3):
                equilibrating[b, i, c] = forces[row, i, c] * w
        for q in range(m):
            expert_k_out[b, q] = expert_k[row, q] * w
        for a in range(observations.shape[1]):
            next_obs[b, a] = observations[row + 1, a]
    return ok


__all__ = ["object_batch", "object_row"]
