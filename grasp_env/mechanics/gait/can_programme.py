"""The can's gait programme: the state tables of a can hand's fingers' ages, the certified
dynamic programme and the greedy rule on them, and the solution :func:`solve_can_gait` gives
(the hand, the turn and the margins of every configuration are in :mod:`.can`; the rules in its
module docstring).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache
from itertools import product

import numba
import numpy as np
from numpy.typing import ArrayLike

from ..minimax import Status
from ..objects import CAN_HEIGHT, CAN_RADIUS, Cylinder
from ..scene import ArrayRecord
from .can import (
    CAN_DEFAULT_LOADED,
    CAN_MAX_AGE,
    CAN_MAX_FINGERS,
    CAN_MAX_LOADED,
    CAN_MAX_TOUCHING,
    CAN_MIN_LOADED,
    CAN_WEIGHT,
    CanHand,
    CanTurn,
    CanValues,
    can_configs,
    can_values,
)
from .programme import MARGIN_TOL, first_best

# ------------------------------------------------------------------------ the tables


@dataclass(frozen=True, eq=False)
class CanStates(ArrayRecord):
    """The hand's states on the can and their moves, as tables.

    Attributes:
        n_fingers, max_age: F and H.
        states: (X, F) each finger's age (poses since placement, 1..H + 1; -1: not
            touching); 3 to 5 fingers touch. A state with an age H + 1 has lost a contact:
            it may only end the trajectory.
        ptr, move, next, config: the moves of state x are move[ptr[x]:ptr[x + 1]] (0 keeps,
            1 + f toggles finger f: lifts it if it touches, places it if not), leading to
            state next[...] with the configuration config[...] (an index into
            :func:`can_configs`) carrying load at the pose.
    """

    n_fingers: int
    max_age: int
    max_loaded: int
    states: np.ndarray
    ptr: np.ndarray
    move: np.ndarray
    next: np.ndarray
    config: np.ndarray

    def index(self, ages: ArrayLike) -> int:
        """The state of ages (F,) (-1: not touching); ValueError if it is none."""
        key = tuple(int(a) for a in np.asarray(ages).reshape(-1))
        hit = np.flatnonzero((self.states == np.array(key)).all(axis=1))
        if len(key) != self.n_fingers or not hit.size:
            raise ValueError(
                f"start must give each of the {self.n_fingers} fingers an age in"
                f" [1, {self.max_age}] or -1, 3 to {CAN_MAX_TOUCHING} touching, got {list(key)}"
            )
        return int(hit[0])

    @property
    def ok(self) -> np.ndarray:
        """(X,) every touching finger within reach (age <= H)."""
        return ~(self.states > self.max_age).any(axis=1)


@cache
def can_states(n_fingers: int, max_age: int, max_loaded: int = CAN_MAX_LOADED) -> CanStates:
    """The state and move tables of a can hand of F fingers whose contacts last H poses."""
    if (
        not 3 <= n_fingers <= CAN_MAX_FINGERS
        or not 1 <= max_age <= CAN_MAX_AGE
        or not CAN_MIN_LOADED <= max_loaded <= CAN_MAX_LOADED
    ):
        raise ValueError(
            f"a can gait needs 3 to {CAN_MAX_FINGERS} fingers, ages 1 to {CAN_MAX_AGE} and"
            f" {CAN_MIN_LOADED} to {CAN_MAX_LOADED} loaded, got {n_fingers}, {max_age} and"
            f" {max_loaded}"
        )
    F, H = n_fingers, max_age
    configs = {c: i for i, c in enumerate(can_configs(F, H, max_loaded))}
    states = [
        s
        for s in product([-1, *range(1, H + 2)], repeat=F)
        if 3 <= sum(a >= 0 for a in s) <= CAN_MAX_TOUCHING
    ]
    code = {s: i for i, s in enumerate(states)}
    ptr, move, nxt, config = [0], [], [], []

    def older(s: tuple[int, ...]) -> tuple[int, ...]:
        return tuple(a + 1 if a >= 0 else -1 for a in s)

    for s in states:
        touching = [f for f in range(F) if s[f] >= 0]
        if all(s[f] <= H for f in touching):  # a lost contact has no moves
            candidates = [(0, s, touching)]
            for f in range(F):
                if s[f] >= 0:  # lift: zero force now, gone next
                    rest = [g for g in touching if g != f]
                    candidates.append((1 + f, (*s[:f], -1, *s[f + 1 :]), rest))
                elif len(touching) < CAN_MAX_TOUCHING:  # place at age 0, loaded next
                    candidates.append((1 + f, (*s[:f], 0, *s[f + 1 :]), touching))
            for m, after, loaded in candidates:
                if not CAN_MIN_LOADED <= len(loaded) <= max_loaded:
                    continue
                y = older(after)
                if y not in code:  # (never: the touching count is kept in range)
                    continue
                move.append(m)
                nxt.append(code[y])
                config.append(configs[tuple((g, s[g]) for g in loaded)])
        ptr.append(len(move))
    arrays = [np.array(a, np.int64) for a in (states, ptr, move, nxt, config)]
    arrays[0] = arrays[0].reshape(len(states), F)
    for a in arrays:
        a.flags.writeable = False
    return CanStates(F, H, max_loaded, *arrays)


# ------------------------------------------------------------------- the programme


@numba.njit(cache=True)
def _table_programme(ptr, move, nxt, vals, T, start, tol):
    """The gait programme of :mod:`.programme` on precomputed move values ``vals`` (T, K)
    (-inf: not allowed): pass 1 the bottleneck, pass 2 the fewest moves then the largest sum
    among the gaits that keep it to within ``tol``, ties to the first in the tables' order.
    ``vals`` of one row serves every pose of T. Returns (value (T + 1, X), policy (T, X),
    start, best)."""
    X = ptr.shape[0] - 1
    one = vals.shape[0] == 1
    value = np.empty((T + 1, X))
    value[T] = np.inf
    first = np.zeros((T, X), np.int64)
    for t in range(T - 1, -1, -1):
        for x in range(X):
            best = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                best = max(best, min(vals[0 if one else t, k], value[t + 1, nxt[k]]))
            value[t, x] = best
            arg = ptr[x] if ptr[x + 1] > ptr[x] else -1  # -1: no move (a lost contact)
            for k in range(ptr[x], ptr[x + 1]):
                if min(vals[0 if one else t, k], value[t + 1, nxt[k]]) >= best - tol:
                    arg = k
                    break
            first[t, x] = arg
    if start < 0:
        bound = -np.inf
        for x in range(X):
            bound = max(bound, value[0, x])
    else:
        bound = value[0, start]
    keep = bound - tol
    moves = np.empty((T + 1, X))
    total = np.empty((T + 1, X))
    moves[T] = 0.0
    total[T] = 0.0
    policy = np.empty((T, X), np.int64)
    for t in range(T - 1, -1, -1):
        slack = tol * (T - t)
        for x in range(X):
            moves[t, x] = np.inf
            total[t, x] = -np.inf
            policy[t, x] = first[t, x]
            if not value[t, x] >= keep:
                continue
            fewest = np.inf
            for k in range(ptr[x], ptr[x + 1]):
                y = nxt[k]
                if vals[0 if one else t, k] >= keep and value[t + 1, y] >= keep:
                    fewest = min(fewest, moves[t + 1, y] + (1.0 if move[k] > 0 else 0.0))
            largest = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                y = nxt[k]
                if vals[0 if one else t, k] >= keep and value[t + 1, y] >= keep:
                    if moves[t + 1, y] + (1.0 if move[k] > 0 else 0.0) == fewest:
                        largest = max(largest, total[t + 1, y] + vals[0 if one else t, k])
            for k in range(ptr[x], ptr[x + 1]):
                y = nxt[k]
                if vals[0 if one else t, k] >= keep and value[t + 1, y] >= keep:
                    c = moves[t + 1, y] + (1.0 if move[k] > 0 else 0.0)
                    s = total[t + 1, y] + vals[0 if one else t, k]
                    if c == fewest and s >= largest - slack:
                        moves[t, x] = c
                        total[t, x] = s
                        policy[t, x] = k
                        break
    if start < 0:
        fewest = np.inf
        for x in range(X):
            if value[0, x] >= keep:
                fewest = min(fewest, moves[0, x])
        largest = -np.inf
        for x in range(X):
            if value[0, x] >= keep and moves[0, x] == fewest:
                largest = max(largest, total[0, x])
        start = 0
        for x in range(X):
            if value[0, x] >= keep and moves[0, x] == fewest and total[0, x] >= largest - tol * T:
                start = x
                break
    return value, policy, start, bound


@numba.njit(cache=True)
def _table_greedy(ptr, nxt, vals, T, tol):
    """The greedy one-pose lookahead of :func:`~.programme.greedy_gait` on move values
    (T, K) or (1, K). Returns (policy (T, X), score (T, X))."""
    X = ptr.shape[0] - 1
    one = vals.shape[0] == 1
    best = np.full((T + 1, X), np.inf)
    for t in range(T):
        for x in range(X):
            b = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                b = max(b, vals[0 if one else t, k])
            best[t, x] = b
    policy = np.empty((T, X), np.int64)
    score = np.empty((T, X))
    for t in range(T):
        for x in range(X):
            top = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                top = max(top, min(vals[0 if one else t, k], best[t + 1, nxt[k]]))
            now = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                if min(vals[0 if one else t, k], best[t + 1, nxt[k]]) >= top - tol:
                    now = max(now, vals[0 if one else t, k])
            arg = ptr[x] if ptr[x + 1] > ptr[x] else -1  # -1: no move (a lost contact)
            for k in range(ptr[x], ptr[x + 1]):
                if (
                    min(vals[0 if one else t, k], best[t + 1, nxt[k]]) >= top - tol
                    and vals[0 if one else t, k] >= now - tol
                ):
                    arg = k
                    break
            policy[t, x] = arg
            score[t, x] = top
    return policy, score


@dataclass(frozen=True, eq=False)
class CanGait(ArrayRecord):
    """A gait on the can along T poses.

    Attributes:
        states: (T,) the state at each pose before its move (-1 after a drop).
        moves: (T,) 0 keeps, 1 + f lifts or places finger f.
        ages: (T, F) each finger's age at the pose, a placed finger's 0 included (-1: none).
        loaded: (T, F) bool, which fingers carry load.
        configs: (T,) the loaded configuration (index into :func:`can_configs`; -1: dropped).
        margins: (T,) radians (-inf after a drop).
        table: the tables the indices refer to.
        policy: (T, X) the rule's move from every state (optimal and greedy gaits), or None.
    """

    states: np.ndarray
    moves: np.ndarray
    ages: np.ndarray
    loaded: np.ndarray
    configs: np.ndarray
    margins: np.ndarray
    table: CanStates = field(repr=False)
    policy: np.ndarray | None = field(default=None, repr=False)

    @property
    def margin(self) -> float:
        return float(self.margins.min())

    @property
    def changes(self) -> int:
        return int(np.count_nonzero(self.moves))

    def events(self) -> list[tuple[int, str, int]]:
        """(pose, "out" or "in", finger) of every phase change."""
        out = []
        for t in np.flatnonzero(self.moves):
            f = int(self.moves[t]) - 1
            out.append((int(t), "out" if self.table.states[self.states[t], f] >= 0 else "in", f))
        return out


def _move_values(table: CanStates, margin: np.ndarray) -> np.ndarray:
    """(T, K) the margin of every move at every pose; (1, K) if every pose has the same
    margins (the can's: a rotation about its axis), which the kernels read at every pose."""
    if len(margin) > 1 and not (margin == margin[:1]).all():
        return np.ascontiguousarray(margin[:, table.config])
    return np.ascontiguousarray(margin[:1, table.config])


def _check_margin(margin: ArrayLike, n_configs: int) -> np.ndarray:
    must = f"a (T, {n_configs}) array of real numbers, finite or -inf, T >= 1"
    try:
        array = np.asarray(margin)
    except (TypeError, ValueError):
        raise ValueError(f"margin must be {must}") from None
    if array.dtype.kind not in "iuf" or array.ndim != 2 or array.shape[1] != n_configs:
        raise ValueError(f"margin must be {must}, got {array.dtype} {array.shape}")
    array = np.ascontiguousarray(array, dtype=float)
    if len(array) < 1 or np.isnan(array).any() or (array == np.inf).any():
        raise ValueError(f"margin must be {must}")
    return array


def _follow_can(table: CanStates, start: int, choices: np.ndarray, margin: np.ndarray) -> CanGait:
    T, F = margin.shape[0], table.n_fingers
    states = np.full(T, -1, np.int64)
    moves = np.zeros(T, np.int64)
    ages = np.full((T, F), -1, np.int64)
    loaded = np.zeros((T, F), bool)
    configs = np.full(T, -1, np.int64)
    margins = np.full(T, -np.inf)
    ok = table.ok
    x = start
    for t in range(T):
        k = int(choices[t])
        if k < 0 or not ok[x]:
            break
        a = table.states[x]
        m = int(table.move[k])
        states[t], moves[t] = x, m
        ages[t] = a
        loaded[t] = a >= 0
        if m:
            f = m - 1
            if a[f] >= 0:
                loaded[t, f] = False  # lifted: zero force
            else:
                ages[t, f] = 0  # placed: touches with zero force
        configs[t] = table.config[k]
        margins[t] = margin[t, configs[t]]
        x = int(table.next[k])
    arrays = (states, moves, ages, loaded, configs, margins)
    for array in arrays:
        array.flags.writeable = False
    return CanGait(*arrays, table)


def _choices(table: CanStates, policy: np.ndarray, x: int) -> np.ndarray:
    out = np.full(len(policy), -1, np.int64)
    for t in range(len(policy)):
        out[t] = policy[t, x]
        if out[t] < 0:  # no move from here: the gait drops
            break
        x = int(table.next[out[t]])
    return out


def optimal_can_gait(
    margin: ArrayLike,
    n_fingers: int,
    max_age: int,
    start: ArrayLike | None = None,
    max_loaded: int = CAN_MAX_LOADED,
) -> CanGait:
    """The gait on the can that maximises the smallest margin, then takes the fewest moves,
    then the largest sum of margins, margins compared to within :data:`MARGIN_TOL`
    (:func:`~.programme.optimal_gait`'s programme on the can's tables). ``margin`` (T, C):
    every configuration's margin at every pose (-inf: unusable); ``start``: the ages (F,) at
    the first pose (-1: not touching), default the best."""
    table = can_states(n_fingers, max_age, max_loaded)
    margin = _check_margin(margin, len(can_configs(n_fingers, max_age, max_loaded)))
    x0 = -1 if start is None else table.index(start)
    _, policy, x, best = _table_programme(
        table.ptr, table.move, table.next, _move_values(table, margin), len(margin), x0,
        MARGIN_TOL,
    )  # fmt: skip
    policy.flags.writeable = False
    choices = _choices(table, policy, x) if best > -np.inf else np.full(len(margin), -1)
    gait = _follow_can(table, x, choices, margin)
    return CanGait(**{**gait.__dict__, "policy": policy})


def can_bottleneck_bound(
    margin_bound: ArrayLike,
    n_fingers: int,
    max_age: int,
    start: ArrayLike | None = None,
    max_loaded: int = CAN_MAX_LOADED,
) -> float:
    """Pass 1 alone on upper bounds of the margins: no gait's smallest margin exceeds it."""
    table = can_states(n_fingers, max_age, max_loaded)
    margin = _check_margin(margin_bound, len(can_configs(n_fingers, max_age, max_loaded)))
    x0 = -1 if start is None else table.index(start)
    return float(
        _table_programme(
            table.ptr,
            table.move,
            table.next,
            _move_values(table, margin),
            len(margin),
            x0,
            MARGIN_TOL,
        )[3]
    )


def greedy_can_gait(
    margin: ArrayLike,
    n_fingers: int,
    max_age: int,
    start: ArrayLike | None = None,
    max_loaded: int = CAN_MAX_LOADED,
) -> CanGait:
    """The greedy baseline on the can (one-pose lookahead, ties within :data:`MARGIN_TOL` to
    the larger margin now, then fewer moves)."""
    table = can_states(n_fingers, max_age, max_loaded)
    margin = _check_margin(margin, len(can_configs(n_fingers, max_age, max_loaded)))
    policy, score = _table_greedy(
        table.ptr, table.next, _move_values(table, margin), len(margin), MARGIN_TOL
    )
    policy.flags.writeable = False
    x = first_best(score[0]) if start is None else table.index(start)
    gait = _follow_can(table, x, _choices(table, policy, x), margin)
    return CanGait(**{**gait.__dict__, "policy": policy})


def best_fixed_can(
    margin: ArrayLike, n_fingers: int, max_age: int, max_loaded: int = CAN_MAX_LOADED
) -> CanGait:
    """The best gait without moves: the same fingers on the same points throughout (a
    contact lasts H poses, so only a trajectory of at most H + 1 poses has one)."""
    table = can_states(n_fingers, max_age, max_loaded)
    margin = _check_margin(margin, len(can_configs(n_fingers, max_age, max_loaded)))
    T = len(margin)
    # a fixed set lasts while its oldest contact stays within reach: age + T - 1 <= H
    lasting = np.flatnonzero(table.states.max(axis=1) + T - 1 <= max_age)
    worst = np.full(len(table.states), -np.inf)
    gaits = {}
    for x in lasting:
        choices = np.empty(T, np.int64)
        y = int(x)
        for t in range(T):
            k = int(table.ptr[y])  # keep, if allowed, is the first of a state's moves
            if table.ptr[y + 1] == k or table.move[k] != 0:
                choices[t:] = -1  # no keep here (five touching, at most four loaded)
                break
            choices[t] = k
            y = int(table.next[k])
        gait = _follow_can(table, int(x), choices, margin)
        worst[x] = gait.margin
        gaits[int(x)] = gait
    x = first_best(worst)
    return gaits.get(x) or _follow_can(table, x, np.full(len(margin), -1), margin)


# ------------------------------------------------------------------------ solved


@dataclass(frozen=True, eq=False)  # compared by identity: a record of solver output
class CanGaitSolution:
    """The can's gait problem solved: the values, the optimal gait, its certified bound, the
    greedy gait and the best fixed set (see :func:`solve_can_gait`)."""

    hand: CanHand
    turn: CanTurn
    can: Cylinder
    weight: float
    mu: float
    values: CanValues
    margin: np.ndarray  # (T, C) the attained margins, the same at every pose
    optimal: CanGait
    bound: float
    greedy: CanGait
    fixed: CanGait

    @property
    def holds(self) -> bool:
        return self.optimal.margin > -np.inf

    @property
    def gap(self) -> float:
        return self.bound - self.optimal.margin if self.holds else 0.0

    @property
    def friction_limit(self) -> float:
        return float(np.arctan(self.mu))

    def uncertified_along(self, gait: CanGait) -> int:
        """Poses of ``gait`` whose configuration's optimum is UNCERTIFIED."""
        return sum(self.values.status(int(c)) == Status.UNCERTIFIED for c in gait.configs if c >= 0)

    def grips(self, gait: CanGait) -> tuple[np.ndarray, np.ndarray]:
        """Friction angles (T, F) of the loaded fingers (NaN otherwise) and the statuses (T,)
        (-1 after a drop) at the gait's certified grips."""
        T, F = gait.loaded.shape
        angles = np.full((T, F), np.nan)
        status = np.full(T, -1, np.int8)
        for t, c in enumerate(gait.configs):
            if c < 0:
                continue
            _, a = self.values.grip(int(c))
            fingers = [f for f, _ in self.values.configs[c]]
            angles[t, fingers] = a
            status[t] = self.values.status(int(c))
        return angles, status

    def object_angles_deg(self, gait: CanGait) -> np.ndarray:
        """The object-frame azimuth (deg, in [0, 360)) of each finger's contact point on the
        can at every pose (NaN: not touching): the point it was placed on, turning with the
        can."""
        world = self.hand.world_angles_deg(gait.ages, self.turn.step_deg)
        out = np.mod(world - self.turn.alphas_deg[:, None], 360.0)
        return np.where(gait.ages >= 0, out, np.nan)


def solve_can_gait(
    hand: CanHand | None = None,
    turn: CanTurn | None = None,
    weight: float = CAN_WEIGHT,
    mu: float = 0.5,
    k_max: float | None = None,
    cg_height: float = 0.0,
    max_loaded: int = CAN_DEFAULT_LOADED,
) -> CanGaitSolution:
    """The certified optimal gait turning the can (defaults: :class:`CanHand`, a full turn in
    10 deg steps, w = 3.4 N, mu = 0.5, k_max = 2 w), its bound, the greedy gait and the best
    fixed set."""
    hand = CanHand() if hand is None else hand
    turn = CanTurn() if turn is None else turn
    can = Cylinder(radius=CAN_RADIUS, height=CAN_HEIGHT)
    values = can_values(hand, turn.step_deg, can, weight, mu, k_max, cg_height, max_loaded)
    F, H, T, L = hand.n_fingers, hand.max_age(turn.step_deg), len(turn), max_loaded
    margin = np.broadcast_to(values.margin, (T, len(values.configs)))
    upper = np.broadcast_to(values.margin_bound, (T, len(values.configs)))
    optimal = optimal_can_gait(margin, F, H, None, L)
    bound = can_bottleneck_bound(upper, F, H, None, L)
    return CanGaitSolution(
        hand, turn, can, float(weight), float(mu), values, margin, optimal, bound,
        greedy_can_gait(margin, F, H, None, L), best_fixed_can(margin, F, H, L),
    )  # fmt: skip
