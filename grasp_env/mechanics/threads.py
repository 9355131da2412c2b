"""The cores this process may use, and persistent thread pools for work that releases the GIL
(the solver's kernels, the vector env's step, MuJoCo's stepping)."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor


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
