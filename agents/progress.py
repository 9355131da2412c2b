"""Never silent for long: one status line on stderr for whatever takes more than a moment.

``with status("collecting 100,000 states") as detail:`` says what is being done once it has
taken :data:`DELAY` seconds, with the seconds so far (and ``detail("epoch 3/20")`` if given):
on a terminal one line redrawn every second, elsewhere (a log, CI) a line every
:data:`LOG_EVERY` seconds. A block that took long ends with a line saying how long.
:func:`say` prints a message without tearing the status line.

:func:`watch_numba` makes numba's compilation of grasp_env's kernels one of these blocks: the
first command after installing (or updating) the package compiles them for a minute or two,
once, and caches them for every later run.

:func:`console` is the rich Console the commands print their tables with: a terminal's own
width, and in a log or a pipe wide enough that no cell is cut and no line is wrapped.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

#: Seconds a block runs silently before its status line appears.
DELAY = 1.0
#: Seconds between status lines when stderr is not a terminal.
LOG_EVERY = 10.0
#: Width of :func:`console` when stdout is not a terminal (rich would assume 80 columns and
#: cut the tables' cells to "16.14…"): wider than any table or line the commands print.
LOG_WIDTH = 10_000
COMPILING = "compiling grasp_env's numba kernels, once after installing (cached for later runs)"


@dataclass
class _Block:
    message: str
    started: float = field(default_factory=time.monotonic)
    detail: str = ""
    shown: bool = False
    next_line: float = 0.0
    last: str = ""

    def line(self, now: float) -> str:
        detail = f"{self.detail}, " if self.detail else ""
        return f"{self.message}: {detail}{now - self.started:.0f} s"


class _StatusLine:
    """The process's one status line, drawn by a daemon thread."""

    def __init__(self) -> None:
        self.blocks: list[_Block] = []
        self.lock = threading.RLock()
        self.drawn = False  # a terminal line is on screen, to be cleared before other output
        self.thread: threading.Thread | None = None
        self.tickers: list[Callable[[float], None]] = []

    def push(self, message: str) -> _Block:
        with self.lock:
            block = _Block(message)
            self.blocks.append(block)
            if self.thread is None:
                self.thread = threading.Thread(target=self._run, daemon=True, name="status")
                self.thread.start()
            return block

    def pop(self, block: _Block) -> None:
        with self.lock:
            self.blocks.remove(block)
            self.clear()
            final = block.line(time.monotonic())
            if block.shown and final != block.last:  # how long it took (unless just logged)
                print(final, file=sys.stderr, flush=True)

    def clear(self) -> None:
        with self.lock:
            if self.drawn:
                sys.stderr.write("\r\x1b[K")
                sys.stderr.flush()
                self.drawn = False

    def _run(self) -> None:
        while True:
            time.sleep(0.25)
            with self.lock:
                now = time.monotonic()
                for tick in self.tickers:
                    tick(now)
                if not self.blocks or now - self.blocks[-1].started < DELAY:
                    continue
                block = self.blocks[-1]
                text = block.line(now)
                if sys.stderr.isatty():
                    sys.stderr.write(f"\r\x1b[K{text}")
                    self.drawn = True
                elif now >= block.next_line:
                    sys.stderr.write(f"{text}\n")
                    block.last = text
                    block.next_line = now + LOG_EVERY
                sys.stderr.flush()
                block.shown = True


_LINE = _StatusLine()


@contextmanager
def status(message: str) -> Iterator[Callable[[str], None]]:
    """Say ``message`` while the block runs, if it takes more than :data:`DELAY` seconds; the
    block gets a function that sets a detail (``"epoch 3/20"``)."""
    block = _LINE.push(message)

    def detail(text: str) -> None:
        block.detail = text

    try:
        yield detail
    finally:
        _LINE.pop(block)


def say(*args: object) -> None:
    """``print`` that first clears the status line (which the next tick redraws)."""
    with _LINE.lock:
        _LINE.clear()
        print(*args, flush=True)


def console() -> Any:
    """A rich ``Console`` on stdout for the commands' tables and lines. On a terminal it takes
    the terminal's width; elsewhere (a log, a pipe, a test's capture) :data:`LOG_WIDTH`, so the
    values are printed whole whatever ``COLUMNS`` says. Like :func:`say`, its ``print`` first
    clears the status line."""
    from rich.console import Console

    class _Console(Console):
        def print(self, *args: Any, **kwargs: Any) -> None:
            with _LINE.lock:
                _LINE.clear()
                super().print(*args, **kwargs)

    terminal = getattr(sys.stdout, "isatty", lambda: False)()
    return _Console(width=None if terminal else LOG_WIDTH)


class _Compiling:
    """A numba event listener: one status block from the first compilation until none has run
    for :data:`DELAY` seconds (kernels compile one after another, with Python between them)."""

    def __init__(self) -> None:
        self.depth = 0
        self.kernels = 0
        self.last_end = 0.0
        self.block: _Block | None = None

    def on_start(self, event: object) -> None:
        with _LINE.lock:
            if self.block is None:
                self.block = _LINE.push(COMPILING)
                self.kernels = 0  # counted per block
            self.depth += 1

    def on_end(self, event: object) -> None:
        with _LINE.lock:
            self.depth -= 1
            self.kernels += 1
            self.last_end = time.monotonic()
            if self.block is not None:
                self.block.detail = f"{self.kernels} kernel{'s' * (self.kernels != 1)}"

    def tick(self, now: float) -> None:
        """Called by the status thread: end the block once compiling has stopped."""
        if self.block is not None and self.depth == 0 and now - self.last_end > DELAY:
            _LINE.pop(self.block)
            self.block = None


def watch_numba() -> None:
    """Show numba's compilations as a status block (the first use after installing); once per
    process, however often it is called."""
    if _LINE.tickers:
        return
    import numba.core.event

    listener = type("Compiling", (_Compiling, numba.core.event.Listener), {})()
    numba.core.event.register("numba:compile", listener)
    _LINE.tickers.append(listener.tick)
