"""The options of ``grasp-env gait`` (:func:`add_arguments`) and the object's defaults for
those the cube's and the can's gaits share (:func:`resolve`): apart from the command, so that
its ``--models`` part (:mod:`.gait_models`) reads them without importing the command back."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from grasp_env.mechanics import PAPER_TURN, SITE_FACES, SITE_OFFSETS, Hand
from grasp_env.mechanics.gait import GAIT_CG_OFFSET

from ..cli import folder_argument, path_argument
from . import gait_can
from .scene_args import floats, friction, numbers, weight

#: The cube's defaults for the options the can's gait shares (``gait_can.CAN_DEFAULTS``).
CUBE_DEFAULTS = {"weight": 5.0, "alpha_start": -90.0, "alpha_end": 90.0, "alpha_step": 1.0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", type=folder_argument, default=Path("results/gait"), help="output dir"
    )
    hand = Hand()
    parser.add_argument(
        "--object", choices=("cube", "can"), default="cube",
        help="the cube's gait along a rotation (default), or the coke can turned a full turn"
        " about its axis by five fingertips round its side (docs/gait.md, 'The can')",
    )  # fmt: skip
    parser.add_argument(
        "--weight", type=weight, default=None,
        help="weight, N, in [1e-6, 1e6] (default 5; the can's 3.4)",
    )  # fmt: skip
    parser.add_argument(
        "--mu", type=friction, default=0.5, help="friction coefficient, in [1e-3, 1e3] (0.5)"
    )
    parser.add_argument(
        "--offsets", type=floats(2 * len(SITE_FACES)), default=None,
        metavar="U1,V1,...,U6,V6",
        help="the sites' offsets from the centres of the faces " + ", ".join(SITE_FACES)
        + f", fractions of the half-width (default {np.ravel(SITE_OFFSETS).tolist()})",
    )  # fmt: skip
    parser.add_argument(
        "--cg-offset", type=floats(3), default=GAIT_CG_OFFSET, metavar="X,Y,Z",
        help=f"centre of gravity relative to the cube's centre, m (default {GAIT_CG_OFFSET})",
    )  # fmt: skip
    parser.add_argument(
        "--axis", type=floats(3), default=PAPER_TURN.axis, metavar="X,Y,Z",
        help="world-frame rotation axis (default the paper's, 1,-1,0; 0,0,1 turns the cube"
        " about its own diagonal, the vertical)",
    )  # fmt: skip
    parser.add_argument(
        "--alpha-start", type=float, default=None, help="first alpha, deg (default -90; can 0)"
    )
    parser.add_argument(
        "--alpha-end", type=float, default=None, help="last alpha, deg (default 90; can 360)"
    )
    parser.add_argument(
        "--alpha-step", type=float, default=None, help="alpha step, deg (default 1; can 10)"
    )
    parser.add_argument(
        "--k-max", type=float, default=None,
        help="bound on |k_ij|, N, in [1e-3, 1e3] x weight (default 2 x weight)",
    )  # fmt: skip
    parser.add_argument(
        "--cone", type=float, default=hand.cone_deg,
        help=f"half-angle of each finger's cone of normals, deg (default {hand.cone_deg:g})",
    )  # fmt: skip
    parser.add_argument(
        "--finger-azimuths", type=numbers, default=hand.finger_azimuths_deg, metavar="A1,...",
        help="azimuths of the fingers' approach, deg (default "
        + ",".join(f"{a:g}" for a in hand.finger_azimuths_deg) + ")",
    )  # fmt: skip
    parser.add_argument(
        "--finger-elevation", type=float, default=hand.finger_elevation_deg,
        help=f"elevation of the fingers' approach, deg (default {hand.finger_elevation_deg:.2f})",
    )  # fmt: skip
    parser.add_argument("--no-thumb", action="store_true", help="a hand without the thumb")
    parser.add_argument("--no-plots", action="store_true", help="write the CSV only")
    gait_can.add_arguments(parser)
    parser.add_argument(
        "--models", nargs="+", type=path_argument, default=[], metavar="MODEL",
        help="trained agents (SB3 model files, e.g. rl-zoo3's, or sb3-contrib's MaskablePPO)"
        " to play on grasp_env/CubeGait-v0 (CubeGaitMoves-v0 for those that choose only the"
        " moves; MaskablePPO with the masks it was trained with, from its file or a"
        " gait_masks.json beside it) beside the optimal and the greedy gait (the default hand,"
        " sites and weight; --axis, --alpha-*, --mu, --cone, --k-max apply)",
    )  # fmt: skip


def resolve(args: argparse.Namespace) -> argparse.Namespace:
    """Fills the shared options left unset with the object's defaults (in place)."""
    defaults = gait_can.CAN_DEFAULTS if getattr(args, "object", "cube") == "can" else CUBE_DEFAULTS
    for name, value in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    return args
