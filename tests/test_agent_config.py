"""The agents' configs and the command line's checks of its input."""

from __future__ import annotations

import types
from pathlib import Path

import pytest
import yaml
from agent_helpers import TINY, tiny

from grasp_env_agents import cli
from grasp_env_agents.commands.train import train
from grasp_env_agents.run.config import CONFIG_DIR, load_config, save_config


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"learning_rate": 1e-3}, "unknown config key 'learning_rate'"),
        ({"ppo": {"lr": 1e-3}}, "unknown config key 'ppo.lr'"),
        ({"n_envs": "4"}, "n_envs must be a valid integer"),
        ({"n_envs": 0}, r"n_envs must be in \[1"),
        ({"seed": 1.5}, "seed must be a valid integer"),
        ({"normalize": "yes"}, "normalize must be a valid boolean"),
        ({"ppo": {"gamma": 1.5}}, r"ppo.gamma must be in \[0.0, 1.0\]"),
        ({"ppo": {"learning_rate": "fast"}}, "ppo.learning_rate must be a valid number"),
        ({"policy": {"net_arch": [16, "wide"]}}, r"policy.net_arch\[1\] must be a valid integer"),
        (
            {"policy": {"activation": "gelu"}},
            "policy.activation must be 'tanh', 'relu' or 'silu', got 'gelu'",
        ),
        ({"imitation": {"rounds": 0}}, r"imitation.rounds must be in \[1"),
        ({"imitation": [1]}, "imitation must be a valid dictionary"),
        ({"imitation": {"label_weight": 0}}, "imitation has nothing to fit: label_weight and"),
        ({"env_id": "grasp_env/CubeGrab-v0"}, "env_id: 'grasp_env/CubeGrab-v0' is not a grasp_env"),
        # registered with gymnasium, but not ours: it used to fail deep inside SB3
        ({"env_id": "CartPole-v1"}, "env_id: 'CartPole-v1' is not a grasp_env environment"),
        (
            {"policy": {"output": "force_directions"}},
            "policy.output: force_directions needs policy.features: grasp",
        ),
        # an SB3 assertion before
        ({"n_envs": 1, "ppo": {"n_steps": 1}}, r"ppo.n_steps \* n_envs must be >= 2.*got 1 \* 1"),
        # "trained" nothing and reported a trained agent before
        ({"total_timesteps": 0, "imitation": None}, "nothing to train: total_timesteps is 0"),
        ({"ppo": {"learning_rate": float("nan")}}, "ppo.learning_rate must be a finite number"),
        ({"ppo": {"target_kl": 0}}, r"ppo.target_kl must be in \(0.0, 10.0\], got 0"),
        ({"policy": {"net_arch": []}}, "policy.net_arch: List should have at least 1 item"),
    ],
)
def test_config_errors_name_the_key(changes, message):
    with pytest.raises(ValueError, match=message):
        tiny(**changes)


def test_config_lists_every_problem():
    with pytest.raises(ValueError, match="3 problems") as error:
        tiny(n_envs=-1, ppo={"gamma": 2, "n_steps": 0})
    lines = str(error.value).splitlines()[1:]
    assert [line.split()[0] for line in lines] == ["n_envs", "ppo.n_steps", "ppo.gamma"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "is empty: a config sets at least env_id and total_timesteps"),
        ("# only a comment\n", "is empty"),
        ("n_envs: 3\n", "2 problems:\n  env_id: missing.*\n  total_timesteps: missing"),
        (
            "env_id: grasp_env/CubeGrasp-v0\ntotal_timesteps: 64\n"
            "ppo:\n  n_steps: 4\n  n_steps: 8\n",
            "line 5: duplicate key 'n_steps' \\(first given on line 4\\)",
        ),
        ("- a list\n", "must be a mapping of keys to values"),
        ("env_id: [unclosed\n", "is not valid YAML"),
    ],
)
def test_config_file_errors(tmp_path, text, message):
    path = tmp_path / "config.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        load_config(path)


def test_config_numbers_as_yaml_writes_them(tmp_path):
    # PyYAML follows YAML 1.1, where 3e-4 and 1e6 are strings: they are numbers here.
    path = tmp_path / "config.yaml"
    path.write_text(
        "env_id: grasp_env/CubeGrasp-v0\ntotal_timesteps: 1e6\nppo:\n  learning_rate: 3e-4\n"
    )
    config = load_config(path)
    assert config.total_timesteps == 1_000_000
    assert config.ppo.learning_rate == pytest.approx(3e-4)
    with pytest.raises(ValueError, match=r"total_timesteps must be a valid integer, got 1\.5"):
        tiny(total_timesteps=1.5)
    with pytest.raises(ValueError, match="n_envs must be a valid integer, got '4'"):
        tiny(n_envs="4")


def test_config_overrides_by_dotted_key(tmp_path):
    save_config(tiny(), tmp_path / "config.yaml")
    config = load_config(tmp_path / "config.yaml", {"seed": 9, "ppo.n_epochs": 3})
    assert (config.seed, config.ppo.n_epochs, config.ppo.n_steps) == (9, 3, 32)
    with pytest.raises(ValueError, match=r"unknown config key 'ppo\.epochs'"):
        load_config(tmp_path / "config.yaml", {"ppo.epochs": 3})
    assert tiny().replace(seed=4) == tiny(seed=4)


def test_config_round_trips_through_yaml(tmp_path):
    config = tiny(imitation={"rounds": 2, "epochs": 3})
    save_config(config, tmp_path / "config.yaml")
    assert load_config(tmp_path / "config.yaml") == config


@pytest.mark.parametrize("path", sorted(CONFIG_DIR.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_configs_load(path):
    config = load_config(path)
    assert config.env_id.startswith("grasp_env/")


def test_unknown_env_keyword_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match=r"env_kwargs for grasp_env/CubeGrasp-v0.*grip_strength"):
        train(tiny(env_kwargs={"grip_strength": 2}), tmp_path / "run", progress_bar=False)


def test_cli_reports_a_bad_config_cleanly(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({**TINY, "n_env": 4}))
    assert cli.main(["train", "--config", str(path), "--run-dir", str(tmp_path / "r")]) == 2
    assert "unknown config key 'n_env'" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["reproduce", "--out", ""],
        ["train", "--run-dir", " "],
        ["results", ""],
        ["gait", "--out", ""],
    ],
)
def test_cli_refuses_an_empty_path(argv, tmp_path, monkeypatch, capsys):
    """An empty --out or run directory would write into the working directory unasked."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    assert stop.value.code == 2
    assert "an empty path" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_shipped_configs_by_name_from_any_directory(tmp_path, monkeypatch):
    """--config NAME finds the shipped config wherever the command runs (and paths still work)."""
    import grasp_env_agents.commands.train as training

    started = []

    def record(config, run_dir, **_):
        started.append((config, run_dir))

    monkeypatch.setattr(training, "train", record)
    report = types.SimpleNamespace(markdown="(the comparison)")
    monkeypatch.setattr("grasp_env_agents.studies.evaluation.evaluate_run", lambda run: report)
    monkeypatch.chdir(tmp_path)  # no configs/ here
    assert cli.main(["train", "--config", "dagger", "--run-dir", "run"]) == 0
    ((config, run_dir),) = started
    assert config == load_config(CONFIG_DIR / "dagger.yaml") and run_dir == Path("run")
    assert cli.main(["train", "--config", "no-such-config"]) == 2


@pytest.mark.parametrize(
    "argv",
    [
        ["reproduce", "--out", "afile"],
        ["train", "--run-dir", "afile/run"],
        ["gait", "--out", "afile"],
    ],
)
def test_cli_refuses_an_output_folder_in_a_files_way(argv, tmp_path, monkeypatch, capsys):
    """Refused before any work (it was an OSError, exit 1, after the computation)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("")
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    assert stop.value.code == 2
    assert "cannot be a folder: a file is in the way" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


@pytest.mark.parametrize(
    ("argv", "error"),
    [
        (["verify", "--agreement", "--seed", "-1"], "argument --seed: must be an integer >= 0"),
        (
            ["verify", "--agreement", "--trajectory", "--scenes", "1e12"],
            "argument --scenes: must be an integer in [1, 100000], got '1e12'",
        ),
        (["evaluate", "run", "--episodes", "2.5"], "argument --episodes: must be an integer >= 1"),
        (["sweep", "s.yaml", "--num-cpus", "0"], "argument --num-cpus: must be an integer >= 1"),
        (["train", "--total-timesteps", "nan"], "argument --total-timesteps: must be an integer"),
    ],
)
def test_cli_counts_name_their_option(argv, error, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    assert stop.value.code == 2 and error in capsys.readouterr().err


def test_cli_counts_are_written_as_configs_write_them():
    from grasp_env_agents.cli import integer_argument

    assert [integer_argument(0)(text) for text in ("1000", "1_000", "1e3", "0")] == [1000] * 3 + [0]


def test_cli_override_errors_name_the_override(tmp_path, capsys):
    argv = ["train", "--config", "dagger", "--run-dir", str(tmp_path / "r")]
    assert cli.main([*argv, "--total-timesteps", "1e13"]) == 2  # above the config's range
    err = capsys.readouterr().err
    assert "dagger.yaml' with total_timesteps=10000000000000: total_timesteps must be" in err
    assert not (tmp_path / "r").exists()
