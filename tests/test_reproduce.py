"""``grasp-env reproduce``: the paper's experiment from the command line."""

import csv
import math

import numpy as np
import pytest

from grasp_env.mechanics import PHI
from grasp_env_agents.cli import main


def read_sweep(path):
    with (path / "sweep.csv").open() as file:
        return list(csv.DictReader(file))


def test_paper_sweep(tmp_path, capsys):
    assert main(["reproduce", "--out", str(tmp_path)]) == 0
    rows = read_sweep(tmp_path)
    assert [float(r["alpha_deg"]) for r in rows] == list(range(-15, 16))
    for column in ("k12", "k13", "k23", "theta1_deg", "theta2_deg", "theta3_deg", "theta_max_deg"):
        assert column in rows[0]
    # the paper's exact scene: pure normal forces balance the weight at every alpha
    assert max(float(r["theta_max_deg"]) for r in rows) <= 1e-6
    # eq. 8 at alpha = 0: every k_ij = w tan(phi) / (3 sqrt 3) = 1.3608 for w = 5
    centre = rows[15]
    for name in ("k12", "k13", "k23"):
        assert float(centre[name]) == pytest.approx(1.3608, abs=5e-5)
        assert float(centre[name]) == pytest.approx(5 * math.tan(PHI) / (3 * math.sqrt(3)))
    # k13 = k23 by the scene's mirror symmetry, and k12 grows with alpha (the trend plot)
    k12 = np.array([float(r["k12"]) for r in rows])
    np.testing.assert_allclose([float(r["k13"]) for r in rows], [float(r["k23"]) for r in rows])
    assert np.all(np.diff(k12) > 0)
    for name in ("trend.png", "theta1_grid.png"):
        assert (tmp_path / name).stat().st_size > 20_000
    assert "wrote" in capsys.readouterr().out


@pytest.mark.parametrize("weight", [1.0, 12.5])
def test_eq8_for_any_weight(tmp_path, weight):
    out = tmp_path / str(weight)
    args = ["reproduce", "--out", str(out), "--weight", str(weight), "--no-plots"]
    assert main([*args, "--alpha-start", "0", "--alpha-end", "0"]) == 0
    (row,) = read_sweep(out)
    expected = weight * math.tan(PHI) / (3 * math.sqrt(3))
    for name in ("k12", "k13", "k23"):
        assert float(row[name]) == pytest.approx(expected, rel=1e-7)


def test_moved_contacts_break_the_zero_angle(tmp_path):
    """Off the face centres the normal lines no longer meet at g: the optimum is > 0, and the
    three angles are equal there (the paper's closing observation)."""
    args = ["reproduce", "--out", str(tmp_path), "--no-plots", "--alpha-step", "5"]
    assert main([*args, "--offsets", "0.3,0.1,-0.2,0.3,0.1,-0.3", "--cg-offset", "0.05,0,0.1"]) == 0
    for row in read_sweep(tmp_path):
        angles = [float(row[f"theta{i}_deg"]) for i in (1, 2, 3)]
        assert 5 < max(angles) < 40
        assert max(angles) - min(angles) < 1e-6


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--weight", "0"], "weight"),
        (["--mu", "-1"], "mu"),
        (["--mu", "1e-4"], "--mu: must be in [0.001, 1000]"),
        (["--mu", "nan"], "--mu: must be in [0.001, 1000]"),
        (["--k-max", "-2"], "--k-max"),
        (["--alpha-step", "0"], "alpha_step_deg"),
        (["--offsets", "0.99,0,0,0,0,1.5"], "offset"),
    ],
)
def test_bad_options_give_clear_errors(tmp_path, capsys, args, message):
    try:
        code = main(["reproduce", "--out", str(tmp_path), "--no-plots", *args])
    except SystemExit as stop:  # refused by argparse, before the command runs
        code = stop.code
    assert code == 2
    err = capsys.readouterr().err
    assert "error" in err
    assert message in err


@pytest.mark.parametrize("command", ["verify", "gait"])
def test_mu_has_the_environments_range_in_every_command(tmp_path, capsys, command):
    # verify --policy EXPERT took mu 1e-4, which its --policy RUN's environment refuses
    with pytest.raises(SystemExit) as stop:
        main([command, "--out", str(tmp_path), "--mu", "1e-4"])
    assert stop.value.code == 2
    assert "--mu: must be in [0.001, 1000], got '1e-4'" in capsys.readouterr().err
