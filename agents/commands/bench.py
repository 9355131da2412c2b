"""``grasp-env bench``: run the speed benchmarks (each prints its rates beside a reference
measured in the same run, and exits with 1 if a target is missed).

The benchmarks ship with the package (``grasp_env_agents.benchmarks``, the repository's
``benchmarks/`` folder); each runs in a process of its own, so that one's compiled kernels and
threads do not disturb the next one's timings. Each judges its targets through
:class:`Targets`, which tells this command which ones it missed: the command's last line then
names them and says that they are why it exits with 1 (:func:`closing_line`, also what a
benchmark run on its own ends with).
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
from importlib import resources
from pathlib import Path

PACKAGE = "grasp_env_agents.benchmarks"
#: The file a benchmark run by ``grasp-env bench`` appends its missed targets to, one a line.
MISSED_FILE = "GRASP_ENV_BENCH_MISSED"


class Targets:
    """A benchmark's targets: :meth:`check` gives each one's verdict (``ok`` or ``MISSED``)
    for its line, :meth:`exit_code` the benchmark's exit status, 1 if one was missed."""

    def __init__(self, benchmark: str) -> None:
        self.benchmark = benchmark
        self.missed: list[str] = []

    def check(self, target: str, ok: bool) -> str:
        """The verdict on ``target`` (what it asks, e.g. ``"CubeGrasp-v0 vector >= 0.6x
        CartPole-v1"``), remembered if missed."""
        if not ok:
            self.missed.append(target)
        return "ok" if ok else "MISSED"

    def exit_code(self) -> int:
        """0 if every target was met, else 1: under ``grasp-env bench`` the missed targets
        go to the command (which names them last), on their own a closing line names them."""
        if not self.missed:
            return 0
        report = os.environ.get(MISSED_FILE)
        if report:
            with open(report, "a") as file:
                file.writelines(f"{self.benchmark}\t{target}\n" for target in self.missed)
        else:
            print(closing_line({self.benchmark: self.missed}, {}), flush=True)
        return 1


def closing_line(missed: dict[str, list[str]], failed: dict[str, int]) -> str:
    """The last line of a run whose exit code is not 0: the targets ``missed`` by benchmark,
    and the benchmarks that ``failed`` otherwise (exit code by name)."""
    parts = []
    count = sum(len(targets) for targets in missed.values())
    if count:
        named = "; ".join(f"{name}: {', '.join(targets)}" for name, targets in missed.items())
        parts.append(f"{count} target{'s' * (count != 1)} missed ({named})")
    if failed:
        codes = ", ".join(f"{name} (exit code {code})" for name, code in failed.items())
        parts.append(f"failed without a verdict on its targets: {codes}")
    return f"exit code 1: {'; '.join(parts)}"


def available() -> list[str]:
    """The benchmark names: ``bench_<name>.py`` in the benchmarks package."""
    files = resources.files(PACKAGE).iterdir()
    return sorted(
        file.name.removeprefix("bench_").removesuffix(".py")
        for file in files
        if file.name.startswith("bench_") and file.name.endswith(".py")
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "names", nargs="*", metavar="NAME", help=f"benchmarks to run (default all: {available()})"
    )
    parser.add_argument(
        "--seconds", type=float, help="time per measurement (each benchmark has its default)"
    )
    parser.add_argument(
        "--contacts",
        metavar="N,N,...",
        help="the solver benchmark only: the numbers of contacts to measure, comma-separated"
        " (3 to 8; default all)",
    )


def run(args: argparse.Namespace) -> int:
    names = args.names or available()
    unknown = sorted(set(names) - set(available()))
    if unknown:
        raise ValueError(f"unknown benchmark(s) {unknown}; available: {available()}")
    if args.seconds is not None and not 0 < args.seconds < math.inf:
        raise ValueError(f"--seconds must be a finite number > 0, got {args.seconds}")
    if args.contacts is not None and names != ["solver"]:
        raise ValueError(
            "--contacts applies to the solver benchmark alone: grasp-env bench solver"
            f" --contacts {args.contacts}"
        )
    extra = [] if args.seconds is None else ["--seconds", str(args.seconds)]
    if args.contacts is not None:
        extra += ["--contacts", args.contacts]  # the benchmark checks its range
    failed: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as folder:
        report = Path(folder) / "missed"
        report.touch()
        for name in names:
            print(f"== grasp-env bench {name}", flush=True)
            command = [sys.executable, "-m", f"{PACKAGE}.bench_{name}", *extra]
            done = subprocess.run(
                command, check=False, env={**os.environ, MISSED_FILE: str(report)}
            )
            if done.returncode:
                failed[name] = done.returncode
        missed: dict[str, list[str]] = {}
        for line in report.read_text().splitlines():
            name, target = line.split("\t", 1)
            missed.setdefault(name, []).append(target)
    if not failed:
        return 0
    # a benchmark that missed targets exits with 1; any other failure is said as such
    failed = {n: c for n, c in failed.items() if not (c == 1 and n in missed)}
    print(closing_line(missed, failed), flush=True)
    return 1
