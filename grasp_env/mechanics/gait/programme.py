"""The dynamic programme over the hand's states (:func:`optimal_gait`, its bound
:func:`bottleneck_bound`) and the baselines: the greedy one-pose lookahead
(:func:`greedy_gait`) and the best gait without moves (:func:`best_fixed`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import ArrayLike

from ..minimax.codes import GAP_TOL
from ..scene import (
    ArrayRecord,
)
from .sites import _MAX_FINGERS, _MAX_SITES, site_sets
from .states import GaitStates, _size_ok, gait_states, move_name

#: Margins (radians) closer than this are tied: the programme and the greedy rule compare
#: margins to within it, and break ties by fewer moves, then the larger sum of margins, then
#: the tables' order (keep before any move, moves by code, states by index). It is the
#: solver's certificate gap (:data:`~grasp_env.mechanics.minimax.codes.GAP_TOL`, 1e-9 rad,
#: 5.7e-8 deg): each optimum is known only to within it, so a margin that is smaller by less
#: is no evidence of a worse grip. Rounding noise in the solver's values is far smaller
#: (about the vertical every set's margin is constant in exact arithmetic and varies by
#: 8e-12 deg), and without the tolerance it decided choices: pass 2 discarded a gait 1e-14 deg
#: below the bottleneck, and the greedy gait's 20 changes came from 1e-15 deg ties.
MARGIN_TOL = GAP_TOL


@numba.njit(cache=True)
def _state_ok(states, reach):
    """(T, X): every touching finger of state x can reach its site at pose t."""
    T = reach.shape[0]
    X, F = states.shape
    ok = np.ones((T, X), np.bool_)
    for t in range(T):
        for x in range(X):
            for f in range(F):
                s = states[x, f]
                if s >= 0 and not reach[t, f, s]:
                    ok[t, x] = False
                    break
    return ok


@numba.njit(cache=True)
def _pose_values(t, states, ptr, move, loaded, margin, reach, ok, out):
    """out[k]: the margin of pose t after move k (CSR) of its state, -inf where the move is
    not allowed there (a touching finger out of reach, or a placement out of reach)."""
    N = reach.shape[2]
    for x in range(states.shape[0]):
        for k in range(ptr[x], ptr[x + 1]):
            v = margin[t, loaded[k]] if ok[t, x] else -np.inf
            m = move[k]
            if m > 0:
                f = (m - 1) // N
                s = (m - 1) % N
                if states[x, f] < 0 and not reach[t, f, s]:  # a placement needs reach now
                    v = -np.inf
            out[k] = v


@numba.njit(cache=True)
def _programme(states, ptr, move, nxt, loaded, margin, reach, start, tol):
    """Backward dynamic programme: bottleneck values, then fewest moves and the largest sum of
    margins among the gaits that keep the best bottleneck to within ``tol``; the policy and
    the start state. Ties (within ``tol`` per margin, ``tol`` times the poses left for a sum)
    go to the first candidate in the tables' order: keep before any move, moves by code,
    start states by index.

    ``start`` < 0: the best start. Returns (value (T + 1, X), policy (T, X), start, best),
    ``best`` the exact best bottleneck (max over the starts of pass 1's value).
    """
    T = margin.shape[0]
    X = states.shape[0]
    ok = _state_ok(states, reach)
    vals = np.empty(move.shape[0])
    value = np.empty((T + 1, X))
    value[T] = np.inf
    first = np.zeros((T, X), np.int64)
    # pass 1: max over moves of min(margin now, value from the next pose), exact (max and min
    # of the inputs, no arithmetic); its move: the first within tol of the best
    for t in range(T - 1, -1, -1):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        for x in range(X):
            best = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                best = max(best, min(vals[k], value[t + 1, nxt[k]]))
            value[t, x] = best
            arg = ptr[x]
            for k in range(ptr[x], ptr[x + 1]):
                if min(vals[k], value[t + 1, nxt[k]]) >= best - tol:
                    arg = k
                    break
            first[t, x] = arg
    if start < 0:
        bound = -np.inf
        for x in range(X):
            bound = max(bound, value[0, x])
    else:
        bound = value[0, start]
    keep = bound - tol  # the margins a gait must keep: the bottleneck, to within tol
    # pass 2: among continuations that keep every margin >= keep, fewest moves, then the
    # largest sum of margins (both additive: exact), ties to the first
    moves = np.empty((T + 1, X))
    total = np.empty((T + 1, X))
    moves[T] = 0.0
    total[T] = 0.0
    policy = np.empty((T, X), np.int64)
    for t in range(T - 1, -1, -1):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        slack = tol * (T - t)  # a sum of T - t margins, each known to within tol
        for x in range(X):
            moves[t, x] = np.inf
            total[t, x] = -np.inf
            policy[t, x] = first[t, x]
            if not value[t, x] >= keep:
                continue
            fewest = np.inf
            for k in range(ptr[x], ptr[x + 1]):
                y = nxt[k]
                if vals[k] >= keep and value[t + 1, y] >= keep:
                    fewest = min(fewest, moves[t + 1, y] + (1.0 if move[k] > 0 else 0.0))
            largest = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                y = nxt[k]
                if vals[k] >= keep and value[t + 1, y] >= keep:
                    if moves[t + 1, y] + (1.0 if move[k] > 0 else 0.0) == fewest:
                        largest = max(largest, total[t + 1, y] + vals[k])
            for k in range(ptr[x], ptr[x + 1]):
                y = nxt[k]
                if vals[k] >= keep and value[t + 1, y] >= keep:
                    c = moves[t + 1, y] + (1.0 if move[k] > 0 else 0.0)
                    s = total[t + 1, y] + vals[k]
                    if c == fewest and s >= largest - slack:
                        moves[t, x] = c
                        total[t, x] = s
                        policy[t, x] = k
                        break
    if start < 0:
        start = _best_start(value[0], moves[0], total[0], keep, tol * T)
    return value, policy, start, bound


@numba.njit(cache=True)
def _best_start(value, moves, total, keep, slack):
    """The first state that keeps ``keep`` with the fewest moves and, within ``slack``, the
    largest sum; state 0 if none keeps it (no gait holds)."""
    fewest = np.inf
    for x in range(value.shape[0]):
        if value[x] >= keep:
            fewest = min(fewest, moves[x])
    largest = -np.inf
    for x in range(value.shape[0]):
        if value[x] >= keep and moves[x] == fewest:
            largest = max(largest, total[x])
    for x in range(value.shape[0]):
        if value[x] >= keep and moves[x] == fewest and total[x] >= largest - slack:
            return x
    return 0


@numba.njit(cache=True)
def _greedy(states, ptr, move, nxt, loaded, margin, reach, tol):
    """The greedy rule from every state at every pose: the move that maximises the smaller of
    the margin now and the best margin the next pose then allows; ties within ``tol``: the
    larger margin now (within ``tol``), then the first in the tables' order (keep before any
    move, so fewer moves). Returns (policy (T, X) CSR indices, score (T, X) of each choice)."""
    T = margin.shape[0]
    X = states.shape[0]
    ok = _state_ok(states, reach)
    vals = np.empty(move.shape[0])
    best = np.full((T + 1, X), np.inf)  # the best margin each state allows at each pose
    for t in range(T):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        for x in range(X):
            b = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                b = max(b, vals[k])
            best[t, x] = b
    policy = np.empty((T, X), np.int64)
    score = np.empty((T, X))
    for t in range(T):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        for x in range(X):
            top = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                top = max(top, min(vals[k], best[t + 1, nxt[k]]))
            now = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                if min(vals[k], best[t + 1, nxt[k]]) >= top - tol:
                    now = max(now, vals[k])
            arg = ptr[x]
            for k in range(ptr[x], ptr[x + 1]):
                if min(vals[k], best[t + 1, nxt[k]]) >= top - tol and vals[k] >= now - tol:
                    arg = k
                    break
            policy[t, x] = arg
            score[t, x] = top
    return policy, score


def first_best(values: np.ndarray, tol: float = MARGIN_TOL) -> int:
    """The first index whose value is within ``tol`` of the largest (ties go to the tables'
    order, not to rounding noise)."""
    values = np.asarray(values, dtype=float)
    return int(np.flatnonzero(values >= values.max() - tol)[0])


@dataclass(frozen=True, eq=False)
class Gait(ArrayRecord):
    """A gait along T poses.

    Attributes:
        states: (T,) the hand's state at each pose, before its move (indices of ``table``).
        moves: (T,) the move made at each pose (0: none; see :mod:`grasp_env.mechanics.gait`).
        contacts: (T, F) the site each finger touches at each pose (-1: none), a finger being
            placed included.
        loaded: (T, F) bool, which fingers carry load.
        sets: (T,) the loaded site set (index into :func:`site_sets`).
        margins: (T,) the margin of each pose, radians.
        table: the state tables the indices refer to.
        policy: for the optimal and the greedy gait, (T, X) the move (CSR index) their rule
            takes from every state at every pose; else None.

    From the pose where a gait breaks the hand's rules (no allowed move is left: the hand
    would lose a site under load or drop below three fingers) its states, sets and contacts
    are -1 and its margins -inf.

    The gait functions return its arrays read-only; gaits compare and hash by value.
    """

    states: np.ndarray
    moves: np.ndarray
    contacts: np.ndarray
    loaded: np.ndarray
    sets: np.ndarray
    margins: np.ndarray
    table: GaitStates = field(repr=False)
    policy: np.ndarray | None = field(default=None, repr=False)

    @property
    def margin(self) -> float:
        """The smallest margin along the trajectory, radians."""
        return float(self.margins.min())

    @property
    def changes(self) -> int:
        """Number of phase changes (fingers lifted or placed)."""
        return int(np.count_nonzero(self.moves))

    def events(self) -> list[tuple[int, str, int, int]]:
        """(pose, "out" or "in", finger, site) of every phase change."""
        out = []
        for t in np.flatnonzero(self.moves):
            f, s = move_name(int(self.moves[t]), self.table.n_sites)  # type: ignore[misc]
            kind = "out" if self.table.states[self.states[t], f] == s else "in"
            out.append((int(t), kind, f, s))
        return out


def _check_inputs(margin: ArrayLike, reach: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    # reach first: its sizes bound the work of every later step (site_sets, gait_states)
    must = (
        "a (T, F, N) boolean array, which of F fingers can push on which of N sites,"
        f" F in [3, {_MAX_FINGERS}] and N in [3, {_MAX_SITES}]"
    )
    try:
        reach = np.ascontiguousarray(reach)
    except (TypeError, ValueError):  # ragged
        raise ValueError(f"reach must be {must}") from None
    # booleans only, as the physics' in_contact: 0.5 is no answer to "can it reach?"
    if reach.ndim != 3 or reach.dtype != bool or not _size_ok(*reach.shape[1:]):
        raise ValueError(f"reach must be {must}, got {reach.dtype} {reach.shape}")
    # -inf marks an unusable set, so real_array's finite check cannot serve here
    must = "a (T, S) array of real numbers, each finite or -inf (an unusable set)"
    try:
        margin = np.ascontiguousarray(margin)
    except (TypeError, ValueError):  # ragged
        raise ValueError(f"margin must be {must}") from None
    if margin.dtype.kind not in "iuf":  # no strings, booleans, None or complex numbers
        raise ValueError(f"margin must be {must}, got {margin.dtype}")
    margin = margin.astype(float, copy=False)
    if margin.ndim != 2 or margin.shape[0] != reach.shape[0]:
        raise ValueError(
            f"margin must be (T, S) and reach (T, F, N) with the same T, got {margin.shape}"
            f" and {reach.shape}"
        )
    if margin.shape[0] < 1:
        raise ValueError("a gait needs at least one pose")
    if margin.shape[1] != len(site_sets(reach.shape[2])):
        raise ValueError(
            f"margin must have one column per set of 3 or 4 of the {reach.shape[2]} sites"
            f" ({len(site_sets(reach.shape[2]))}), got {margin.shape[1]}"
        )
    if np.any(np.isnan(margin)) or np.any(margin == np.inf):
        raise ValueError("margins must be finite or -inf (an unusable set), not NaN or +inf")
    return margin, reach


def _follow(
    table: GaitStates, start: int, choices: np.ndarray, margin: np.ndarray, reach: np.ndarray
) -> Gait:
    """The gait of CSR move indices ``choices`` (T,) from state ``start``, with the margins
    it earns; it ends (-1, -inf) at the first pose where a choice is not allowed."""
    T, N = margin.shape[0], table.n_sites
    ok = _state_ok(table.states, reach)
    states = np.full(T, -1, np.int64)
    moves = np.zeros(T, np.int64)
    contacts = np.full((T, table.n_fingers), -1, np.int64)
    loaded = np.zeros((T, table.n_fingers), bool)
    sets = np.full(T, -1, np.int64)
    margins = np.full(T, -np.inf)
    x = start
    for t in range(T):
        k = int(choices[t])
        if k < 0 or not ok[t, x]:
            break
        a = table.states[x]
        m = int(table.move[k])
        lifted = placed = -1
        if m:
            f, s = move_name(m, N)  # type: ignore[misc]
            if a[f] == s:
                lifted = f
            elif reach[t, f, s]:
                placed = f
            else:
                break  # a placement out of reach
        states[t], moves[t] = x, m
        contacts[t] = a
        loaded[t] = a >= 0
        if lifted >= 0:
            loaded[t, lifted] = False  # zero force while it lifts
        if placed >= 0:
            contacts[t, placed] = s  # touches with zero force
        sets[t] = table.loaded[k]
        margins[t] = margin[t, sets[t]]
        x = int(table.next[k])
    arrays = (states, moves, contacts, loaded, sets, margins)
    for array in arrays:
        array.flags.writeable = False  # a result, compared and hashed by value
    return Gait(*arrays, table)


def _start_index(table: GaitStates, start: ArrayLike | None) -> int:
    return -1 if start is None else table.index(start, "start")


def _policy_choices(table: GaitStates, policy: np.ndarray, start: int) -> np.ndarray:
    choices = np.empty(len(policy), np.int64)
    x = start
    for t in range(len(policy)):
        choices[t] = policy[t, x]
        x = int(table.next[choices[t]])
    return choices


def optimal_gait(margin: ArrayLike, reach: ArrayLike, start: ArrayLike | None = None) -> Gait:
    """The gait that maximises the smallest margin (then: fewest moves, largest sum), margins
    compared to within :data:`MARGIN_TOL`: its smallest margin is within it of the best, and
    among the gaits that keep that, it has the fewest moves and, to within MARGIN_TOL per pose,
    the largest sum; remaining ties go to the tables' order.

    Args:
        margin: (T, S) the margin of every site set (:func:`site_sets`) at every pose, -inf
            where a set is unusable.
        reach: (T, F, N) bool, which finger can push on which site at every pose.
        start: the hand's state at the first pose, an assignment (F,) of sites (-1: none);
            default the best one.

    Returns:
        The gait with its ``policy``, optimal from every state: a move that maximises the
        smallest margin from there on, and among those the gait's secondary choices (fewest
        moves, largest sum) wherever the gait's own smallest margin can still be kept. If no
        gait (from ``start``) keeps the rules at every pose, the best smallest margin is -inf
        and the gait drops at the first pose (states -1, margins -inf), not at an arbitrary
        one: check ``gait.margin > -inf``.
    """
    margin, reach = _check_inputs(margin, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    _, policy, x, best = _programme(
        table.states, table.ptr, table.move, table.next, table.loaded, margin, reach,
        _start_index(table, start), MARGIN_TOL,
    )  # fmt: skip
    policy.flags.writeable = False
    # every gait drops somewhere: none is optimal, so none is followed
    choices = _policy_choices(table, policy, x) if best > -np.inf else np.full(len(margin), -1)
    gait = _follow(table, x, choices, margin, reach)
    return Gait(**{**gait.__dict__, "policy": policy})


def greedy_gait(margin: ArrayLike, reach: ArrayLike, start: ArrayLike | None = None) -> Gait:
    """The greedy baseline: at each pose the move that maximises the smaller of that pose's
    margin and the best margin the next pose then allows (a one-pose lookahead, so that it
    lifts a finger before the finger loses its site, where it can); ties (to within
    :data:`MARGIN_TOL`): the larger margin now, then fewer moves. Default start: its own
    best first choice. Its ``policy`` is the greedy rule from every state at every pose."""
    margin, reach = _check_inputs(margin, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    policy, score = _greedy(
        table.states, table.ptr, table.move, table.next, table.loaded, margin, reach, MARGIN_TOL
    )
    policy.flags.writeable = False
    x = first_best(score[0]) if start is None else table.index(start, "start")
    gait = _follow(table, x, _policy_choices(table, policy, x), margin, reach)
    return Gait(**{**gait.__dict__, "policy": policy})


def best_fixed(margin: ArrayLike, reach: ArrayLike) -> Gait:
    """The best gait without moves: one set of fingers on one set of sites throughout."""
    margin, reach = _check_inputs(margin, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    ok = _state_ok(table.states, reach)
    keep = table.ptr[:-1]  # a state's first move: keep, if at most four fingers touch
    worst = np.where(ok, margin[:, table.loaded[keep]], -np.inf).min(axis=0)
    worst[table.move[keep] != 0] = -np.inf
    x = first_best(worst)
    return _follow(table, x, np.full(len(margin), keep[x]), margin, reach)


def bottleneck_bound(
    margin_bound: ArrayLike, reach: ArrayLike, start: ArrayLike | None = None
) -> float:
    """The best smallest margin any gait could reach with margins ``margin_bound`` (pass 1 of
    the programme alone): an upper bound on the optimal gait's margin if these bound the
    margins from above."""
    margin, reach = _check_inputs(margin_bound, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    _, _, _, bound = _programme(
        table.states, table.ptr, table.move, table.next, table.loaded, margin, reach,
        _start_index(table, start), MARGIN_TOL,
    )  # fmt: skip
    return float(bound)
