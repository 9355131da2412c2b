"""``grasp-env reproduce``: the paper's experiment (§II and §IV), on its cube or any object.

The cube turns quasi-statically about an axis; at every pose the minimax problem is solved
anew. Writes the table (``sweep.csv``), the paper's trend plot (``trend.png``: the minimised
maximum friction angle and the k_ij against alpha) and its Fig. 2 (``theta1_grid.png``:
theta_1 over a 100 x 100 grid of (k12, k13) at alpha = 0, the optimum marked).

With ``--object`` and ``--contacts`` (or ``--fingers``) the same trajectory and the same
table and trend plot are made for any object held by 3 to 8 contacts
(:mod:`.reproduce_object`); the printed tables then give the optimum per pose with its status
and certificate gap, and each contact's friction angle, force and margin.
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from grasp_env.mechanics import (
    MinimaxResult,
    Scene,
    Status,
    Trajectory,
    contact_pairs,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)
from grasp_env.mechanics.forces import Grasp

from ..cli import folder_argument, integer_argument, shown_text
from ..progress import console, status
from ..studies.plotting import plot_series
from .reproduce_object import (
    CONTACTS_HELP,
    finger_contacts,
    object_argument,
    object_scene,
    shape_name,
)
from .scene_args import add_scene_arguments, floats, scene_from_arguments


def newtons_argument(text: str) -> float:
    """An argparse type for a force limit: a finite number of newtons > 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 < value < math.inf:  # (NaN is not)
        raise argparse.ArgumentTypeError(
            f"must be a finite number of newtons > 0, got {shown_text(text)}"
        )
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", type=folder_argument, default=Path("results/reproduce"), help="output dir"
    )
    add_scene_arguments(parser)
    parser.add_argument(
        "--axis", type=floats(3), default=(1.0, -1.0, 0.0), metavar="X,Y,Z",
        help="world-frame rotation axis of the trajectory (paper: 1,-1,0)",
    )  # fmt: skip
    parser.add_argument("--alpha-start", type=float, default=-15.0, help="first alpha, deg")
    parser.add_argument("--alpha-end", type=float, default=15.0, help="last alpha, deg")
    parser.add_argument("--alpha-step", type=float, default=1.0, help="alpha step, deg")
    parser.add_argument(
        "--k-max", type=float, default=None, help="bound on |k_ij|, N (default 2 x weight)"
    )
    parser.add_argument(
        "--f-max", type=newtons_argument, default=None,
        help="limit on each finger's force |P_i|, N (default none)",
    )  # fmt: skip
    parser.add_argument("--no-plots", action="store_true", help="write the CSV only")
    parser.add_argument(
        "--object", type=object_argument, default=None, metavar="SPEC",
        help="the grasped object instead of the paper's cube: cube, can, box:x=X,y=Y,z=Z,"
        " cylinder:r=R,h=H, sphere:r=R or mesh:FILE (metres); needs --contacts or --fingers",
    )  # fmt: skip
    place = parser.add_mutually_exclusive_group()
    place.add_argument(
        "--contacts", default=None, metavar="SPEC",
        help="the object's 3 to 8 contacts, ';'-separated, in its surface coordinates (below)",
    )  # fmt: skip
    place.add_argument(
        "--fingers", type=integer_argument(3, 8), default=None, metavar="N",
        help="N (3 to 8) contacts placed evenly around the object (below)",
    )  # fmt: skip
    cg = parser._option_string_actions["--cg-offset"]  # (scene_args says the cube's)
    cg.help = "centre of gravity relative to the object's centre, m (default 0)"
    offsets = parser._option_string_actions["--offsets"]
    offsets.help = f"{offsets.help}; the paper's cube only (--object: see --contacts)"
    parser.epilog = CONTACTS_HELP
    parser.formatter_class = argparse.RawDescriptionHelpFormatter


@dataclass(frozen=True)
class Sweep:
    """The experiment's result: one row per pose."""

    scene: Scene
    trajectory: Trajectory
    k_max: float
    grasp: Grasp  # batched over the poses
    optimum: MinimaxResult
    f_max: float | None = None


def run_sweep(
    scene: Scene, trajectory: Trajectory, k_max: float | None = None, f_max: float | None = None
) -> Sweep:
    """Solve the minimax problem at every pose of ``trajectory`` (one batched call): the box
    |k_ij| <= ``k_max`` (default 2 x weight, the environments' k_max_ratio) and, if given,
    |P_i| <= ``f_max``."""
    k_max = 2.0 * scene.weight if k_max is None else float(k_max)
    grasp = scene_grasp(scene, trajectory.rotations())
    optimum = solve_minimax(grasp, k_max, f_max)
    return Sweep(scene, trajectory, k_max, grasp, optimum, f_max)


def newtons(value: float) -> str:
    """A force or k_ij (N) for tables and figures: 5 significant digits, so that it reads the
    same at any weight (1.3608, 1.3608e+06, 1.3608e-06) where fixed decimals lose it."""
    return f"{value:#.5g}"


def pair_names(n_contacts: int) -> list[str]:
    return [f"k{i + 1}{j + 1}" for i, j in contact_pairs(n_contacts)]


def write_csv(sweep: Sweep, path: Path) -> None:
    n = sweep.scene.n_contacts
    header = ["alpha_deg", *pair_names(n)]
    header += [f"theta{i + 1}_deg" for i in range(n)]
    header += ["theta_max_deg", "lower_bound_deg", "status"]
    header += [f"F{i + 1}{c}" for i in range(n) for c in "xyz"]
    opt = sweep.optimum
    with path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        for t, alpha in enumerate(sweep.trajectory.alphas_deg):
            writer.writerow(
                [
                    f"{alpha:g}",
                    *(f"{k:.10g}" for k in opt.k[t]),
                    *(f"{a:.10g}" for a in np.rad2deg(opt.angles[t])),
                    f"{np.rad2deg(opt.max_angle[t]):.10g}",
                    f"{np.rad2deg(opt.lower_bound[t]):.10g}",
                    Status(int(opt.status[t])).name.lower(),
                    *(f"{f:.10g}" for f in sweep.grasp.equilibrating[t].ravel()),
                ]
            )


def print_table(sweep: Sweep) -> None:
    from rich.table import Table

    n = sweep.scene.n_contacts
    limit = np.rad2deg(sweep.scene.friction_limit)
    table = Table(
        title=f"Minimax grip along the trajectory (w = {sweep.scene.weight:g} N, "
        f"mu = {sweep.scene.mu:g}, theta_lim = {limit:.2f} deg)"
    )
    for name in ["alpha", *pair_names(n), *(f"theta{i + 1}" for i in range(n)), "max", "holds"]:
        table.add_column(name, justify="right")
    opt = sweep.optimum
    for t, alpha in enumerate(sweep.trajectory.alphas_deg):
        angles = np.rad2deg(opt.angles[t])
        table.add_row(
            f"{alpha:g}",
            *(newtons(k) for k in opt.k[t]),
            *(f"{a:.4f}" for a in angles),
            f"{angles.max():.4f}",
            "yes" if angles.max() <= limit else "NO",
        )
    console().print(table)


def print_object_tables(sweep: Sweep, items: Sequence[str]) -> None:
    """The optimum at every pose (max theta_i, the contact attaining it, status, certificate
    gap, all angles in degrees; 8 decimals, the certificate's 1e-9 rad being 5.7e-8 deg), then
    each contact at the worst pose (its friction angle theta_i, force |P_i| and margin
    theta_lim - theta_i) and its least margin along the trajectory."""
    from rich.table import Table

    scene, optimum, alphas_deg = sweep.scene, sweep.optimum, sweep.trajectory.alphas_deg
    limit = np.rad2deg(scene.friction_limit)
    angles = np.rad2deg(optimum.angles)
    gaps = np.rad2deg(optimum.gap)
    title = (
        f"Minimax grip of the {shape_name(scene.shape)} along the trajectory ({scene.n_contacts}"
        f" contacts, w = {scene.weight:g} N, mu = {scene.mu:g}, theta_lim = {limit:.2f} deg)"
    )
    table = Table(title=title)
    for name in ("alpha", "max theta (deg)", "at contact", "status", "gap (deg)", "holds"):
        table.add_column(name, justify="right")
    for t, alpha in enumerate(alphas_deg):
        table.add_row(
            f"{alpha:g}",
            f"{angles[t].max():.8f}",
            str(int(np.argmax(angles[t])) + 1),
            Status(int(optimum.status[t])).name.lower(),
            f"{gaps[t]:.1e}",
            "yes" if angles[t].max() <= limit else "NO",
        )
    console().print(table)
    worst = int(np.argmax(angles.max(axis=1)))
    table = Table(title=f"The contacts at the worst pose, alpha = {alphas_deg[worst]:g} deg")
    columns = ("contact", "spec", "point (m)", "theta (deg)", "|P| (N)", "margin (deg)")
    for name in (*columns, "least margin along the trajectory (deg)"):
        table.add_column(name, justify="left" if name == "spec" else "right")
    norms = np.linalg.norm(sweep.grasp.forces(optimum.k)[worst], axis=-1)
    tiny = np.abs(scene.contacts) <= 1e-12 * scene.shape.extent  # a mesh's rounding: 0
    point = np.where(tiny, 0.0, scene.contacts)
    for i, item in enumerate(items):
        table.add_row(
            str(i + 1),
            item,
            ", ".join(f"{c:.4g}" for c in point[i]),
            f"{angles[worst, i]:.8f}",
            newtons(norms[i]),
            f"{limit - angles[worst, i]:.8f}",
            f"{limit - angles[:, i].max():.8f}",
        )
    console().print(table)


def plot_trend(sweep: Sweep, path: Path) -> None:
    """Save :func:`trend_figure`."""
    import matplotlib.pyplot as plt

    fig = trend_figure(sweep)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def trend_figure(sweep: Sweep) -> Any:
    """The optimal friction angles and k_ij against alpha."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alphas = sweep.trajectory.alphas_deg
    fig, (ax_theta, ax_k) = plt.subplots(2, 1, figsize=(7, 7.5), sharex=True)
    n = sweep.scene.n_contacts
    angles = np.rad2deg(sweep.optimum.angles).T
    ax_theta.axhline(np.rad2deg(sweep.scene.friction_limit), color="k", ls="--", label="atan(mu)")
    plot_series(ax_theta, alphas, angles, [f"theta{i + 1}" for i in range(n)], "deg")
    ax_theta.set_ylabel("friction angle at the optimum (deg)")
    ax_theta.legend(loc="center right")
    ax_theta.set_title("Minimised maximum friction angle along the trajectory")
    # k scales with the weight: curves coincide or are 0 relative to it, not to 1 N
    plot_series(ax_k, alphas, sweep.optimum.k.T, pair_names(n), "N", scale=sweep.scene.weight)
    ax_k.set_xlabel("alpha (deg)")
    ax_k.set_ylabel("optimal interaction scalar k_ij (N)")
    ax_k.legend(loc="best")
    fig.tight_layout()
    return fig


def theta1_grid(sweep: Sweep, points: int = 100) -> tuple[np.ndarray, ...]:
    """theta_1 (deg) over a points x points grid of (k12, k13) at alpha = 0 (the paper's Fig. 2).

    theta_1 depends on k12 and k13 only; k23 is held at its optimum. The grid spans 0 to
    2.5 times the larger optimal value, so the optimum sits inside it. Returns the k12 and k13
    grids, theta_1 on them and the optimal k at alpha = 0.
    """
    scene, trajectory = sweep.scene, sweep.trajectory
    grasp = scene_grasp(scene, pose_rotation(trajectory.axis, 0.0))
    k_opt = solve_minimax(grasp, sweep.k_max, sweep.f_max).k
    top = 2.5 * max(abs(k_opt[0]), abs(k_opt[1]), 0.1 * scene.weight)
    k12, k13 = np.meshgrid(np.linspace(0, top, points), np.linspace(0, top, points))
    k = np.broadcast_to(k_opt, (points, points, len(k_opt))).copy()
    k[..., 0], k[..., 1] = k12, k13
    theta1 = np.rad2deg(grasp.angles(k)[..., 0])  # the grasp broadcasts over the grid
    return k12, k13, theta1, k_opt


def plot_theta1_grid(sweep: Sweep, path: Path) -> None:
    """Save :func:`theta1_figure`."""
    import matplotlib.pyplot as plt

    figure = theta1_figure(sweep)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def theta1_figure(sweep: Sweep) -> Any:
    """The paper's Fig. 2: theta_1 over (k12, k13) at alpha = 0, as a surface and contours,
    the optimum marked, the other k_ij's values said."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k12, k13, theta1, k_opt = theta1_grid(sweep)
    fig = plt.figure(figsize=(11, 4.8))
    ax3d = fig.add_subplot(1, 2, 1, projection="3d")
    ax3d.plot_surface(k12, k13, theta1, cmap="viridis", linewidth=0)
    ax3d.set_xlabel("k12 (N)")
    ax3d.set_ylabel("k13 (N)")
    ax3d.set_zlabel("theta1 (deg)")
    names = pair_names(sweep.scene.n_contacts)
    others = ", ".join(
        f"{name} = {newtons(k)} N" for name, k in zip(names[2:], k_opt[2:], strict=True)
    )
    fig.suptitle(
        "theta1 over (k12, k13) at alpha = 0 (the paper's Fig. 2); "
        f"{others} (held at the optimum; it does not act on finger 1)"
    )
    ax = fig.add_subplot(1, 2, 2)
    contour = ax.contourf(k12, k13, theta1, levels=30, cmap="viridis")
    fig.colorbar(contour, ax=ax, label="theta1 (deg)")
    ax.plot(
        k_opt[0], k_opt[1], "r*", ms=14, label=f"optimum ({newtons(k_opt[0])}, {newtons(k_opt[1])})"
    )
    ax.set_xlabel("k12 (N)")
    ax.set_ylabel("k13 (N)")
    ax.legend(loc="upper right")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return fig


def run(args: argparse.Namespace) -> int:
    trajectory = Trajectory(args.axis, args.alpha_start, args.alpha_end, args.alpha_step)
    if args.k_max is not None and not (np.isfinite(args.k_max) and args.k_max > 0):
        raise ValueError(f"--k-max must be a finite number > 0, got {args.k_max}")
    items: tuple[str, ...] = ()
    if args.object is None:
        if args.contacts is not None or args.fingers is not None:
            option = "--contacts" if args.contacts is not None else "--fingers"
            raise ValueError(
                f"{option} places contacts on --object's surface: give --object too"
                " (e.g. --object cube; without both, the paper's cube and contacts)"
            )
        scene = scene_from_arguments(args)
    else:
        scene, items = scene_of_object(args)
    with status(f"solving the minimax problem at {len(trajectory)} poses"):
        sweep = run_sweep(scene, trajectory, args.k_max, args.f_max)
    args.out.mkdir(parents=True, exist_ok=True)
    if items:
        print_object_tables(sweep, items)
    else:
        print_table(sweep)
    write_csv(sweep, args.out / "sweep.csv")
    written = ["sweep.csv"]
    if not args.no_plots:
        # the paper's Fig. 2 (theta1_grid.png) is its cube's three-finger grip
        plots = ["trend.png"] if items else ["trend.png", "theta1_grid.png"]
        with status(f"drawing {' and '.join(plots)}"):
            plot_trend(sweep, args.out / "trend.png")
            if not items:
                plot_theta1_grid(sweep, args.out / "theta1_grid.png")
        written += plots
    opt = sweep.optimum
    worst = np.rad2deg(opt.max_angle.max())
    print(
        f"worst optimal max friction angle {worst:.4f} deg "
        f"(limit {np.rad2deg(scene.friction_limit):.2f} deg); "
        f"largest certificate gap {np.rad2deg(opt.gap.max()):.2e} deg"
    )
    if items:
        counts = np.bincount(opt.status.ravel(), minlength=len(Status))
        print(
            "statuses: "
            + ", ".join(f"{s.name.lower()} {counts[s]}" for s in Status if counts[s])
            + (
                "; uncertified: the certificate's gap exceeds 1e-9 rad (the gap column says by"
                " how much; its lower bound holds)"
                if counts[Status.UNCERTIFIED]
                else ""
            )
        )
    print(f"wrote {', '.join(str(args.out / name) for name in written)}")
    return 0


def scene_of_object(args: argparse.Namespace) -> tuple[Scene, tuple[str, ...]]:
    """The scene of ``--object`` held at ``--contacts`` (or ``--fingers``), and the contacts'
    specs; ValueErrors name the option at fault."""
    if args.offsets is not None:
        raise ValueError(
            "--offsets moves the paper cube's face-centre contacts: with --object, give the"
            " contacts' places in --contacts (e.g. --contacts='-x:0.3,0.1;-y;-z' on a box)"
        )
    if args.contacts is None and args.fingers is None:
        raise ValueError("--object needs its contacts: give --contacts or --fingers")
    if args.contacts is not None:
        text, option = args.contacts, "--contacts"
    else:
        text, option = finger_contacts(args.object, args.fingers), "--fingers"
    scene, items = object_scene(
        args.object, text, weight=args.weight, mu=args.mu, cg_offset=args.cg_offset, option=option
    )
    if args.contacts is None:
        print(f"--fingers {args.fingers}: --contacts={text!r}")
    return scene, items
