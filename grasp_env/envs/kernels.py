"""The environments' compiled kernels: the step (eq. 4 and eq. 2 for a batch of grips) and the
per-pose geometry of episodes (the numpy mechanics written out per pose).

The single and the vector environments step through the one kernel :func:`grip_row` (the single
env by :func:`step_grip`, the batches by :func:`evaluate_grips` and :func:`step_batch`), so all
compute the very same numbers. Building an episode (and screening candidate scenes) costs one
minimax solve per pose; around it, numpy's per-call costs on batches of a few hundred poses came
to as much again, so :func:`pose_geometry` does the arithmetic of
:func:`grasp_env.mechanics.pose_rotation`, :func:`~grasp_env.mechanics.grasp` and
:func:`~grasp_env.mechanics.equilibrating_forces` in one pass (``tests/test_envs.py`` checks it
against those functions), and :func:`observation_grasps` rebuilds the grasp from observations
for the expert.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Every division here is guarded or divides by a count or a validated positive scale, so the
# numpy error model's plain division is safe; the python model's zero checks cost a third of
# the step.
_kernel = numba.njit(cache=True, nogil=True, error_model="numpy")

#: A finger is released when its net force is at most this fraction of the forces it is made
#: of: |P_i| <= RELEASE (|F_i| + sum_j |k_ij|). Such a P_i is the rounding left by forces that
#: cancel (the solver's optimum releases fingers exactly, but a float32 action leaves about
#: 1e-8 of those forces, measured on random four-finger scenes and in the gait environment), so
#: its direction means nothing: the finger counts as inside its cone, theta_i = 0, as in the
#: solver (which holds a released finger at its cone's apex). Forces of 1e-5 w and more, which
#: the optimum does use, are far above it.
RELEASE = 1e-6

#: From this many sub-environments a vector step's kernel is split across the cores this
#: process may use (the grasp and the gait envs': their kernels release the GIL and each row
#: depends on its own inputs alone); fewer are not worth the hand-off to a thread.
PARALLEL_FROM = 512


@_kernel
def _equilibrating(p, force, torque, out):
    """Minimum-norm forces F_i = -f / n + mu x q_i balancing (f, tau) at contacts p (n, 3);
    False (and ``out`` untouched) if the contacts are collinear.

    The closed form of :func:`grasp_env.mechanics.equilibrating_forces` (q_i = p_i - c about
    the contacts' centroid c, J mu = c x f - tau with J = sum_i |q_i|^2 I - q_i q_i^T).
    """
    n = p.shape[0]
    c = np.zeros(3)
    for i in range(n):
        for a in range(3):
            c[a] += p[i, a]
    for a in range(3):
        c[a] /= n
    q = np.empty((n, 3))
    j = np.zeros((3, 3))
    for i in range(n):
        for a in range(3):
            q[i, a] = p[i, a] - c[a]
        s = q[i, 0] ** 2 + q[i, 1] ** 2 + q[i, 2] ** 2
        for a in range(3):
            j[a, a] += s
            for b in range(3):
                j[a, b] -= q[i, a] * q[i, b]
    r0 = c[1] * force[2] - c[2] * force[1] - torque[0]
    r1 = c[2] * force[0] - c[0] * force[2] - torque[1]
    r2 = c[0] * force[1] - c[1] * force[0] - torque[2]
    # J symmetric positive definite: solve by the adjugate
    c00 = j[1, 1] * j[2, 2] - j[1, 2] * j[1, 2]
    c01 = j[0, 2] * j[1, 2] - j[0, 1] * j[2, 2]
    c02 = j[0, 1] * j[1, 2] - j[0, 2] * j[1, 1]
    c11 = j[0, 0] * j[2, 2] - j[0, 2] * j[0, 2]
    c12 = j[0, 1] * j[0, 2] - j[0, 0] * j[1, 2]
    c22 = j[0, 0] * j[1, 1] - j[0, 1] * j[0, 1]
    det = j[0, 0] * c00 + j[0, 1] * c01 + j[0, 2] * c02
    if not det > 0.0:  # collinear or coinciding contacts (or NaN): no grasp
        return False
    m0 = (c00 * r0 + c01 * r1 + c02 * r2) / det
    m1 = (c01 * r0 + c11 * r1 + c12 * r2) / det
    m2 = (c02 * r0 + c12 * r1 + c22 * r2) / det
    for i in range(n):
        out[i, 0] = -force[0] / n + m1 * q[i, 2] - m2 * q[i, 1]
        out[i, 1] = -force[1] / n + m2 * q[i, 0] - m0 * q[i, 2]
        out[i, 2] = -force[2] / n + m0 * q[i, 1] - m1 * q[i, 0]
    return True


@_kernel
def _directions(p, pairs, out):
    """u_ij = (p_j - p_i) / |p_j - p_i| for the pairs (m, 2): out (m, 3); False if two
    contacts coincide."""
    for q in range(pairs.shape[0]):
        i, j = pairs[q, 0], pairs[q, 1]
        d0 = p[j, 0] - p[i, 0]
        d1 = p[j, 1] - p[i, 1]
        d2 = p[j, 2] - p[i, 2]
        norm = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if not norm > 0.0:
            return False
        out[q, 0] = d0 / norm
        out[q, 1] = d1 / norm
        out[q, 2] = d2 / norm
    return True


@_kernel
def pose_geometry(
    relative, object_normals, axis, alpha_start, alpha_step, length, weight, mu,
    extra_force, extra_torque, edge, episode, step, start_rotation, pairs, low, high,
    alphas, rotations, positions, forces, directions, normals, observations, limit,
):  # fmt: skip
    """The world-frame grasp and observation of poses (episode[P], step[P]) of E scenes, with
    forces in units of the weight w (so that nothing depends on its scale).

    Scene arrays: ``relative`` contacts c_i - g and ``object_normals`` (E, n, 3), unit ``axis``
    (E, 3), trajectory ``alpha_start``, ``alpha_step`` (degrees) and ``length``, ``weight``,
    ``mu``, ``extra_force`` and ``extra_torque`` (E, 3, newtons), and the cube's ``edge`` L.
    Fills ``alphas`` (P,), ``rotations`` R = Rot(axis, alpha) R0 (P, 3, 3) (eq. 5), the contact
    ``positions`` p_i (P, n, 3), the equilibrating ``forces`` F_i / w (P, n, 3), ``directions``
    u_ij (P, m, 3), ``normals`` (P, n, 3), ``observations`` (P, size) float32 clipped to
    [``low``, ``high``] (the layout of :mod:`grasp_env.envs.observation`), and ``limit`` =
    atan(mu) (P,).
    """
    n = relative.shape[1]
    rot = np.empty((3, 3))
    force = np.empty(3)
    torque = np.empty(3)
    row = np.empty(observations.shape[1])
    for b in range(episode.shape[0]):
        e = episode[b]
        alpha = alpha_start[e] + alpha_step[e] * step[b]
        alphas[b] = alpha
        angle = np.deg2rad(alpha)
        cos, sin = math.cos(angle), math.sin(angle)
        rx, ry, rz = axis[e, 0], axis[e, 1], axis[e, 2]
        # R = cos I + (1 - cos) r r^T + sin [r]x, then times R0
        rot[0, 0] = cos + (1 - cos) * rx * rx
        rot[0, 1] = (1 - cos) * rx * ry - sin * rz
        rot[0, 2] = (1 - cos) * rx * rz + sin * ry
        rot[1, 0] = (1 - cos) * ry * rx + sin * rz
        rot[1, 1] = cos + (1 - cos) * ry * ry
        rot[1, 2] = (1 - cos) * ry * rz - sin * rx
        rot[2, 0] = (1 - cos) * rz * rx - sin * ry
        rot[2, 1] = (1 - cos) * rz * ry + sin * rx
        rot[2, 2] = cos + (1 - cos) * rz * rz
        for r in range(3):
            for c in range(3):
                rotations[b, r, c] = (
                    rot[r, 0] * start_rotation[0, c]
                    + rot[r, 1] * start_rotation[1, c]
                    + rot[r, 2] * start_rotation[2, c]
                )
        big = rotations[b]
        p = positions[b]
        for i in range(n):
            for r in range(3):
                normals[b, i, r] = (
                    big[r, 0] * object_normals[e, i, 0]
                    + big[r, 1] * object_normals[e, i, 1]
                    + big[r, 2] * object_normals[e, i, 2]
                )
                p[i, r] = (
                    big[r, 0] * relative[e, i, 0]
                    + big[r, 1] * relative[e, i, 1]
                    + big[r, 2] * relative[e, i, 2]
                )
        # the load in units of w: f / w = (0, 0, -1) + f_d / w, tau / w (metres)
        w = weight[e]
        for a in range(3):
            force[a] = extra_force[e, a] / w
            torque[a] = extra_torque[e, a] / w
        force[2] -= 1.0
        _equilibrating(p, force, torque, forces[b])
        _directions(p, pairs, directions[b])
        limit[b] = math.atan(mu[e])
        # the observation: lengths in units of L, forces of w
        for a in range(3):  # R's first two columns, one after the other
            row[a] = big[a, 0]
            row[3 + a] = big[a, 1]
        for i in range(n):
            for a in range(3):
                row[6 + 3 * i + a] = p[i, a] / edge
                row[6 + 3 * n + 3 * i + a] = normals[b, i, a]
        for a in range(3):
            row[6 + 6 * n + a] = force[a]
            row[9 + 6 * n + a] = torque[a] / edge
        row[12 + 6 * n] = limit[b]
        row[13 + 6 * n] = step[b] / length[e]
        for a in range(row.shape[0]):
            observations[b, a] = min(max(row[a], low[a]), high[a])


@_kernel
def observation_grasps(observations, pairs, forces, basis, normals):
    """The grasps in an observation batch (B, size), in units of w and L: the equilibrating
    ``forces`` (B, n, 3), the interaction ``basis`` e_ij (B, m, n, 3) and the ``normals``.
    Returns the index of the first observation whose contacts are collinear, or -1."""
    n = forces.shape[1]
    positions = np.empty((n, 3))
    force = np.empty(3)
    torque = np.empty(3)
    u = np.empty((pairs.shape[0], 3))
    for b in range(observations.shape[0]):
        obs = observations[b]
        for i in range(n):
            for a in range(3):
                positions[i, a] = obs[6 + 3 * i + a]
                normals[b, i, a] = obs[6 + 3 * n + 3 * i + a]
        for a in range(3):
            force[a] = obs[6 + 6 * n + a]
            torque[a] = obs[9 + 6 * n + a]
        if not (
            _equilibrating(positions, force, torque, forces[b]) and _directions(positions, pairs, u)
        ):
            return b
        basis[b] = 0.0
        for q in range(pairs.shape[0]):
            for a in range(3):
                basis[b, q, pairs[q, 0], a] = u[q, a]
                basis[b, q, pairs[q, 1], a] = -u[q, a]
    return -1


@_kernel
def released(force, k, w, pairs, i, p):
    """Whether finger ``i`` is released (:data:`RELEASE`): its net force ``p`` = P_i / w, at
    most RELEASE times the equilibrating ``force`` F_i / w and the grips ``k`` (newtons, the
    weight ``w``) it is made of."""
    size = math.sqrt(force[0] ** 2 + force[1] ** 2 + force[2] ** 2)
    for q in range(pairs.shape[0]):
        if pairs[q, 0] == i or pairs[q, 1] == i:
            size += abs(k[q]) / w
    return math.sqrt(p[0] ** 2 + p[1] ** 2 + p[2] ** 2) <= RELEASE * size


@_kernel
def grip_row(
    forces, directions, normals, pairs, row, actions, b, k_max_ratio, w, limit, k, net, theta,
    margin, unit,
):  # fmt: skip
    """:func:`step_grip` for row ``b`` of batched arrays: ``actions`` (B, m), and it fills
    ``k[b]``, ``net[b]``, ``theta[b]`` and ``margin[b]`` by index. The one step of every
    environment: the batched kernels call it row by row without taking slices (each slice of an
    array costs numba a reference count, which came to a sixth of the vector step).
    """
    n = forces.shape[1]
    m = directions.shape[1]
    finite = True
    for i in range(n):
        for c in range(3):
            unit[i, c] = forces[row, i, c]
    for q in range(m):
        a = actions[b, q]
        if not math.isfinite(a):
            finite = False
        kq = min(max(a, -1.0), 1.0) * k_max_ratio
        k[b, q] = kq * w
        # P_i += k_ij u_ij and P_j -= k_ij u_ij: the basis e_ij of eq. 4
        i = pairs[q, 0]
        j = pairs[q, 1]
        for c in range(3):
            v = kq * directions[row, q, c]
            unit[i, c] += v
            unit[j, c] -= v
    # A released finger has |P_i| <= RELEASE (|F_i| + S_i), S_i = sum_j |k_ij| / w, so (by
    # |F_i| <= |P_i| + S_i) |P_i| <= 2 RELEASE S_i / (1 - RELEASE) <= 2.01 RELEASE (n - 1)
    # k_max / w: only forces that small are looked at closely.
    small = (2.01 * RELEASE * (n - 1) * k_max_ratio) ** 2
    worst = np.inf
    for i in range(n):
        px, py, pz = unit[i, 0], unit[i, 1], unit[i, 2]
        net[b, i, 0], net[b, i, 1], net[b, i, 2] = px * w, py * w, pz * w
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
        # eq. 2 as atan2(|P x n|, P . n), accurate near 0 where acos is not; written with
        # atan, which costs half as much as atan2 here (the step's largest cost)
        tangential = math.sqrt(cx * cx + cy * cy + cz * cz)
        normal = px * nx + py * ny + pz * nz
        if normal > 0.0:
            t = math.atan(tangential / normal)
        elif tangential > 0.0:
            t = 0.5 * math.pi + math.atan(-normal / tangential)
        else:  # unreachable: P_i = 0 is released
            t = 0.0
        theta[b, i] = t
        margin[b, i] = limit - t
        worst = min(worst, limit - t)
    return finite, worst


@_kernel
def step_grip(
    forces, directions, normals, pairs, row, action, k_max_ratio, w, limit, k, net, theta, margin,
    unit,
):  # fmt: skip
    """One (pose, action) pair: the step of every environment (eq. 4 and eq. 2), computed in
    units of the weight w and reported in newtons.

    ``forces`` (R, n, 3) equilibrating forces F_i / w, ``directions`` (R, m, 3) the unit
    vectors u_ij and ``normals`` (R, n, 3) of R stored poses, of which ``row`` is the one;
    ``action`` (m,) is clipped to [-1, 1] and scaled by ``k_max_ratio`` (k_max / w); ``w`` is
    the weight, newtons, and ``limit`` theta_lim. Fills ``k`` (m,) and ``net`` (n, 3) P in
    newtons, ``theta`` and ``margin`` (n,), using ``unit`` (n, 3) as scratch for P / w;
    returns (finite, reward): finite is False if an action element is not finite (the outputs
    are then meaningless). A released finger (:data:`RELEASE`) has theta_i = 0. The angles of
    P / w do not depend on w, and nothing here can overflow or underflow for any w. The
    arithmetic is :func:`grip_row`'s, on the arrays as batches of one (contiguous arrays).
    """
    m, n = action.shape[0], theta.shape[0]
    return grip_row(
        forces, directions, normals, pairs, row, action.reshape(1, m), 0, k_max_ratio, w, limit,
        k.reshape(1, m), net.reshape(1, n, 3), theta.reshape(1, n), margin.reshape(1, n), unit,
    )  # fmt: skip


@_kernel
def evaluate_grips(forces, directions, normals, pairs, rows, actions, k_max_ratio, weight, limit):
    """:func:`step_grip` for a batch of (pose, action) pairs: ``rows`` (B,) pick the poses,
    ``actions`` (B, m), ``weight`` and ``limit`` (B,). Returns (ok, k, P, theta, margin,
    reward), k (B, m) and P (B, n, 3) in newtons; ok is False if an action is not finite."""
    count = rows.shape[0]
    n = forces.shape[1]
    m = directions.shape[1]
    k = np.empty((count, m))
    net = np.empty((count, n, 3))
    theta = np.empty((count, n))
    margin = np.empty((count, n))
    reward = np.empty(count)
    unit = np.empty((n, 3))
    ok = True
    for b in range(count):
        finite, reward[b] = grip_row(
            forces, directions, normals, pairs, rows[b], actions, b, k_max_ratio, weight[b],
            limit[b], k, net, theta, margin, unit,
        )  # fmt: skip
        ok &= finite
    return ok, k, net, theta, margin, reward


@_kernel
def step_batch(
    forces, directions, normals, observations, alphas, expert_k, expert_reward, pairs, rows,
    actions, k_max_ratio, weight, limit,
    next_obs, reward, k, net, theta, margin, equilibrating, expert_k_out, expert_out, gap, alpha,
):  # fmt: skip
    """The vector environments' step: :func:`step_grip` for every sub-environment and, in the
    same pass, the rest of its step's results (one read of each stored row, no temporaries).

    Stored rows (the vector env's store): ``forces`` and ``expert_k`` in units of w,
    ``directions``, ``normals``, ``observations`` (observation t + 1 follows pose t),
    ``alphas`` and ``expert_reward``. Per sub-environment: ``rows``, ``actions``, ``weight``
    and ``limit``. Fills ``next_obs``, ``reward``, ``k``, ``net``, ``theta``, ``margin``,
    ``equilibrating`` (F in newtons), ``expert_k_out`` (newtons), ``expert_out``, ``gap`` =
    expert reward - reward and ``alpha``.
    """
    n = forces.shape[1]
    m = directions.shape[1]
    unit = np.empty((n, 3))
    for b in range(rows.shape[0]):
        row = rows[b]
        w = weight[b]
        _, r = grip_row(
            forces, directions, normals, pairs, row, actions, b, k_max_ratio, w, limit[b], k,
            net, theta, margin, unit,
        )  # fmt: skip
        reward[b] = r
        best = expert_reward[row]
        expert_out[b] = best
        gap[b] = best - r
        alpha[b] = alphas[row]
        for i in range(n):
            for c in range(3):
                equilibrating[b, i, c] = forces[row, i, c] * w
        for q in range(m):
            expert_k_out[b, q] = expert_k[row, q] * w
        for a in range(observations.shape[1]):
            next_obs[b, a] = observations[row + 1, a]
