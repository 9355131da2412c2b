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
import os
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from grasp_env import ENV_IDS
from grasp_env.mechanics import (
    PHI,
    Scene,
    Trajectory,
    friction_angles,
    grasp_matrix,
    load_wrench,
    matrix_quaternion,
    n_pairs,
    quaternion_matrix,
    scene_grasp,
    solve_minimax,
)
from grasp_env.physics import (
    SETTINGS,
    GraspView,
    PhysicsReport,
    RolloutReport,
    StabilityChecker,
    check_trajectories,
)
from grasp_env_agents.studies.agreement import (
    FAR_FROM_EDGE_DEG,
    Agreement,
    TrajectoryCase,
    agreement_sets,
    check_cases,
    check_sets,
    gait_cases,
    summarise,
    summarise_trajectories,
    trajectory_cases,
)

from ..cli import folder_argument, integer_argument, path_argument
from ..progress import console, status
from .scene_args import add_scene_arguments, floats, scene_from_arguments

HELP = "check grip forces in MuJoCo physics along a trajectory (or --agreement)"
#: Scenes of the trajectory study by default: about 70 trajectories and the 66 of the gaits
#: (200 give 638 with the gaits, 732 with docs/physics.md's learned policy).
DEFAULT_SCENES = 20
#: The most --scenes takes: about 300,000 trajectories, a day of rollouts on 2 cores.
MAX_SCENES = 100_000
#: The video of a rollout: frames per pose (spread evenly over the simulated time after the
#: settle) and frames per second.
FRAMES_PER_POSE, FPS = 10, 30
#: The environments that can drive a saved model's grip (``--env``): grasp_env's but the gait
#: ones, whose hand phases fingers in and out.
MODEL_ENV_IDS = tuple(env_id for env_id in ENV_IDS if "Gait" not in env_id)
DEFAULT_MODEL_ENV = "grasp_env/CubeGrasp-v0"


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
    scene = scene_from_arguments(args)
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


# ------------------------------------------------------------------------------ the policies


def expert_forces(scene: Scene, trajectory: Trajectory) -> np.ndarray:
    """The minimax grip at every pose, k_max = 2 w as in the environments: (T, n, 3)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    return grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)


def equal_k_forces(scene: Scene, trajectory: Trajectory) -> np.ndarray:
    """The paper's symmetric grip, k_ij = w tan(phi) / (3 sqrt 3) for every pair (eq. 8)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    k = scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(n_pairs(scene.n_contacts))
    return grasp.forces(k)


def model_name(path: Path) -> str:
    """A short name for a saved model in titles: its run directory's name, or the file's."""
    path = path.resolve()
    if path.is_dir():
        return path.name
    return path.parent.name if path.name == "model.zip" else path.stem


class SavedModel(NamedTuple):
    """A saved model to verify, and the environment that drives it."""

    path: Path  # its .zip, or a training run's directory
    algo: str | None  # None: the file's policy class says
    env_id: str
    env_kwargs: dict[str, Any]  # the run's (its grip depends on them: k_max_ratio, faces)


def model_setup(path: Path, algo: str | None, env_id: str | None) -> SavedModel:
    """The saved model at ``path``, the algorithm that wrote it and the environment that
    drives it: those of the run's ``config.yaml`` (its ``env_kwargs`` too) when ``path`` is a
    ``grasp-env train`` run directory (or its model.zip), else ``algo`` and ``env_id``
    (default :data:`DEFAULT_MODEL_ENV`) with the environment's defaults. An ``algo`` that
    contradicts the run's is refused."""
    from ..learning.models import ALGORITHMS

    if algo is not None and algo not in ALGORITHMS:
        raise ValueError(f"--algo must be one of {', '.join(ALGORITHMS)}, got {algo!r}")
    path = Path(path)
    run_dir = path if path.is_dir() else path.parent if path.name == "model.zip" else None
    if run_dir is None or not (run_dir / "config.yaml").is_file():
        return SavedModel(path, algo, check_model_env(env_id or DEFAULT_MODEL_ENV), {})
    from ..run.config import load_config

    config = load_config(run_dir / "config.yaml")
    if algo is not None and algo != config.algo:
        raise ValueError(
            f"--algo {algo}: the run {run_dir} was trained with algo: {config.algo} (its"
            f" config.yaml); drop --algo or give --algo {config.algo}"
        )
    trained_on = config.env_id if config.env_id in MODEL_ENV_IDS else DEFAULT_MODEL_ENV
    return SavedModel(path, config.algo, check_model_env(env_id or trained_on), config.env_kwargs)


def check_model_env(env_id: str) -> str:
    """``env_id`` if it is one of :data:`MODEL_ENV_IDS` (ValueError naming --env if not)."""
    if env_id not in MODEL_ENV_IDS:
        raise ValueError(
            f"--env must be one of {', '.join(MODEL_ENV_IDS)} (the grasp environments that can"
            f" drive a saved model), got {env_id!r}"
        )
    return env_id


def model_forces(
    model: SavedModel, scene: Scene, trajectory: Trajectory
) -> tuple[Scene, np.ndarray]:
    """A saved model's grip, stepping its environment pinned to ``scene`` and ``trajectory``.

    The model is read by :func:`grasp_env_agents.learning.models.load_agent` (no code from the file
    runs; the ``vecnormalize.pkl`` beside it, if any, normalises the observations). Returns
    the environment's scene and the contact forces it applied, (T, n, 3).
    """
    return model_grips(model, [(scene, trajectory)])[0]


def model_env(model: SavedModel) -> Any:
    """The model's environment, made with the run's ``env_kwargs``; episodes run past a slip
    (the whole trajectory is verified)."""
    import gymnasium as gym  # the RL stack only when a model is verified

    import grasp_env  # noqa: F401  (registers the environments)

    kwargs = {**model.env_kwargs, "terminate_on_slip": False}
    try:
        return gym.make(model.env_id, **kwargs)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"the run's env_kwargs {model.env_kwargs} do not make {model.env_id}: {error}"
        ) from None


def model_fingers(model: SavedModel) -> int:
    """The number of fingers of the model's environment."""
    env = model_env(model)
    env.close()
    return len(env.unwrapped.faces)


def model_grips(
    model: SavedModel, problems: list[tuple[Scene, Trajectory]]
) -> list[tuple[Scene, np.ndarray]]:
    """:func:`model_forces` on several (scene, trajectory) problems, the model loaded once."""
    path, env_id = model.path, model.env_id
    model_file = path / "model.zip" if path.is_dir() else path
    if not model_file.is_file():
        raise ValueError(
            f"--policy must be 'expert', 'equal-k' or the path of a saved model; {model_file}"
            " is not a file"
        )
    from ..learning.models import load_agent, misfit

    agent = load_agent(path, model.algo)
    env = model_env(model)
    problem = misfit(agent.model, env, env_id)
    if problem:
        env.close()
        raise ValueError(
            f"--env {env_id} does not fit the model: {problem} (give --env the environment the"
            " model was trained on)"
        )
    grips = []
    for scene, trajectory in problems:
        options: dict = {
            "weight": scene.weight,
            "mu": scene.mu,
            "cg_offset": scene.cg_offset.tolist(),
            "trajectory": {
                "axis": tuple(trajectory.axis),
                "alpha_start_deg": trajectory.alpha_start_deg,
                "alpha_end_deg": trajectory.alpha_end_deg,
                "alpha_step_deg": trajectory.alpha_step_deg,
            },
        }
        if scene.n_contacts == len(env.unwrapped.faces):
            options["contacts"] = scene.contacts.tolist()
        obs, _ = env.reset(seed=0, options={"scene": options})
        env_scene = env.unwrapped.scene
        forces, done = [], False
        while not done:
            action, _ = agent.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            forces.append(info["contact_forces"])
            done = terminated or truncated
        forces = np.array(forces)
        # The forces must balance the load at our poses: a guard against a mismatched
        # trajectory.
        if len(forces) != len(trajectory) or not _balanced(env_scene, trajectory, forces):
            env.close()
            raise ValueError(f"the environment {env_id} did not follow the verified trajectory")
        grips.append((env_scene, forces))
    env.close()
    return grips


def _balanced(scene: Scene, trajectory: Trajectory, forces: np.ndarray) -> bool:
    """Whether ``forces`` (T, n, 3) balance ``scene``'s load at every pose: G P = -(f, tau)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    wrench = load_wrench(scene.weight, scene.extra_force, scene.extra_torque)
    residual = grasp_matrix(grasp.positions) @ forces.reshape(len(forces), -1, 1)
    return bool(np.allclose(residual[..., 0], -wrench, atol=1e-6 * scene.weight))


def _matplotlib():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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


def _angle_axis(ax, values: np.ndarray, limit: float) -> None:
    """Scale ``ax``'s y axis to the friction angles ``values`` (deg) and draw the friction
    limit if it lies in that range or near it; otherwise say where it is."""
    top = float(np.max(values))
    if limit <= 1.5 * top:
        ax.axhline(limit, color="k", ls="--", lw=1, label=f"atan(mu) = {limit:.2f} deg")
        top = max(top, limit)
    else:
        ax.text(
            0.99, 0.96, f"atan(mu) = {limit:.2f} deg, far above", transform=ax.transAxes,
            ha="right", va="top", fontsize=8,
        )  # fmt: skip
    ax.set_ylim(0.0, 1.12 * top if top > 0 else 1.0)


def _plot_poses(scene, alphas, angles, limit, reports: list[PhysicsReport], title, path) -> None:
    plt = _matplotlib()
    length = float(np.max(scene.size))
    holds = np.array([r.holds for r in reports])
    slip = np.array([r.slip.max() for r in reports])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    top.plot(alphas, angles, "-", color="0.5", label="max friction angle (analytic)")
    top.scatter(alphas[holds], angles[holds], c="tab:green", zorder=3, label="MuJoCo: holds")
    top.scatter(alphas[~holds], angles[~holds], c="tab:red", marker="x", zorder=3,
                label="MuJoCo: slips")  # fmt: skip
    _angle_axis(top, angles, limit)
    top.set_ylabel("max friction angle, deg")
    top.set_title(title, fontsize=10)
    top.legend(fontsize=8, loc="lower left")
    floor = 1e-6  # um: smaller slides are drawn here
    bottom.semilogy(alphas, np.maximum(1e6 * slip, floor), "o-", ms=3, label="largest slide")
    bottom.axhline(1e6 * SETTINGS["slip_threshold"] * length, color="k", ls="--", lw=1,
                   label="slip threshold")  # fmt: skip
    bottom.legend(fontsize=8)
    bottom.set_xlabel("alpha, deg")
    bottom.set_ylabel(f"slide in the hold, um (floor {floor:g})")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------------------ the rollout


def pose_alpha(alphas: np.ndarray, coordinate: float | np.ndarray) -> float | np.ndarray:
    """The alpha (deg) of a pose coordinate t + s (between poses t and t + 1)."""
    return np.interp(coordinate, np.arange(len(alphas)), alphas)


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


def _imageio():
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401  (imageio's MP4 writer)
    except ImportError:
        raise ValueError(
            '--video writes with imageio and imageio-ffmpeg: pip install "grasp-env[video]"'
        ) from None
    return imageio


def write_video(
    path: Path, scene: Scene, alphas: np.ndarray, report: RolloutReport, size: int = 480
) -> int:
    """Write ``report``'s rollout as an MP4 of ``size`` x ``size`` pixels: FRAMES_PER_POSE
    frames per pose, evenly spaced in simulated time after the settle, at FPS frames per
    second, each with alpha, the largest friction angle and the margin. Returns the frame
    count."""
    imageio = _imageio()
    motion, qpos, n = report.motion, report.trace.qpos, scene.n_contacts
    limit = float(np.degrees(scene.friction_limit))
    angles = np.degrees(motion.friction_angles(scene).max(axis=-1))
    count = FRAMES_PER_POSE * len(alphas)
    steps = np.linspace(motion.settle_steps, len(motion) - 1, count).round().astype(int)
    # A run that diverged stands at its last finite state.
    finite = np.all(np.isfinite(qpos), axis=1)
    last_finite = np.maximum.accumulate(np.where(finite, np.arange(len(qpos)), 0))
    view = GraspView(scene, width=size, height=size)
    # Written beside it and renamed when complete: an interrupted run leaves no short video.
    partial = path.with_name(f"{path.stem}.partial.mp4")
    try:
        with imageio.get_writer(partial, format="FFMPEG", fps=FPS, macro_block_size=16) as writer:
            for k in steps:
                # MuJoCo turns the load about the object; the picture turns the object instead.
                rotation, state = motion.rotations[k], qpos[last_finite[k]].copy()
                state[:3] = rotation @ state[:3]
                state[3:7] = matrix_quaternion(rotation @ quaternion_matrix(state[3:7]))
                state[7:] = (state[7:].reshape(n, 3) @ rotation.T).ravel()
                text = (
                    f"alpha {pose_alpha(alphas, motion.pose[k]):+.2f} deg",
                    f"largest friction angle {angles[k]:.2f} deg",
                    f"margin {limit - angles[k]:+.2f} deg (atan mu {limit:.2f})",
                )
                forces = motion.forces[k] @ rotation.T
                image = view.render_state(state, rotation, forces, motion.contact[k], text)
                writer.append_data(image)
        os.replace(partial, path)
    finally:
        view.close()
        partial.unlink(missing_ok=True)
    return count


def plot_rollouts(
    scene: Scene, alphas: np.ndarray, runs: list[tuple[str, RolloutReport]], title: str, path
) -> None:
    """Along the run (after the settle): each grip's largest friction angle of a finger in
    contact, the friction limit, and its largest slide since placed against the threshold."""
    plt = _matplotlib()
    length = float(np.max(scene.size))
    limit = float(np.degrees(scene.friction_limit))
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    floor = 1e-6  # um: smaller slides are drawn here
    largest = []
    for (label, report), colour in zip(
        runs, ("tab:blue", "tab:orange", "tab:purple"), strict=False
    ):
        motion, trace = report.motion, report.trace
        steps = slice(motion.settle_steps, None)
        alpha = pose_alpha(alphas, motion.pose[steps])
        angles = np.degrees(motion.friction_angles(scene)[steps].max(axis=-1))
        largest.append(angles)
        slide = np.maximum.accumulate(trace.slip[steps].max(axis=-1)) * length * 1e6
        slide = np.minimum(slide, 1e6 * length)  # past L the finger has left its face
        width = 3.0 if not largest[:-1] and len(runs) > 1 else 1.2  # the first beneath
        top.plot(alpha, angles, color=colour, lw=width, label=label)
        bottom.semilogy(alpha, np.maximum(slide, floor), color=colour, lw=width, label=label)
        if report.first_failure is not None:
            x = pose_alpha(alphas, report.first_failure)
            top.axvline(x, color=colour, ls=":", lw=1)
            bottom.axvline(x, color=colour, ls=":", lw=1)
    _angle_axis(top, np.concatenate(largest), limit)
    top.set_ylabel("largest friction angle, deg")
    top.set_title(title, fontsize=10)
    top.legend(fontsize=8, loc="lower left")
    bottom.axhline(1e6 * SETTINGS["slip_threshold"] * length, color="k", ls="--", lw=1,
                   label="slip threshold")  # fmt: skip
    bottom.set_xlabel("alpha, deg (dotted: where MuJoCo first failed)")
    bottom.set_ylabel(f"slide since placed, um (floor {floor:g}, top L)")
    bottom.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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


def _margin_ticks(ax, ticks: tuple[float, ...]) -> None:
    """Plain tick labels on a symlog axis (its own crowd together around 0)."""
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])


def _plot_agreement(sets, reports: list[PhysicsReport], path: Path) -> None:
    plt = _matplotlib()
    excess = np.array([s.max_angle_deg - s.limit_deg for s in sets])
    slip = np.array([max(r.slip.max(), 1e-12) for r in reports])
    holds = np.array([r.holds for r in reports])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.scatter(excess[holds], 1e3 * slip[holds], s=6, c="tab:green", label="MuJoCo: holds")
    ax.scatter(excess[~holds], 1e3 * slip[~holds], s=6, c="tab:red", label="MuJoCo: slips")
    ax.set_xscale("symlog", linthresh=0.01)
    _margin_ticks(ax, (-10, -1, -0.1, -0.01, 0, 0.01, 0.1, 1, 10))
    ax.set_yscale("log")
    ax.axvline(0.0, color="k", lw=1)
    ax.set_xlabel("max friction angle - atan(mu), deg")
    ax.set_ylabel("max slip, mm")
    ax.set_title("analytic friction cone vs MuJoCo")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def learned_cases(cases: list[TrajectoryCase], model: SavedModel) -> list[TrajectoryCase]:
    """A saved model's grips (kind "learned") on the scenes and trajectories of the study's
    expert cases whose number of fingers is the model environment's (:func:`model_grips`)."""
    fingers = model_fingers(model)
    experts = [
        c for c in cases
        if c.kind == "expert" and c.trajectory is not None and c.scene.n_contacts == fingers
    ]  # fmt: skip
    if not experts:
        raise ValueError(
            f"--policy: no scene of the study has the model's {fingers} fingers (the scenes"
            " alternate three and four fingers, and skip a few): give more --scenes"
        )
    grips = model_grips(model, [(c.scene, c.trajectory) for c in experts])
    return [
        TrajectoryCase("learned", scene, c.alphas_deg, c.rotations, forces, None, c.trajectory)
        for c, (scene, forces) in zip(experts, grips, strict=True)
    ]


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


def _plot_trajectory_agreement(cases, reports: list[RolloutReport], path: Path) -> None:
    plt = _matplotlib()
    margin = np.array([r.margin_deg for r in reports])
    floor = 1e-12
    slide = np.array(
        [
            max(r.slip.max() / np.max(c.scene.size), floor)
            for c, r in zip(cases, reports, strict=True)
        ]
    )
    holds = np.array([r.holds for r in reports])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.scatter(margin[holds], slide[holds], s=8, c="tab:green", label="MuJoCo: holds")
    ax.scatter(margin[~holds], slide[~holds], s=8, c="tab:red", marker="x", label="MuJoCo: slips")
    ax.set_xscale("symlog", linthresh=0.05)
    _margin_ticks(ax, (-10, -1, -0.1, 0, 0.1, 1, 10))
    ax.set_yscale("log")
    ax.axvline(0.0, color="k", lw=1)
    ax.axhline(SETTINGS["slip_threshold"], color="k", ls="--", lw=1, label="slip threshold")
    ax.set_xlabel("analytic margin over the run: atan(mu) - largest friction angle, deg")
    ax.set_ylabel(f"largest slide, units of L (floor {floor:g})")
    ax.set_title(f"{len(reports)} trajectories, each one continuous MuJoCo rollout")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
