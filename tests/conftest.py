"""Test session set-up.

Hypothesis draws the same examples on every run, so a test run (and CI) is reproducible;
``HYPOTHESIS_PROFILE=explore pytest`` draws new ones, to search further.

The numba kernels compile once, before the xdist workers start: each worker would otherwise
compile the minimax solver on its own, side by side, into an empty cache. :func:`pytest_configure`
runs :func:`grasp_env.warm.warm` on the controller only (two processes at a time, every kernel
compiled once: the solver's entries, the conic solver, then one reset and step of each
environment that ``pytest -m fast`` makes); the workers then load it all from numba's cache
(next to the sources, or ``NUMBA_CACHE_DIR``, the same for every process); a warm cache costs
it about 5 s. A run in one process (``-p no:xdist`` or ``-n 0``) compiles as it goes, what its
tests need only.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

settings.register_profile("reproducible", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))

#: what grasp_env.warm did, for the report header
_WARMED = pytest.StashKey[Any]()


def pytest_configure(config: pytest.Config) -> None:
    distributed = getattr(config.option, "dist", "no") != "no"
    workers = getattr(config.option, "numprocesses", None) or 0
    if hasattr(config, "workerinput") or not distributed or workers < 2:
        return
    if config.option.collectonly:
        return
    from grasp_env.warm import warm

    config.stash[_WARMED] = warm(processes=2)


def pytest_report_header(config: pytest.Config) -> list[str]:
    if _WARMED not in config.stash:
        return []
    done = config.stash[_WARMED]
    lines = [
        f"numba kernels compiled or loaded for the workers in {done.seconds:.0f} s"
        f" ({done.cpu_seconds:.0f} s CPU)"
    ]
    return lines + [f"  numba warm-up failed: {line}" for line in done.failed]


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """``pytest -m fast`` does not import the test files that mark no test ``fast`` (collecting
    them, which imports torch, SB3 and Ray, took each worker about 6 s of CPU)."""
    if config.option.markexpr != "fast" or not collection_path.name.startswith("test_"):
        return None
    if collection_path.suffix != ".py" or "mark.fast" in collection_path.read_text():
        return None
    return True


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_a_test_folder(tmp_path_factory):
    """SB3 models made without a log folder would each leave an empty folder in /tmp."""
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))


@pytest.fixture(autouse=True)
def _same_working_directory():
    """Every test starts and ends in the directory the session started in: a test whose code
    changes the process's directory (Ray Tune runs a trial in its trial folder, which the test
    then removes) would otherwise leave a worker in a deleted directory, and every later test
    of that worker fails with FileNotFoundError."""
    start = os.getcwd()
    yield
    try:
        moved = os.getcwd() != start
    except FileNotFoundError:
        moved = True
    if moved:
        os.chdir(start)
