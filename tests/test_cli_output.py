"""What the commands print and when they check: tables whole in a log, forces readable at any
accepted weight, weights outside the range refused, ``gait --models`` checked before the work,
``grasp-env bench``'s closing line."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import warnings
from importlib import resources

import numpy as np
import pytest

from grasp_env.mechanics import PHI, Scene, Trajectory
from grasp_env_agents.cli import main
from grasp_env_agents.commands import bench
from grasp_env_agents.commands.reproduce import newtons, run_sweep, theta1_figure, trend_figure

OFFSETS = ["--offsets", "0.3,0.1,-0.2,0.3,0.1,-0.3", "--cg-offset", "0.05,0,0.1"]


def table_rows(printed: str) -> list[list[str]]:
    """The cells of a rich table's body rows."""
    return [
        [cell.strip() for cell in line.split("│")[1:-1]]
        for line in printed.splitlines()
        if line.startswith("│")
    ]


@pytest.mark.parametrize("columns", [None, "80"])
def test_reproduce_table_is_whole_in_a_log(tmp_path, capsys, monkeypatch, columns):
    """stdout is not a terminal (a log): every cell whole, even with COLUMNS exported (rich cut
    the angles to "16.14…" at its default 80 columns)."""
    if columns is None:
        monkeypatch.delenv("COLUMNS", raising=False)
    else:
        monkeypatch.setenv("COLUMNS", columns)
    argv = ["reproduce", *OFFSETS, "--alpha-step", "5", "--no-plots", "--out", str(tmp_path)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "…" not in printed
    rows = table_rows(printed)
    saved = list(csv.DictReader((tmp_path / "sweep.csv").open()))
    assert len(rows) == len(saved) == 7
    for cells, row in zip(rows, saved, strict=True):
        assert cells[1:4] == [newtons(float(row[k])) for k in ("k12", "k13", "k23")]
        angles = [f"{float(row[f'theta{i}_deg']):.4f}" for i in (1, 2, 3)]
        assert cells[4:7] == angles
    assert rows[0][4] == "16.1449"  # alpha = -15 deg, the audit's example


def test_verify_lines_are_not_wrapped_in_a_log(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    assert main(["verify", "--alphas=-1,1,1", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    (line,) = [line for line in printed.splitlines() if line.startswith("MuJoCo: holds at")]
    assert line.endswith(f"plot {tmp_path / 'verify.png'}")  # one line, not wrapped at 80
    assert len(table_rows(printed)) == 3


@pytest.mark.parametrize("weight", [1e-6, 1e6])
def test_k_reads_at_the_ends_of_the_weight_range(tmp_path, capsys, weight):
    """k scales with the weight: 5 significant digits where 4 decimals printed 0.0000 (1e-6)
    or cut 1360827.6345 to "13608…"; the plots stay right and quiet."""
    argv = ["reproduce", "--weight", f"{weight:g}", "--out", str(tmp_path)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main([*argv, "--alpha-start", "0", "--alpha-end", "0"]) == 0
    # ours and matplotlib's (the record also catches other threads', e.g. an earlier test's)
    quiet = [w for w in caught if "grasp_env" in w.filename or "matplotlib" in w.filename]
    assert [(str(w.message), w.filename, w.lineno) for w in quiet] == []
    ((_alpha, *cells),) = table_rows(capsys.readouterr().out)
    eq8 = newtons(weight * np.tan(PHI) / (3 * np.sqrt(3)))  # every k_ij at alpha = 0
    assert eq8.startswith("2.7217e") and cells[:3] == [eq8] * 3

    sweep = run_sweep(Scene(weight=weight), Trajectory())
    figure = theta1_figure(sweep)
    assert f"k23 = {newtons(sweep.optimum.k[15, 2])} N" in figure.texts[0].get_text()
    # the k curves coincide or vanish relative to the weight, not to 1 N
    k_axis = trend_figure(sweep).axes[1]
    assert [t.get_text() for t in k_axis.texts] == ["the lines coincide: k13 = k23 throughout"]


@pytest.mark.parametrize("command", ["reproduce", "verify", "gait"])
@pytest.mark.parametrize("weight", ["1e300", "1e-300"])
@pytest.mark.fast
def test_weights_outside_the_range_are_refused(tmp_path, capsys, command, weight):
    out = tmp_path / "out"
    with pytest.raises(SystemExit, match="2"):
        main([command, "--weight", weight, "--out", str(out)])
    captured = capsys.readouterr()
    assert "argument --weight: must be in [1e-06, 1e+06] N" in captured.err
    assert captured.out == "" and not out.exists()


def test_gait_checks_models_before_solving(tmp_path, capsys):
    import gymnasium as gym
    from stable_baselines3 import PPO

    import grasp_env  # noqa: F401  (registers the environments)

    out = tmp_path / "gait"
    argv = ["gait", "--alpha-start", "-5", "--alpha-end", "5", "--no-plots", "--out", str(out)]
    missing = tmp_path / "nonexistent.zip"
    assert main([*argv, "--models", str(missing)]) == 2
    captured = capsys.readouterr()
    assert f"{missing}: no such model file" in captured.err
    assert "solved in" not in captured.out and not out.exists()

    grasp_model = tmp_path / "grasp.zip"  # a grasp agent observes (32,), the gait env (110,)
    PPO("MlpPolicy", gym.make("grasp_env/CubeGrasp-v0"), n_steps=64, batch_size=64).save(
        grasp_model
    )
    out.mkdir()
    (out / "gait.csv").write_text("an earlier run's\n")
    assert main([*argv, "--models", str(grasp_model)]) == 2
    captured = capsys.readouterr()
    assert f"{grasp_model}: the model observes (32,)" in captured.err
    assert "not a gait agent" in captured.err
    assert "solved in" not in captured.out
    assert (out / "gait.csv").read_text() == "an earlier run's\n"  # not overwritten


# ------------------------------------------------------------------------------ bench

FAKE = {
    "bench_fast.py": """
import sys
from grasp_env_agents.commands.bench import Targets
targets = Targets("fast")
print("speed 1 op/s, target >= 2:", targets.check("speed >= 2 op/s", False))
print("size 1, target <= 3:", targets.check("size <= 3", True))
sys.exit(targets.exit_code())
""",
    "bench_good.py": """
import sys
from grasp_env_agents.commands.bench import Targets
targets = Targets("good")
print("rate:", targets.check("rate >= 1", True))
sys.exit(targets.exit_code())
""",
    "bench_crash.py": "raise RuntimeError('the benchmark broke')\n",
    "bench_solver.py": "import sys\nprint('solver argv:', sys.argv[1:])\n",
}


@pytest.fixture
def fake_benchmarks(tmp_path, monkeypatch):
    """A package of four tiny benchmarks in place of grasp_env_agents.benchmarks."""
    package = tmp_path / "fake_grasp_benchmarks"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for name, text in FAKE.items():
        (package / name).write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    path = os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))
    monkeypatch.setenv("PYTHONPATH", path)
    monkeypatch.setattr(bench, "PACKAGE", package.name)
    return package.name


def test_bench_says_last_which_targets_were_missed(fake_benchmarks, capfd):
    assert main(["bench", "good"]) == 0
    assert "exit code" not in capfd.readouterr().out

    assert main(["bench", "fast", "good"]) == 1
    lines = capfd.readouterr().out.splitlines()
    assert "speed 1 op/s, target >= 2: MISSED" in lines
    assert lines[-1] == "exit code 1: 1 target missed (fast: speed >= 2 op/s)"
    assert sum("exit code" in line for line in lines) == 1  # the benchmark left it to bench

    assert main(["bench"]) == 1  # all three: a failure is not called a missed target
    assert capfd.readouterr().out.splitlines()[-1] == (
        "exit code 1: 1 target missed (fast: speed >= 2 op/s); failed without a verdict on"
        " its targets: crash (exit code 1)"
    )


def test_bench_passes_contacts_to_the_solver_benchmark_alone(fake_benchmarks, capfd):
    assert main(["bench", "solver", "--contacts", "6,8", "--seconds", "0.5"]) == 0
    assert "solver argv: ['--seconds', '0.5', '--contacts', '6,8']" in capfd.readouterr().out
    assert main(["bench", "good", "--contacts", "6"]) == 2
    assert "--contacts applies to the solver benchmark alone" in capfd.readouterr().err
    assert main(["bench", "--contacts", "6"]) == 2  # all of them: not the solver's alone


def test_a_benchmark_on_its_own_says_why_it_exits_1(fake_benchmarks):
    env = {k: v for k, v in os.environ.items() if k != bench.MISSED_FILE}
    command = [sys.executable, "-m", f"{fake_benchmarks}.bench_fast"]
    done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    assert done.returncode == 1
    assert done.stdout.splitlines()[-1] == "exit code 1: 1 target missed (fast: speed >= 2 op/s)"


def test_the_benchmarks_judge_their_targets_through_targets():
    """One place gives the verdicts and the closing line: no benchmark spells MISSED itself."""
    files = [f for f in resources.files(bench.PACKAGE).iterdir() if f.name.startswith("bench_")]
    assert {"bench_envs.py", "bench_solver.py"} <= {f.name for f in files}
    for file in files:
        text = file.read_text()
        assert "MISSED" not in text, file.name
        assert ("Targets(" in text) == ("target" in text.lower()), file.name
