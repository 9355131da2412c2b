"""``grasp-env bench``: run the speed benchmarks in ``benchmarks/`` (each prints its ratios)."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

HELP = "run the speed benchmarks in benchmarks/"
BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def available() -> list[str]:
    return sorted(path.stem.removeprefix("bench_") for path in BENCHMARKS.glob("bench_*.py"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "names", nargs="*", metavar="NAME", help=f"benchmarks to run (default all: {available()})"
    )


def run(args: argparse.Namespace) -> int:
    names = args.names or available()
    unknown = sorted(set(names) - set(available()))
    if unknown:
        raise ValueError(f"unknown benchmark(s) {unknown}; available: {available()}")
    status = 0
    for name in names:
        print(f"== benchmarks/bench_{name}.py", flush=True)
        done = subprocess.run([sys.executable, str(BENCHMARKS / f"bench_{name}.py")], check=False)
        status = status or done.returncode
    return status
