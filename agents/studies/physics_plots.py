"""The figures and the video of ``grasp-env verify``: the pose check's angles and verdicts, the
rollouts' slip and drift, the agreement studies' margins, and the rollout video."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from grasp_env.mechanics import (
    Scene,
    matrix_quaternion,
    quaternion_matrix,
)
from grasp_env.physics import (
    SETTINGS,
    GraspView,
    PhysicsReport,
    RolloutReport,
)

#: The video of a rollout: frames per pose (spread evenly over the simulated time after the
#: settle) and frames per second.
FRAMES_PER_POSE, FPS = 10, 30


def _matplotlib():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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


def pose_alpha(alphas: np.ndarray, coordinate: float | np.ndarray) -> float | np.ndarray:
    """The alpha (deg) of a pose coordinate t + s (between poses t and t + 1)."""
    return np.interp(coordinate, np.arange(len(alphas)), alphas)


def _imageio():
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401  (imageio's MP4 writer)
    except ImportError:
        raise ValueError(
            '--video writes with imageio and imageio-ffmpeg: pip install "grasp-env[video]"'
        ) from None
    return imageio


def video_steps(
    scene: Scene, report: RolloutReport, n_poses: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The frames of ``report``'s rollout video: FRAMES_PER_POSE per pose, evenly spaced in
    simulated time after the settle. Returns their steps, the last finite state at each step
    (a run that diverged stands at its last finite state), the largest friction angle at each
    step and the friction limit (deg)."""
    motion, qpos = report.motion, report.trace.qpos
    limit = float(np.degrees(scene.friction_limit))
    angles = np.degrees(motion.friction_angles(scene).max(axis=-1))
    count = FRAMES_PER_POSE * n_poses
    steps = np.linspace(motion.settle_steps, len(motion) - 1, count).round().astype(int)
    finite = np.all(np.isfinite(qpos), axis=1)
    last_finite = np.maximum.accumulate(np.where(finite, np.arange(len(qpos)), 0))
    return steps, last_finite, angles, limit


def write_frames(path: Path, frames: Iterable[np.ndarray]) -> None:
    """Write ``frames`` as an MP4 at FPS, beside ``path`` and renamed when complete: an
    interrupted run leaves no short video."""
    imageio = _imageio()
    partial = path.with_name(f"{path.stem}.partial.mp4")
    try:
        with imageio.get_writer(partial, format="FFMPEG", fps=FPS, macro_block_size=16) as writer:
            for image in frames:
                writer.append_data(image)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def write_video(
    path: Path, scene: Scene, alphas: np.ndarray, report: RolloutReport, size: int = 480
) -> int:
    """Write ``report``'s rollout as an MP4 of ``size`` x ``size`` pixels (the frames of
    :func:`video_steps`, at FPS frames per second), each with alpha, the largest friction
    angle and the margin. Returns the frame count."""
    _imageio()  # before the view: say at once if the writer is missing
    motion, qpos, n = report.motion, report.trace.qpos, scene.n_contacts
    steps, last_finite, angles, limit = video_steps(scene, report, len(alphas))

    def frame(k: int) -> np.ndarray:
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
        return view.render_state(state, rotation, forces, motion.contact[k], text)

    view = GraspView(scene, width=size, height=size)
    try:
        write_frames(path, (frame(k) for k in steps))
    finally:
        view.close()
    return len(steps)


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
