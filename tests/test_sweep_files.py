"""Sweep files and results specs: their checks, overrides, and the shipped studies."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from sweep_helpers import TINY, write

from grasp_env_agents.studies import results, sweep


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
