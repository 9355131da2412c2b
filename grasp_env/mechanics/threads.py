"""The cores this process may use, and persistent thread pools for work that releases the GIL
(the solver's kernels, the vector env's step, MuJoCo's stepping)."""

from __future__ import annotations

import itertools
import os
import threading
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


def in_parts(name: str, count: int, part: Callable[[int, int], _T], parts: int) -> list[_T]:
    """``part(lo, hi)`` over ``parts`` contiguous parts of ``range(count)`` (at most ``count``,
    at least one), the results in order: the calling thread runs the first part, the pool
    ``name`` the others. For work that releases the GIL (compiled kernels, MuJoCo's stepping)
    and whose items depend on their own inputs alone, so that the parts are the very numbers
    of one call."""
    parts = max(1, min(parts, count))
    if parts == 1:
        return [part(0, count)]
    bounds = [count * p // parts for p in range(parts + 1)]
    pool = thread_pool(name, max(1, available_cores() - 1))
    others = [pool.submit(part, lo, hi) for lo, hi in itertools.pairwise(bounds[1:])]
    try:
        first = part(bounds[0], bounds[1])
    finally:  # the other parts write into the caller's arrays: never leave them running
        wait(others)
    return [first, *(other.result() for other in others)]
