"""The cores this process may use, and persistent thread pools for work that releases the GIL
(the solver's kernels, the vector env's step, MuJoCo's stepping)."""

from __future__ import annotations

import itertools
import math
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from typing import TypeVar

_T = TypeVar("_T")


def available_cores() -> int:
    """The cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


_pools: dict[str, tuple[int, ThreadPoolExecutor]] = {}  # name: (the process that made it, pool)
_lock = threading.Lock()


def thread_pool(name: str, size: int) -> ThreadPoolExecutor:
    """The pool ``name`` of ``size`` threads, made on first use; a new one in a forked child
    (SubprocVecEnv, Ray workers), where the parent's threads do not exist and work handed to
    them would never run."""
    with _lock:
        made = _pools.get(name)
        if made is None or made[0] != os.getpid():
            made = _pools[name] = (os.getpid(), ThreadPoolExecutor(size, thread_name_prefix=name))
        return made[1]


#: How much sooner than the calling thread the pool's parts should end: the caller then finds
#: them done instead of sleeping until they are (waking a sleeping thread took about 50 us on
#: the 2-core virtual machines measured, docs/environments.md).
LEAD_SECONDS = 20e-6
# name: (the seconds the pool's parts start after the caller's, the caller's seconds per item),
# each a running mean over recent calls
_timing: dict[str, tuple[float, float]] = {}


def hand_off(name: str) -> tuple[float, float] | None:
    """What :func:`in_parts` has measured for the pool ``name`` (running means): the seconds
    the pool's parts start after the caller's, and the caller's seconds per item; None before
    its first split call."""
    return _timing.get(name)


def caller_items(name: str, count: int, parts: int) -> int:
    """How many of ``count`` items the calling thread takes when :func:`in_parts` splits them
    into ``parts`` (2 or more): an even share, and as many more as it does in the pool's start
    lag and :data:`LEAD_SECONDS`, shared with the other parts; at least one item, and leaving
    at least one to each other part."""
    lag, per_item = _timing.get(name, (0.0, math.inf))
    extra = (lag + LEAD_SECONDS) / per_item * (parts - 1) / parts
    return min(count - parts + 1, max(1, round(count / parts + extra)))


def in_parts(name: str, count: int, part: Callable[[int, int], _T], parts: int) -> list[_T]:
    """``part(lo, hi)`` over ``parts`` contiguous parts of ``range(count)`` (at most ``count``,
    at least one), the results in order: the calling thread runs the first part, the pool
    ``name`` the others. For work that releases the GIL (compiled kernels, MuJoCo's stepping)
    and whose items depend on their own inputs alone, so that the parts are the very numbers
    of one call, however the items are split.

    The pool's threads start their parts some tens of microseconds after the caller starts
    its own, so an even split leaves the caller asleep while they finish. The caller takes
    more items instead: as many as it does in that start lag (measured per ``name``) and
    :data:`LEAD_SECONDS`, shared with the other parts. For parts of milliseconds that is an
    even split; for the vector step's parts of 0.3 ms about 54% for the caller."""
    parts = max(1, min(parts, count))
    if parts == 1:
        return [part(0, count)]
    first_count = caller_items(name, count, parts)
    rest = count - first_count
    bounds = [0, *(first_count + rest * p // (parts - 1) for p in range(parts))]

    def timed(lo: int, hi: int) -> tuple[float, _T]:
        return time.perf_counter(), part(lo, hi)

    pool = thread_pool(name, max(1, available_cores() - 1))
    others = [pool.submit(timed, lo, hi) for lo, hi in itertools.pairwise(bounds[1:])]
    try:
        start = time.perf_counter()
        first = part(bounds[0], bounds[1])
        end = time.perf_counter()
    finally:  # the other parts write into the caller's arrays: never leave them running
        wait(others)
    starts, results = zip(*(other.result() for other in others), strict=True)
    lag, per_item = max(starts) - start, max(end - start, 1e-9) / first_count
    mean_lag, mean_per_item = _timing.get(name, (lag, per_item))
    _timing[name] = (0.8 * mean_lag + 0.2 * lag, 0.8 * mean_per_item + 0.2 * per_item)
    return [first, *results]
