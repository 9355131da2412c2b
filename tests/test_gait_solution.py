"""Finger gaits: the certified gait on the default scene, the long trajectories that need
phasing, and ``grasp-env gait`` (docs/gait.md, "The certificate", "Results")."""

from __future__ import annotations

from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_TURN,
    VERTICAL_TURN,
    GaitScene,
    Hand,
    Trajectory,
    scene_grasp,
    solve_gait,
)

GAP = 1e-9  # radians: the solver's certificate
GAIT_ID = "grasp_env/CubeGait-v0"
MOVES_ID = "grasp_env/CubeGaitMoves-v0"

# ------------------------------------------------------------- the mechanics of a gait


@pytest.fixture(scope="module")
def coarse():
    """The paper's axis over [-90, 90] deg in 3 deg steps."""
    return solve_gait(trajectory=Trajectory(PAPER_TURN.axis, -90.0, 90.0, 3.0))


def test_gait_keeps_the_rules(coarse):
    gait = coarse.optimal
    hand, scene = coarse.hand, coarse.scene
    rotations = coarse.trajectory.rotations()
    normals = np.einsum("tij,nj->tni", rotations, scene.normals)
    reach = hand.reach(normals)  # from the rotated normals, not from site_reach
    for t in range(len(rotations)):
        fingers = np.flatnonzero(gait.contacts[t] >= 0)
        assert all(reach[t, f, gait.contacts[t, f]] for f in fingers)  # touching: reachable
        assert 3 <= gait.loaded[t].sum() <= 4
        assert set(np.flatnonzero(gait.loaded[t])) <= set(fingers)
        assert len(fingers) - gait.loaded[t].sum() <= 1  # at most one finger changing
        if t:
            was, now = gait.contacts[t - 1], gait.contacts[t]
            changed = np.flatnonzero(was != now)  # a lift at t - 1 and a placement at t
            for f in changed:  # lifted at t - 1 with zero force, and/or placed at t with none
                assert was[f] < 0 or not gait.loaded[t - 1, f]
                assert now[f] < 0 or not gait.loaded[t, f]


def test_gait_grips_balance_the_load(coarse):
    """At every pose the loaded fingers' forces at the certified grip balance the load and
    their friction angles give the pose's margin; unloaded fingers carry nothing."""
    gait = coarse.optimal
    k, angles = coarse.grips(gait)
    scene, rotations = coarse.scene, coarse.trajectory.rotations()
    limit = scene.friction_limit
    for t in range(len(rotations)):
        fingers = np.flatnonzero(gait.loaded[t])
        sites = gait.contacts[t, fingers]
        order = np.argsort(sites)
        g = scene_grasp(scene.scene(sites[order]), rotations[t])
        F = scene.scene(sites[order]).n_contacts
        pairs = list(combinations(range(5), 2))
        finger_pairs = [tuple(sorted((fingers[order][i], fingers[order][j])))
                        for i, j in combinations(range(F), 2)]  # fmt: skip
        kt = np.array([k[t, pairs.index(p)] for p in finger_pairs])
        P = g.forces(kt)
        np.testing.assert_allclose(P.sum(axis=0), [0, 0, scene.weight], atol=1e-9)
        torque = np.cross(g.positions, P).sum(axis=0)
        np.testing.assert_allclose(torque, 0, atol=1e-9)
        # a finger the optimum releases (|P_i| ~ 1e-10 w, the cone's apex) has no meaningful
        # direction; every other finger's angle is recomputed exactly
        pushing = np.linalg.norm(P, axis=1) > 1e-6 * scene.weight
        assert pushing.sum() >= 3
        reported = angles[t, fingers[order]]
        np.testing.assert_allclose(g.angles(kt)[pushing], reported[pushing], atol=1e-9)
        assert np.isclose(limit - reported.max(), gait.margins[t], atol=1e-12)
        assert np.all(np.isnan(angles[t, np.flatnonzero(~gait.loaded[t])]))
        unused = [q for q, p in enumerate(pairs) if p not in finger_pairs]
        assert np.all(k[t, unused] == 0)
        assert np.all(np.abs(kt) <= 2 * scene.weight + 1e-12)


def test_certified_on_the_default_scene(coarse):
    assert coarse.holds and 0 <= coarse.gap <= GAP
    assert coarse.optimal.margin <= coarse.bound <= coarse.optimal.margin + GAP
    assert abs(coarse.bound_gait.margin - coarse.optimal.margin) <= GAP
    v = coarse.values
    assert np.all(v.margin <= v.margin_bound)
    usable = np.isfinite(v.margin)
    assert np.all(v.margin_bound[usable] - v.margin[usable] <= GAP)


@pytest.mark.parametrize("trajectory", [PAPER_TURN, VERTICAL_TURN], ids=["paper", "vertical"])
def test_long_trajectories_need_phasing(trajectory):
    """No fixed set of fingers stays reachable and holding, a gait does; the greedy choice
    does not."""
    solution = solve_gait(trajectory=trajectory)
    assert solution.fixed.margin < 0
    assert solution.optimal.margin > np.deg2rad(5)
    assert solution.optimal.changes > 0
    assert solution.greedy.margin < solution.optimal.margin
    # friction alone does not force it: ignoring reach, some fixed set holds throughout
    assert solution.values.margin.min(axis=0).max() > 0


# ------------------------------------------------------------------------- the command


def test_gait_command(tmp_path, capsys):
    import csv

    from grasp_env_agents.cli import main

    out = tmp_path / "gait"
    assert main(["gait", "--out", str(out), "--alpha-step", "10"]) == 0
    printed = capsys.readouterr().out
    assert "optimal gait: worst margin" in printed and "greedy gait" in printed
    assert (out / "gait.png").stat().st_size > 10_000
    rows = list(csv.DictReader((out / "gait.csv").open()))
    assert [float(r["alpha_deg"]) for r in rows] == list(range(-90, 91, 10))
    names = Hand().names
    for row in rows:
        loaded = [n for n in names if row[f"theta_{n}_deg"]]
        assert 3 <= len(loaded) <= 4
        assert all(row[f"site_{n}"] for n in loaded)  # a loaded finger touches a site
        theta = max(float(row[f"theta_{n}_deg"]) for n in loaded)
        assert np.isclose(float(row["theta_max_deg"]), theta, atol=1e-7)
        limit = np.rad2deg(np.arctan(0.5))
        assert np.isclose(float(row["margin_deg"]), limit - theta, atol=1e-7)
        assert row["status"] in ("interior", "boundary", "not_pushing")
    assert any(row["event"] for row in rows)  # it phases fingers


def test_gait_command_refuses_bad_options(capsys):
    from grasp_env_agents.cli import main

    assert main(["gait", "--cone", "200", "--no-plots"]) == 2
    assert "cone_deg" in capsys.readouterr().err
    assert main(["gait", "--k-max", "-1", "--no-plots"]) == 2


def test_gait_command_refuses_when_no_gait_holds(tmp_path, capsys):
    """A gait that drops somewhere is a result (the greedy one does); no gait at all is not:
    a message naming the options, not NaN and an empty table."""
    from grasp_env_agents.cli import main

    out = tmp_path / "gait"
    for option in (["--cone", "1e-9"], ["--finger-elevation", "90"]):
        argv = ["gait", "--no-plots", "--no-thumb", "--alpha-step", "10", "--out", str(out)]
        assert main([*argv, *option]) == 2
        printed = capsys.readouterr()
        assert "nan" not in printed.out and "Optimal gait" not in printed.out
        assert "error: no gait keeps three fingers" in printed.err
        assert all(name in printed.err for name in ("--cone", "--finger-elevation", "--no-thumb"))
        assert not (out / "gait.csv").exists()
    # the mechanics say so, exactly: no optimum, no arbitrary gait, no NaN gap
    trajectory = Trajectory(PAPER_TURN.axis, -90.0, 90.0, 10.0)
    solution = solve_gait(hand=Hand(cone_deg=1e-9), trajectory=trajectory)
    assert not solution.holds and solution.bound == -np.inf and solution.gap == 0.0
    assert (solution.optimal.sets == -1).all() and solution.optimal.changes == 0


def test_gait_command_bounds_k_max(capsys):
    """--k-max within the environments' k_max_ratio range times the weight, checked before
    any solving and named in newtons (beyond it a solve takes minutes)."""
    import argparse

    from grasp_env_agents.cli import main
    from grasp_env_agents.commands import gait as command

    argv = ["gait", "--no-plots", "--alpha-step", "90"]
    assert main([*argv, "--k-max", "1e8"]) == 2
    err = capsys.readouterr().err
    assert "--k-max must be within [0.005, 5000] N (0.001 to 1000 x the weight, 5 N here)" in err
    assert "got 1e+08" in err
    for value in ("0.001", "nan", "inf"):
        assert main([*argv, "--weight", "2", "--k-max", value]) == 2
        assert "--k-max must be within [0.002, 2000] N" in capsys.readouterr().err
    # with --models too: the option and its unit, not the environment's k_max_ratio
    assert main([*argv, "--k-max", "1e5", "--models", "m.zip"]) == 2
    assert "--k-max must be within" in capsys.readouterr().err
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    for value in ("0.005", "5000"):  # the ends are accepted
        command.problem(parser.parse_args(["--k-max", value]))


def test_gait_command_plays_models_beside_the_gaits(tmp_path, capsys, monkeypatch):
    """--models: each policy played on the environment, the optimal and greedy gaits' episodes
    matching the dynamic programme's own figures."""
    import argparse

    import gymnasium as gym
    from stable_baselines3 import PPO

    from grasp_env_agents.cli import main
    from grasp_env_agents.commands import gait as command

    monkeypatch.setenv("COLUMNS", "200")  # rich's width
    model = PPO("MlpPolicy", gym.make(GAIT_ID), n_steps=64, batch_size=64, seed=0)
    model.learn(64)
    # as rl-zoo3 lays out two seeds' runs: the same folder and file names below each log folder
    files = [tmp_path / f"seed{s}" / "ppo" / "CubeGait_1" / "agent.zip" for s in (0, 1)]
    for file in files:
        model.save(file)
    # an agent of the moves-only environment is played there
    moves_model = PPO("MlpPolicy", gym.make(MOVES_ID), n_steps=64, batch_size=64, seed=0)
    moves_model.learn(64)
    files.append(tmp_path / "moves.zip")
    moves_model.save(files[-1])
    argv = ["--alpha-step", "10", "--no-plots", "--out", str(tmp_path / "gait")]
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    args = parser.parse_args([*argv, "--models", *map(str, files)])
    rows = dict(command.compare_models(args))
    solution = solve_gait(GaitScene(), Hand(), Trajectory(PAPER_TURN.axis, -90, 90, 10))
    optimal, greedy = rows["optimal gait (certified)"], rows["greedy gait"]
    assert optimal.held == 19 and optimal.ended_deg is None
    assert abs(optimal.worst - solution.optimal.margin) < 1e-6  # float32 actions
    dropped = np.flatnonzero(solution.greedy.sets < 0)
    assert greedy.held == (dropped[0] if len(dropped) else 19)
    labels = [f"seed{s}/ppo/CubeGait_1/agent.zip" for s in (0, 1)]
    assert all(0 <= rows[label].held <= 19 for label in labels)
    (moves,) = [episode for label, episode in rows.items() if label.endswith("/moves.zip")]
    assert 0 <= moves.held <= 19
    printed = capsys.readouterr().out
    assert "IQM" in printed  # two agents: the aggregate row
    assert all(label in printed for label in labels)  # whole, on a wide terminal
    assert command.model_labels([Path("a/x.zip"), Path("b/x.zip")]) == ["a/x.zip", "b/x.zip"]
    assert command.model_labels([Path("a/x.zip")] * 2) == ["a/x.zip"] * 2  # the same file twice

    assert main(["gait", *argv, "--offsets", ",".join(["0"] * 12), "--models", "m.zip"]) == 2
    assert "drop --offsets" in capsys.readouterr().err
    grasp_model = PPO("MlpPolicy", gym.make("grasp_env/CubeGrasp-v0"), n_steps=64, batch_size=64)
    grasp_model.save(tmp_path / "grasp.zip")
    assert main(["gait", *argv, "--models", str(tmp_path / "grasp.zip")]) == 2
    assert "not a gait agent" in capsys.readouterr().err
