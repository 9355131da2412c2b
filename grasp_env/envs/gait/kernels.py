"""The gait environment's step: the compiled kernel that looks the move up in the task's
tables and scores the grip with the environments' step kernel
(:func:`~grasp_env.envs.kernels.evaluate_grips`), shared by the single and the vector
environment (:func:`_step`), and the certified grip of a move (:func:`optimal_actions`)."""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from ...mechanics.gait import MIN_LOADED
from ...mechanics.threads import available_cores, in_parts
from ..kernels import PARALLEL_FROM, evaluate_grips
from .tasks import GaitTask


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _allowed(x, t, m, csr, states, reach):
    """The CSR index of move ``m`` from state ``x`` at pose ``t``, or -1 if the rules refuse
    it (``csr`` says which moves keep the counts and sites; a placement needs reach)."""
    k = csr[x, m]
    if k >= 0 and m > 0:
        N = reach.shape[2]
        f = (m - 1) // N
        if states[x, f] < 0 and not reach[t, f, (m - 1) % N]:
            return -1  # a placement out of reach
    return k


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _score_grips(
    size, forces_w, directions, normals, pairs, chosen, ts, actions, moves_table, k_max_ratio,
    weight, limit, T, F, P, floats, flags,
):  # fmt: skip
    """The grips of the sub-environments whose loaded set has 3 + ``size`` fingers, scored by
    :func:`~grasp_env.envs.kernels.evaluate_grips` in one call (layout: :func:`_step`)."""
    n = forces_w.shape[1]
    m_pairs = directions.shape[1]
    count = 0
    for b in range(chosen.shape[0]):
        if chosen[b] >= 0 and moves_table[chosen[b], 2] == size:
            count += 1
    if count == 0:
        return
    S = forces_w.shape[0] // T
    items = np.empty(count, np.int64)
    rows = np.empty(count, np.int64)
    grip = np.empty((count, m_pairs))
    j = 0
    for b in range(chosen.shape[0]):
        k = chosen[b]
        if k >= 0 and moves_table[k, 2] == size:
            items[j] = b
            rows[j] = ts[b] * S + moves_table[k, 3]
            for q in range(m_pairs):
                grip[j, q] = actions[b, moves_table[k, 4 + q]]
            j += 1
    _, kk, net, angles, _, reward = evaluate_grips(
        forces_w, directions, normals, pairs, rows, grip, k_max_ratio, np.full(count, weight),
        np.full(count, limit),
    )  # fmt: skip
    FT, FK, FF, LOADED = 1, 1 + F, 1 + F + P, 4 + F
    for j in range(count):
        b = items[j]
        k = chosen[b]
        for i in range(n):  # released fingers (kernels.RELEASE) have angle 0
            f = moves_table[k, 10 + i]
            floats[b, FT + f] = angles[j, i]
            flags[b, LOADED + f] = True
            for a in range(3):
                floats[b, FF + 3 * f + a] = net[j, i, a]
        for q in range(m_pairs):
            floats[b, FK + moves_table[k, 4 + q]] = kk[j, q]
        floats[b, 0] = reward[j]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _step_kernel(
    xs, ts, actions, csr, states, ptr, code, moves_table, reach,
    forces3, directions3, normals3, pairs3, forces4, directions4, normals4, pairs4,
    params, observations, contact_obs, terminate_on_slip, floats, ints, flags, obs_out,
):  # fmt: skip
    """One step of B sub-environments in states ``xs`` at poses ``ts`` (see :func:`_step` for
    the layout of the outputs ``floats``, ``ints`` and ``flags``); ``params`` holds k_max / w,
    w and theta_lim, ``observations`` (T + 1, pose part + reach part).
    Returns False if an action is not finite."""
    k_max_ratio, weight, limit = params[0], params[1], params[2]
    B = xs.shape[0]
    F = states.shape[1]
    N = reach.shape[2]
    T = reach.shape[0]
    P = F * (F - 1) // 2
    base = N + 1
    chosen = np.full(B, -1, np.int64)
    floats[:] = 0.0
    flags[:] = False
    # floats: reward, theta (F), k (P), forces (3F); ints: next, move, contacts (F);
    # flags: dropped, refused, terminated, bad, lost (F), loaded (F), slip (F)
    FT = 1
    LOST, SLIP = 4, 4 + 2 * F
    for b in range(B):
        for a in range(actions.shape[1]):
            if not math.isfinite(actions[b, a]):
                flags[b, 3] = True
        x, t = xs[b], ts[b]
        ints[b, 1] = 0
        # 1. contacts out of reach are lost under load: the move is void
        left = 0
        c = 0
        power = 1
        lost_any = False
        for f in range(F):
            s = states[x, f]
            if s >= 0 and not reach[t, f, s]:
                flags[b, LOST + f] = True
                lost_any = True
            elif s >= 0:
                left += 1
                c += (s + 1) * power
            power *= base
        if lost_any:
            floats[b, 0] = limit - 0.5 * np.pi  # a lost finger's angle counts as 90 deg
            ints[b, 0] = code[c] if left >= MIN_LOADED else -1
            continue
        # 2. the move: the argmax of the scores (ties: the lower move, keep first)
        m = 0
        for j in range(1, actions.shape[1] - P):
            if actions[b, P + j] > actions[b, P + m]:
                m = j
        k = _allowed(x, t, m, csr, states, reach)
        if k < 0:
            flags[b, 1] = True
            k = ptr[x]  # keep
        chosen[b] = k
        ints[b, 1] = moves_table[k, 0]
        ints[b, 0] = moves_table[k, 1]
    # 3. the grips of the loaded sets, by the environments' step kernel (eq. 4, eq. 2), one
    # call per set size
    rest = (chosen, ts, actions, moves_table, k_max_ratio, weight, limit, T, F, P, floats, flags)
    _score_grips(0, forces3, directions3, normals3, pairs3, *rest)
    _score_grips(1, forces4, directions4, normals4, pairs4, *rest)
    # 4. the outcome and the next observations (the last pose's, phase 1, after the end)
    cells = contact_obs.shape[1]
    width = observations.shape[1] - cells
    for b in range(B):
        y = ints[b, 0]
        flags[b, 0] = y < 0
        any_slip = False
        for f in range(F):
            slip = flags[b, LOST + f] or floats[b, FT + f] > limit
            flags[b, SLIP + f] = slip
            any_slip = any_slip or slip
            ints[b, 2 + f] = -1 if y < 0 else states[y, f]
        flags[b, 2] = y < 0 or (terminate_on_slip and any_slip)
        t1 = min(ts[b] + 1, T)
        obs_out[b, :width] = observations[t1, :width]
        if y < 0:
            obs_out[b, width : width + cells] = 0.0
        else:
            obs_out[b, width : width + cells] = contact_obs[y]
        obs_out[b, width + cells :] = observations[t1, width:]
    finite = True
    for b in range(B):
        finite = finite and not flags[b, 3]
    return finite


def _step(
    task: GaitTask, xs: np.ndarray, ts: np.ndarray, actions: np.ndarray, terminate_on_slip: bool
) -> dict[str, np.ndarray]:
    """Step a batch of states ``xs`` (B,) at poses ``ts`` with ``actions`` (B, P + M): the
    next states (-1: dropped), rewards, terminations, observations and the info arrays, as
    views of three fresh buffers (one kernel call with few arguments: the single environment
    pays numba's per-argument dispatch on every step; a large batch is one call a core, on
    contiguous parts); a ValueError (and nothing changed) if an action is not finite."""
    B, F, P = len(xs), task.n_fingers, task.n_pairs
    floats, ints, flags, obs = _buffers(task, B)

    def part(lo: int, hi: int) -> bool:
        return _step_kernel(
            xs[lo:hi], ts[lo:hi], actions[lo:hi], *task.kernel_arrays, terminate_on_slip,
            floats[lo:hi], ints[lo:hi], flags[lo:hi], obs[lo:hi],
        )  # fmt: skip

    parts = available_cores() if B >= PARALLEL_FROM else 1
    if not all(in_parts("grasp-gait-step", B, part, parts)):
        rows = np.flatnonzero(flags[:, 3]).tolist()
        raise ValueError(f"actions must be finite numbers; rows {rows} are not")
    return {
        "reward": floats[:, 0],
        "theta": floats[:, 1 : 1 + F],
        "k": floats[:, 1 + F : 1 + F + P],
        "contact_forces": floats[:, 1 + F + P :].reshape(B, F, 3),
        "next": ints[:, 0],
        "move": ints[:, 1],
        "contacts": ints[:, 2:],
        "dropped": flags[:, 0],
        "refused": flags[:, 1],
        "terminated": flags[:, 2],
        "lost": flags[:, 4 : 4 + F],
        "loaded": flags[:, 4 + F : 4 + 2 * F],
        "slip": flags[:, 4 + 2 * F :],
        "obs": obs,
    }


def _buffers(task: GaitTask, B: int) -> tuple[np.ndarray, ...]:
    F, P = task.n_fingers, task.n_pairs
    return (
        np.empty((B, 1 + F + P + 3 * F)),
        np.empty((B, 2 + F), np.int64),
        np.empty((B, 4 + 3 * F), bool),
        np.empty((B, task.observation_size), np.float32),
    )


_INFO = ("refused", "lost", "move", "theta", "loaded", "k", "contact_forces", "slip", "contacts")


# ----------------------------------------------------------- the certified grip of a move


def optimal_actions(
    task: GaitTask, xs: np.ndarray, ts: np.ndarray, moves: np.ndarray
) -> np.ndarray:
    """The full actions (B, P + M) float32 that make ``moves`` (B,) from states ``xs`` at poses
    ``ts`` with the certified minimax grip of the fingers that then carry load: the move's
    score 1 (the others -1) and k / k_max of the loaded set's optimum (eq. 2, 4). A move the
    rules refuse gets the grip of keeping the contacts, which is what the step then does."""
    actions = np.empty((len(xs), task.n_pairs + task.n_moves), np.float32)
    table = task.table
    _optimal_actions(
        np.asarray(xs, np.int64), np.asarray(ts, np.int64), np.asarray(moves, np.int64),
        task.csr, table.states, table.ptr, task.solution.reach, task.moves_table, *task.grips,
        actions,
    )  # fmt: skip
    return actions


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _optimal_actions(xs, ts, moves, csr, states, ptr, reach, moves_table, grips3, grips4, out):
    """:func:`optimal_actions` into ``out`` (a refused move: :func:`_step_kernel` keeps)."""
    T = reach.shape[0]
    P = out.shape[1] - csr.shape[1]
    for b in range(xs.shape[0]):
        x, t, m = xs[b], ts[b], moves[b]
        k = _allowed(x, t, m, csr, states, reach)
        if k < 0:
            k = ptr[x]  # keep
        out[b, :P] = 0.0
        out[b, P:] = -1.0
        out[b, P + m] = 1.0
        grips = grips3 if moves_table[k, 2] == 0 else grips4
        row = t * (grips.shape[0] // T) + moves_table[k, 3]
        for q in range(grips.shape[1]):
            out[b, moves_table[k, 4 + q]] = grips[row, q]


def check_moves(moves: Any, shape: tuple[int, ...], count: int) -> np.ndarray:
    """``moves`` as an int64 array of ``shape`` (() for one), or a ValueError saying what a move
    is: an integer in [0, ``count``) (numpy integers too; booleans and floats refused)."""
    array = np.asarray(moves)
    if array.dtype.kind not in "iu" or array.shape != shape:
        raise ValueError(f"a move is an integer in [0, {count - 1}] (shape {shape}), got {moves!r}")
    if np.any(array < 0) or np.any(array >= count):
        raise ValueError(f"moves must be in [0, {count - 1}], got {moves!r}")
    return array.astype(np.int64)


__all__ = ["check_moves", "optimal_actions"]
