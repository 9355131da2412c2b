"""Results across runs: the IQM with its bootstrap interval, and the README's results table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sweep_helpers import write

from grasp_env_agents.studies import results


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
