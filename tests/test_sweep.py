"""Sweeps on Ray Tune and results across runs (IQM with bootstrap intervals)."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from grasp_env_agents.studies import results, sweep

TINY = {
    "env_id": "grasp_env/CubeGraspRandom-v0",
    "env_kwargs": {"terminate_on_slip": False},
    "n_envs": 4,
    "seed": 0,
    "total_timesteps": 256,
    "eval_freq": 128,
    "eval_episodes": 8,
    "checkpoint_freq": 128,
    "torch_threads": 1,
    "policy": {"net_arch": [16], "features": "grasp"},
    "ppo": {"n_steps": 32, "batch_size": 64, "n_epochs": 1},
}


def write(path: Path, data: dict | str) -> Path:
    """``data`` as YAML, or a string as the file's text (YAML no dict can give)."""
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


# --- results ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_iqm_is_the_mean_of_the_middle_runs_and_its_interval_a_bootstrap() -> None:
    values = [0.3, 5.0, 0.1, 0.2, 0.4, 0.25, 0.35, 9.0]
    estimate = results.iqm_interval(values)
    # brute force: the mean of the middle half of the sorted runs
    assert estimate.iqm == pytest.approx(np.mean(sorted(values)[2:6]))
    # an independent percentile bootstrap over runs agrees with rliable's interval
    rng = np.random.default_rng(1)
    samples = rng.choice(values, size=(20_000, len(values)))
    iqms = np.sort(samples, axis=1)[:, 2:6].mean(1)
    low, high = np.percentile(iqms, [2.5, 97.5])
    assert estimate.low == pytest.approx(low, abs=0.02)
    assert estimate.high == pytest.approx(high, abs=0.05)
    assert estimate.low <= estimate.iqm <= estimate.high
    np.random.seed(7)  # noqa: NPY002 -- whatever numpy's global generator holds: same runs, same interval
    assert results.iqm_interval(values) == estimate
    assert np.random.randint(1 << 30) == np.random.RandomState(7).randint(1 << 30)  # noqa: NPY002


def test_the_bootstraps_iqm_is_rliables_bit_for_bit() -> None:
    from rliable import metrics

    rng = np.random.default_rng(0)
    for runs in (1, 2, 3, 4, 5, 8, 13, 30):
        for _ in range(50):
            scores = rng.normal(size=(runs, 1)) * 10 ** rng.uniform(-3, 3)
            assert results._aggregate_iqm(scores) == metrics.aggregate_iqm(scores)


def test_iqm_refuses_missing_or_nan_values() -> None:
    with pytest.raises(ValueError, match="finite"):
        results.iqm_interval([0.1, float("nan")])
    with pytest.raises(ValueError, match="at least one run"):
        results.iqm_interval([])


def test_iqm_without_rliable_names_the_extra(monkeypatch) -> None:
    """A bare install (no `results` extra): a clear error, not a ModuleNotFoundError."""
    import sys

    monkeypatch.setitem(sys.modules, "rliable", None)  # import rliable then raises ImportError
    with pytest.raises(ValueError, match=r"grasp-env\[results\]"):
        results.iqm_interval([0.1, 0.2])


def test_the_table_says_the_machine_was_shared_only_of_runs_that_waited() -> None:
    """Every table ended "(CPU below wall: the machine was shared)", of anyone's runs."""
    metrics = {"mean_gap_deg": 0.5, "p90_gap_deg": 1.0, "success_rate": 0.9}

    def group(*minutes: tuple[float, float], policy: str = results.AGENT) -> results.Group:
        runs = [
            results.RunResult(Path(f"r{i}"), i, metrics, wall, cpu)
            for i, (wall, cpu) in enumerate(minutes)
        ]
        return results.Group("g", runs, policy=policy)

    idle = results.table([group((10.0, 9.9))], 8)
    assert idle.endswith("minutes of training from the initial evaluation on.")
    assert "shared" not in idle
    assert results.table([group((30.0, 10.0))], 8).endswith(
        "on (CPU time below 80% of wall time in the run: the machine was shared)."
    )
    # CPU above wall (two threads) is no sign; a baseline's runs (no training of their own)
    # are not counted
    assert results.shared_note([group((10.0, 9.9), (12.0, 12.5))]) == ""
    note = results.shared_note([group((10.0, 9.9), (30.0, 10.0)), group((3, 1), policy="x")])
    assert note == " (CPU time below 80% of wall time in 1 of 2 runs: the machine was shared)"
    assert "in all 2 runs" in results.shared_note([group((10.0, 1.0), (30.0, 10.0))])


def test_replace_table_rewrites_only_between_the_markers(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{results.BEGIN}\nold table\n{results.END}\nafter\n")
    results.replace_table(readme, "| new |")
    assert readme.read_text() == f"intro\n{results.BEGIN}\n| new |\n{results.END}\nafter\n"
    readme.write_text("no markers")
    with pytest.raises(ValueError, match="markers"):
        results.replace_table(readme, "| new |")
    readme.write_text(f"intro\n{results.END}\nold table\n{results.BEGIN}\nafter\n")
    with pytest.raises(ValueError, match=r"README.md: the end marker .* before the begin marker"):
        results.replace_table(readme, "| new |")
    assert "old table" in readme.read_text()


def test_results_checks_the_readme_markers_before_any_evaluation(tmp_path: Path, capsys) -> None:
    from grasp_env_agents import cli

    readme = write(tmp_path / "README.md", f"{results.END}\n{results.BEGIN}\n")
    spec = write(tmp_path / "spec.yaml", {"groups": [{"label": "a", "runs": "no-such-run*"}]})
    assert cli.main(["results", str(spec), "--readme", str(readme)]) == 2
    assert "the end marker" in capsys.readouterr().err  # not: no run directories match


# --- sweep files -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ({"groups": []}, "groups must be a non-empty list"),
        ({"groups": [{"label": "a"}]}, "needs a label and runs"),
        ({"groups": [{"label": "a", "runs": "r*", "seed": 1}]}, "accepts label, config"),
        ({"groups": [{"label": "a", "runs": "r*", "policy": 3}]}, "policy must be a policy"),
        (
            {"final": "curve", "groups": [{"label": "a", "runs": "r*", "policy": "random"}]},
            "needs final: evaluation",
        ),
        ({"episodes": 0, "groups": [{"label": "a", "runs": "r*"}]}, "positive integer"),
        ({"episodes": True, "groups": [{"label": "a", "runs": "r*"}]}, "got True"),
        ({"groups": [{"label": "a", "runs": "r*", "seed": 1}]}, r"unknown key\(s\) \['seed'\]"),
        ({"grops": []}, r"unknown key\(s\) \['grops'\]; accepted keys: \['episodes'"),
        ("groups: [", r"spec.yaml' is not valid YAML: while parsing"),
        ("groups: []\ngroups: [{label: a, runs: r}]\n", "line 2: duplicate key 'groups'"),
    ],
)
def test_bad_results_specs_are_refused_naming_the_key(
    tmp_path: Path, spec: dict, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        results.load_spec(write(tmp_path / "spec.yaml", spec))


def test_overrides_set_dotted_keys_without_touching_the_base() -> None:
    base = {"ppo": {"learning_rate": 1e-3}, "seed": 0}
    out = sweep.with_overrides(base, {"ppo.learning_rate": 1e-4, "policy.net_arch": [8], "seed": 3})
    assert out == {"ppo": {"learning_rate": 1e-4}, "policy": {"net_arch": [8]}, "seed": 3}
    assert base == {"ppo": {"learning_rate": 1e-3}, "seed": 0}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"serach": "grid"}, r"sweep.yaml: unknown key\(s\) \[.serach.\]"),
        ({"search": "bayes"}, "search must be one of"),
        ({"metric": "reward"}, "metric must be one of"),
        ({"seeds": [0, -1]}, "seeds must be"),
        ({"space": {"ppo.learning_rate": {"uniform": [1e-3, 1e-4]}}}, "low < high"),
        ({"space": {"ppo.learning_rate": {"normal": [0, 1]}}}, "must be a plain value or"),
        ({"search": "optuna", "seeds": [0, 1]}, "search the seed as a key"),
        ({"config": "no-such-config"}, "no such file"),
        ({"seeds": [0], "space": {"seed": {"grid": [0, 1]}}}, "given by the seeds key"),
        # one config and seed run twice: the report refuses it as two seeds, after the training
        ({"seeds": [0, 1, 0]}, r"seeds lists \[0\] more than once"),
        ({"space": {"ppo.n_epochs": {"grid": [1, 2, 1]}}}, "space.ppo.n_epochs.grid lists a"),
        ({"num_samples": 2, "seeds": [0, 1]}, "num_samples: 2 repeats every point"),
        ({"num_samples": 3, "space": {"seed": {"grid": [0, 1]}}}, "num_samples: 3 repeats"),
    ],
)
def test_bad_sweep_files_are_refused_naming_the_key(
    tmp_path: Path, change: dict, message: str
) -> None:
    write(tmp_path / "tiny.yaml", TINY)
    path = write(tmp_path / "sweep.yaml", {"config": "tiny.yaml", **change})
    with pytest.raises(ValueError, match=message):
        sweep.load_sweep(path)


def test_a_sweep_repeats_a_space_it_samples(tmp_path: Path) -> None:
    """num_samples > 1 draws new points of a sampled space: accepted (a repeated grid is not)."""
    write(tmp_path / "tiny.yaml", TINY)
    space = {"ppo.n_epochs": {"grid": [1, 2]}, "policy.log_std_init": {"uniform": [-4, -2]}}
    settings = {"config": "tiny.yaml", "num_samples": 3, "seeds": [0, 1], "space": space}
    assert sweep.load_sweep(write(tmp_path / "sweep.yaml", settings))["num_samples"] == 3


def test_runs_of_one_seed_are_not_counted_as_seeds(tmp_path: Path, capsys) -> None:
    """Two runs of one config and seed gave a "2 seeds" IQM with a zero-width interval."""
    from grasp_env_agents import cli

    for name in ("run a", "run b"):
        (tmp_path / name).mkdir()
        write(tmp_path / name / "config.yaml", TINY)
        (tmp_path / name / "model.zip").write_bytes(b"")  # refused before it is read
    a, b = (str(tmp_path / name) for name in ("run a", "run b"))
    argv = ["evaluate", a, b, "--episodes", "2", "--physics-episodes", "0"]
    assert cli.main(argv) == 2
    assert (
        f"grasp-env evaluate: error: runs {a!r} and {b!r} share their config and seed 0: the"
        " same experiment run twice, not two seeds; give runs of distinct seeds"
    ) in capsys.readouterr().err
    groups = [{"label": "t", "runs": "run*"}]
    spec = write(tmp_path / "spec.yaml", {"episodes": 2, "groups": groups})
    assert cli.main(["results", str(spec)]) == 2
    assert f"group 't': runs {a!r} and {b!r} share seed 0:" in capsys.readouterr().err
    assert not list(tmp_path.glob("*/evaluation-*"))  # refused before evaluating either run
    # a group built otherwise (a sweep's report) is refused too, naming the runs
    same = [results.RunResult(Path(name), 4, {}, 0.0, 0.0) for name in ("x", "y", "z")]
    with pytest.raises(ValueError, match=r"runs 'x', 'y' and 'z' share seed 4: .* 3 times"):
        results.Group("g", same)
    # distinct seeds: a group; named by what the runs' names share, not "run " or the first
    write(tmp_path / "run b" / "config.yaml", {**TINY, "seed": 1})
    assert results.group_dirs([Path(a), Path(b)]) == [[Path(a), Path(b)]]
    assert results._common_name([Path(a), Path(b)]) == "run"
    assert results._common_name([Path("first"), Path("second")]) == "first, second"
    # a sweep's trial folders share their prefix across groups: the differing keys name them
    for name, rate, seed in (("trial_0", 1e-4, 0), ("trial_1", 3e-4, 0), ("trial_2", 1e-4, 1)):
        (tmp_path / name).mkdir()
        write(
            tmp_path / name / "config.yaml", {**TINY, "seed": seed, "ppo": {"learning_rate": rate}}
        )
    grouped = results.group_dirs([tmp_path / n for n in ("trial_0", "trial_1", "trial_2")])
    assert results.group_names(grouped) == ["ppo.learning_rate=0.0001", "ppo.learning_rate=0.0003"]


def test_a_group_of_runs_of_different_recipes_is_refused(tmp_path: Path, capsys) -> None:
    """A spec group of a three- and a four-finger run gave one row "2 seeds"."""
    from grasp_env_agents import cli

    four = {**TINY, "env_id": "grasp_env/CubeGrasp4-v0", "seed": 1}
    for name, config in (("run a", TINY), ("run b", four)):
        (tmp_path / name).mkdir()
        write(tmp_path / name / "config.yaml", config)
        (tmp_path / name / "model.zip").write_bytes(b"")  # refused before it is read
    groups = [{"label": "t", "runs": "run*"}]
    spec = write(tmp_path / "spec.yaml", {"episodes": 2, "groups": groups})
    assert cli.main(["results", str(spec)]) == 2
    assert (
        "group 't': its runs' config.yaml differ in env_id, not only in the seed: a group is"
        " one recipe over seeds"
    ) in capsys.readouterr().err
    assert not list(tmp_path.glob("*/evaluation-*"))  # refused before evaluating either run
    # nested keys are named by their dotted path
    write(tmp_path / "run b" / "config.yaml", {**TINY, "seed": 1, "ppo": {"n_steps": 64}})
    with pytest.raises(
        ValueError, match=r"differ in ppo\.batch_size, ppo\.n_epochs, ppo\.n_steps,"
    ):
        results.check_one_recipe("", [tmp_path / "run a", tmp_path / "run b"])
    write(tmp_path / "run b" / "config.yaml", {**TINY, "seed": 1})
    results.check_one_recipe("", [tmp_path / "run a", tmp_path / "run b"])  # seeds only: one


def test_sweep_files_and_specs_are_read_as_configs_are(tmp_path: Path) -> None:
    """The configs' YAML: a key given twice is refused, 1e-4 is a number (in the sweep file
    and in its base config); a directory is no file."""
    write(tmp_path / "tiny.yaml", TINY)
    text = "config: tiny.yaml\nseeds: [0]\nseeds: [1]\n"
    with pytest.raises(ValueError, match=r"sweep\.yaml', line 3: duplicate key 'seeds'"):
        sweep.load_sweep(write(tmp_path / "sweep.yaml", text))
    base = yaml.safe_dump(TINY).replace("ppo:\n", "ppo:\n  learning_rate: 3e-4\n")
    write(tmp_path / "tiny.yaml", base)
    text = "config: tiny.yaml\nspace:\n  policy.log_std_init: {uniform: [-4e0, -2e0]}\n"
    study = sweep.load_sweep(write(tmp_path / "sweep.yaml", text))
    sweep.check_space(study)
    assert sweep.trial_config(study, {}).ppo.learning_rate == 3e-4
    with pytest.raises(ValueError, match="is a directory, not a file"):
        sweep.load_sweep(tmp_path)
    with pytest.raises(ValueError, match="is a directory, not a file"):
        results.load_spec(tmp_path)


def test_more_cpus_per_trial_than_the_local_ray_has_is_refused_before_ray(
    tmp_path: Path, monkeypatch, capsys
) -> None:
    """Ray would leave the trial pending forever; a cluster (--address) is Ray's to judge."""
    import sys

    from grasp_env_agents import cli

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises: refused before it
    write(tmp_path / "tiny.yaml", TINY)
    path = write(tmp_path / "sweep.yaml", {"config": "tiny.yaml", "cpus_per_trial": 2})
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"cpus_per_trial is 2 but the local Ray has 1 CPU"):
        sweep.sweep(path, out, num_cpus=1)
    monkeypatch.setattr(sweep.os, "cpu_count", lambda: 1)
    assert cli.main(["sweep", str(path), "--out", str(out)]) == 2
    assert "cpus_per_trial is 2 but the local Ray has 1 CPU(s) (the machine's" in (
        capsys.readouterr().err
    )
    assert not out.exists()
    with pytest.raises(ImportError):  # an existing cluster: on to Ray
        sweep.sweep(path, out, address="auto")
    assert sweep.local_cpus({"cpus_per_trial": 2}, 2) == 2


STUDIES = Path(__file__).parent.parent / "configs" / "studies"


@pytest.mark.parametrize("path", sorted(STUDIES.glob("*-seeds.yaml")), ids=lambda p: p.name)
def test_the_shipped_studies_load(path: Path) -> None:
    """Every study behind the README's table is a valid sweep of a valid config."""
    study = sweep.load_sweep(path)
    sweep.check_space(study)
    assert study["seeds"] == [0, 1, 2, 3, 4]


def test_the_readme_spec_names_a_study_for_each_group() -> None:
    """The README's spec reads each trained group's records from its study's output."""
    episodes, final, groups = results.load_spec(STUDIES / "readme.yaml")
    assert (episodes, final) == (2048, "evaluation")
    for group in groups:
        study = group["runs"].split("/")[-3]  # ../../docs/records/<study>/runs/*
        assert (STUDIES / f"{study}.yaml").is_file(), group["label"]
        if "config" in group:
            assert sweep.load_sweep(STUDIES / f"{study}.yaml")["config"].endswith(
                Path(group["config"]).name
            )


@pytest.mark.slow
def test_the_readme_table_is_what_the_kept_records_give() -> None:
    """The README's results table is regenerated from docs/records, never typed: five seeds a
    group, and the command's table equals the README's."""
    episodes, groups = results.build_groups(STUDIES / "readme.yaml")
    assert [len(group.runs) for group in groups] == [5] * len(groups)
    readme = (STUDIES.parents[1] / "README.md").read_text()
    kept = readme.split(results.BEGIN, 1)[1].split(results.END, 1)[0]
    assert kept.strip() == results.table(groups, episodes)


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


# --- a sweep on a local Ray ------------------------------------------------------------------


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
