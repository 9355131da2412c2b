"""``grasp-env bench``: run the speed benchmarks (each prints its rates beside a reference
measured in the same run, and exits with 1 if a target is missed).

The benchmarks ship with the package (``grasp_env_agents.benchmarks``, the repository's
``benchmarks/`` folder); each runs in a process of its own, so that one's compiled kernels and
threads do not disturb the next one's timings.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
from importlib import resources

HELP = "run the speed benchmarks (ratios against references measured in the same run)"
PACKAGE = "grasp_env_agents.benchmarks"


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


def run(args: argparse.Namespace) -> int:
    names = args.names or available()
    unknown = sorted(set(names) - set(available()))
    if unknown:
        raise ValueError(f"unknown benchmark(s) {unknown}; available: {available()}")
    if args.seconds is not None and not 0 < args.seconds < math.inf:
        raise ValueError(f"--seconds must be a finite number > 0, got {args.seconds}")
    extra = [] if args.seconds is None else ["--seconds", str(args.seconds)]
    status = 0
    for name in names:
        print(f"== grasp-env bench {name}", flush=True)
        command = [sys.executable, "-m", f"{PACKAGE}.bench_{name}", *extra]
        done = subprocess.run(command, check=False)
        status = status or done.returncode
    return status
