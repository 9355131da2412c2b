"""The command line is never silent for long: the status line, and numba's first compilation."""

from __future__ import annotations

import time

import numba
import numba.core.event
import pytest

from grasp_env_agents import progress


@pytest.fixture
def quick(monkeypatch):
    """Status lines after 0.1 s, and in a log every 0.3 s (stderr is captured: not a tty)."""
    monkeypatch.setattr(progress, "DELAY", 0.1)
    monkeypatch.setattr(progress, "LOG_EVERY", 0.3)


def test_a_long_block_says_what_it_does_and_how_long_it_took(quick, capsys):
    with progress.status("collecting states") as detail:
        detail("round 1 of 2")
        time.sleep(0.8)
    time.sleep(0.3)  # the status thread's last tick
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) >= 2  # at 0.1 s, every 0.3 s, and the total (unless just logged)
    assert all(line.startswith("collecting states: round 1 of 2, ") for line in lines)
    assert lines[-1].endswith(" 1 s")


def test_a_short_block_says_nothing(quick, capsys):
    with progress.status("a moment"):
        time.sleep(0.01)
    time.sleep(0.3)
    assert capsys.readouterr().err == ""


def test_numba_compiling_is_shown(quick, capsys):
    progress.watch_numba()
    progress.watch_numba()  # the CLI calls it for every command: one listener still

    @numba.njit
    def square_root_sum(n):
        total = 0.0
        for i in range(n):
            total += i**0.5
        return total

    # a compilation long enough to be seen whatever numba has warmed up before: numba's own
    # event around half a second, with a real compilation (its own event) inside
    data = {"dispatcher": None, "args": (), "return_type": None}
    with numba.core.event.trigger_event("numba:compile", data=data):
        time.sleep(0.5)
        assert square_root_sum(4) == pytest.approx(1 + 2**0.5 + 3**0.5)
    time.sleep(0.6)  # the block ends once nothing has compiled for DELAY
    err = capsys.readouterr().err
    assert err.count("compiling grasp_env's numba kernels, once after installing") >= 1
    assert "2 kernels, " in err.splitlines()[-1]
