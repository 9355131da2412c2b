"""The gait environment's task: one configuration's tables, computed once and shared by
every environment, expert and vector environment made with it (:func:`gait_task`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from itertools import combinations
from typing import Any

import numpy as np

from ...mechanics import (
    PAPER_TURN,
    GaitScene,
    GaitSolution,
    Hand,
    Trajectory,
    contact_pairs,
    solve_gait,
)
from ...mechanics.checks import is_integer
from ...mechanics.gait import GaitStates, gait_states
from ..spec import CONE, MU
from ..validation import TRAJECTORY_KEYS, check_k_max_ratio, check_trajectory

#: The paper's axis over [-90, 90] deg in 1 deg steps, as the ``trajectory`` keyword's mapping.
PAPER_TURN_SPEC = {key: getattr(PAPER_TURN, key) for key in TRAJECTORY_KEYS}


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
    mu = MU.check(mu)
    cone_deg = CONE.check(cone_deg)
    k_max_ratio = check_k_max_ratio(k_max_ratio)
    if start is not None:
        sites = isinstance(start, Sequence | np.ndarray) and not isinstance(start, str | bytes)
        if not sites or not all(is_integer(s) and -1 <= s < 1 << 31 for s in start):
            raise ValueError(
                f"start must be a site (0-5, or -1 for none) for each finger, got {start!r}"
            )
        start = tuple(int(s) for s in start)
    return gait_task(trajectory, mu, cone_deg, k_max_ratio, start)


__all__ = ["PAPER_TURN_SPEC", "GaitTask", "gait_task"]
