"""The gait environment: hold the cube along a long rotation, choosing at every pose the grip
and which finger to phase out or in (issue 16, docs/gait.md).

Everything that does not depend on the agent is computed once per configuration (and shared by
every environment made with it): the certified minimax of every site set at every pose, the
hand's reach, the state tables of :mod:`grasp_env.mechanics.gait` and the dynamic programme's
policy, which is the expert. A step looks up the move in the tables and scores the grip with
the environments' step kernel :func:`~grasp_env.envs.kernels.evaluate_grips`; the single and
the vector environments share :func:`_step`, so they compute the very same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from itertools import combinations
from numbers import Integral
from typing import Any

import gymnasium as gym
import numba
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..mechanics import (
    PAPER_TURN,
    GaitScene,
    GaitSolution,
    Hand,
    Trajectory,
    contact_pairs,
    solve_gait,
)
from ..mechanics.checks import is_integer
from ..mechanics.gait import MIN_LOADED, GaitStates, gait_states
from ..mechanics.threads import available_cores, in_parts
from .kernels import PARALLEL_FROM, evaluate_grips
from .validation import (
    DEFAULT_K_MAX_RATIO,
    MAX_ENVS,
    MU_RANGE,
    TRAJECTORY_KEYS,
    action_array,
    check_autoreset_mode,
    check_bool,
    check_integer,
    check_k_max_ratio,
    check_max_episode_steps,
    check_number,
    check_seed,
    check_trajectory,
    end_step,
    refuse_ended,
    split_reset_mask,
)

#: The paper's axis over [-90, 90] deg in 1 deg steps, as the ``trajectory`` keyword's mapping.
PAPER_TURN_SPEC = {key: getattr(PAPER_TURN, key) for key in TRAJECTORY_KEYS}
_SQRT3 = float(np.sqrt(3.0))


# ------------------------------------------------------------------------------- the task


@dataclass(frozen=True, eq=False)
class GaitTask:
    """One configuration's precomputed tables (read-only, shared between environments).

    Attributes:
        solution: the certified gait problem solved (values, reach, optimal and greedy gaits
            with their policies over every state).
        start: the state index episodes start from.
        csr: (X, M) the CSR index of move m from state x, -1 where the move breaks the rules.
        pair_columns: (K, 6) for every CSR move, the action column (finger pair) of each
            interaction pair of the loaded set, in the set's order (its sites increasing).
        set_fingers: (K, 4) the finger at each contact of the loaded set, -1 past its size.
        group, column: (K,) the loaded set's size group (0: three, 1: four) and its column.
        moves_table: (K, 14) the step kernel's per-move table: move, next state, group,
            column, pair_columns, set_fingers.
        grasps: per group, (T * S_n, n, 3) equilibrating forces F / w, (T * S_n, m, 3) unit
            pair directions u_ij, (T * S_n, n, 3) normals (row t * S_n + column) and the
            pairs (m, 2).
        grips: per group, (T * S_n, m) float32 the certified minimax grip k* / k_max of every
            set at every pose (row t * S_n + column), clipped to the action box: the grip
            part of the actions of ``optimal_grip`` (:func:`optimal_actions`).
        observations: (T + 1, 14 + 6 N) the pose part of the observation, row T after the end.
        reach_obs: (T + 1, F N) float32 reach flags.
        contact_obs: (X, F N) float32 one-hot contacts of every state.
    """

    solution: GaitSolution
    start: int
    csr: np.ndarray
    pair_columns: np.ndarray
    set_fingers: np.ndarray
    group: np.ndarray
    column: np.ndarray
    moves_table: np.ndarray
    grasps: tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], ...]
    grips: tuple[np.ndarray, np.ndarray]
    observations: np.ndarray
    reach_obs: np.ndarray
    contact_obs: np.ndarray
    k_max_ratio: float
    alphas: np.ndarray

    @cached_property
    def table(self) -> GaitStates:
        return self.solution.optimal.table

    @cached_property
    def n_poses(self) -> int:
        return len(self.alphas)

    @cached_property
    def n_fingers(self) -> int:
        return self.solution.hand.n_fingers

    @cached_property
    def n_sites(self) -> int:
        return self.solution.scene.n_sites

    @cached_property
    def n_pairs(self) -> int:
        return self.n_fingers * (self.n_fingers - 1) // 2

    @cached_property
    def n_moves(self) -> int:
        return 1 + self.n_fingers * self.n_sites

    @cached_property
    def weight(self) -> float:
        return self.solution.scene.weight

    @cached_property
    def limit(self) -> float:
        return self.solution.scene.friction_limit

    def pose_size(self) -> int:
        return 14 + 6 * self.n_sites

    @cached_property
    def expert_margins(self) -> np.ndarray:
        return self.solution.optimal.margins

    @cached_property
    def observation_size(self) -> int:
        return self.pose_size() + 2 * self.n_fingers * self.n_sites

    @cached_property
    def kernel_arrays(self) -> tuple:
        """The step kernel's task arguments, in its order."""
        table = self.table
        return (
            self.csr, table.states, table.ptr, table.code, self.moves_table, self.solution.reach,
            *self.grasps[0], *self.grasps[1],
            np.array([self.k_max_ratio, self.weight, self.limit]),
            np.ascontiguousarray(np.hstack([self.observations, self.reach_obs])),
            self.contact_obs,
        )  # fmt: skip


def _pose_observations(solution: GaitSolution) -> np.ndarray:
    """Rotation (6), site positions / L (3N), site normals (3N), load / w (3), torque / (w L)
    (3), theta_lim and phase: (T + 1, 14 + 6N) float32, row T the last pose with phase 1."""
    scene = solution.scene
    rotations = solution.trajectory.rotations()
    T = len(rotations)
    relative = scene.sites - np.asarray(scene.cg_offset)
    positions = np.einsum("tij,nj->tni", rotations, relative) / scene.size
    normals = np.einsum("tij,nj->tni", rotations, scene.normals)
    force = np.array([0.0, 0.0, -1.0]) + np.asarray(scene.extra_force) / scene.weight
    torque = np.asarray(scene.extra_torque) / (scene.weight * scene.size)
    rows = np.concatenate(
        [
            rotations[:, :, 0],
            rotations[:, :, 1],
            positions.reshape(T, -1),
            normals.reshape(T, -1),
            np.broadcast_to(force, (T, 3)),
            np.broadcast_to(torque, (T, 3)),
            np.full((T, 1), scene.friction_limit),
            (np.arange(T) / T)[:, None],
        ],
        axis=1,
    )
    last = rows[-1:].copy()
    last[0, -1] = 1.0
    return np.vstack([rows, last]).astype(np.float32)


@lru_cache(maxsize=8)
def gait_task(
    trajectory: Trajectory, mu: float, cone_deg: float, k_max_ratio: float, start: tuple | None
) -> GaitTask:
    """The task of one configuration (cached: every environment made with it shares it)."""
    scene = GaitScene(mu=mu)
    hand = Hand(cone_deg=cone_deg)
    table = gait_states(hand.n_fingers, scene.n_sites)
    first = None if start is None else table.states[table.index(start, "start")]
    solution = solve_gait(scene, hand, trajectory, k_max_ratio * scene.weight, first)
    F, N = table.n_fingers, table.n_sites
    X, M = len(table.states), table.n_moves
    if not solution.holds:
        if first is not None:
            reach = solution.reach[0]
            away = [(f, int(s)) for f, s in enumerate(first) if s >= 0 and not reach[f, s]]
            if away:
                raise ValueError(
                    f"start {list(start)}: at the first pose these (finger, site) pairs are out of"
                    f" reach (cone_deg={cone_deg}): {away}"
                )
        origin = "" if start is None else f" from start {list(start)}"
        raise ValueError(
            f"no gait{origin} keeps three fingers on sites within reach along this trajectory"
            f" (cone_deg={cone_deg}); widen the cone or shorten the trajectory"
        )
    x0 = int(solution.optimal.states[0])
    csr = np.full((X, M), -1, np.int64)
    owner = np.repeat(np.arange(X), np.diff(table.ptr))
    csr[owner, table.move] = np.arange(len(table.move))
    finger_pairs = {p: q for q, p in enumerate(combinations(range(F), 2))}
    K = len(table.move)
    pair_columns = np.zeros((K, 6), np.int64)
    set_fingers = np.full((K, 4), -1, np.int64)
    group = np.empty(K, np.int64)
    column = np.empty(K, np.int64)
    lookup = {}
    for members in solution.values.groups:
        for c, s in enumerate(members.members):
            lookup[int(s)] = (members.sites.shape[1] - 3, c)
    sets = solution.values.sets
    for k in range(K):
        a = table.states[owner[k]].copy()
        m = int(table.move[k])
        if m:
            f, s = divmod(m - 1, N)
            if a[f] == s:
                a[f] = -1  # lifted: carries no load
        sites = sets[table.loaded[k]]
        fingers = [int(np.flatnonzero(a == s)[0]) for s in sites]
        set_fingers[k, : len(fingers)] = fingers
        for q, (i, j) in enumerate(combinations(range(len(fingers)), 2)):
            pair_columns[k, q] = finger_pairs[tuple(sorted((fingers[i], fingers[j])))]
        group[k], column[k] = lookup[int(table.loaded[k])]
    grasps, grips = [], []
    for n in (3, 4):
        p = contact_pairs(n)
        found = [m for m in solution.values.groups if m.sites.shape[1] == n]
        if not found:  # no usable set of this size: a placeholder no move refers to
            grasps.append((np.zeros((0, n, 3)), np.zeros((0, len(p), 3)), np.zeros((0, n, 3)), p))
            grips.append(np.zeros((0, len(p)), np.float32))
            continue
        k_star = found[0].optimum.k / (k_max_ratio * scene.weight)
        grips.append(np.clip(k_star, -1, 1).reshape(-1, len(p)).astype(np.float32))
        g = found[0].grasp
        T, S = g.equilibrating.shape[:2]
        u = g.basis[:, :, np.arange(len(p)), p[:, 0], :]  # +u_ij at contact i
        grasps.append(
            (
                np.ascontiguousarray(g.equilibrating.reshape(T * S, n, 3) / scene.weight),
                np.ascontiguousarray(u.reshape(T * S, len(p), 3)),
                np.ascontiguousarray(g.normals.reshape(T * S, n, 3)),
                p,
            )
        )
    reach = solution.reach.reshape(len(solution.trajectory), -1).astype(np.float32)
    contact_obs = np.zeros((X, F, N), np.float32)
    fingers, touched = np.nonzero(table.states >= 0)
    contact_obs[fingers, touched, table.states[fingers, touched]] = 1.0
    task = GaitTask(
        solution,
        x0,
        csr,
        pair_columns,
        set_fingers,
        group,
        column,
        np.column_stack([table.move, table.next, group, column, pair_columns, set_fingers]),
        tuple(grasps),
        (grips[0], grips[1]),
        _pose_observations(solution),
        np.vstack([reach, reach[-1:]]),
        contact_obs.reshape(X, F * N),
        k_max_ratio,
        solution.trajectory.alphas_deg,
    )
    for array in (csr, pair_columns, set_fingers, group, column, task.moves_table, *grips):
        array.flags.writeable = False
    return task


# ------------------------------------------------------------------------------ the step


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


# ------------------------------------------------------------------------- the policies


class _GaitPolicy:
    """Acts from observations with a move table over (pose, state) and the certified grip."""

    def __init__(
        self,
        trajectory: Mapping[str, Any] | None = None,
        mu: float = 0.5,
        cone_deg: float = 60.0,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        start: Sequence[int] | None = None,
        optimal_grip: bool = False,
    ) -> None:
        self.task = _task(trajectory, mu, cone_deg, k_max_ratio, start)
        self.optimal_grip = check_bool("optimal_grip", optimal_grip)

    def _policy(self) -> np.ndarray:
        raise NotImplementedError

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """Actions for one observation (size,) or a batch (B, size): returns (actions, None)
        (the signature of a Stable-Baselines3 model's ``predict``); with ``optimal_grip``
        the moves alone (int64), the actions of ``grasp_env/CubeGaitMoves-v0``."""
        task = self.task
        obs = np.asarray(observation, dtype=np.float64)
        size = task.pose_size() + 2 * task.n_fingers * task.n_sites
        if obs.ndim not in (1, 2) or obs.shape[-1] != size:
            raise ValueError(f"observation must be ({size},) or (batch, {size}), got {obs.shape}")
        if not np.all(np.isfinite(obs)):
            raise ValueError("observation must be finite")
        batch = obs.reshape(-1, size)
        T, F, N = task.n_poses, task.n_fingers, task.n_sites
        phase = batch[:, task.pose_size() - 1]
        if np.any((phase < 0.0) | (phase > 1.0)):  # outside the space: no pose of the run
            raise ValueError(
                f"the observation's phase (entry {task.pose_size() - 1}) must be within [0, 1],"
                f" got {phase[(phase < 0.0) | (phase > 1.0)][:5].tolist()}"
            )
        t = np.minimum(np.rint(phase * T).astype(np.int64), T - 1)
        onehot = batch[:, task.pose_size() : task.pose_size() + F * N].reshape(-1, F, N) > 0.5
        assignment = np.where(onehot.any(axis=2), onehot.argmax(axis=2), -1)
        code = ((assignment + 1) * (N + 1) ** np.arange(F)).sum(axis=1)
        x = task.table.code[code]
        if np.any(x < 0):
            raise ValueError("the observation's contacts are no state of the hand")
        moves = task.table.move[self._policy()[t, x]]
        actions = moves if self.optimal_grip else optimal_actions(task, x, t, moves)
        return (actions[0] if obs.ndim == 1 else actions), None


class GaitExpert(_GaitPolicy):
    """The certified optimal gait as a policy: from the pose (the observation's phase) and the
    hand's contacts, the dynamic programme's move (optimal from any state, not only along
    its own gait) and the certified minimax grip of the fingers that then carry load.

    Args: the gait environment's ``trajectory``, ``mu``, ``cone_deg``, ``k_max_ratio``,
    ``start`` (the same configuration shares the environment's tables) and ``optimal_grip``
    (True: it acts with the moves alone, in ``grasp_env/CubeGaitMoves-v0``).
    """

    def _policy(self) -> np.ndarray:
        return self.task.solution.optimal.policy


class GreedyGait(_GaitPolicy):
    """The greedy baseline as a policy: at each pose the move that maximises the smaller of
    this pose's margin and the best the next pose then allows, with the certified grip."""

    def _policy(self) -> np.ndarray:
        return self.task.solution.greedy.policy


def _task(
    trajectory: Mapping[str, Any] | None,
    mu: float,
    cone_deg: float,
    k_max_ratio: float,
    start: Sequence[int] | None,
) -> GaitTask:
    if trajectory is not None and not isinstance(trajectory, Mapping):
        raise ValueError(
            f"trajectory must be a mapping with the keys {TRAJECTORY_KEYS}, got {trajectory!r}"
        )
    spec = {**PAPER_TURN_SPEC, **(trajectory or {})}
    trajectory = check_trajectory(spec)
    mu = check_number("mu", mu, *MU_RANGE)
    cone_deg = check_number("cone_deg", cone_deg, 0.0, 180.0, open_low=True, open_high=True)
    k_max_ratio = check_k_max_ratio(k_max_ratio)
    if start is not None:
        sites = isinstance(start, Sequence | np.ndarray) and not isinstance(start, str | bytes)
        if not sites or not all(is_integer(s) and -1 <= s < 1 << 31 for s in start):
            raise ValueError(
                f"start must be a site (0-5, or -1 for none) for each finger, got {start!r}"
            )
        start = tuple(int(s) for s in start)
    return gait_task(trajectory, mu, cone_deg, k_max_ratio, start)


# ------------------------------------------------------------------------ the environments


class CubeGaitEnv(gym.Env[np.ndarray, np.ndarray]):
    """Phase fingers out and in: hold the cube along a long rotation with a hand that reaches.

    ## Description
    The paper promises "an algorithm ... when to phase out a finger": a finger may reach a
    joint limit while the object turns, and must then hand its load to the others. A hand of
    five fingers (`grasp_env.mechanics.Hand`: four below the cube pushing up and inwards a
    quarter turn apart, a thumb above pushing down) can push on a face only while the face's
    inward normal lies within `cone_deg` (60 deg) of the finger's approach. The cube (unit
    edge, w = 5 N, centre of gravity 0.05 m off centre) carries one contact site per face,
    off-centre (`grasp_env.mechanics.gait.SITE_OFFSETS`); it turns about the paper's axis
    from -90 to +90 deg in 1 deg steps (181 poses). No fixed set of fingers stays within
    reach for the whole turn: at every pose the agent chooses the grip (the interaction
    forces of the fingers that carry load) and may lift one finger or place one. It is
    sequential: a finger must be lifted (with zero force, the others holding) before its
    site leaves its reach, and placed (within reach) before it is needed. The certified
    optimal gait (the dynamic programme of docs/gait.md) keeps a worst margin of 6.97 deg;
    the greedy one-pose lookahead (`GreedyGait`) loses a contact and drops the cube, at
    alpha = -44 deg from this environment's start (at -19 deg from its own best start).

    ## Action Space
    `Box(-1, 1, (P + M,), float32)` with P = F (F - 1) / 2 = 10 finger pairs and
    M = 1 + F N = 31 moves (F = 5 fingers, N = 6 sites):
    - `action[:P]`: the grip, k_fg = a_fg x k_max for the finger pairs (f, g), f < g, in the
      order of `grasp_env.mechanics.contact_pairs(5)` (k_max = `k_max_ratio` x w; k > 0
      squeezes the pair, eq. 4); pairs whose fingers do not both carry load are ignored.
    - `action[P:]`: scores of the moves; the move made is the argmax (ties: the lower index).
      Move 0 keeps the contacts; move 1 + f N + s toggles finger f on site s: it lifts f if f
      is on s (f carries no force at this pose and is gone from the next), and places f on s
      if both are free (f touches with zero force now and carries load from the next pose).
      Fingers are 0-3 (finger1-finger4) and 4 (the thumb); sites 0-5 on the faces
      -x, -y, -z, +x, +y, +z.

    With `optimal_grip=True` (the id `grasp_env/CubeGaitMoves-v0`) the action is the move
    alone, `Discrete(M)`, and the environment grips with the certified minimax optimum of the
    fingers that carry load after the move (a refused move: of those that carry it now), as
    the optimal and the greedy gait do: what is learnt is when to phase a finger out or in.

    ## Observation Space
    `Box(low, high, (110,), float32)`, world frame, forces in units of w, lengths of L:

    | index     | observation                                                | bounds  |
    |-----------|------------------------------------------------------------|---------|
    | 0-5       | first two columns of the orientation R                     | [-1, 1] |
    | 6-23      | site positions R (c_s - g) / L, site by site               | [-√3, √3] |
    | 24-41     | inward site normals R nu_s                                 | [-1, 1] |
    | 42-44     | load force (0, 0, -1) + f_d / w                            | [-2, 1] |
    | 45-47     | extra torque tau_d / (w L)                                 | [-1, 1] |
    | 48        | friction limit theta_lim = atan(mu), radians               | [0, pi/2] |
    | 49        | phase: steps taken / trajectory length                     | [0, 1]  |
    | 50-79     | contacts: 1 where finger f touches site s (index 50 + f N + s) | {0, 1} |
    | 80-109    | reach: 1 where finger f can push on site s at this pose    | {0, 1}  |

    ## Rewards
    min over the fingers that carry load of (theta_lim - theta_i), radians (eq. 2, 4), as in
    the other environments; a released finger (its force at most 1e-6 of the forces it is
    made of, `grasp_env.envs.kernels.RELEASE`) counts as inside its cone, angle 0 (the optimum
    often lets the fourth finger go, and float32 actions alone leave such a finger about
    1e-8 w in an arbitrary direction). A finger whose site has
    left its reach while it touches the object has lost its contact under load: the step's
    reward is theta_lim - pi/2 (its friction angle counts as 90 deg: it cannot push).

    ## The hand's rules
    - Refused (the move is ignored, `info["refused"]`, the grip still applies): lifting a
      finger when only three touch (fewer than three would carry load), placing a finger when
      four touch, on a site taken or out of its reach, or toggling a finger on a site it is
      not on while it touches another.
    - Lost contact (`info["lost"]`): a touching finger whose site is out of its reach at this
      pose leaves the hand; a slip (see Episode End). With fewer than three fingers left the
      cube drops.
    - A finger is never lifted under load: a lift takes its force to zero at that pose.

    ## Starting State
    The first pose (alpha = -90 deg), the hand in the optimal gait's first state (finger1 on
    -z, finger3 on +x, finger4 on +y); nothing is random. `start` sets another first state.

    ## Episode End
    - Termination: the cube drops (fewer than three fingers left), or, with
      `terminate_on_slip=True`, a loaded finger slips (theta_i > theta_lim) or a contact is
      lost.
    - Truncation: after the last pose.

    ## Info
    `alpha_deg`, `contacts` (F,) the site each finger touches after the step's move (-1: none),
    `move` (the move made, 0 if refused), `refused`, `lost` (F,) bool, `loaded` (F,) bool (the
    fingers that carried load), `theta` (F,) radians (0 for a finger carrying no load), `k`
    (P,) newtons (0 for pairs not both loaded),
    `contact_forces` (F, 3) newtons, `slip` (F,) bool, `expert_reward` (the optimal gait's
    margin at this pose, from the episode's start).

    ## Arguments
    ```python
    gym.make("grasp_env/CubeGait-v0", trajectory=None, mu=0.5, cone_deg=60.0,
             k_max_ratio=2.0, terminate_on_slip=True, start=None, optimal_grip=False)
    ```
    - `trajectory`: a mapping with the keys `axis`, `alpha_start_deg`, `alpha_end_deg`,
      `alpha_step_deg` (missing keys: the paper's axis over [-90, 90] deg by 1 deg); e.g.
      `{"axis": (0, 0, 1), "alpha_start_deg": -180, "alpha_end_deg": 180}`, a full turn about
      the vertical (the cube turns about its own diagonal).
    - `mu`: the friction coefficient. `cone_deg`: the half-angle of every finger's cone.
    - `k_max_ratio`: k_max / w. `terminate_on_slip`: see Episode End.
    - `start`: the first state, an assignment of a site (0-5, or -1 for none) to each of the
      five fingers, 3 or 4 touching; default the optimal gait's.
    - `optimal_grip`: the action is the move only, the grip the certified optimum (see
      Action Space); `grasp_env/CubeGaitMoves-v0` sets it.
    The configuration is solved when the first environment with it is made (about 3 s: the
    certified minimax of 35 site sets at 181 poses and the dynamic programme), then shared.

    ## Version History
    - v0: initial version.
    """

    metadata = {"render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        trajectory: Mapping[str, Any] | None = None,
        mu: float = 0.5,
        cone_deg: float = 60.0,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        terminate_on_slip: bool = True,
        start: Sequence[int] | None = None,
        optimal_grip: bool = False,
        render_mode: str | None = None,
    ) -> None:
        if render_mode is not None:  # a TypeError: SB3's make_vec_env then makes it without
            raise TypeError(f"the gait environment has no render modes, got {render_mode!r}")
        self.render_mode = None
        self.task = _task(trajectory, mu, cone_deg, k_max_ratio, start)
        self.terminate_on_slip = check_bool("terminate_on_slip", terminate_on_slip)
        self.optimal_grip = check_bool("optimal_grip", optimal_grip)
        task = self.task
        P, M = task.n_pairs, task.n_moves
        F, N = task.n_fingers, task.n_sites
        self.action_space: spaces.Space = (
            spaces.Discrete(M)
            if self.optimal_grip
            else spaces.Box(-1.0, 1.0, (P + M,), dtype=np.float32)
        )
        low = np.concatenate(
            [-np.ones(6), np.full(3 * N, -_SQRT3), -np.ones(3 * N), [-2.0, -2.0, -2.0],
             -np.ones(3), [0.0, 0.0], np.zeros(2 * F * N)]
        )  # fmt: skip
        high = np.concatenate(
            [np.ones(6), np.full(3 * N, _SQRT3), np.ones(3 * N), np.ones(3), np.ones(3),
             [np.pi / 2, 1.0], np.ones(2 * F * N)]
        )  # fmt: skip
        self.observation_space = spaces.Box(
            low.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )
        self._x = task.start
        self._t = 0
        self._done = True
        self._xs = np.zeros(1, np.int64)  # the kernel's inputs, reused
        self._ts = np.zeros(1, np.int64)

    def _observation(self, x: int, t: int) -> np.ndarray:
        task = self.task
        return np.concatenate([task.observations[t], task.contact_obs[x], task.reach_obs[t]])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        # Checked before seeding: a refused reset changes nothing.
        seed = check_seed("seed", seed)
        if options:  # None and {} are the only options
            raise ValueError(f"the gait environment takes no reset options, got {options!r}")
        super().reset(seed=seed)
        self._x, self._t, self._done = self.task.start, 0, False
        return self._observation(self._x, 0), {}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError("the episode has ended (or not started): call reset()")
        task = self.task
        t = self._t
        self._xs[0], self._ts[0] = self._x, t
        if self.optimal_grip:
            moves = check_moves(action, (), task.n_moves)[None]
            a = optimal_actions(task, self._xs, self._ts, moves)[0]
        else:
            a = action_array(action, self.action_space.shape)
        floats, ints, flags, obs = _buffers(task, 1)
        if not _step_kernel(
            self._xs, self._ts, a.reshape(1, -1), *task.kernel_arrays, self.terminate_on_slip,
            floats, ints, flags, obs,
        ):  # fmt: skip
            raise ValueError(f"actions must be finite numbers, got {a.tolist()}")
        f, i, g = floats[0], ints[0], flags[0]  # the layout of _step
        F, P = task.n_fingers, task.n_pairs
        terminated = bool(g[2])
        self._t = t + 1
        truncated = self._t == task.n_poses and not terminated
        self._done = terminated or truncated
        if not g[0]:
            self._x = int(i[0])
        info = {
            "refused": bool(g[1]),
            "lost": g[4 : 4 + F],
            "move": int(i[1]),
            "theta": f[1 : 1 + F],
            "loaded": g[4 + F : 4 + 2 * F],
            "k": f[1 + F : 1 + F + P],
            "contact_forces": f[1 + F + P :].reshape(F, 3),
            "slip": g[4 + 2 * F :],
            "contacts": i[2:],
            "alpha_deg": float(task.alphas[t]),
            "expert_reward": float(task.expert_margins[t]),
        }
        return obs[0], float(f[0]), terminated, truncated, info


class CubeGaitVectorEnv(VectorEnv):
    """Batched `grasp_env/CubeGait-v0`: N sub-environments stepped by one table look-up and
    one step-kernel call per set size; step for step equal to N single environments.

    Args:
        num_envs: number of sub-environments.
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (the step after an episode ends resets
            that sub-environment, ignoring its action, with reward 0), ``SAME_STEP`` (it
            resets at once; the last observation and info are in ``info["final_obs"]`` and
            ``info["final_info"]``) or ``DISABLED`` (episodes never reset by themselves:
            reset the ended ones with ``reset(options={"reset_mask": mask})``; stepping one
            that ended raises a RuntimeError). The modes' values are accepted too.
        max_episode_steps: None (the default: an episode runs to the trajectory's end) or an
            integer >= 1: each sub-environment's episode is truncated after that many steps,
            as Gymnasium's ``TimeLimit`` truncates a single environment's (truncated is True
            at that step even if the episode terminated there too; at the trajectory's end
            the gait itself truncates only episodes that did not terminate).
            ``gym.make_vec(id, ..., max_episode_steps=k)`` passes it.
        **kwargs: the single environment's keywords.

    ``reset(options={"reset_mask": mask})`` (a numpy bool array of shape ``(num_envs,)``), in
    every mode, returns the sub-environments where ``mask`` is True to the start (nothing is
    random) and the observations of all, as Gymnasium's ``SyncVectorEnv``.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}  # noqa: RUF012

    def __init__(
        self,
        num_envs: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        self.num_envs = check_integer("num_envs", num_envs, 1, MAX_ENVS)
        mode = check_autoreset_mode(autoreset_mode)
        self.max_episode_steps = check_max_episode_steps(max_episode_steps)
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.render_mode = None
        self.template = CubeGaitEnv(**kwargs)
        self.task = self.template.task
        self.terminate_on_slip = self.template.terminate_on_slip
        self.single_observation_space = self.template.observation_space
        self.single_action_space = self.template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        # Truncation at step _end: the trajectory's end, where the gait truncates only what did
        # not terminate, unless max_episode_steps cuts there or before (TimeLimit's rule: it
        # truncates whatever happened at that step).
        poses, cut = self.task.n_poses, self.max_episode_steps
        self._end = poses if cut is None else min(poses, cut)
        self._cut_terminated = cut is not None and cut <= poses
        self._x = np.full(self.num_envs, self.task.start, np.int64)
        self._t = np.zeros(self.num_envs, np.int64)
        # Ended episodes not reset yet: NEXT_STEP resets them at the next step, DISABLED
        # refuses to step them.
        self._autoreset = np.zeros(self.num_envs, bool)
        self._dropped = np.zeros(self.num_envs, bool)  # ended with the cube dropped
        self._started = False

    def _observations(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        task = self.task
        return np.concatenate(
            [task.observations[t], task.contact_obs[x], task.reach_obs[t]], axis=1
        )

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: Any = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every sub-environment (nothing is random: ``seed`` seeds ``np_random``), or
        those where ``options={"reset_mask": mask}`` is True."""
        mask, options = split_reset_mask(options, self.num_envs)
        if mask is None:
            mask = np.ones(self.num_envs, bool)
        if seed is None or isinstance(seed, Integral):
            check_seed("seed", seed)
        elif isinstance(seed, Sequence | np.ndarray) and not isinstance(seed, str | bytes):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed must list {self.num_envs} seeds, got {len(seed)}")
            for i, s in enumerate(seed):
                check_seed(f"seed[{i}]", s)
            seed = seed[int(np.argmax(mask))]  # the first reset sub-environment's
        else:
            raise ValueError(f"seed must be None, an integer >= 0 or a list, got {seed!r}")
        if options:  # None and {} are the only options besides the mask
            raise ValueError(
                f"the gait environment takes no reset options but reset_mask, got {options!r}"
            )
        if not mask.all() and not self._started:
            raise RuntimeError(
                "the first reset() resets every sub-environment: call it without a reset_mask"
            )
        if seed is not None:
            self._np_random, _ = seeding.np_random(int(seed))
        self._x[mask] = self.task.start
        self._t[mask] = 0
        self._autoreset[mask] = False
        self._dropped[mask] = False
        self._started = True
        observations = self._observations(self._x, self._t)
        # a dropped cube's last observation shows no contacts (the state is kept)
        observations[self._dropped, self.task.pose_size() : -self.task.reach_obs.shape[1]] = 0.0
        return observations, {}

    def _restart(self, envs: np.ndarray) -> np.ndarray:
        """Start new episodes in ``envs`` (SAME_STEP autoreset); their first observations."""
        self._x[envs] = self.task.start
        self._t[envs] = 0
        self._dropped[envs] = False
        return self._observations(self._x[envs], self._t[envs])

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        refuse_ended(self.autoreset_mode, self._autoreset)
        task = self.task
        if self.template.optimal_grip:
            moves = check_moves(actions, (self.num_envs,), task.n_moves)
        else:
            a = action_array(actions, self.action_space.shape)
        restarting = np.flatnonzero(self._autoreset)
        xs, t = self._x.copy(), self._t.copy()
        if restarting.size:  # NEXT_STEP: these reset and ignore their action (stepped from the
            xs[restarting] = task.start  # start with a zero action or keeping, undone below)
            t[restarting] = 0
            if self.template.optimal_grip:
                moves[restarting] = 0
            else:
                a = a.copy()
                a[restarting] = 0.0
        if self.template.optimal_grip:
            a = optimal_actions(task, xs, t, moves)
        out = _step(task, xs, t, a, self.terminate_on_slip)  # ValueError before any change
        dropped, reward, observations = out["dropped"], out["reward"], out["obs"]
        terminated = out["terminated"]
        self._t = t + 1
        truncated = self._t == self._end
        if not self._cut_terminated:
            truncated &= ~terminated
        self._x = np.where(dropped, xs, out["next"])
        info = {key: out[key] for key in _INFO}
        info.update(alpha_deg=task.alphas[t], expert_reward=task.expert_margins[t])
        mask = np.ones(self.num_envs, bool)
        if restarting.size:  # they start afresh: the first observation, nothing happened
            self._x[restarting] = task.start
            self._t[restarting] = 0
            observations[restarting] = self._observations(self._x[restarting], self._t[restarting])
            reward[restarting] = 0.0
            terminated[restarting] = False
            truncated[restarting] = False
            mask[restarting] = False
        self._dropped = dropped & terminated  # not the restarted ones
        self._autoreset = end_step(
            self.autoreset_mode, observations, info, terminated | truncated, mask, self._restart
        )
        return observations, reward, terminated, truncated, info


__all__ = ["CubeGaitEnv", "CubeGaitVectorEnv", "GaitExpert", "GaitTask", "GreedyGait", "gait_task"]
