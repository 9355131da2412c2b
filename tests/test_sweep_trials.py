"""Sweeps on Ray Tune: trials, resume, interrupts, and a two-trial sweep on a local Ray."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from sweep_helpers import TINY, write

from grasp_env_agents.studies import results, sweep


def test_a_key_the_config_refuses_fails_before_any_trial(tmp_path: Path) -> None:
    write(tmp_path / "tiny.yaml", TINY)
    path = write(
        tmp_path / "sweep.yaml",
        {"config": "tiny.yaml", "space": {"ppo.n_epoch": {"grid": [1, 2]}}},
    )
    with pytest.raises(ValueError, match="n_epoch"):
        sweep.check_space(sweep.load_sweep(path))


@pytest.mark.parametrize(
    ("rounds", "phases", "finished"),
    [
        (0, [("initial", 0), ("ppo", 128)], False),
        (0, [("initial", 0), ("ppo", 128), ("ppo", 256)], True),
        # the imitation's 200 labelled states come first: 200 + 128 is not 256 PPO steps
        (2, [("initial", 0), ("imitation", 100), ("imitation", 200), ("ppo", 328)], False),
        (2, [("initial", 0), ("imitation", 100), ("imitation", 200), ("ppo", 456)], True),
        (2, [("initial", 0), ("imitation", 100)], False),  # a round short, no PPO yet
    ],
)
def test_a_trial_counts_as_finished_only_after_its_rounds_and_steps(
    tmp_path: Path, rounds: int, phases: list[tuple[str, int]], finished: bool
) -> None:
    from grasp_env_agents.run.config import config_from_dict
    from grasp_env_agents.run.curve import FIELDS

    imitation = {"imitation": {"rounds": rounds, "samples_per_round": 100}} if rounds else {}
    config = config_from_dict(TINY | imitation)
    (tmp_path / "model.zip").write_bytes(b"")  # written on an interrupt too: not the test
    with (tmp_path / "learning_curve.csv").open("w", newline="") as file:
        writer = csv.DictWriter(file, FIELDS, restval="0")
        writer.writeheader()
        writer.writerows({"phase": phase, "env_steps": steps} for phase, steps in phases)
    assert sweep._finished(tmp_path, config) is finished


def test_a_trial_run_again_keeps_its_training_and_its_evaluation(tmp_path, monkeypatch) -> None:
    """After a killed driver Tune runs finished trials again: they trained nothing but were
    evaluated again (minutes each on 2,048 scenes)."""
    from ray import tune

    from grasp_env_agents.commands import train
    from grasp_env_agents.run.curve import FIELDS
    from grasp_env_agents.studies import evaluation

    calls = []
    monkeypatch.setattr(train, "train", lambda *a, **k: calls.append("train"))
    monkeypatch.setattr(evaluation, "evaluate_run", lambda *a, **k: calls.append("evaluate"))
    monkeypatch.setattr(results, "read_run", lambda *a: results.RunResult(Path(), 0, {}, 1, 1))
    monkeypatch.setattr(tune, "report", lambda metrics: calls.append("report"))

    class Context:
        def get_trial_name(self) -> str:
            return "trial_0"

    monkeypatch.setattr(tune, "get_context", Context)
    run = tmp_path / "runs" / "trial_0"
    run.mkdir(parents=True)
    write(run / "config.yaml", TINY)
    (run / "model.zip").write_bytes(b"")
    with (run / "learning_curve.csv").open("w", newline="") as file:
        writer = csv.DictWriter(file, FIELDS, restval="0")
        writer.writeheader()
        writer.writerow({"phase": "ppo", "env_steps": 256})  # finished
    write(tmp_path / "tiny.yaml", TINY)
    study = sweep.load_sweep(write(tmp_path / "sweep.yaml", {"config": "tiny.yaml", "episodes": 4}))
    (results.evaluation_dir(run, 4)).mkdir()
    (results.evaluation_dir(run, 4) / "report.md").write_text("")
    sweep.run_trial({}, study, str(tmp_path))
    assert calls == ["report"]
    (results.evaluation_dir(run, 4) / "report.md").unlink()  # killed while evaluating
    sweep.run_trial({}, study, str(tmp_path))
    assert calls == ["report", "evaluate", "report"]


def test_every_value_a_search_can_draw_is_checked_before_any_trial(tmp_path: Path) -> None:
    """A bad value after a choice's first failed only inside trials, with Ray's tracebacks."""
    write(tmp_path / "tiny.yaml", TINY)
    for space, bad in (
        ({"ppo.n_epochs": {"choice": [1, 0]}}, "n_epochs"),
        ({"ppo.n_epochs": {"randint": [1, 2000]}}, "n_epochs"),  # high - 1 is drawn
        ({"ppo.gamma": {"uniform": [0.5, 1.5]}}, "gamma"),
    ):
        settings = {"config": "tiny.yaml", "search": "random", "num_samples": 4, "space": space}
        study = sweep.load_sweep(write(tmp_path / "sweep.yaml", settings))
        with pytest.raises(ValueError, match=bad):
            sweep.check_space(study)
    settings["space"] = {"ppo.n_epochs": {"choice": [1, 2]}, "ppo.gamma": {"uniform": [0, 1]}}
    sweep.check_space(sweep.load_sweep(write(tmp_path / "sweep.yaml", settings)))


def test_a_sweep_folder_holds_one_sweep(tmp_path: Path) -> None:
    """An edited sweep file run into the same --out restored the old experiment silently."""
    write(tmp_path / "tiny.yaml", TINY)
    settings = {"config": "tiny.yaml", "seeds": [0, 1], "space": {"ppo.n_epochs": 1}}
    out = tmp_path / "out"
    sweep.check_same_sweep(sweep.load_sweep(write(tmp_path / "sweep.yaml", settings)), out)
    assert (out / "sweep.yaml").is_file()
    sweep.check_same_sweep(sweep.load_sweep(tmp_path / "sweep.yaml"), out)  # the same: resumes
    edited = {**settings, "seeds": [0, 1, 2], "space": {"ppo.n_epochs": 2}}
    with pytest.raises(ValueError, match=r"holds another sweep \(its sweep.yaml differs in seeds,"
                       r" space\)"):  # fmt: skip
        sweep.check_same_sweep(sweep.load_sweep(write(tmp_path / "sweep.yaml", edited)), out)
    write(tmp_path / "tiny.yaml", {**TINY, "n_envs": 8})  # the base config edited
    with pytest.raises(ValueError, match=r"differs in base_config\)"):
        sweep.check_same_sweep(sweep.load_sweep(write(tmp_path / "sweep.yaml", settings)), out)


class FakeResult:
    """What Tune's ResultGrid yields for a trial."""

    def __init__(self, config: dict, run_dir: Path | None) -> None:
        self.config, self.error = config, None
        self.metrics = {} if run_dir is None else {"run_dir": str(run_dir)}


def fake_sweep(tmp_path: Path, monkeypatch, results: list[FakeResult]) -> Path:
    """A sweep file whose Tune experiment yields ``results`` (no Ray, no training)."""
    import ray

    write(tmp_path / "tiny.yaml", TINY)
    settings = {"config": "tiny.yaml", "search": "random", "num_samples": 3, "seeds": [0],
                "episodes": 4, "space": {"ppo.n_epochs": {"choice": [1, 2]}}}  # fmt: skip
    monkeypatch.setattr(ray, "init", lambda **_: None)
    monkeypatch.setattr(ray, "shutdown", lambda: None)

    class Experiment:
        def fit(self) -> list[FakeResult]:
            return results

    monkeypatch.setattr(sweep, "tuner", lambda *_: Experiment())
    return write(tmp_path / "sweep.yaml", settings)


def test_an_interrupted_sweep_says_how_to_resume(tmp_path: Path, monkeypatch, capsys) -> None:
    """Ctrl-C: Tune stopped cleanly and the report died on KeyError: 'run_dir'."""
    from grasp_env_agents import cli

    done = FakeResult({"ppo.n_epochs": 1, "seed": 0}, tmp_path / "trial_1")
    path = fake_sweep(tmp_path, monkeypatch, [done, FakeResult({"seed": 0}, None)])
    argv = ["sweep", str(path), "--out", str(tmp_path / "out"), "--num-cpus", "1"]
    assert cli.main(argv) == 130
    assert (
        "interrupted: 1 of 2 trials unfinished: run the same command again to resume the sweep"
    ) in capsys.readouterr().err


def test_sigterm_stops_a_sweep_as_ctrl_c_does(tmp_path: Path, monkeypatch) -> None:
    """SIGTERM to the driver: Ray's handler printed a stack address and exited 1; as SIGINT,
    Tune stops its trials cleanly (here, without Tune: Python's KeyboardInterrupt)."""
    import os
    import signal

    path = fake_sweep(tmp_path, monkeypatch, [])

    class Terminated:
        def fit(self) -> list:
            os.kill(os.getpid(), signal.SIGTERM)
            return []

    monkeypatch.setattr(sweep, "tuner", lambda *_: Terminated())
    before = signal.getsignal(signal.SIGTERM)
    # Python's own SIGINT handler (earlier tests' Ray may have left another in place)
    interrupt = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            sweep.sweep(path, tmp_path / "out", num_cpus=1)
    finally:
        signal.signal(signal.SIGINT, interrupt)
    assert signal.getsignal(signal.SIGTERM) is before  # restored


def test_a_point_a_random_search_draws_twice_is_reported_once(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    """The report refused the sweep's own repeats as "the same experiment run twice"."""
    runs = {name: tmp_path / name for name in ("trial_1", "trial_2", "trial_3")}
    metrics = {"mean_gap_deg": 1.0, "p90_gap_deg": 2.0, "success_rate": 0.5}
    read = {d: results.RunResult(d, 0, metrics, 1.0, 1.0) for d in runs.values()}
    monkeypatch.setattr(results, "read_run", lambda run_dir, _: read[Path(run_dir)])
    monkeypatch.setattr(results, "plot_curves", lambda groups, path: None)
    drawn = [
        FakeResult({"ppo.n_epochs": 2, "seed": 0}, runs["trial_1"]),
        FakeResult({"ppo.n_epochs": 1, "seed": 0}, runs["trial_2"]),
        FakeResult({"ppo.n_epochs": 2, "seed": 0}, runs["trial_3"]),  # trial_1 again
    ]
    path = fake_sweep(tmp_path, monkeypatch, drawn)
    groups = sweep.sweep(path, tmp_path / "out", num_cpus=1)
    assert {g.label: [r.run_dir.name for r in g.runs] for g in groups} == {
        "ppo.n_epochs=2": ["trial_1"],
        "ppo.n_epochs=1": ["trial_2"],
    }
    assert "trial_3 repeats trial_1 (ppo.n_epochs=2, seed 0): reported once" in (
        capsys.readouterr().out
    )


@pytest.mark.slow
def test_two_trial_sweep_on_a_local_ray_then_resumed(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    write(tmp_path / "tiny.yaml", TINY)
    path = write(
        tmp_path / "sweep.yaml",
        {
            "config": "tiny.yaml",
            "episodes": 4,  # not the runs' own eval_episodes: the report must use these
            "seeds": [0],
            "space": {"ppo.learning_rate": {"grid": [1e-4, 3e-4]}, "torch_threads": 1},
        },
    )
    out = tmp_path / "out"
    groups = sweep.sweep(path, out, num_cpus=2)

    runs = sorted((out / "runs").iterdir())
    assert len(runs) == 2
    rates = set()
    for run in runs:  # each trial a training run of its own, with checkpoints
        assert (run / "model.zip").is_file()
        assert sorted(p.name for p in (run / "checkpoints").glob("ppo_*_steps.zip"))
        config = yaml.safe_load((run / "config.yaml").read_text())
        rates.add(config["ppo"]["learning_rate"])
        with (run / "evaluation-4-scenes" / "comparison.csv").open() as file:
            agent = next(r for r in csv.DictReader(file) if r["policy"] == "trained agent")
        assert int(agent["episodes"]) == 4
        (reported,) = [r for g in groups for r in g.runs if r.run_dir == run]
        assert reported.metrics["mean_gap_deg"] == float(agent["mean_gap_deg"])
    assert rates == {1e-4, 3e-4}
    assert sorted(len(g.runs) for g in groups) == [1, 1]
    report = (out / "results.md").read_text()
    assert "ppo.learning_rate=0.0001" in report and "ppo.learning_rate=0.0003" in report
    # grouped by the searched key alone, the config named without the machine's path
    assert "torch_threads" not in report and str(tmp_path) not in report
    assert "| `tiny.yaml` |" in report
    assert (out / "learning_curves.png").stat().st_size > 10_000

    # the same command again restores the finished experiment: nothing is trained again
    stamps = {run: (run / "model.zip").stat().st_mtime_ns for run in runs}
    sweep.sweep(path, out, num_cpus=2)
    assert {run: (run / "model.zip").stat().st_mtime_ns for run in runs} == stamps


@pytest.mark.slow
def test_evaluate_several_runs_reports_across_seeds(tmp_path: Path) -> None:
    from grasp_env_agents import cli
    from grasp_env_agents.commands.train import train
    from grasp_env_agents.run.config import config_from_dict

    runs = []
    for seed in (0, 1):
        config = config_from_dict({**TINY, "seed": seed, "total_timesteps": 128})
        runs.append(tmp_path / f"tiny-s{seed}")
        train(config, runs[-1], progress_bar=False)
    out = tmp_path / "across"
    argv = ["evaluate", *map(str, runs), "--episodes", "4", "--physics-episodes", "0"]
    assert cli.main([*argv, "--out", str(out)]) == 0
    for run in runs:  # each run's own report, in its evaluation folder (not replaced by --out)
        assert (run / "evaluation-4-scenes" / "comparison.csv").is_file()
    with (out / "results.csv").open() as file:
        rows = list(csv.DictReader(file))
    assert sorted(int(r["seed"]) for r in rows) == [0, 1]
    assert {r["group"] for r in rows} == {"tiny-s"}  # one recipe: the configs differ in the seed
    gaps = [float(r["mean_gap_deg"]) for r in rows]
    report = (out / "results.md").read_text()
    assert f"| tiny-s | `{runs[0] / 'config.yaml'}` | 2 |" in report
    # the IQM of two runs is their mean (both are the middle half)
    assert f"{np.mean(gaps):.2f}" in report
    assert (out / "learning_curves.png").stat().st_size > 10_000

    # a results spec: the trained agents and, from the same evaluations, a baseline's row
    spec = write(
        tmp_path / "spec.yaml",
        {
            "episodes": 4,
            "groups": [
                {"label": "tiny", "config": "tiny.yaml", "runs": "tiny-s*"},
                {"label": "equal k", "runs": "tiny-s*", "policy": "equal k (paper eq. 8)"},
            ],
        },
    )
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{results.BEGIN}\nold\n{results.END}\n")
    argv = ["results", str(spec), "--out", str(tmp_path / "table"), "--readme", str(readme)]
    assert cli.main(argv) == 0
    with (runs[0] / "evaluation-4-scenes" / "comparison.csv").open() as file:
        equal_k = next(r for r in csv.DictReader(file) if r["policy"] == "equal k (paper eq. 8)")
    rows = {r.split("|")[1].strip(): r for r in readme.read_text().splitlines() if "|" in r}
    assert f"{float(equal_k['mean_gap_deg']):.2f} [" in rows["equal k"]
    assert rows["equal k"].rstrip(" |").endswith("none | none")  # a baseline has no training
    assert f"{np.mean(gaps):.2f} [" in rows["tiny"] and "none" not in rows["tiny"]

    # run records (docs/records): the runs without models, checkpoints and logs give the same
    # table; a run with neither a model nor that evaluation is no run
    table = readme.read_text()
    for run in runs:
        (run / "model.zip").unlink()
        shutil.rmtree(run / "checkpoints")
        shutil.rmtree(run / "tb")
    readme.write_text(f"intro\n{results.BEGIN}\nold\n{results.END}\n")
    assert cli.main(argv) == 0
    assert readme.read_text() == table
    shutil.rmtree(runs[1] / "evaluation-4-scenes")
    assert results.expand_runs("tiny-s*", tmp_path, 4) == [runs[0]]
