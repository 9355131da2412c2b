"""``grasp-env verify``: check grip forces in MuJoCo physics.

A policy chooses the grip at every pose of the paper's trajectory: ``expert`` (the minimax
optimum over |k_ij| <= 2 w, the default), ``equal-k`` (the paper's symmetric grip
k_ij = w tan(phi) / (3 sqrt 3) for every pair, eq. 8) or a saved Stable-Baselines3 model (its
.zip, or a ``grasp-env train`` run directory; read by
``grasp_env_agents.learning.models.load_agent``,
which runs no code from the file), driven through a Gymnasium environment.

Each pose on its own (the default): every pose is a separate MuJoCo check (a 0.05 s settle at
mu = 10, then a 0.2 s hold at the scene's mu), and the table compares the analytic verdict (max
friction angle within atan(mu)) with MuJoCo's: the grasp holds when no loaded fingertip slides
or lifts off its face by more than 1e-5 L (L the box's largest edge: 10 um for the 1 m cube)
nor slides faster than 1e-5 L/s, and the object's centre of gravity moves at most 0.001 L and it
turns at most 0.1 deg. A finger pushing at most 0.001 w is released (lifted off, not judged).
Writes ``verify.png``.

With ``--trajectory``: the grip is carried through the whole trajectory in one continuous
MuJoCo rollout (``grasp_env.physics.check_trajectories``): the settle at the first pose, a
0.1 s dwell at each pose, the load turning at 0.05 s per degree between poses while the forces
follow the grip, and the 0.2 s hold at the last pose; slip, drift and rotation accumulate over
the whole run. The table gives each pose's verdicts (analytic and MuJoCo, over the steps nearer
to that pose than to its neighbours), the slip and drift so far; the last lines the verdict on
the trajectory, its margin and where each verdict first failed. Writes ``rollout.png`` and
``rollout.json``. With ``--video FILE.mp4`` (which implies ``--trajectory``) the rollout is
also written as a video (:func:`write_video`): 10 frames per pose at 30 fps, each showing the
cube where MuJoCo has it, the fingertips, the force arrows and friction cones coloured by
nearness to slip, and alpha, the largest friction angle and the margin. ``--alphas`` sets the
trajectory (default the paper's -15 to +15 deg by 1 deg).

With ``--object SPEC`` and ``--contacts SPEC`` or ``--fingers N`` (the syntax of ``grasp-env
reproduce --object``: e.g. ``--object can --fingers 4``): the expert's grip on that object,
pose by pose or (``--trajectory``, ``--video``) in one rollout; MuJoCo's model is the object's
own box, cylinder, sphere or mesh geom, with torsional and rolling friction on curved objects
(docs/physics.md, "Any shape").

With ``--agreement``: the pose agreement study of ``grasp_env_agents.studies.agreement`` (force sets
from 0 to 40 deg max friction angle and within 0.01 to 1 deg of the cone's edge, mu = tan 10,
20 and 30 deg, several poses and contact layouts; writes ``agreement.png``); with
``--agreement --trajectory`` the trajectory study (``--scenes`` random scenes, each with the
expert's grip and grips perturbed to cross the limit mid-trajectory or stay inside it by 0.05
to 2 deg, plus the equal-k grip at eight mu, a grip that slips only between coarse steps and
windows of the certified finger-phasing gait, as planned and perturbed; ``--policy`` with a
saved model adds its grips on the study's scenes with the environment's number of fingers,
driven through ``--env``; writes ``trajectory_agreement.png``). Both print the confusion
matrix, the runtime and a last line with the overall agreement and the agreement at >= 0.05 deg
from the edge, and exit with 1 if any case at >= 0.05 deg from the edge disagrees.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from grasp_env.mechanics import (
    Scene,
    Trajectory,
    friction_angles,
)
from grasp_env.physics import (
    StabilityChecker,
    check_trajectories,
)
from grasp_env_agents.studies.agreement import (
    FAR_FROM_EDGE_DEG,
    Agreement,
    agreement_sets,
    check_sets,
    summarise,
)
from grasp_env_agents.studies.trajectory_agreement import (
    check_cases,
    gait_cases,
    summarise_trajectories,
    trajectory_cases,
)

from ..cli import folder_argument, integer_argument, path_argument
from ..progress import console, status
from ..studies.grips import (
    DEFAULT_MODEL_ENV,
    MODEL_ENV_IDS,
    SavedModel,
    equal_k_forces,
    expert_forces,
    learned_cases,
    model_fingers,
    model_forces,
    model_name,
    model_setup,
)
from ..studies.physics_plots import (
    FPS,
    FRAMES_PER_POSE,
    _imageio,
    _plot_agreement,
    _plot_poses,
    _plot_trajectory_agreement,
    plot_rollouts,
    pose_alpha,
    write_video,
)
from .reproduce import scene_of_object
from .reproduce_object import object_argument
from .scene_args import add_scene_arguments, floats, scene_from_arguments

#: Scenes of the trajectory study by default: about 70 trajectories and the 66 of the gaits
#: (200 give 638 with the gaits, 732 with docs/physics.md's learned policy).
DEFAULT_SCENES = 20
#: The most --scenes takes: about 300,000 trajectories, a day of rollouts on 2 cores.
MAX_SCENES = 100_000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--policy",
        default="expert",
        metavar="expert|equal-k|PATH",
        help="the grip: the minimax expert (default), the paper's equal-k grip, or a saved"
        " SB3 model (a .zip, or a `grasp-env train` run directory); with --agreement"
        " --trajectory, a saved model whose grips join the study",
    )
    parser.add_argument(
        "--algo",
        default=None,
        help="the algorithm that wrote a saved model, checked against the file (default: the"
        " one its policy class names)",
    )
    parser.add_argument(
        "--env",
        default=None,
        help=f"environment that drives a saved model, one of {', '.join(MODEL_ENV_IDS)}"
        f" (default: the run's, from its config.yaml; {DEFAULT_MODEL_ENV} for a model file)",
    )
    add_scene_arguments(parser)
    parser.add_argument(
        "--object", type=object_argument, default=None, metavar="SPEC",
        help="the grasped object instead of the paper's cube, as `grasp-env reproduce"
        " --object` takes it: cube, can, box:x=X,y=Y,z=Z, cylinder:r=R,h=H, sphere:r=R or"
        " mesh:FILE (metres); needs --contacts or --fingers; the expert's grip",
    )  # fmt: skip
    place = parser.add_mutually_exclusive_group()
    place.add_argument(
        "--contacts", default=None, metavar="SPEC",
        help="the object's 3 to 8 contacts, ';'-separated, in its surface coordinates (see"
        " `grasp-env reproduce --help`)",
    )  # fmt: skip
    place.add_argument(
        "--fingers", type=integer_argument(3, 8), default=None, metavar="N",
        help="N (3 to 8) contacts placed evenly around the object",
    )  # fmt: skip
    parser.add_argument(
        "--alphas",
        type=floats(3),
        default=(-15.0, 15.0, 1.0),
        metavar="START,END,STEP",
        help="the trajectory's alphas, deg (default the paper's: --alphas=-15,15,1)",
    )
    parser.add_argument(
        "--trajectory",
        action="store_true",
        help="carry the grip through the whole trajectory in one continuous MuJoCo rollout"
        " (default: each pose checked on its own); with --agreement, the trajectory study",
    )
    parser.add_argument(
        "--agreement", action="store_true", help="run the analytic-vs-MuJoCo agreement study"
    )
    parser.add_argument(
        "--scenes",
        type=integer_argument(1, MAX_SCENES),
        default=None,
        metavar="N",
        help=f"random scenes of the trajectory study (default {DEFAULT_SCENES}, about 3"
        " trajectories each, plus 69 of gaits; 200 give 638)",
    )
    parser.add_argument(
        "--video",
        type=path_argument,
        default=None,
        metavar="FILE.mp4",
        help=f"write the rollout as a video ({FRAMES_PER_POSE} frames per pose at {FPS} fps,"
        " 480x480); implies --trajectory",
    )
    parser.add_argument(
        "--seed",
        type=integer_argument(0),
        default=None,
        help="seed of the agreement studies (default 0)",
    )
    parser.add_argument(
        "--out", type=folder_argument, default=Path("results/verify"), help="output dir"
    )


def run(args: argparse.Namespace) -> int:
    if args.scenes is not None and not (args.agreement and args.trajectory):
        raise ValueError(
            "--scenes is for the trajectory study: use it with --agreement --trajectory"
        )
    scenes = DEFAULT_SCENES if args.scenes is None else args.scenes
    if args.seed is not None and not args.agreement:
        raise ValueError("--seed is for the agreement studies: use it with --agreement")
    seed = 0 if args.seed is None else args.seed
    saved = args.policy not in ("expert", "equal-k")
    for option, value in (("--algo", args.algo), ("--env", args.env)):
        if value is not None and not saved:
            raise ValueError(
                f"{option} is for a saved model: use it with --policy PATH (a .zip or a run"
                " directory)"
            )
    model = model_setup(Path(args.policy), args.algo, args.env) if saved else None
    if args.video is not None:
        if args.agreement:
            raise ValueError("--video writes the rollout: use it without --agreement")
        if args.video.suffix.lower() != ".mp4":  # the container ffmpeg writes is chosen by it
            raise ValueError(f"--video {args.video}: the video is an MP4, name it FILE.mp4")
        _imageio()  # before the rollout: say at once if the writer is missing
        existed = args.video.exists()
        try:  # before the rollout: say at once if the file cannot be written
            args.video.parent.mkdir(parents=True, exist_ok=True)  # as --out is
            args.video.open("ab").close()
        except OSError as error:
            raise ValueError(f"--video {args.video}: cannot write it ({error.strerror})") from None
        if not existed:  # the video appears when it is complete
            args.video.unlink()
        args.trajectory = True
    args.out.mkdir(parents=True, exist_ok=True)
    if args.agreement and args.object is not None:
        raise ValueError(
            "--object checks one object's grip: the agreement study on every shape is"
            " python -m grasp_env_agents.benchmarks.study_physics_shapes"
        )
    if args.agreement:
        if args.trajectory:
            if args.policy == "equal-k":
                raise ValueError(
                    "--policy with --agreement --trajectory adds a saved model's grips:"
                    " give its .zip or run directory (the expert and equal-k grips are"
                    " in the study already)"
                )
            return run_trajectory_agreement(seed, scenes, args.out, model)
        if args.policy != "expert":
            raise ValueError("--policy with --agreement is for the trajectory study (--trajectory)")
        return run_agreement(seed, args.out)
    if args.object is None:
        if args.contacts is not None or args.fingers is not None:
            option = "--contacts" if args.contacts is not None else "--fingers"
            raise ValueError(
                f"{option} places contacts on --object's surface: give --object too"
                " (e.g. --object can; without both, the paper's cube and contacts)"
            )
        scene = scene_from_arguments(args)
    else:
        if saved or args.policy == "equal-k":
            raise ValueError(
                "--object checks the expert's grip (the equal-k grip is the paper cube's, eq."
                " 8, and a saved model grips its environment's cube): drop --policy"
            )
        scene, _ = scene_of_object(args)
    start, end, step = args.alphas
    trajectory = Trajectory(alpha_start_deg=start, alpha_end_deg=end, alpha_step_deg=step)
    if args.policy == "expert":
        forces, label = expert_forces(scene, trajectory), "expert"
    elif args.policy == "equal-k":
        forces, label = equal_k_forces(scene, trajectory), "equal-k"
    else:
        fingers = model_fingers(model)
        if args.offsets is not None and fingers != scene.n_contacts:
            raise ValueError(
                f"--offsets places the paper's three fingers, and the model's {model.env_id} has"
                f" {fingers}: drop --offsets (its fingers then sit at their faces' centres)"
            )
        scene, forces = model_forces(model, scene, trajectory)
        label = f"learned ({model_name(model.path)})"
    if args.trajectory:
        return run_rollout(scene, trajectory, forces, label, args.out, args.video)
    return run_poses(scene, trajectory, forces, label, args.out)


# ------------------------------------------------------------------------------ the tables


VERDICT = {True: "[green]holds[/]", False: "[red]slips[/]"}


def micro(metres: float) -> str:
    """A length in micrometres for the tables: 3 decimals, or 3 digits past a millimetre (a
    finger that slipped flies off)."""
    um = 1e6 * float(metres)
    return f"{um:.3f}" if abs(um) < 1e3 else f"{um:.3g}"


# ------------------------------------------------------------------------------ pose by pose


def run_poses(
    scene: Scene, trajectory: Trajectory, forces: np.ndarray, label: str, out: Path
) -> int:
    """Check every pose on its own in MuJoCo; print the table; save the plot."""
    from rich.table import Table

    rotations = trajectory.rotations()
    normals = scene.normals @ np.swapaxes(rotations, -1, -2)
    angles = np.degrees(friction_angles(forces, normals).max(axis=-1))
    limit = float(np.degrees(scene.friction_limit))
    checker = StabilityChecker(scene)
    start = time.perf_counter()
    reports = checker.check_batch(rotations, forces)
    elapsed = time.perf_counter() - start
    checker.close()

    table = Table(title=f"MuJoCo check of the {label} grip (limit atan(mu) = {limit:.2f} deg)")
    for column in ("alpha deg", "max theta deg", "predicted", "MuJoCo", "slip um", "drift um"):
        table.add_column(column, justify="right")
    for alpha, angle, report in zip(trajectory.alphas_deg, angles, reports, strict=True):
        table.add_row(
            f"{alpha:+.1f}",
            f"{angle:.3f}",
            VERDICT[bool(angle <= limit)],
            VERDICT[report.holds],
            micro(report.slip.max()),
            micro(report.drift),
        )
    printer = console()
    printer.print(table)
    held = sum(r.holds for r in reports)
    agree = sum(r.holds == (a <= limit) for r, a in zip(reports, angles, strict=True))
    path = out / "verify.png"
    title = f"{label} grip, each pose checked on its own: MuJoCo holds at {held}/{len(reports)}"
    _plot_poses(scene, trajectory.alphas_deg, angles, limit, reports, title, path)
    printer.print(
        f"MuJoCo: holds at {held}/{len(reports)} poses; analytic and MuJoCo agree at"
        f" {agree}/{len(reports)}; {1e3 * elapsed / len(reports):.1f} ms per check; plot {path}"
    )
    return 0


# ------------------------------------------------------------------------------ the rollout


def run_rollout(
    scene: Scene,
    trajectory: Trajectory,
    forces: np.ndarray,
    label: str,
    out: Path,
    video: Path | None = None,
) -> int:
    """Carry the grip through the trajectory in one MuJoCo rollout; print the per-pose table
    and the verdict; save the plot and the report (and the video)."""
    from rich.table import Table

    alphas = trajectory.alphas_deg
    limit = float(np.degrees(scene.friction_limit))
    start = time.perf_counter()
    report = check_trajectories([(scene, trajectory.rotations(), forces, None)])[0]
    elapsed = time.perf_counter() - start

    table = Table(
        title=f"one MuJoCo rollout of the {label} grip (limit atan(mu) = {limit:.2f} deg)"
    )
    columns = ("alpha deg", "max theta deg", "predicted", "MuJoCo", "slip um", "drift um")
    for column in columns:
        table.add_column(column, justify="right")
    for t, alpha in enumerate(alphas):
        table.add_row(
            f"{alpha:+.1f}",
            f"{report.max_angle_deg[t]:.3f}",
            VERDICT[bool(report.pose_predicted[t])],
            VERDICT[bool(report.pose_holds[t])],
            micro(report.slip[t].max()),
            micro(report.drift[t]),
        )
    printer = console()
    printer.print(table)

    def where(coordinate: float | None) -> str:
        return (
            "none" if coordinate is None else f"alpha = {pose_alpha(alphas, coordinate):+.2f} deg"
        )

    word = {True: "holds", False: "slips"}
    printer.print(
        f"{len(report.motion)} steps, {report.time:.2f} s simulated after the settle, in"
        f" {elapsed:.2f} s; MuJoCo holds at {int(report.pose_holds.sum())}/{len(alphas)} poses"
        f" (after a failure the motion under way carries on); first failure, analytic:"
        f" {where(report.predicted_first_failure)}, MuJoCo: {where(report.first_failure)}"
    )
    if report.diverged:
        printer.print(
            "MuJoCo stopped the run on a warning (an unstable simulation) before its end:"
            " counted as a failure at the last pose"
        )
    path, data = out / "rollout.png", out / "rollout.json"
    plot_rollouts(scene, alphas, [(label, report)], f"{label} grip in one MuJoCo rollout", path)
    data.write_text(
        json.dumps({"policy": label, "alphas_deg": alphas.tolist(), **report.as_dict()}, indent=1)
    )
    printer.print(f"plot {path}, report {data}")
    if video is not None:
        with status(f"rendering the video {video}"):
            frames = write_video(video, scene, alphas, report)
        printer.print(f"video {video}: {frames} frames at {FPS} fps")
    print(
        f"trajectory: analytic {word[report.predicted_holds]}, MuJoCo {word[report.holds]}"
        f" ({'agree' if report.agrees else 'DISAGREE'}); margin {report.margin_deg:+.3f} deg,"
        f" largest slide {micro(report.slip.max())} um, drift {micro(report.drift.max())} um,"
        f" rotation {report.rotation_deg.max():.4f} deg"
    )
    return 0


# ------------------------------------------------------------------------------ the agreement


def _verdict(result: Agreement) -> int:
    """The exit code of an agreement study: 1 (and why) unless every verdict far from the
    edge agrees, the target a script can test."""
    if result.far == 1.0:
        return 0
    wrong = round((1.0 - result.far) * result.n_far)
    print(
        f"exit 1: {wrong} of the {result.n_far} verdicts at >= {FAR_FROM_EDGE_DEG} deg from"
        " the edge disagree (exit 0 needs every one of them to agree)"
    )
    return 1


def _confusion_table(title: str, confusion: np.ndarray):
    from rich.table import Table

    table = Table(title=title)
    table.add_column("")
    table.add_column("MuJoCo holds", justify="right")
    table.add_column("MuJoCo slips", justify="right")
    for label, row in zip(("analytic holds", "analytic slips"), confusion, strict=True):
        table.add_row(label, *(str(int(v)) for v in row))
    return table


def _bands_table(distance: np.ndarray, agree: np.ndarray, what: str):
    from rich.table import Table

    bands = Table(title="agreement by distance from the cone's edge")
    for column in ("distance, deg", what, "agree"):
        bands.add_column(column, justify="right")
    bands_deg = {
        f"under {FAR_FROM_EDGE_DEG}": distance < FAR_FROM_EDGE_DEG,
        f"{FAR_FROM_EDGE_DEG} to 1": (distance >= FAR_FROM_EDGE_DEG) & (distance <= 1.0 + 1e-9),
        "over 1": distance > 1.0 + 1e-9,
    }
    for label, band in bands_deg.items():
        bands.add_row(label, str(int(band.sum())), str(int(agree[band].sum())))
    return bands


def run_agreement(seed: int, out: Path) -> int:
    """The pose study: confusion matrix, runtime and the one-line summary."""
    from tqdm import tqdm

    printer = console()
    start = time.perf_counter()
    sets = agreement_sets(seed)
    generated = time.perf_counter()
    reports = check_sets(sets, progress=lambda s: tqdm(s, desc="MuJoCo checks", unit="set"))
    checked = time.perf_counter()
    observed = np.array([r.holds for r in reports])
    result = summarise(sets, observed)
    printer.print(_confusion_table("analytic (rows) vs MuJoCo (columns)", result.confusion))
    distance = np.array([s.edge_distance_deg for s in sets])
    predicted = np.array([s.predicted_holds for s in sets])
    printer.print(_bands_table(distance, predicted == observed, "sets"))
    path = out / "agreement.png"
    _plot_agreement(sets, reports, path)
    printer.print(
        f"runtime: {checked - start:.1f} s ({generated - start:.1f} s generating {len(sets)}"
        f" force sets, {checked - generated:.1f} s in MuJoCo,"
        f" {1e3 * (checked - generated) / len(sets):.1f} ms per check); plot {path}"
    )
    print(result.line())
    return _verdict(result)


def run_trajectory_agreement(
    seed: int,
    scenes: int,
    out: Path,
    model: SavedModel | None = None,
) -> int:
    """The trajectory study: confusion matrix, agreement by kind of grip and by distance from
    the edge, the disagreements, runtime and the one-line summary. With a saved ``model`` its
    grips on the study's scenes of its environment's number of fingers are cases too."""
    from rich.table import Table
    from tqdm import tqdm

    printer = console()
    start = time.perf_counter()
    cases = trajectory_cases(
        seed, scenes, progress=lambda s: tqdm(s, desc="scenes' trajectories", unit="scene")
    )
    with status("generating the gaits' trajectories"):
        cases += gait_cases(seed)
    if model is not None:
        with status(f"driving {model_name(model.path)} through {model.env_id}"):
            cases += learned_cases(cases, model)
    generated = time.perf_counter()
    reports = check_cases(
        cases, progress=lambda c: tqdm(c, desc="MuJoCo rollouts", unit="trajectory")
    )
    checked = time.perf_counter()
    result = summarise_trajectories(reports)
    printer.print(_confusion_table("analytic (rows) vs MuJoCo (columns), whole trajectories",
                                   result.confusion))  # fmt: skip
    agree = np.array([r.agrees for r in reports])
    kinds = Table(title="agreement by grip")
    for column in ("grip", "trajectories", "agree", "MuJoCo holds"):
        kinds.add_column(column, justify="right")
    names = [c.kind for c in cases]
    for kind in dict.fromkeys(names):
        mine = np.array([n == kind for n in names])
        held = sum(r.holds for r, m in zip(reports, mine, strict=True) if m)
        kinds.add_row(kind, str(int(mine.sum())), str(int(agree[mine].sum())), str(held))
    printer.print(kinds)
    distance = np.abs([r.margin_deg for r in reports])
    printer.print(_bands_table(distance, agree, "trajectories"))
    for case, report in zip(cases, reports, strict=True):
        if not report.agrees:
            printer.print(
                f"disagrees: {case.kind}, {case.scene.n_contacts} fingers, margin"
                f" {report.margin_deg:+.3f} deg, analytic"
                f" {'holds' if report.predicted_holds else 'slips'}, MuJoCo"
                f" {'holds' if report.holds else 'slips'} (largest slide"
                f" {1e6 * report.slip.max():.2f} um)"
            )
    path = out / "trajectory_agreement.png"
    _plot_trajectory_agreement(cases, reports, path)
    seconds = checked - generated
    printer.print(
        f"runtime: {checked - start:.1f} s ({generated - start:.1f} s generating {len(cases)}"
        f" trajectories, {seconds:.1f} s in MuJoCo, {1e3 * seconds / len(cases):.0f} ms per"
        f" rollout); plot {path}"
    )
    print(result.line("trajectories"))
    return _verdict(result)
