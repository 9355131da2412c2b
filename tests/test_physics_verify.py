"""`grasp-env verify`: pose and trajectory checks, videos, the agreement studies and saved models
(docs/physics.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from physics_helpers import SHORT_GAIT

from grasp_env.physics import (
    SETTINGS,
)
from grasp_env_agents.cli import main
from grasp_env_agents.studies import trajectory_agreement

# ----------------------------------------------------------------------- grasp-env verify


def test_verify_equal_k_grip_slips_at_the_trajectory_ends(tmp_path, capsys):
    # mu = 0.1 (5.71 deg): the equal-k grip's max angle passes it for |alpha| >= 10 deg or so.
    status = main(["verify", "--policy", "equal-k", "--mu", "0.1", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert status == 0
    assert (tmp_path / "verify.png").stat().st_size > 10_000
    rows = [line for line in out.splitlines() if line.startswith("│")]
    assert len(rows) == 31
    ends, middle = rows[0] + rows[-1], rows[15]
    assert ends.count("slips") == 4  # predicted and MuJoCo, at both ends
    assert middle.count("holds") == 2
    assert "agree at 31/31" in out


def test_verify_trajectory_carries_the_expert_grip_in_one_rollout(tmp_path, capsys):
    status = main(["verify", "--trajectory", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert status == 0
    rows = [line for line in out.splitlines() if line.startswith("│")]
    assert len(rows) == 31 and all(row.count("holds") == 2 for row in rows)
    verdict = out.strip().splitlines()[-1]
    assert verdict.startswith("trajectory: analytic holds, MuJoCo holds (agree); margin +26.5")
    assert (tmp_path / "rollout.png").stat().st_size > 10_000
    report = json.loads((tmp_path / "rollout.json").read_text())
    assert report["policy"] == "expert" and len(report["alphas_deg"]) == 31
    assert report["holds"] and all(report["pose_holds"]) and report["first_failure"] is None


def test_verify_trajectory_reports_where_the_equal_k_grip_first_slips(tmp_path, capsys):
    # mu = 0.1 (5.71 deg): the equal-k grip is past the limit from the start (9.3 deg at -15).
    argv = ["verify", "--trajectory", "--policy", "equal-k", "--mu", "0.1", "--out", str(tmp_path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "trajectory: analytic slips, MuJoCo slips (agree); margin -3.6" in out
    assert "first failure, analytic: alpha = -15.00 deg, MuJoCo: alpha = -15.00 deg" in " ".join(
        out.split()
    )
    report = json.loads((tmp_path / "rollout.json").read_text())
    assert report["predicted_first_failure"] == 0.0 and not report["holds"]
    assert not report["pose_predicted"][0] and report["pose_predicted"][15]


def test_verify_trajectory_agreement_on_one_scene(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(trajectory_agreement, "GAIT_TRAJECTORIES", SHORT_GAIT)
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "1", "--out", str(tmp_path)]
    status = main(argv)
    out = capsys.readouterr().out
    # One scene gives the expert's grip and two perturbed ones, plus 8 equal-k, coarse steps
    # and the gait with its two perturbations.
    assert out.strip().splitlines()[-1].startswith("agreement: 100.00% overall (15 trajectories)")
    assert status == 0
    assert "coarse steps" in out and "gait crossing" in out and "MuJoCo slips" in out
    assert (tmp_path / "trajectory_agreement.png").stat().st_size > 10_000


def test_verify_refuses_scenes_outside_the_trajectory_study(tmp_path, capsys):
    assert main(["verify", "--scenes", "3", "--out", str(tmp_path)]) == 2
    assert "--agreement --trajectory" in capsys.readouterr().err
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "0", "--out", str(tmp_path)]
    with pytest.raises(SystemExit, match="2"):
        main(argv)
    error = capsys.readouterr().err
    assert "argument --scenes: must be an integer in [1, 100000], got '0'" in error


def test_verify_and_gait_say_which_path_they_cannot_write(tmp_path, capsys):
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    # the video's folder is created as --out's is, unless a file is in the way
    video = blocked / "videos" / "x.mp4"
    assert main(["verify", "--video", str(video), "--out", str(tmp_path)]) == 2
    assert f"--video {video}: cannot write it (Not a directory)" in capsys.readouterr().err
    assert main(["verify", "--video", str(tmp_path / "x.txt"), "--out", str(tmp_path)]) == 2
    assert "the video is an MP4, name it FILE.mp4" in capsys.readouterr().err
    assert not (tmp_path / "x.txt").exists()  # refused before anything is written
    with pytest.raises(SystemExit, match="2"):  # refused before the gait is solved
        main(["gait", "--out", str(blocked / "out")])
    assert "argument --out: " in (err := capsys.readouterr().err)
    assert "a file is in the way" in err


def test_verify_states_the_current_settings():
    from grasp_env_agents.commands import verify

    def num(value: float) -> str:
        return f"{value:g}".replace("e-0", "e-")

    doc = " ".join(verify.__doc__.split())
    for phrase in (
        f"{num(SETTINGS['settle_time'])} s settle at mu = {num(SETTINGS['settle_mu'])}",
        f"{num(SETTINGS['hold_time'])} s hold",
        f"more than {num(SETTINGS['slip_threshold'])} L",
        f"faster than {num(SETTINGS['slip_speed'])} L/s",
        f"at most {num(SETTINGS['drift_threshold'])} L",
        f"at most {num(SETTINGS['rotation_threshold_deg'])} deg",
        f"at most {num(SETTINGS['released_force'])} w is released",
        f"{num(SETTINGS['pose_hold_time'])} s dwell",
        f"{num(SETTINGS['time_per_degree'])} s per degree",
    ):
        assert phrase in doc, phrase


@pytest.mark.slow  # about 13 s, most of it importing Stable-Baselines3 and building PPO
def test_verify_runs_a_saved_model(tmp_path, capsys):
    import gymnasium as gym
    from stable_baselines3 import PPO

    import grasp_env  # noqa: F401

    path = tmp_path / "model.zip"
    PPO("MlpPolicy", gym.make("grasp_env/CubeGrasp-v0"), seed=0, device="cpu").save(path)
    status = main(["verify", "--policy", str(tmp_path), "--out", str(tmp_path)])  # a run dir
    out = capsys.readouterr().out
    assert status == 0
    assert "MuJoCo: holds at" in out
    assert len([line for line in out.splitlines() if line.startswith("│")]) == 31
    argv = ["verify", "--trajectory", "--policy", str(path), "--out", str(tmp_path)]
    assert main(argv) == 0
    assert "trajectory: analytic" in capsys.readouterr().out
    assert json.loads((tmp_path / "rollout.json").read_text())["policy"].startswith("learned (")


@pytest.mark.slow  # about 40 s: Stable-Baselines3, PPO and a small trajectory study
def test_verify_trajectory_agreement_adds_a_saved_models_grips(tmp_path, capsys, monkeypatch):
    import gymnasium as gym
    from stable_baselines3 import PPO

    import grasp_env  # noqa: F401

    monkeypatch.setattr(trajectory_agreement, "GAIT_TRAJECTORIES", SHORT_GAIT)
    PPO("MlpPolicy", gym.make("grasp_env/CubeGrasp-v0"), seed=0, device="cpu").save(
        tmp_path / "model.zip"
    )
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "2", "--policy", str(tmp_path)]
    main([*argv, "--out", str(tmp_path)])
    out = capsys.readouterr().out
    # Of the two scenes, the first has three fingers (the environment's): one learned grip.
    assert "(19 trajectories)" in out.strip().splitlines()[-1]
    assert "learned" in out
    argv = ["verify", "--agreement", "--trajectory", "--policy", "equal-k"]
    assert main([*argv, "--out", str(tmp_path)]) == 2
    assert "saved model" in capsys.readouterr().err


def test_verify_drives_a_run_with_its_own_env_kwargs(tmp_path, capsys):
    from grasp_env_agents.run.config import config_from_dict, save_config
    from grasp_env_agents.studies.grips import model_env, model_setup

    run = tmp_path / "run"
    run.mkdir()
    config = {"env_id": "grasp_env/CubeGrasp4-v0", "env_kwargs": {"k_max_ratio": 10.0}}
    config["total_timesteps"] = 1024
    save_config(config_from_dict(config), run / "config.yaml")
    model = model_setup(run, None, None)
    env = model_env(model)
    # the grip the model commands is the one its run trained with (k_max = 10 w)
    assert (model.env_id, env.unwrapped.k_max_ratio) == ("grasp_env/CubeGrasp4-v0", 10.0)
    assert not env.unwrapped.terminate_on_slip  # the whole trajectory is verified
    # the paper's three fingers cannot be placed on its four: refused, not ignored
    argv = ["verify", "--policy", str(run), "--offsets", "0.1,0,0,0,0,0", "--out", str(tmp_path)]
    assert main(argv) == 2
    assert "--offsets places the paper's three fingers" in capsys.readouterr().err
    # a study whose scenes have none of its four fingers says so before any rollout
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "1", "--policy", str(run)]
    assert main([*argv, "--out", str(tmp_path)]) == 2
    assert "no scene of the study has the model's 4 fingers" in capsys.readouterr().err


def test_verify_rejects_a_missing_model(tmp_path, capsys):
    status = main(["verify", "--policy", str(tmp_path / "none.zip"), "--out", str(tmp_path)])
    assert status == 2
    assert "is not a file" in capsys.readouterr().err


def test_an_agreement_study_that_misses_says_why_it_exits_1(capsys):
    from grasp_env_agents.commands.verify import _verdict
    from grasp_env_agents.studies.agreement import agreement

    holds = np.array([True, True, False, False])
    far = np.array([1.0, 1.0, 1.0, 0.01])  # deg from the edge
    assert _verdict(agreement(holds, holds, far)) == 0
    assert capsys.readouterr().out == ""
    assert _verdict(agreement(holds, np.array([True, False, False, True]), far)) == 1
    assert "exit 1: 1 of the 3 verdicts at >= 0.05 deg from the edge disagree" in (
        capsys.readouterr().out
    )
