"""The ``grasp-env`` command line: one sub-command per module of ``grasp_env_agents``.

Each command is a module of :mod:`grasp_env_agents.commands` defining
``add_arguments(parser)`` and ``run(args) -> int``; its one-line summary is here, in
:data:`SUMMARIES` (the only copy), so that the top-level ``--help`` imports no command module.
Only the chosen command's module is imported, so ``grasp-env reproduce`` never pays for
importing torch.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import math
import sys
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path

from grasp_env import __version__

from .progress import status, watch_numba

#: Each sub-command's one-line summary: ``grasp-env --help``'s list and the command's
#: description.
SUMMARIES = {
    "reproduce": "the paper's quasi-static sweep (or any object's, with --object): optimal k_ij"
    " and friction angles, plots",
    "train": "train an agent (PPO, TD3 or SAC) from a YAML config",
    "evaluate": "compare a trained agent with the minimax expert and baselines",
    "verify": "check grip forces in MuJoCo physics along a trajectory",
    "bench": "run the speed benchmarks in benchmarks/",
    "sweep": "a sweep on Ray Tune (grid, random or Optuna) over config keys and seeds",
    "results": "results across runs: IQM and 95% bootstrap intervals over seeds, the README table",
    "gait": "when to phase fingers out and in: the certified optimal gait along a long rotation",
}


def path_argument(text: str) -> Path:
    """An argparse type for file and folder arguments: an empty one would silently mean the
    working directory."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path: give a file or folder name")
    return Path(text)


def folder_argument(text: str) -> Path:
    """An argparse type for output folders (created if missing): refused at once, before any
    work, if it or a folder above it is a file."""
    path = path_argument(text)
    for folder in (path, *path.parents):
        if folder.exists():
            if not folder.is_dir():
                above = "" if folder == path else f" ({folder} is)"
                raise argparse.ArgumentTypeError(
                    f"{path} cannot be a folder: a file is in the way{above}"
                )
            break
    return path


#: The largest seed: numpy's legacy generators and SB3's ``set_random_seed`` take an unsigned
#: 32-bit integer (a config's ``seed``, a sweep's ``seeds``, ``--seed``).
MAX_SEED = 2**32 - 1
#: Characters of a refused argument shown in its message (a 5,000-digit number is not).
SHOWN = 40


def shown_text(text: str) -> str:
    """``text`` quoted for a message, cut to :data:`SHOWN` characters with its length if
    longer."""
    if len(text) <= SHOWN:
        return repr(text)
    return f"{text[: SHOWN // 2]!r}... ({len(text):,} characters)"


def integer_argument(low: int, high: int | None = None) -> Callable[[str], int]:
    """An argparse type for counts and seeds: an integer >= ``low`` (and <= ``high`` if
    given), written as configs take them (``1000``, ``1_000`` or ``1e3``)."""
    accepted = f">= {low}" if high is None else f"in [{low}, {high}]"

    def integer(text: str) -> int:
        try:
            number = float(text) if "e" in text.lower() else int(text)
        except ValueError:  # not a number, or past the 4,300 digits Python converts
            number = math.nan
        if not (
            math.isfinite(number)
            and number == int(number)
            and low <= number <= (math.inf if high is None else high)
        ):
            raise argparse.ArgumentTypeError(
                f"must be an integer {accepted}, got {shown_text(text)}"
            )
        return int(number)

    return integer


def seed_argument() -> Callable[[str], int]:
    """An argparse type for seeds: an integer in [0, :data:`MAX_SEED`] (2^32 - 1)."""
    return integer_argument(0, MAX_SEED)


#: The import names of pyproject.toml's ``agents`` extra (tests/test_package.py checks them):
#: ``pip install grasp-env`` is the library alone, and the command line needs the extra.
AGENTS_EXTRA = (
    "torch",
    "stable_baselines3",
    "sb3_contrib",
    "matplotlib",
    "yaml",
    "pydantic",
    "tqdm",
    "rich",
    "tensorboard",
)


def main(argv: list[str] | None = None) -> int:
    missing = [name for name in AGENTS_EXTRA if importlib.util.find_spec(name) is None]
    if missing:  # one line, not an ImportError from deep inside a command
        print(
            f"grasp-env needs the agents extra ({', '.join(missing)} not installed): "
            'pip install "torch==2.13.0" "grasp-env[agents]"',
            file=sys.stderr,
        )
        return 1
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(
        prog="grasp-env", description="Grip-force optimisation for multi-fingered grasps."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = argv[0] if argv and argv[0] in SUMMARIES else None
    for name, summary in SUMMARIES.items():
        # help is %-formatted by argparse, description is not
        command = sub.add_parser(name, help=summary.replace("%", "%%"), description=summary)
        if name == chosen:
            helping = "-h" in argv or "--help" in argv  # its output is the usage alone
            loading = (
                nullcontext() if helping else status(f"grasp-env {name}: loading its libraries")
            )
            try:
                with loading:
                    module = importlib.import_module(f".commands.{name}", __package__)
            except KeyboardInterrupt:  # Ctrl-C while torch and friends load
                print("interrupted", file=sys.stderr)
                return 130
            module.add_arguments(command)
            command.set_defaults(run=module.run)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    watch_numba()  # the first command after installing compiles for a while: say so
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt as stop:
        print(f"interrupted: {stop}" if str(stop) else "interrupted", file=sys.stderr)
        return 130
    except ValueError as error:  # bad input: a clear message, not a traceback
        print(f"grasp-env {args.command}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # a path it cannot read or write (the message names it)
        print(f"grasp-env {args.command}: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
