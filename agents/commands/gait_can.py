"""``grasp-env gait --object can``: the certified gait that turns a coke can about its axis.

The paper's stretch ("turning a coke can about its axis requires phasing in and out of the
fingers"): the can stands upright and turns a full turn about its vertical axis; five
fingertips round its side each reach a patch of it (``grasp_env.mechanics.gait.can``), so
every contact turns out of reach after a while and its finger must lift and be placed again.
Prints the optimal gait beside the greedy one and the best fixed set, and writes ``gait.csv``
(per pose: each finger's point on the can, its phase event, friction angles, the margin and
the minimax status) and ``gait.png``. docs/gait.md, "The can", has the model. ``--mujoco``
carries the optimal gait's whole turn through one continuous MuJoCo rollout (one fingertip per
finger, placed on its finger's new point at each placement) and ``--video`` writes it.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from grasp_env.mechanics import Status
from grasp_env.mechanics.gait.can import (
    CAN_DEFAULT_LOADED,
    CAN_MAX_LOADED,
    CAN_MIN_LOADED,
    CAN_WEIGHT,
    CanHand,
    CanTurn,
)
from grasp_env.mechanics.gait.can_programme import CanGait, CanGaitSolution, solve_can_gait
from grasp_env.physics.can_gait import can_gait_schedule, check_can_gait
from grasp_env.physics.gait import GaitRollout

from ..progress import status

#: The can's defaults for the options the cube's gait shares (``--weight``, ``--alpha-*``).
CAN_DEFAULTS = {"weight": CAN_WEIGHT, "alpha_start": 0.0, "alpha_end": 360.0, "alpha_step": 10.0}
#: The cube's options that mean nothing for the can (its hand is a CanHand).
CUBE_ONLY = ("offsets", "cg_offset", "axis", "cone", "finger_azimuths", "finger_elevation")
#: The can's options (:func:`add_arguments`), refused for the cube.
CAN_ONLY = ("reach", "max_loaded", "mujoco", "mujoco_window", "video")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The can's own options (the shared ones are the cube gait's)."""
    hand = CanHand()
    parser.add_argument(
        "--reach", type=float, default=hand.reach_deg,
        help="--object can: half-width of each finger's patch of the side, deg in (0, 90]"
        f" (default {hand.reach_deg:g})",
    )  # fmt: skip
    parser.add_argument(
        "--max-loaded", type=int, default=CAN_DEFAULT_LOADED,
        choices=range(CAN_MIN_LOADED, CAN_MAX_LOADED + 1),
        help="--object can: most fingers carrying load at a pose (five may always touch;"
        f" 5 loaded solves every five-finger configuration, slow; default {CAN_DEFAULT_LOADED})",
    )  # fmt: skip
    parser.add_argument(
        "--mujoco", action="store_true",
        help="--object can: carry the optimal gait's whole turn through one continuous MuJoCo"
        " rollout (one fingertip per finger, placed again on new points) and print both"
        " verdicts",
    )  # fmt: skip
    parser.add_argument(
        "--mujoco-window", type=str, default=None, metavar="START,STOP",
        help="--object can: the poses [START, STOP) the rollout carries (default: every pose,"
        " the whole turn; implies --mujoco)",
    )  # fmt: skip
    parser.add_argument(
        "--video", type=Path, default=None, metavar="FILE.mp4",
        help="--object can: write the rollout as a video (implies --mujoco)",
    )  # fmt: skip


def check_options(args: argparse.Namespace, defaults: argparse.Namespace) -> None:
    """ValueError naming the cube's options that were given with ``--object can``."""
    given = [n for n in CUBE_ONLY if getattr(args, n) != getattr(defaults, n)]
    if args.no_thumb:
        given.append("no_thumb")
    if args.models:
        given.append("models")
    if given:
        options = ", ".join("--" + n.replace("_", "-") for n in given)
        raise ValueError(f"--object can takes the can's hand, not the cube's: drop {options}")
    if args.video is not None:
        check_video(args.video)
        args.mujoco = True
    if args.mujoco_window is not None:
        args.mujoco = True


def check_cube_options(args: argparse.Namespace) -> None:
    """ValueError naming the can's options that were given without ``--object can``."""
    add_arguments(parser := argparse.ArgumentParser())
    defaults = parser.parse_args([])
    given = [n for n in CAN_ONLY if getattr(args, n) != getattr(defaults, n)]
    if given:
        options = ", ".join("--" + n.replace("_", "-") for n in given)
        raise ValueError(f"{options}: the can's options, given with --object can only")


def check_video(path: Path) -> None:
    """ValueError unless ``path`` is a writable FILE.mp4 (verify's ``--video`` rules)."""
    if path.suffix.lower() != ".mp4":
        raise ValueError(f"--video {path}: the video is an MP4, name it FILE.mp4")
    existed = path.exists()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.open("ab").close()
    except OSError as error:
        raise ValueError(f"--video {path}: cannot write it ({error.strerror})") from None
    if not existed:
        path.unlink()


def mujoco_window(solution: CanGaitSolution, text: str | None) -> tuple[int, int]:
    """The poses [start, stop) of ``--mujoco-window`` (default: every pose, the whole turn)."""
    n_poses = len(solution.turn)
    if text is None:
        return 0, n_poses
    try:
        start, stop = (int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(
            f"--mujoco-window {text!r}: give two pose indices START,STOP with"
            f" 0 <= START < STOP <= {n_poses}"
        ) from None
    return start, stop


def run_mujoco(solution: CanGaitSolution, args: argparse.Namespace) -> None:
    """Carry the optimal gait's window through MuJoCo, print the verdict, write the video."""
    start, stop = mujoco_window(solution, args.mujoco_window)
    cpu = time.process_time()
    with status(f"the optimal gait in one MuJoCo rollout, poses [{start}, {stop})"):
        rollout = check_can_gait(solution, start=start, stop=stop)
    cpu = time.process_time() - cpu
    report, alphas = rollout.report, solution.turn.alphas_deg[start:stop]
    events = [e for e in solution.optimal.events() if start <= e[0] < stop]
    placements = len(can_gait_schedule(solution, start=start, stop=stop).sites)

    def where(x: float | None) -> str:
        """A pose coordinate of the window (t + s between poses t and t + 1) as alpha."""
        if x is None:
            return "holds"
        return f"first failure at alpha = {alphas[0] + x * solution.turn.step_deg:.1f} deg"

    print(
        f"MuJoCo, alpha {alphas[0]:g} to {alphas[-1]:g} deg ({stop - start} poses,"
        f" {len(events)} phase changes, {placements} placements on"
        f" {rollout.scene.n_contacts} fingertips,"
        f" {report.time:.1f} s simulated, {cpu:.1f} s CPU): {where(report.first_failure)};"
        f" analytic: {where(report.predicted_first_failure)}; margin"
        f" {report.margin_deg:.3f} deg, largest slip {np.nanmax(report.slip):.2e} m, drift"
        f" {report.drift.max():.2e} m, rotation {report.rotation_deg.max():.2e} deg"
    )
    if args.video is not None:
        frames = write_video(args.video, rollout, alphas, solution.hand.names)
        print(f"wrote {args.video} ({frames} frames)")


#: The video's fingertips are drawn as spheres this many times the model's tip radius (a
#: pad of 8 mm on the can), touching the side where the model's tip does; a lifted one is
#: drawn pulled back a further :data:`DRAWN_LIFT` of its radii (the model parks its tip two
#: tip radii, 2.6 mm, off the side: too little to see), grey and without an arrow.
DRAWN_TIP, DRAWN_LIFT = 3.0, 1.5


def write_video(
    path: Path, rollout: GaitRollout, alphas: np.ndarray, names: tuple[str, ...], size: int = 480
) -> int:
    """Write a finger gait's rollout (one tip per finger, its point changing at placements)
    as an MP4 of ``size`` x ``size`` pixels with the frames of ``physics_plots.write_video``
    (FRAMES_PER_POSE a pose, evenly spaced in simulated time after the settle, at FPS; the
    object turned by its pose; alpha, the largest friction angle and the margin written on
    it) and the fingers lifted named. Each frame draws the friction cones and the pushes at
    that frame's points, and the fingertips as spheres (:data:`DRAWN_TIP`,
    :data:`DRAWN_LIFT`). Returns the frame count."""
    from grasp_env.mechanics import Scene, matrix_quaternion, quaternion_matrix
    from grasp_env.physics import GraspView
    from grasp_env.physics.model import _z_to, length_unit

    from ..studies.physics_plots import _imageio, pose_alpha, video_steps, write_frames

    _imageio()  # before the view: say at once if the writer is missing
    scene, report = rollout.scene, rollout.report
    motion, qpos, n = report.motion, report.trace.qpos, scene.n_contacts
    steps, last_finite, angles, limit = video_steps(scene, report, len(alphas))
    length = length_unit(scene)

    def scene_at(k: int) -> Scene:
        """The scene whose contacts are the tips' points at step ``k``."""
        return Scene(
            shape=scene.shape, contacts=motion.points[k] * length, weight=scene.weight,
            mu=scene.mu, cg_offset=scene.cg_offset,
        )  # fmt: skip

    view = GraspView(scene_at(steps[0]), width=size, height=size)
    view.camera.elevation, view.camera.distance = -20.0, 2.4  # from above the can's side
    drawn = np.zeros(n)  # the drawn tips' radii beyond the model's, set once it is built

    def frame(k: int) -> np.ndarray:
        # MuJoCo turns the load about the object; the picture turns the object instead.
        rotation, state = motion.rotations[k], qpos[last_finite[k]].copy()
        state[:3] = rotation @ state[:3]
        state[3:7] = matrix_quaternion(rotation @ quaternion_matrix(state[3:7]))
        touching = motion.contact[k]
        normals = motion.normals[k] @ rotation.T  # inward, world frame
        back = drawn * np.where(touching, 1.0, 1.0 + DRAWN_LIFT * DRAWN_TIP / (DRAWN_TIP - 1))
        tips = state[7:].reshape(n, 3) @ rotation.T - back[:, None] * normals
        state[7:] = tips.ravel()
        lifted = ", ".join(names[f] for f in np.flatnonzero(~touching)) or "none"
        text = (
            f"alpha {pose_alpha(alphas, motion.pose[k]):+.2f} deg",
            f"largest friction angle {angles[k]:.2f} deg",
            f"margin {limit - angles[k]:+.2f} deg (atan mu {limit:.2f})",
            f"lifted: {lifted}",
        )
        view.scene = scene_at(k)  # the pushes and colours at this step's points
        if view.model is not None:  # and the cones
            for i in range(n):
                cone = view.model.geom(f"cone{i}").id
                view.model.geom_pos[cone] = motion.points[k, i]
                view.model.geom_quat[cone] = _z_to(-motion.normals[k, i])
        forces = motion.forces[k] @ rotation.T
        return view.render_state(state, rotation, forces, touching, text)

    try:
        frame(steps[0])  # builds the view's model: its tips are then drawn larger
        tips = [view.model.geom(f"tip{i}").id for i in range(n)]
        drawn[:] = (DRAWN_TIP - 1.0) * view.model.geom_size[tips, 0]
        view.model.geom_size[tips, 0] *= DRAWN_TIP
        write_frames(path, (frame(k) for k in steps))
    finally:
        view.close()
    return len(steps)


def _deg(x: float) -> str:
    return "drops" if x == -np.inf else f"{np.rad2deg(x):.3f} deg"


def _dropped(solution: CanGaitSolution, gait: CanGait) -> str:
    drop = np.flatnonzero(gait.configs < 0)
    return f", drops at alpha = {solution.turn.alphas_deg[drop[0]]:g} deg" if len(drop) else ""


def summary(solution: CanGaitSolution, seconds: float) -> list[str]:
    """The printed lines: the three gaits, the certificate, the solver's statuses, the cost."""
    opt, greedy, fixed = solution.optimal, solution.greedy, solution.fixed
    values = solution.values
    lines = [
        f"optimal gait: worst margin {_deg(opt.margin)} (certified: no gait exceeds"
        f" {_deg(solution.bound)}, gap {np.rad2deg(solution.gap):.1e} deg),"
        f" {opt.changes} phase changes{_dropped(solution, opt)}",
        f"greedy gait: worst margin {_deg(greedy.margin)}, {greedy.changes} phase changes"
        f"{_dropped(solution, greedy)}",
    ]
    if fixed.margin > -np.inf:
        lines.append(f"best fixed set: {_deg(fixed.margin)}")
    else:
        lines.append("best fixed set: none stays within reach along the whole turn")
    lines.append(
        f"ignoring the moves, the best configuration keeps {_deg(float(values.margin.max()))}"
    )
    lines.append(
        f"solved in {seconds:.2f} s ({len(values.configs):,} configurations of 3 to"
        f" {max(len(c) for c in values.configs)} loaded fingers, one certified minimax each"
        f" (the same at every pose: the can turns about its axis), {values.uncertified}"
        f" uncertified ({solution.uncertified_along(opt)} along the optimal gait);"
        f" {len(solution.turn)} poses)"
    )
    return lines


def write_csv(solution: CanGaitSolution, path: Path) -> None:
    gait = solution.optimal
    names = solution.hand.names
    angles, statuses = solution.grips(gait)
    points = solution.object_angles_deg(gait)
    limit = solution.friction_limit
    events = {t: f"{names[f]} {kind}" for t, kind, f in gait.events()}
    header = ["alpha_deg", *(f"point_{n}_deg" for n in names), "event"]
    header += [f"theta_{n}_deg" for n in names] + ["theta_max_deg", "margin_deg", "status"]
    with path.open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(header)
        for t, alpha in enumerate(solution.turn.alphas_deg):
            loaded = gait.loaded[t]
            writer.writerow(
                [
                    f"{alpha:g}",
                    *("" if np.isnan(p) else f"{p:g}" for p in points[t]),
                    events.get(t, ""),
                    *(
                        f"{np.rad2deg(a):.10g}" if loaded[f] else ""
                        for f, a in enumerate(angles[t])
                    ),
                    f"{np.rad2deg(limit - gait.margins[t]):.10g}",
                    f"{np.rad2deg(gait.margins[t]):.10g}",
                    Status(int(statuses[t])).name.lower() if statuses[t] >= 0 else "dropped",
                ]
            )


def plot(solution: CanGaitSolution, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alphas = solution.turn.alphas_deg
    step = solution.turn.step_deg
    names = solution.hand.names
    F = len(names)
    fig, axes = plt.subplots(
        3, 1, figsize=(10, 9), sharex=True, gridspec_kw={"height_ratios": [1, 1, 1.3]}
    )
    cmap = plt.get_cmap("viridis")
    for ax, gait, label in (
        (axes[0], solution.optimal, "optimal"),
        (axes[1], solution.greedy, "greedy"),
    ):
        points = solution.object_angles_deg(gait)
        for f in range(F):
            for t in range(len(alphas)):
                if gait.ages[t, f] < 0:
                    continue
                ax.broken_barh(
                    [(alphas[t] - step / 2, step)], (f - 0.35, 0.7),
                    color=cmap(points[t, f] / 360.0),
                    alpha=1.0 if gait.loaded[t, f] else 0.3, linewidth=0,
                )  # fmt: skip
        drop = np.flatnonzero(gait.configs < 0)
        if len(drop):
            ax.axvline(alphas[drop[0]], color="r", lw=2)
            ax.text(alphas[drop[0]], F - 0.5, " drops", color="r", va="top")
        ax.set_yticks(range(F), names)
        ax.set_ylim(-0.6, F - 0.4)
        ax.invert_yaxis()
        ax.set_title(
            f"{label} gait: fingers touching (light: no force, being placed or lifted);"
            f" worst margin {_deg(gait.margin)}, {gait.changes} phase changes",
            fontsize=9,
        )
    mappable = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, 360))
    label = "the point touched: its azimuth on the can (deg)"
    fig.colorbar(mappable, ax=list(axes), label=label, pad=0.01)
    ax = axes[2]
    ax.plot(alphas, np.rad2deg(solution.optimal.margins), "-", color="k", label="optimal gait")
    greedy = np.rad2deg(solution.greedy.margins)
    ax.plot(alphas, greedy, "--", color="tab:red", label="greedy gait")
    if solution.fixed.margin > -np.inf:
        ax.plot(alphas, np.rad2deg(solution.fixed.margins), ":", label="best fixed set")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_ylabel("margin atan(mu) - max theta_i (deg)")
    ax.set_xlabel("alpha, the can's turn about its axis (deg)")
    ax.legend(fontsize=8, loc="lower right")
    fig.suptitle(
        f"Turning a coke can ({solution.weight:g} N, mu {solution.mu:g}) by {len(alphas)} poses"
        f" with {F} fingers, each reaching {solution.hand.reach_deg:g} deg either way"
    )
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    """Solve, print, write gait.csv and gait.png; exit status 2 (a ValueError) if no gait holds."""
    hand = CanHand(reach_deg=args.reach)
    turn = CanTurn(args.alpha_start, args.alpha_end, args.alpha_step)
    start = time.perf_counter()
    with status(f"the certified minimax of every configuration, then the gait ({len(turn)} poses)"):
        solution = solve_can_gait(
            hand, turn, args.weight, args.mu, args.k_max, max_loaded=args.max_loaded
        )
    seconds = time.perf_counter() - start
    if not solution.holds:
        raise ValueError(
            "no gait keeps three fingers on the can within reach along this turn (--reach"
            f" {args.reach:g} deg, --alpha-step {args.alpha_step:g} deg): widen --reach or allow"
            " more loaded fingers (--max-loaded)"
        )
    for line in summary(solution, seconds):
        print(line)
    args.out.mkdir(parents=True, exist_ok=True)
    write_csv(solution, args.out / "gait.csv")
    written = ["gait.csv"]
    if not args.no_plots:
        plot(solution, args.out / "gait.png")
        written.append("gait.png")
    print(f"wrote {', '.join(str(args.out / name) for name in written)}")
    if args.mujoco:
        run_mujoco(solution, args)
    return 0
