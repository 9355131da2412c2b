"""The verify and evaluate commands: their options and refusals."""

from __future__ import annotations

from pathlib import Path

import pytest
from agent_helpers import TINY

from grasp_env_agents import cli
from grasp_env_agents.run.config import config_from_dict, load_config, save_config


def saved_run(folder: Path, algo: str = "ppo", env_id: str = TINY["env_id"]) -> Path:
    """A run directory as grasp-env train leaves it, without the training: its config.yaml
    and an untrained ``algo`` model of ``env_id``."""
    import gymnasium as gym

    from grasp_env_agents.learning.models import ALGORITHMS

    folder.mkdir()
    settings = {**TINY, "algo": algo, "env_id": env_id}
    if algo != "ppo":
        del settings["ppo"]
    save_config(config_from_dict(settings), folder / "config.yaml")
    extra = {} if algo == "ppo" else {"buffer_size": 64}
    model = ALGORITHMS[algo]("MlpPolicy", gym.make(env_id), seed=0, device="cpu", **extra)
    model.save(folder / "model.zip")
    return folder


def test_verify_takes_the_algorithm_from_the_run(tmp_path, capsys):
    """It failed to rebuild a TD3 run's model as PPO's unless given --algo td3."""
    run = saved_run(tmp_path / "td3-run", "td3")
    out = tmp_path / "out"
    assert cli.main(["verify", "--policy", str(run), "--out", str(out)]) == 0
    assert "MuJoCo: holds at" in capsys.readouterr().out
    argv = ["verify", "--trajectory", "--policy", str(run / "model.zip"), "--out", str(out)]
    assert cli.main([*argv, "--algo", "td3"]) == 0
    assert "trajectory: analytic" in capsys.readouterr().out
    assert cli.main([*argv, "--algo", "ppo"]) == 2
    err = capsys.readouterr().err
    assert f"--algo ppo: the run {run} was trained with algo: td3" in err
    assert cli.main([*argv, "--algo", "dqn"]) == 2
    assert "--algo must be one of ppo, td3, sac, got 'dqn'" in capsys.readouterr().err
    # and the environment: a four-finger run is driven by the four-finger env without --env
    four = saved_run(tmp_path / "four", env_id="grasp_env/CubeGrasp4-v0")
    assert cli.main(["verify", "--policy", str(four), "--out", str(out)]) == 0
    assert "MuJoCo: holds at" in capsys.readouterr().out


@pytest.mark.parametrize("env_id", ["bogus", "CartPole-v1", "grasp_env/CubeGait-v0"])
def test_verify_refuses_an_env_that_cannot_drive_a_model(tmp_path, capsys, env_id):
    """A traceback from gymnasium or the environment before (NameNotFound, TypeError about
    terminate_on_slip, AttributeError 'faces')."""
    argv = ["verify", "--policy", str(tmp_path), "--env", env_id, "--out", str(tmp_path / "o")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--env must be one of grasp_env/CubeGrasp-v0, " in err and f"got {env_id!r}" in err
    assert "grasp_env/CubeGrasp4-v0" in err
    assert not (tmp_path / "o").exists()


def test_verify_says_when_the_model_does_not_fit_the_env(tmp_path, capsys):
    """SB3's "Unexpected observation shape" before."""
    run = saved_run(tmp_path / "run")
    argv = ["verify", "--policy", str(run), "--env", "grasp_env/CubeGrasp4-v0"]
    assert cli.main([*argv, "--out", str(tmp_path / "out")]) == 2
    assert (
        "--env grasp_env/CubeGrasp4-v0 does not fit the model: the model observes (32,) and acts"
        " in (3,), grasp_env/CubeGrasp4-v0 observes (38,) and acts in (6,)"
    ) in capsys.readouterr().err


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--algo", "td3"], "--algo is for a saved model: use it with --policy PATH"),
        (["--env", "grasp_env/CubeGrasp-v0"], "--env is for a saved model"),
        (["--policy", "equal-k", "--env", "bogus"], "--env is for a saved model"),
        (["--agreement", "--algo", "ppo"], "--algo is for a saved model"),
        (["--seed", "3"], "--seed is for the agreement studies: use it with --agreement"),
        (["--policy", "equal-k", "--seed", "3"], "--seed is for the agreement studies"),
    ],
)
def test_verify_refuses_options_it_would_ignore(tmp_path, capsys, options, message):
    """--algo, --env and --seed were silently ignored without a saved model (or a study)."""
    assert cli.main(["verify", *options, "--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_evaluate_refuses_a_run_given_twice(tmp_path, capsys, monkeypatch):
    """It evaluated the run twice and reported "seeds 2"."""
    run = saved_run(tmp_path / "run")
    (tmp_path / "link").symlink_to(run)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["evaluate", "run", "run/", "--episodes", "1"]) == 2
    assert "RUN run is given twice: give each run once" in capsys.readouterr().err
    assert cli.main(["evaluate", "run", str(run), "link", "--episodes", "1"]) == 2
    assert f"RUN run is given twice (as run and {run})" in capsys.readouterr().err
    assert cli.main(["evaluate", "link", "./run", "--episodes", "1"]) == 2
    assert "RUN link is given twice (as link and run)" in capsys.readouterr().err
    assert not list(run.glob("evaluation-*"))


def test_evaluate_names_a_model_that_does_not_fit_its_runs_environment(tmp_path, capsys):
    """SB3's "Unexpected observation shape (2, 38)" named neither the file nor the cause."""
    run = saved_run(tmp_path / "run")  # a three-finger model
    config = load_config(run / "config.yaml")
    save_config(config.replace(env_id="grasp_env/CubeGrasp4-v0"), run / "config.yaml")
    assert cli.main(["evaluate", str(run), "--episodes", "2"]) == 2
    assert (
        f"{run / 'model.zip'} does not fit its run's environment (config.yaml): the model"
        " observes (32,) and acts in (3,), grasp_env/CubeGrasp4-v0 observes (38,) and acts in"
        " (6,)"
    ) in capsys.readouterr().err
    assert cli.main(["evaluate", str(tmp_path / "nowhere")]) == 2
    assert "is not a grasp-env train run directory (it has no config.yaml)" in (
        capsys.readouterr().err
    )


@pytest.mark.parametrize("episodes", ["0", "-3", "1048577", "99999999999"])
def test_evaluate_checks_episodes_up_front(tmp_path, capsys, episodes):
    """It named an internal num_envs for too many before."""
    run = saved_run(tmp_path / "run")
    try:
        code = cli.main(["evaluate", str(run), "--episodes", episodes])
    except SystemExit as stop:  # below 1: refused by argparse
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err
    assert "--episodes" in err and ("[1, 1048576]" in err or "integer >= 1" in err)
    assert not list(run.glob("evaluation-*"))


def test_cli_help_is_the_usage_alone():
    """--help prints no progress line while the command's libraries load (about 2 s)."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "grasp_env_agents.cli", "train", "--help"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert done.stdout.startswith("usage: grasp-env train") and done.stderr == ""
