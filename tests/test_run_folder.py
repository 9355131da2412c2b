"""A training run's folder (:mod:`grasp_env_agents.run.folder`): the names of its files, which
runs written before keep (the records in docs/records still read), and a round trip: what
``grasp-env train`` writes is where the readers look."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from grasp_env_agents.learning import checkpoints
from grasp_env_agents.learning.models import load_agent
from grasp_env_agents.run.config import config_from_dict, load_config
from grasp_env_agents.run.folder import EvaluationFolder, RunFolder, model_file
from grasp_env_agents.studies import results
from grasp_env_agents.studies.grips import model_name, model_setup

RECORDS = Path(__file__).parents[1] / "docs" / "records"

TINY = {
    "env_id": "grasp_env/CubeGrasp-v0",
    "env_kwargs": {"terminate_on_slip": False},
    "n_envs": 2,
    "seed": 3,
    "total_timesteps": 64,
    "eval_freq": 32,
    "eval_episodes": 2,
    "checkpoint_freq": 32,
    "normalize": True,
    "policy": {"net_arch": [16, 16]},
    "ppo": {"n_steps": 16, "batch_size": 32, "n_epochs": 1},
}


@pytest.mark.fast
def test_the_layout_keeps_the_names_runs_were_written_with(tmp_path):
    run = RunFolder(tmp_path)
    names = {
        "config": run.config,
        "model": run.model,
        "vecnormalize": run.vecnormalize,
        "curve": run.curve,
        "curve_plot": run.curve_plot,
        "checkpoints": run.checkpoints,
        "eval_log": run.eval_log,
        "tensorboard": run.tensorboard,
        "tensorboard_of": run.tensorboard_of("ppo"),
        "checkpoint": run.checkpoint("td3", 2048),
        "imitation_checkpoint": run.imitation_checkpoint(3),
        "round_data": run.round_data(3),
        "evaluation": run.evaluation(2048).path,
        "report": run.evaluation(2048).report,
        "comparison": run.evaluation(2048).comparison,
        "grip_plot": run.evaluation(2048).grip_plot,
        "own_report": run.own_evaluation.report,
    }
    assert {key: path.relative_to(tmp_path).as_posix() for key, path in names.items()} == {
        "config": "config.yaml",
        "model": "model.zip",
        "vecnormalize": "vecnormalize.pkl",
        "curve": "learning_curve.csv",
        "curve_plot": "learning_curve.png",
        "checkpoints": "checkpoints",
        "eval_log": "eval",
        "tensorboard": "tb",
        "tensorboard_of": "tb/ppo",
        "checkpoint": "checkpoints/td3_2048_steps.zip",
        "imitation_checkpoint": "checkpoints/imitation_round_3.zip",
        "round_data": "checkpoints/imitation_round_3.npz",
        "evaluation": "evaluation-2048-scenes",
        "report": "evaluation-2048-scenes/report.md",
        "comparison": "evaluation-2048-scenes/comparison.csv",
        "grip_plot": "evaluation-2048-scenes/grip_along_alpha.png",
        "own_report": "report.md",
    }
    # the checkpoints' own names, parsed back by the module that writes them
    assert checkpoints.checkpoint_steps(run.checkpoint("sac", 96)) == 96
    assert checkpoints.model_checkpoint(tmp_path, "ppo", 0) == run.checkpoint("ppo", 0)
    assert checkpoints.imitation_checkpoint(tmp_path, 1) == run.imitation_checkpoint(1)
    assert results.evaluation_dir(tmp_path, 16) == run.evaluation(16).path


@pytest.mark.fast
def test_the_folder_is_a_value():
    assert RunFolder("runs/a") == RunFolder(Path("runs/a"))  # a str becomes a Path
    assert isinstance(RunFolder("runs/a").path, Path)
    assert len({RunFolder("runs/a"), RunFolder(Path("runs/a"))}) == 1
    with pytest.raises(AttributeError):
        RunFolder("runs/a").path = Path("runs/b")  # frozen
    assert EvaluationFolder("out").report == Path("out/report.md")


@pytest.mark.fast
def test_a_model_file_names_its_run_only_as_model_zip(tmp_path):
    assert RunFolder.of_model(tmp_path / "model.zip") == RunFolder(tmp_path)
    assert RunFolder.of_model(tmp_path / "checkpoints" / "ppo_64_steps.zip") is None
    assert RunFolder.of_model(tmp_path / "agent.zip") is None
    assert model_file(tmp_path) == tmp_path / "model.zip"  # a folder: its model
    assert model_file(tmp_path / "agent.zip") == tmp_path / "agent.zip"
    assert model_name(tmp_path / "model.zip") == tmp_path.name
    assert model_name(tmp_path / "agent.zip") == "agent"


@pytest.mark.fast
def test_what_a_folder_holds(tmp_path):
    run = RunFolder(tmp_path / "run")
    assert not (run.is_run() or run.is_finished() or run.is_record(4))
    run.path.mkdir()
    run.config.write_text("seed: 2\n")
    assert run.is_run() and not run.is_finished() and not run.is_record(4)
    run.curve.write_text("phase,env_steps\n")
    run.evaluation(4).path.mkdir()
    run.evaluation(4).comparison.write_text("policy\n")
    assert run.is_record(4) and not run.is_record(8)  # an evaluation on 4 scenes only
    run.model.write_bytes(b"")
    assert run.is_finished()
    assert results.run_seed(run.path) == 2


@pytest.mark.fast
@pytest.mark.parametrize("study", sorted(p.name for p in RECORDS.iterdir() if p.is_dir()))
def test_the_kept_records_still_read(study):
    """Every run record in docs/records (written before this module) is a record to the
    readers: its config loads, its curve and its evaluation on 2048 scenes are found."""
    runs = results.expand_runs(f"{study}/runs/*", RECORDS, 2048)
    assert len(runs) == 5
    for run_dir in runs:
        run = RunFolder(run_dir)
        assert run.is_run() and run.is_record(2048) and not run.is_finished()
        assert load_config(run.config).seed == results.run_seed(run_dir)
        result = results.read_run(run_dir, 2048)  # no evaluation needed: it reads the record
        assert 0.0 <= result.metrics["success_rate"] <= 1.0
        assert result.curve and result.wall_minutes > 0


def test_a_tiny_run_writes_where_the_readers_look(tmp_path):
    """``grasp-env train`` writes every file of the layout; the readers (the agent's loader,
    ``--resume``'s checkpoint search, ``verify``'s run set-up, the results) read them back."""
    from grasp_env_agents.commands.train import train

    config = config_from_dict(TINY)
    model = train(config, tmp_path / "run", progress_bar=False)
    run = RunFolder(tmp_path / "run")
    written = [run.config, run.model, run.vecnormalize, run.curve, run.curve_plot]
    written += [run.eval_log / "evaluations.npz", run.checkpoint("ppo", 64)]
    assert [path for path in written if not path.is_file()] == []
    assert run.tensorboard_of("ppo").is_dir()
    assert run.is_run() and run.is_finished()

    assert load_config(run.config) == config
    agent = load_agent(run.path)
    assert agent.normalizer is not None  # vecnormalize.pkl found beside model.zip
    obs = np.zeros((1, *model.observation_space.shape), np.float32)
    np.testing.assert_array_equal(
        agent.model.predict(obs, deterministic=True)[0],
        model.predict(obs, deterministic=True)[0],
    )
    start = checkpoints.find_start(run.path, config.normalize, 0)
    assert (start.checkpoint, start.model_steps) == (run.checkpoint("ppo", 64), 64)
    assert start.vecnormalize is not None and start.vecnormalize.is_file()
    setup = model_setup(run.model, None, None)  # verify --policy RUN/model.zip
    assert (setup.algo, setup.env_id) == ("ppo", config.env_id)
    curve = results.read_curve(run.curve)
    assert curve[-1]["env_steps"] == 64

    # kept as a record (no model, checkpoints or logs), with an evaluation copied in
    evaluation = next(RECORDS.glob("default-seeds/runs/*/evaluation-2048-scenes"))
    shutil.copytree(evaluation, run.evaluation(2048).path)
    for kept in (run.model, run.vecnormalize):
        kept.unlink()
    shutil.rmtree(run.checkpoints)
    shutil.rmtree(run.tensorboard)
    assert results.expand_runs("run", tmp_path, 2048) == [run.path]
    with pytest.raises(ValueError, match="no run directories match"):
        results.expand_runs("run", tmp_path, 16)  # no evaluation on 16 scenes, no model
    assert results.read_run(run.path, 2048).seed == TINY["seed"]
