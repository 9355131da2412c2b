"""The cores this process may use, and persistent thread pools for work that releases the GIL
(the solver's kernels, the vector env's step, MuJoCo's stepping)."""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
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


def in_parts(name: str, count: int, part: Callable[[int, int], _T], smallest: int) -> list[_T]:
    """``part(lo, hi)`` over contiguous parts of ``range(count)``, one per available core (the
    caller runs the first, the pool ``name`` the others); one part if ``count < smallest``.
    For a batch kernel that releases the GIL and whose rows depend on their own inputs alone,
    so that the parts are the very numbers of one call. Returns the parts' results in order."""
    if count < smallest:
        return [part(0, count)]
    cores = available_cores()
    bounds = [count * p // cores for p in range(cores + 1)]
    others = [
        thread_pool(name, cores - 1).submit(part, lo, hi)
        for lo, hi in itertools.pairwise(bounds[1:])
    ]
    return [part(bounds[0], bounds[1]), *(other.result() for other in others)]
