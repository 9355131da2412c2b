"""``grasp-env gait``: when to phase a finger out or in along a long rotation.

The paper calls for "an algorithm ... when to phase out a finger" and gives none; this command
computes the certified optimal gait (``--object can``: the can's, :mod:`.gait_can`). A hand
with reach (``grasp_env.mechanics.Hand``: four fingers below pushing up and inwards, a thumb
above pushing down, each within a 60 deg cone of face normals) holds the cube by sites, one per
face, off-centre; the cube turns about the paper's axis from -90 to +90 deg (or any axis and
range). At every pose the certified minimax is solved for every set of 3 or 4 sites; the
dynamic programme over the hand's states then gives the gait that maximises the smallest
friction-angle margin along the whole trajectory, certified by the same programme on the
solver's bounds. Prints the gait and compares it with the greedy choice and the best fixed set
of fingers; writes ``gait.csv`` (one row per pose) and ``gait.png`` (which fingers touch along
alpha, the margin, the finger forces; optimal against greedy). docs/gait.md has the rules.
"""

from __future__ import annotations

import argparse
import csv
import time
from itertools import combinations
from pathlib import Path

import numpy as np

from grasp_env.mechanics import (
    SITE_FACES,
    SITE_OFFSETS,
    Gait,
    GaitScene,
    GaitSolution,
    Hand,
    Status,
    Trajectory,
    solve_gait,
)
from grasp_env.mechanics.gait import _MAX_FINGERS, site_sets

from ..progress import console, status
from . import gait_can
from .gait_models import (  # noqa: F401  (the --models part, under the names it had here)
    Episode,
    check_observes,
    check_rliable,
    compare_models,
    env_kwargs,
    load_models,
    model_labels,
    play,
)
from .gait_options import add_arguments, resolve

FINGERS = (3, _MAX_FINGERS)  # fingers a gait may have, the thumb included (the state tables)
#: The hand's fields, by the options that set them (their errors name the option).
HAND_OPTIONS = {"finger_azimuths_deg": "--finger-azimuths", "cone_deg": "--cone"}
HAND_OPTIONS["finger_elevation_deg"] = "--finger-elevation"


def problem(args: argparse.Namespace) -> tuple[GaitScene, Hand, Trajectory]:
    """The scene, hand and trajectory the options describe (ValueError if invalid)."""
    resolve(args)
    offsets = SITE_OFFSETS if args.offsets is None else np.reshape(args.offsets, (-1, 2))
    scene = GaitScene.on_faces(
        SITE_FACES, offsets, weight=args.weight, mu=args.mu, cg_offset=args.cg_offset
    )
    hand = make_hand(args)
    trajectory = Trajectory(args.axis, args.alpha_start, args.alpha_end, args.alpha_step)
    if args.k_max is not None:
        _check_k_max(args)
    return scene, hand, trajectory


def _check_k_max(args: argparse.Namespace) -> None:
    # the environments' k_max_ratio range: beyond it the certificate means little, and the
    # solver takes minutes
    from grasp_env.envs.validation import K_MAX_RATIO_RANGE

    low, high = K_MAX_RATIO_RANGE
    if not low <= args.k_max / args.weight <= high:  # NaN fails too
        raise ValueError(
            f"--k-max must be within [{low * args.weight:g}, {high * args.weight:g}] N"
            f" ({low:g} to {high:g} x the weight, {args.weight:g} N here), got {args.k_max:g}"
        )


def make_hand(args: argparse.Namespace) -> Hand:
    """The hand of ``--finger-azimuths``, ``--finger-elevation``, ``--no-thumb`` and
    ``--cone``; a ValueError names the option (3 to 6 fingers, the thumb included)."""
    low, high = FINGERS
    thumb = int(not args.no_thumb)
    azimuths = tuple(args.finger_azimuths)
    if not low <= len(azimuths) + thumb <= high:
        with_thumb = "besides the thumb" if thumb else "without the thumb (--no-thumb)"
        raise ValueError(
            f"--finger-azimuths must give {low - thumb} to {high - thumb} azimuths {with_thumb},"
            f" comma-separated in degrees (A1,...,An: a gait needs {low} to {high} fingers),"
            f" got {len(azimuths)}: {','.join(f'{a:g}' for a in azimuths)}"
        )
    try:
        return Hand(azimuths, args.finger_elevation, bool(thumb), args.cone)
    except ValueError as error:
        message = str(error)
        for field, option in HAND_OPTIONS.items():  # the option, and the hand's field it sets
            message = message.replace(field, f"{option} ({field})")
        raise ValueError(message) from None


# ------------------------------------------------------------------------------ report


def _deg(x: float) -> str:
    return "drops" if x == -np.inf else f"{np.rad2deg(x):.3f} deg"


def _contacts(solution: GaitSolution, gait: Gait, t: int) -> str:
    names = solution.hand.names
    return " ".join(
        f"{names[f]}:{SITE_FACES[s]}" + ("" if gait.loaded[t, f] else "(0)")
        for f, s in enumerate(gait.contacts[t])
        if s >= 0
    )


def segments(gait: Gait) -> list[tuple[int, int]]:
    """Runs of poses [start, end] with the same contacts and loads (until a drop)."""
    held = np.flatnonzero(gait.sets >= 0)
    if not len(held):
        return []
    out, start = [], 0
    for t in range(1, held[-1] + 1):
        same = np.array_equal(gait.contacts[t], gait.contacts[t - 1]) and np.array_equal(
            gait.loaded[t], gait.loaded[t - 1]
        )
        if not same:
            out.append((start, t - 1))
            start = t
    out.append((start, int(held[-1])))
    return out


def print_gait(solution: GaitSolution, gait: Gait, title: str) -> None:
    from rich.table import Table

    alphas = solution.trajectory.alphas_deg
    table = Table(title=title)
    for name in ("alpha (deg)", "fingers on sites ((0): touching, no force)", "worst margin"):
        table.add_column(name, justify="left" if "fingers" in name else "right")
    for start, end in segments(gait):
        span = f"{alphas[start]:g}" if start == end else f"{alphas[start]:g} .. {alphas[end]:g}"
        worst = gait.margins[start : end + 1].min()
        table.add_row(span, _contacts(solution, gait, start), _deg(worst))
    console().print(table)


def summary(solution: GaitSolution, seconds: float) -> list[str]:
    alphas = solution.trajectory.alphas_deg
    opt, greedy, fixed = solution.optimal, solution.greedy, solution.fixed
    lines = [
        f"optimal gait: worst margin {_deg(opt.margin)} (certified: no gait exceeds"
        f" {_deg(solution.bound)}, gap {np.rad2deg(solution.gap):.1e} deg),"
        f" {opt.changes} phase changes",
    ]
    drop = np.flatnonzero(greedy.sets < 0)
    where = f", drops at alpha = {alphas[drop[0]]:g} deg" if len(drop) else ""
    lines.append(
        f"greedy gait: worst margin {_deg(greedy.margin)}, {greedy.changes} phase changes{where}"
    )
    if fixed.margin > -np.inf:
        lines.append(f"best fixed set ({_contacts(solution, fixed, 0)}): {_deg(fixed.margin)}")
    else:
        lines.append("best fixed set: none stays within reach along the whole trajectory")
    sets = site_sets(solution.scene.n_sites)
    free = solution.values.margin.min(axis=0)
    best = int(np.argmax(free))
    names = ",".join(SITE_FACES[s] for s in sets[best]) if len(sets[best]) else ""
    lines.append(
        f"ignoring reach, the best fixed set of sites ({names}) would keep {_deg(free[best])}"
    )
    lines.append(
        f"solved in {seconds:.2f} s ({len(alphas)} poses x {np.isfinite(free).sum()} site sets"
        f" of certified minimax, and the dynamic programme)"
    )
    return lines


def no_gait(args: argparse.Namespace) -> str:
    """Why there is no gait to report, and the options that change it (reach: the hand and
    the faces' normals along the trajectory)."""
    thumb = ", drop --no-thumb" if args.no_thumb else ""
    return (
        "no gait keeps three fingers on sites within reach along this trajectory (alpha"
        f" {args.alpha_start:g} to {args.alpha_end:g} deg, --cone {args.cone:g} deg); widen"
        f" --cone, move the fingers (--finger-azimuths, --finger-elevation{thumb}) or shorten"
        " or turn the trajectory (--alpha-start, --alpha-end, --axis)"
    )


def write_csv(solution: GaitSolution, path: Path) -> None:
    gait = solution.optimal
    names = solution.hand.names
    F = len(names)
    k, angles = solution.grips(gait)
    status = solution.statuses(gait)
    limit = solution.scene.friction_limit
    events = {t: f"{names[f]} {kind} {SITE_FACES[s]}" for t, kind, f, s in gait.events()}
    pairs = [f"k_{names[f]}_{names[g]}" for f, g in combinations(range(F), 2)]
    header = ["alpha_deg", *(f"site_{n}" for n in names), "event", *pairs]
    header += [f"theta_{n}_deg" for n in names]
    header += ["theta_max_deg", "margin_deg", "status"]
    with path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        for t, alpha in enumerate(solution.trajectory.alphas_deg):
            loaded = gait.loaded[t]
            both = [loaded[f] and loaded[g] for f, g in combinations(range(F), 2)]
            writer.writerow(
                [
                    f"{alpha:g}",
                    *(SITE_FACES[s] if s >= 0 else "" for s in gait.contacts[t]),
                    events.get(t, ""),
                    *(f"{v:.10g}" if b else "" for v, b in zip(k[t], both, strict=True)),
                    *(
                        f"{np.rad2deg(a):.10g}" if loaded[f] else ""
                        for f, a in enumerate(angles[t])
                    ),
                    f"{np.rad2deg(limit - gait.margins[t]):.10g}",
                    f"{np.rad2deg(gait.margins[t]):.10g}",
                    Status(int(status[t])).name.lower() if status[t] >= 0 else "dropped",
                ]
            )


def plot(solution: GaitSolution, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    alphas = solution.trajectory.alphas_deg
    step = solution.trajectory.alpha_step_deg
    names = solution.hand.names
    F = len(names)
    colours = plt.get_cmap("tab10").colors
    fig, axes = plt.subplots(
        4, 1, figsize=(10, 11), sharex=True, gridspec_kw={"height_ratios": [1, 1, 1.3, 1.3]}
    )
    for ax, gait, label in (
        (axes[0], solution.optimal, "optimal"),
        (axes[1], solution.greedy, "greedy"),
    ):
        for f in range(F):
            for t in range(len(alphas)):
                s = gait.contacts[t, f]
                if s < 0:
                    continue
                loaded = gait.loaded[t, f]
                ax.broken_barh(
                    [(alphas[t] - step / 2, step)], (f - 0.35, 0.7),
                    color=colours[s], alpha=1.0 if loaded else 0.3, linewidth=0,
                )  # fmt: skip
        drop = np.flatnonzero(gait.sets < 0)
        if len(drop):
            ax.axvline(alphas[drop[0]], color="r", lw=2)
            ax.text(alphas[drop[0]], F - 0.5, " drops", color="r", va="top")
        ax.set_yticks(range(F), names)
        ax.set_ylim(-0.6, F - 0.4)
        ax.invert_yaxis()
        ax.set_title(
            f"{label} gait: sites touched (light: no force, being placed or lifted);"
            f" worst margin {_deg(gait.margin)}, {gait.changes} phase changes",
            fontsize=10,
        )
    patches = [Patch(color=colours[s], label=f"site on {f}") for s, f in enumerate(SITE_FACES)]
    axes[0].legend(handles=patches, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    ax = axes[2]
    ax.plot(alphas, np.rad2deg(solution.optimal.margins), "-", color="k", label="optimal gait")
    ax.plot(alphas, np.rad2deg(solution.greedy.margins), "--", color="tab:red", label="greedy gait")
    fixed = solution.fixed
    if fixed.margin > -np.inf:
        ax.plot(alphas, np.rad2deg(fixed.margins), ":", color="tab:blue", label="best fixed set")
    free = solution.values.margin
    best = int(np.argmax(free.min(axis=0)))
    ax.plot(alphas, np.rad2deg(free[:, best]), ":", color="grey",
            label="best fixed set of sites, reach ignored")  # fmt: skip
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_ylabel("margin atan(mu) - max theta_i (deg)")
    ax.legend(fontsize=8, loc="lower left")
    ax = axes[3]
    for gait, style, width in ((solution.optimal, "-", 1.6), (solution.greedy, "--", 0.9)):
        magnitude = np.linalg.norm(solution.forces(gait), axis=-1)
        for f in range(F):
            label = names[f] if gait is solution.optimal else None
            colour = plt.get_cmap("Dark2").colors[f % 8]  # fingers, not sites: other colours
            ax.plot(alphas, magnitude[:, f], style, lw=width, color=colour, label=label)
    ax.set_ylabel("finger force |P_f| (N); dashed: greedy")
    ax.set_xlabel("alpha (deg)")
    ax.legend(fontsize=8, ncol=F, loc="upper left")
    axis = np.round(solution.trajectory.axis, 3).tolist()
    fig.suptitle(f"Finger gait along {len(alphas)} poses about {axis}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    resolve(args)
    if args.object == "can":
        add_arguments(parser := argparse.ArgumentParser())
        gait_can.check_options(args, parser.parse_args([]))
        if args.k_max is not None:
            _check_k_max(args)
        return gait_can.run(args)
    gait_can.check_cube_options(args)
    scene, hand, trajectory = problem(args)
    check_rliable(args)
    loaded = []
    if args.models:  # before solving: refuse options the environment cannot take, and models
        with status(f"loading and checking {len(args.models)} model(s)"):
            loaded = load_models(args)  # missing, unreadable or not observing the gait env
    start = time.perf_counter()
    with status(
        f"the certified minimax of every site set at {len(trajectory):,} poses, then the gait"
    ):
        solution = solve_gait(scene, hand, trajectory, args.k_max)
    seconds = time.perf_counter() - start
    if not solution.holds:
        raise ValueError(no_gait(args))
    print_gait(solution, solution.optimal, "Optimal gait (certified)")
    for line in summary(solution, seconds):
        print(line)
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(solution, args.out / "gait.csv")
    written = ["gait.csv"]
    if not args.no_plots:
        plot(solution, args.out / "gait.png")
        written.append("gait.png")
    print(f"wrote {', '.join(str(args.out / name) for name in written)}")
    if args.models:
        compare_models(args, loaded)
    return 0
