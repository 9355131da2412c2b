"""The hand's states (which finger touches which site) and their moves, as tables
(:func:`gait_states`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numba
import numpy as np
from numpy.typing import ArrayLike

from ..scene import (
    ArrayRecord,
)
from .sites import _MAX_FINGERS, _MAX_SITES, MAX_LOADED, MAX_TOUCHING, MIN_LOADED, site_sets


@dataclass(frozen=True, eq=False)
class GaitStates(ArrayRecord):
    """The hand's states (which finger touches which site) and their moves, as tables.

    Attributes:
        n_fingers, n_sites: F and N.
        states: (X, F) the site each finger touches (-1: none); 3 or 4 fingers touch.
        code: ((N + 1)^F,) state index of an assignment's code sum_f (a_f + 1) (N + 1)^f, -1
            where the assignment is not a state.
        ptr, move, next, loaded: the valid moves of state x are move[ptr[x]:ptr[x + 1]] (move
            codes, increasing: keep first), leading to state next[...] with the site set
            loaded[...] (an index into :func:`site_sets`) carrying load at the pose.
    """

    n_fingers: int
    n_sites: int
    states: np.ndarray
    code: np.ndarray
    ptr: np.ndarray
    move: np.ndarray
    next: np.ndarray
    loaded: np.ndarray

    @property
    def n_moves(self) -> int:
        return 1 + self.n_fingers * self.n_sites

    def index(self, assignment: ArrayLike, name: str = "assignment") -> int:
        """The state index of an assignment (F,) of sites (-1: not touching); ValueError,
        naming it ``name`` (the caller's keyword), if it is no state (not F integer sites, a
        site used twice, fewer than 3 or more than 4 fingers touching)."""
        try:
            a = np.asarray(assignment)
        except (TypeError, ValueError):  # ragged
            a = np.empty(0)
        # integers only: 2.7 is refused, not truncated to site 2
        if (
            a.shape != (self.n_fingers,)
            or a.dtype.kind not in "iu"
            or np.any(a < -1)
            or np.any(a >= self.n_sites)
        ):
            raise ValueError(
                f"{name} must give each of the {self.n_fingers} fingers a site in"
                f" [-1, {self.n_sites - 1}] (-1: none), got {a.tolist() if a.size else assignment}"
            )
        a = a.astype(np.int64)
        x = int(self.code[int(np.sum((a + 1) * (self.n_sites + 1) ** np.arange(self.n_fingers)))])
        if x < 0:
            raise ValueError(
                f"{name} {a.tolist()} is no state of the hand: sites must differ and"
                f" {MIN_LOADED} to {MAX_TOUCHING} fingers touch"
            )
        return x


@numba.njit(cache=True)
def _enumerate(F, N, set_code):
    """States, the code table and the moves in CSR form (see :class:`GaitStates`)."""
    base = N + 1
    total = base**F
    code = np.full(total, -1, np.int64)
    digits = np.empty(F, np.int64)
    states = np.empty((total, F), np.int64)
    count = 0
    for c in range(total):
        rest = c
        used = 0
        touching = 0
        ok = True
        for f in range(F):
            digits[f] = rest % base - 1
            rest //= base
            if digits[f] >= 0:
                bit = 1 << digits[f]
                if used & bit:
                    ok = False
                used |= bit
                touching += 1
        if ok and MIN_LOADED <= touching <= MAX_TOUCHING:
            code[c] = count
            states[count] = digits
            count += 1
    states = states[:count]
    M = 1 + F * N
    ptr = np.zeros(count + 1, np.int64)
    move = np.empty(count * M, np.int64)
    nxt = np.empty(count * M, np.int64)
    loaded = np.empty(count * M, np.int64)
    k = 0
    power = np.empty(F, np.int64)
    for f in range(F):
        power[f] = base**f
    for x in range(count):
        a = states[x]
        used = 0
        touching = 0
        c = 0
        for f in range(F):
            if a[f] >= 0:
                used |= 1 << a[f]
                touching += 1
            c += (a[f] + 1) * power[f]
        for m in range(M):
            if m == 0:  # keep: every touching finger carries load
                move[k], nxt[k], loaded[k] = 0, x, set_code[used]
                k += 1
                continue
            f = (m - 1) // N
            s = (m - 1) % N
            if a[f] == s:  # lift: zero force now, gone next
                if MIN_LOADED <= touching - 1 <= MAX_LOADED:
                    rest = used & ~(1 << s)
                    move[k], nxt[k], loaded[k] = m, code[c - (s + 1) * power[f]], set_code[rest]
                    k += 1
            elif a[f] < 0 and not used & (1 << s) and touching < MAX_TOUCHING:
                # place: touches now with zero force, loaded next
                move[k], nxt[k], loaded[k] = m, code[c + (s + 1) * power[f]], set_code[used]
                k += 1
        ptr[x + 1] = k
    return states, code, ptr, move[:k].copy(), nxt[:k].copy(), loaded[:k].copy()


def _size_ok(n_fingers: int, n_sites: int) -> bool:
    """Whether a hand of F fingers on N sites is within range: the site sets and the states
    grow combinatorially with them."""
    return 3 <= n_fingers <= _MAX_FINGERS and 3 <= n_sites <= _MAX_SITES


@cache
def gait_states(n_fingers: int, n_sites: int) -> GaitStates:
    """The state and move tables of a hand of F fingers on N sites (cached)."""
    if not _size_ok(n_fingers, n_sites):
        raise ValueError(
            f"a gait needs 3 to {_MAX_FINGERS} fingers and 3 to {_MAX_SITES} sites,"
            f" got {n_fingers} and {n_sites}"
        )
    set_code = np.full(1 << n_sites, -1, np.int64)
    for i, s in enumerate(site_sets(n_sites)):
        set_code[sum(1 << j for j in s)] = i
    arrays = _enumerate(n_fingers, n_sites, set_code)
    for array in arrays:
        array.flags.writeable = False
    return GaitStates(n_fingers, n_sites, *arrays)


def move_name(move: int, n_sites: int) -> tuple[int, int] | None:
    """(finger, site) a move toggles, or None for keep."""
    return None if move == 0 else ((move - 1) // n_sites, (move - 1) % n_sites)
