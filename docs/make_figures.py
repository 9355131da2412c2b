"""Make the figures of docs/physics.md: ``python docs/make_figures.py`` (about 50 s).

- ``docs/verify.png``: ``grasp-env verify --policy equal-k --mu 0.1``, each pose checked on
  its own.
- ``docs/rollout.png``: three grips carried along the paper's 31-pose trajectory in one
  continuous MuJoCo rollout each, on a scene with moved contacts and centre of gravity where
  the expert's largest friction angle is 11.31 deg and mu is set 2 deg above it: the expert's
  grip, and the expert's perturbed by a bump mid-trajectory so that its largest friction angle
  passes the limit by 0.5 deg (it crosses it) or stays 0.5 deg inside it
  (:func:`grasp_env_agents.studies.trajectory_agreement.perturbed_k`).
- ``docs/video_still.png``: the first frame of ``grasp-env verify --video`` of the expert's
  grip on that scene (its largest friction angle, 11.31 deg at alpha = -15 deg, 2 deg inside
  the limit: the cones orange).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from grasp_env.mechanics import PAPER_FACES, Scene, Trajectory, scene_grasp, solve_minimax
from grasp_env.physics import SETTINGS, check_trajectories
from grasp_env.physics.motion import plan_motion, released
from grasp_env_agents.cli import main
from grasp_env_agents.studies.physics_plots import plot_rollouts
from grasp_env_agents.studies.trajectory_agreement import perturbed_k

DOCS = Path(__file__).resolve().parent
LAYOUT = {
    "faces": PAPER_FACES,
    "offsets": [[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]],
    "cg_offset": (0.05, -0.03, 0.02),
}


def largest_step_angle(scene: Scene, rotations, forces) -> float:
    """The largest friction angle (deg) of a loaded finger over a rollout's steps."""
    motion = plan_motion(scene, rotations, forces, None, SETTINGS)
    loaded = motion.contact & ~released(motion.forces, 1.0, SETTINGS["released_force"])
    angles = np.where(loaded, motion.friction_angles(scene), 0.0)
    return float(np.degrees(angles[motion.settle_steps :].max()))


def rollout_figure(path: Path) -> None:
    trajectory = Trajectory()
    rotations, alphas = trajectory.rotations(), trajectory.alphas_deg
    unlimited = Scene.on_faces(**LAYOUT)
    grasps = scene_grasp(unlimited, rotations)
    k = solve_minimax(grasps, 2 * unlimited.weight).k  # mu does not change the optimum's k
    limit = largest_step_angle(unlimited, rotations, grasps.forces(k)) + 2.0
    scene = Scene.on_faces(**LAYOUT, mu=float(np.tan(np.radians(limit))))
    grasps = scene_grasp(scene, rotations)
    runs = [("expert", grasps.forces(k))]
    for label, offset in (("crossing by 0.5 deg", 0.5), ("0.5 deg inside", -0.5)):
        rng = np.random.default_rng(0)
        perturbed = perturbed_k(scene, rotations, alphas, k, np.radians(limit + offset), rng)
        runs.append((label, grasps.forces(perturbed)))
    reports = check_trajectories([(scene, rotations, forces, None) for _, forces in runs])
    for (label, _), report in zip(runs, reports, strict=True):
        print(
            f"{label}: analytic holds {report.predicted_holds}, MuJoCo holds {report.holds},"
            f" margin {report.margin_deg:+.3f} deg, first failure {report.first_failure}"
            f" (analytic {report.predicted_first_failure})"
        )
    title = (
        f"three grips in 31-pose rollouts (moved contacts and cg, atan(mu) = {limit:.2f} deg):"
        "\nMuJoCo fails where the perturbed grip's angle crosses the limit"
    )
    labelled = [(label, r) for (label, _), r in zip(runs, reports, strict=True)]
    plot_rollouts(scene, alphas, labelled, title, path)


def video_still(path: Path) -> None:
    import imageio

    mu = float(np.tan(np.radians(13.31)))
    offsets = ",".join(f"{v:g}" for v in np.ravel(LAYOUT["offsets"]))
    cg = ",".join(f"{v:g}" for v in LAYOUT["cg_offset"])
    with tempfile.TemporaryDirectory() as out:
        video = Path(out) / "rollout.mp4"
        argv = ["verify", "--offsets", offsets, "--cg-offset", cg, "--mu", f"{mu:.6f}"]
        main([*argv, "--video", str(video), "--out", out])
        with imageio.get_reader(str(video), "ffmpeg") as reader:
            imageio.imwrite(path, reader.get_data(0))


def verify_figure(path: Path) -> None:
    with tempfile.TemporaryDirectory() as out:
        main(["verify", "--policy", "equal-k", "--mu", "0.1", "--out", out])
        shutil.copy(Path(out) / "verify.png", path)


if __name__ == "__main__":
    verify_figure(DOCS / "verify.png")
    rollout_figure(DOCS / "rollout.png")
    video_still(DOCS / "video_still.png")
