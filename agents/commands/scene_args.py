"""Command-line options that describe a three-finger scene, shared by reproduce and verify."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

import numpy as np

from grasp_env.mechanics import DEFAULT_MU, DEFAULT_WEIGHT, PAPER_FACES, Scene


def numbers(text: str) -> tuple[float, ...]:
    """An argparse type: comma-separated numbers, any count."""
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError("expected comma-separated numbers") from None


def floats(count: int) -> Callable[[str], tuple[float, ...]]:
    """An argparse type: ``count`` comma-separated numbers."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers") from None
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers")
        return values

    return parse


def within(range_name: str, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a number in the environments' range ``range_name`` of
    ``grasp_env.envs.validation`` (docs/environments.md; far beyond them forces in newtons
    overflow or underflow, or the friction cone closes or opens flat)."""

    def parse(text: str) -> float:
        from grasp_env.envs import validation  # (gymnasium: only once an option is parsed)

        low, high = getattr(validation, range_name)
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not low <= value <= high:  # (NaN is not)
            raise argparse.ArgumentTypeError(f"must be in [{low:g}, {high:g}]{unit}, got {text!r}")
        return value

    return parse


#: --weight and --mu: the environments' ranges.
weight = within("WEIGHT_RANGE", " N")
friction = within("MU_RANGE")


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """--weight, --mu, --offsets and --cg-offset of the paper's three-finger grasp."""
    parser.add_argument(
        "--weight",
        type=weight,
        default=DEFAULT_WEIGHT,
        help=f"weight, N, in [1e-6, 1e6] (default {DEFAULT_WEIGHT})",
    )
    parser.add_argument(
        "--mu",
        type=friction,
        default=DEFAULT_MU,
        help=f"friction coefficient, in [1e-3, 1e3] (default {DEFAULT_MU})",
    )
    parser.add_argument(
        "--offsets",
        type=floats(6),
        default=None,
        metavar="U1,V1,U2,V2,U3,V3",
        help="contact offsets from the face centres, fractions of the half-width (default 0)",
    )
    parser.add_argument(
        "--cg-offset", type=floats(3), default=(0.0, 0.0, 0.0), metavar="X,Y,Z",
        help="centre of gravity relative to the cube's centre, m (default 0)",
    )  # fmt: skip


def scene_from_arguments(args: argparse.Namespace) -> Scene:
    """The scene the options of :func:`add_scene_arguments` describe (ValueError if invalid)."""
    offsets = None if args.offsets is None else np.reshape(args.offsets, (3, 2))
    return Scene.on_faces(
        PAPER_FACES, offsets=offsets, weight=args.weight, mu=args.mu, cg_offset=args.cg_offset
    )
