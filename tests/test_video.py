"""``grasp-env verify --video``: the rollout decoded back, frame count, motion and overlay."""

from __future__ import annotations

import sys

import numpy as np

from grasp_env.mechanics import Scene, Trajectory
from grasp_env.physics import GraspView
from grasp_env_agents.cli import main
from grasp_env_agents.studies.grips import expert_forces
from grasp_env_agents.studies.physics_plots import FPS, FRAMES_PER_POSE

#: The overlay's dark box at 480 x 480 (three lines of text at the top left), and a band of
#: the picture well below it.
CORNER = (slice(0, 75), slice(0, 260))
BELOW = (slice(100, None), slice(None))


def test_verify_video_writes_the_rollout_with_its_overlay(tmp_path, capsys):
    import imageio

    path = tmp_path / "videos" / "rollout.mp4"  # its folder is created, as --out's is
    argv = ["verify", "--alphas=-10,10,10", "--video", str(path), "--out", str(tmp_path)]
    assert main(argv) == 0
    assert f"{3 * FRAMES_PER_POSE} frames at {FPS} fps" in capsys.readouterr().out
    assert (tmp_path / "rollout.json").is_file()  # --video implies --trajectory
    assert sorted(p.name for p in path.parent.glob("*.mp4")) == ["rollout.mp4"]
    reader = imageio.get_reader(str(path), "ffmpeg")
    assert reader.get_meta_data()["fps"] == FPS
    frames = np.array(list(reader.iter_data())).astype(int)
    reader.close()
    assert frames.shape == (3 * FRAMES_PER_POSE, 480, 480, 3)

    # The first frame is the first pose after the settle: the same picture as GraspView draws
    # of that pose without text, but for the overlay (the tips pressed in by micrometres).
    scene = Scene.on_faces()
    trajectory = Trajectory(alpha_start_deg=-10.0, alpha_end_deg=10.0, alpha_step_deg=10.0)
    view = GraspView(scene)
    plain = view.render(trajectory.rotations()[0], expert_forces(scene, trajectory)[0])
    view.close()
    difference = np.abs(frames[0] - plain.astype(int))
    assert difference[BELOW].mean() < 2.0  # codec noise only
    assert difference[CORNER].mean() > 60.0  # the dark box
    white = np.all(frames[0][CORNER] > 200, axis=-1)
    assert white.sum() > 300  # its text

    # The cube turns 20 deg and the overlay's alpha changes with it.
    first, last = frames[0], frames[-1]
    assert np.mean(np.any(np.abs(last - first)[BELOW] > 30, axis=-1)) > 0.02
    assert np.any(np.all(np.abs(last - first)[CORNER] > 100, axis=-1))
    steps = np.abs(np.diff(frames, axis=0)).max(axis=(1, 2, 3))
    assert np.sum(steps > 30) >= FRAMES_PER_POSE  # it moves through the run, not in one jump


def test_verify_video_refuses_the_agreement_study_and_a_missing_writer(
    tmp_path, capsys, monkeypatch
):
    video = str(tmp_path / "v.mp4")
    assert main(["verify", "--agreement", "--video", video, "--out", str(tmp_path)]) == 2
    assert "without --agreement" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "imageio", None)  # imageio not installed
    assert main(["verify", "--video", video, "--out", str(tmp_path)]) == 2
    assert 'pip install "grasp-env[video]"' in capsys.readouterr().err


def test_an_interrupted_video_leaves_no_file(tmp_path, monkeypatch):
    """Ctrl-C while frames are written: exit 130 and no short video under the asked name."""
    render = GraspView.render_state
    frames = []

    def interrupted(self, *args):
        frames.append(1)
        if len(frames) == 5:
            raise KeyboardInterrupt
        return render(self, *args)

    monkeypatch.setattr(GraspView, "render_state", interrupted)
    path = tmp_path / "rollout.mp4"
    argv = ["verify", "--alphas=-10,10,10", "--video", str(path), "--out", str(tmp_path)]
    assert main(argv) == 130
    assert len(frames) == 5 and not list(tmp_path.glob("*.mp4"))
