"""Finger gaits: the hand's reach, the dynamic programme against brute force over all gaits,
the certificate, and the long trajectories that need phasing (docs/gait.md)."""

from __future__ import annotations

from itertools import combinations, permutations
from pathlib import Path

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_TURN,
    START_ROTATION,
    VERTICAL_TURN,
    GaitScene,
    Hand,
    Trajectory,
    best_fixed,
    bottleneck_bound,
    gait_states,
    greedy_gait,
    optimal_gait,
    scene_grasp,
    site_sets,
    solve_gait,
)
from grasp_env.mechanics.hand import FINGER_ELEVATION_DEG

GAP = 1e-9  # radians: the solver's certificate

# ------------------------------------------------------------------------------ the hand


def test_default_hand():
    hand = Hand()
    assert hand.n_fingers == 5
    assert hand.names == ("finger1", "finger2", "finger3", "finger4", "thumb")
    a = hand.approach
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0)
    np.testing.assert_allclose(a[-1], [0, 0, -1])  # the thumb pushes straight down
    np.testing.assert_allclose(np.rad2deg(np.arcsin(a[:4, 2])), FINGER_ELEVATION_DEG)
    np.testing.assert_allclose(FINGER_ELEVATION_DEG, 35.26439, atol=1e-5)
    # at the start pose finger 1 pushes exactly along the corner face -x's inward normal
    np.testing.assert_allclose(START_ROTATION @ [1.0, 0.0, 0.0], a[0], atol=1e-12)


@pytest.mark.parametrize("cone", [10.0, 60.0, 120.0])
def test_reach_is_the_cone_of_normals(cone):
    hand = Hand(finger_azimuths_deg=(30.0,), finger_elevation_deg=20.0, thumb=False, cone_deg=cone)
    a = hand.approach[0]
    # normals at angles cone - 0.01 and cone + 0.01 deg from the approach, about any axis
    rng = np.random.default_rng(0)
    side = np.cross(a, rng.normal(size=(50, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    for delta, inside in ((-0.01, True), (0.01, False)):
        angle = np.deg2rad(cone + delta)
        normals = np.cos(angle) * a + np.sin(angle) * side
        assert np.all(hand.reach(normals)[0] == inside)
    assert hand.reach(a[None])[0, 0]


def test_reach_is_batched():
    hand = Hand()
    normals = np.random.default_rng(1).normal(size=(7, 2, 6, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    reach = hand.reach(normals)
    assert reach.shape == (7, 2, 5, 6)
    cosine = normals @ hand.approach.T  # (7, 2, 6, 5)
    np.testing.assert_array_equal(reach, np.swapaxes(cosine, -1, -2) >= 0.5 - 1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cone_deg": 0.0}, "cone_deg"),
        ({"cone_deg": 180.0}, "cone_deg"),
        ({"finger_elevation_deg": 91.0}, "elevation"),
        ({"finger_azimuths_deg": ()}, "azimuths"),
        ({"finger_azimuths_deg": (0.0, np.nan)}, "azimuths"),
        ({"finger_azimuths_deg": "abc"}, "azimuths"),
        ({"finger_azimuths_deg": tuple(range(6))}, "at most 6"),
        # refused, not converted: "no" is truthy, "123" three fingers at 1, 2 and 3 deg
        ({"thumb": "no"}, "thumb must be True or False, got 'no'"),
        ({"thumb": 1}, "thumb must be True or False, got 1"),
        ({"finger_azimuths_deg": "123"}, "finger_azimuths_deg must be a sequence"),
        ({"finger_azimuths_deg": (0.0, True)}, r"finger_azimuths_deg must be .* booleans"),
        ({"finger_azimuths_deg": 30.0}, "finger_azimuths_deg must be a sequence"),
        ({"cone_deg": "60"}, r"cone_deg must be a finite number in \(0, 180\), got '60'"),
        ({"cone_deg": True}, r"cone_deg must be a finite number in \(0, 180\), got True"),
        ({"cone_deg": None}, r"cone_deg must be a finite number in \(0, 180\), got None"),
        ({"finger_elevation_deg": "30"}, r"finger_elevation_deg must be .* in \[-90, 90\]"),
    ],
)
def test_bad_hands(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Hand(**kwargs)


def test_hands_take_numpy_numbers():
    hand = Hand(np.array([0, 90, 180]), np.float32(30), np.bool_(False), np.int64(45))
    assert hand.finger_azimuths_deg == (0.0, 90.0, 180.0) and hand.thumb is False
    assert type(hand.finger_elevation_deg) is float and hand.cone_deg == 45.0


def test_bad_reach_inputs():
    with pytest.raises(ValueError, match="shape"):
        Hand().reach(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        Hand().reach(np.full((2, 3), np.nan))


# ------------------------------------------------------------------------------ the scene


def test_default_scene_has_a_site_per_face():
    scene = GaitScene()
    assert scene.n_sites == 6
    np.testing.assert_array_equal(np.abs(scene.normals).sum(axis=1), 1)
    np.testing.assert_array_equal(np.abs(scene.normals).sum(axis=0), 2)  # +-x, +-y, +-z
    # the inward normal points into the box from the site's face
    assert np.all(np.sum(scene.normals * scene.sites, axis=1) < 0)


@pytest.mark.parametrize(
    ("sites", "match"),
    [
        (np.zeros((2, 3)), "shape"),
        (np.zeros((9, 3)), "shape"),
        ([[0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.7]], "face"),
        ([[0.5, 0, 0], [0, 0.5, 0], [0.5, 0.5, 0]], "face"),  # on an edge
        ([[0.5, 0, 0], [0, 0.5, 0], [0, 0.5, 0]], "coincide"),
        ([[0.5, 0, 0], [0, 0.5, 0], [0, 0, np.nan]], "finite"),
    ],
)
def test_bad_sites(sites, match):
    with pytest.raises(ValueError, match=match):
        GaitScene(sites=np.array(sites, dtype=float))


def test_bad_scene_values():
    with pytest.raises(ValueError, match="mu"):
        GaitScene(mu=0.0)
    with pytest.raises(ValueError, match="inside the box"):
        GaitScene(cg_offset=(0.6, 0, 0))
    # strings are refused, not converted to numbers
    with pytest.raises(ValueError, match=r"offsets must be an array of shape \(6, 2\)"):
        GaitScene.on_faces(offsets=[["0.1", "0.1"]] * 6)
    with pytest.raises(ValueError, match=r"offsets must be .* booleans"):
        GaitScene.on_faces(offsets=[[True, 0.1]] * 6)
    with pytest.raises(ValueError, match="faces must be a sequence"):
        GaitScene.on_faces(faces="-x-y-z", offsets=[])


# ----------------------------------------------------------------- brute force, all gaits


def touching(a):
    return [f for f, s in enumerate(a) if s >= 0]


def brute_force(margin, reach, start=None):
    """The best (smallest margin, -moves, sum of margins) over every gait, by enumeration.

    Written from the rules in the gait module's docstring, not from its tables: at each pose
    every touching finger must reach its site; the move is to keep (all touching fingers
    carry load), lift a touching finger (zero force now, gone next) or place a free finger on
    a free site it reaches now (zero force now, loaded next); 3 or 4 fingers touch, 3 or 4
    carry load.
    """
    T, F, N = reach.shape
    index = {s: i for i, s in enumerate(site_sets(N))}
    best = (-np.inf, 0, 0.0)

    def walk(t, a, low, moves, total):
        nonlocal best
        if t == T:
            best = max(best, (low, -moves, total))
            return
        if any(not reach[t, f, a[f]] for f in touching(a)):
            return  # a touching finger lost its site
        options = [(None, a)]
        for f in range(F):
            if a[f] >= 0:
                options.append(((f, "lift"), (*a[:f], -1, *a[f + 1 :])))
            elif len(touching(a)) < 4:  # at most four fingers touch
                for s in range(N):
                    if s not in a and reach[t, f, s]:
                        options.append(((f, "place"), (*a[:f], s, *a[f + 1 :])))
        for move, after in options:
            lifted = move is not None and move[1] == "lift"
            loaded = sorted(a[f] for f in touching(a) if not (lifted and f == move[0]))
            if not 3 <= len(loaded) <= 4:
                continue
            value = margin[t, index[tuple(loaded)]]
            walk(t + 1, after, min(low, value), moves + (move is not None), total + value)

    starts = [tuple(start)] if start is not None else []
    if start is None:
        for count in (3, 4):
            for fingers in combinations(range(F), count):
                for sites in permutations(range(N), count):
                    a = [-1] * F
                    for f, s in zip(fingers, sites, strict=True):
                        a[f] = s
                    starts.append(tuple(a))
    for a in starts:
        walk(0, a, np.inf, 0, 0.0)
    return best


def random_case(rng):
    """Small problems with ties (integer margins), unusable sets and patchy reach."""
    F = int(rng.integers(3, 6))
    N = int(rng.integers(3, 6 if F < 5 else 5))
    T = int(rng.integers(1, 6 if F * N <= 12 else 4))
    sets = len(site_sets(N))
    margin = rng.integers(-2, 4, (T, sets)).astype(float)
    margin[:, rng.random(sets) < 0.15] = -np.inf  # unusable sets (collinear, coplanar)
    reach = rng.random((T, F, N)) < rng.uniform(0.5, 0.95)
    return margin, reach


def objective(gait):
    return (gait.margin, -gait.changes, float(gait.margins.sum()))


def test_programme_matches_brute_force_on_random_cases():
    rng = np.random.default_rng(16)
    feasible = 0
    for case in range(300):
        margin, reach = random_case(rng)
        best = brute_force(margin, reach)
        gait = optimal_gait(margin, reach)
        assert gait.margin == best[0], case
        if best[0] > -np.inf:
            feasible += 1
            assert objective(gait) == best, case
            # the gait itself keeps the rules: replayed by the brute force from its start,
            # no gait from there beats it
            assert brute_force(margin, reach, gait.table.states[gait.states[0]]) == best
            assert greedy_gait(margin, reach).margin <= gait.margin
            fixed = best_fixed(margin, reach)
            assert fixed.margin <= gait.margin and fixed.changes == 0
    assert feasible >= 200  # most cases have a gait: the comparison is not vacuous


def test_fixed_set_matches_brute_force():
    rng = np.random.default_rng(3)
    for _ in range(60):
        margin, reach = random_case(rng)
        _, F, N = reach.shape
        index = {s: i for i, s in enumerate(site_sets(N))}
        best = -np.inf
        for count in (3, 4):
            for fingers in combinations(range(F), count):
                for sites in permutations(range(N), count):
                    if all(reach[:, f, s].all() for f, s in zip(fingers, sites, strict=True)):
                        best = max(best, margin[:, index[tuple(sorted(sites))]].min())
        assert best_fixed(margin, reach).margin == best


def test_policy_is_optimal_from_every_state():
    """The policy's move from any state at any pose leads to the best smallest margin from
    there (the expert acts from states off its own gait too)."""
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(60):
        margin, reach = random_case(rng)
        gait = optimal_gait(margin, reach)
        table = gait.table
        T = len(margin)
        for _ in range(3):
            t = int(rng.integers(T))
            x = int(rng.integers(len(table.states)))
            tail = brute_force(margin[t:], reach[t:], table.states[x])[0]
            assert optimal_gait(margin[t:], reach[t:], table.states[x]).margin == tail
            if tail == -np.inf:
                continue
            k = gait.policy[t, x]
            moved = _value_of(table, margin, reach, t, x, k)
            after = table.states[table.next[k]]
            then = brute_force(margin[t + 1 :], reach[t + 1 :], after)[0] if t + 1 < T else np.inf
            assert min(moved, then) == tail
            checked += 1
    assert checked >= 50


def _value_of(table, margin, reach, t, x, k):
    """The margin of move k (CSR) from state x at pose t, from the rules directly."""
    a = table.states[x]
    move = table.move[k]
    loaded = [s for s in a if s >= 0]
    if move:
        f, s = divmod(move - 1, table.n_sites)
        if a[f] == s:
            loaded.remove(s)
        elif not reach[t, f, s]:
            return -np.inf
    if any(s >= 0 and not reach[t, f, s] for f, s in enumerate(a)):
        return -np.inf
    return margin[t, site_sets(table.n_sites).index(tuple(sorted(loaded)))]


def test_start_state_is_kept():
    rng = np.random.default_rng(5)
    for _ in range(40):
        margin, reach = random_case(rng)
        table = gait_states(reach.shape[1], reach.shape[2])
        a = table.states[int(rng.integers(len(table.states)))]
        gait = optimal_gait(margin, reach, a)
        assert gait.margin == brute_force(margin, reach, a)[0]
        if gait.margin > -np.inf:
            np.testing.assert_array_equal(table.states[gait.states[0]], a)


def test_certificate_propagates():
    """The programme on upper bounds bounds every gait; its gait attains within the gap."""
    rng = np.random.default_rng(11)
    for _ in range(100):
        margin, reach = random_case(rng)
        margin = margin + rng.uniform(0, 0.3, margin.shape)  # break ties: attained values
        gap = rng.uniform(0, 0.05, margin.shape)
        upper = margin + gap
        best = optimal_gait(margin, reach).margin
        bound = bottleneck_bound(upper, reach)
        if best == -np.inf:
            assert bound == -np.inf
            continue
        assert best <= bound <= best + gap.max()
        # the bound's own gait, on the attained margins, is within the gap of the optimum
        sets = optimal_gait(upper, reach).sets
        attained = min(margin[t, s] for t, s in enumerate(sets))
        along = max(gap[t, s] for t, s in enumerate(sets))
        assert bound - along - 1e-12 <= attained <= best  # (margin + gap) - gap: rounding


# ------------------------------------------------------------------------ bad inputs


def test_bad_programme_inputs():
    reach = np.ones((3, 4, 4), bool)
    margin = np.zeros((3, len(site_sets(4))))
    with pytest.raises(ValueError, match="same T"):
        optimal_gait(margin[:2], reach)
    with pytest.raises(ValueError, match="one column per set"):
        optimal_gait(margin[:, :3], reach)
    with pytest.raises(ValueError, match="NaN"):
        optimal_gait(np.full_like(margin, np.nan), reach)
    with pytest.raises(ValueError, match="no state"):
        optimal_gait(margin, reach, start=[0, 0, 1, 2])
    with pytest.raises(ValueError, match="no state"):
        optimal_gait(margin, reach, start=[0, -1, -1, 2])
    with pytest.raises(ValueError, match="start must give"):
        optimal_gait(margin, reach, start=[0, 1, 2])
    with pytest.raises(ValueError, match="fingers"):
        gait_states(2, 4)
    # refused, not converted: a reach of 0.5, margins of strings
    with pytest.raises(ValueError, match=r"reach must be a .* boolean array.* got float64"):
        optimal_gait(margin, reach.astype(float))
    with pytest.raises(ValueError, match=r"margin must be .* real numbers.* got <U"):
        optimal_gait(margin.astype(str), reach)
    with pytest.raises(ValueError, match=r"margin must be .* real numbers.* got bool"):
        optimal_gait(margin > 0, reach)


@pytest.mark.parametrize("gait", [optimal_gait, greedy_gait, best_fixed, bottleneck_bound])
def test_too_many_sites_are_refused_before_any_work(gait):
    """The site count is checked before the sets are enumerated: 120 sites took 2.5 s before
    their error, 500 ran out of memory."""
    for reach in (np.ones((1, 5, 120), bool), np.ones((1, 5, 500), bool)):
        with pytest.raises(ValueError, match=r"reach must be .* N in \[3, 8\], got bool"):
            gait(np.zeros((1, 35)), reach)
    with pytest.raises(ValueError, match=r"reach must be .* F in \[3, 6\]"):
        gait(np.zeros((1, 35)), np.ones((1, 40, 7), bool))
    for kwargs, match in (
        ({"trajectory": {"alpha_start_deg": 0}}, "trajectory must be a Trajectory, got dict"),
        ({"hand": 3}, "hand must be a Hand, got int"),
        ({"scene": "paper"}, "scene must be a GaitScene, got str"),
    ):
        with pytest.raises(ValueError, match=match):
            solve_gait(**kwargs)


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


# ------------------------------------------------------------------------ the environment

GAIT_ID = "grasp_env/CubeGait-v0"
MOVES_ID = "grasp_env/CubeGaitMoves-v0"


def make_gait(**kwargs):
    import gymnasium as gym

    import grasp_env  # noqa: F401  (registers the environments)

    return gym.make(GAIT_ID, **kwargs)


def play(env, policy, steps=None):
    """Rewards and infos of one episode played by ``policy(obs) -> action``."""
    obs, _ = env.reset(seed=0)
    rewards, infos = [], []
    done = False
    while not done and (steps is None or len(rewards) < steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        rewards.append(reward)
        infos.append(info)
        done = terminated or truncated
    return np.array(rewards), infos, terminated


@pytest.mark.parametrize("env_id", [GAIT_ID, MOVES_ID])
def test_gait_env_check_env(env_id):
    import warnings

    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
    assert env_id in __import__("grasp_env").ENV_IDS


def test_moves_env_grips_with_the_certified_optimum():
    """CubeGaitMoves-v0: the agent chooses the move, the environment grips with the certified
    minimax of the fingers that then carry load. Each step earns that set's certified margin
    (the solver's, to float32 rounding of the grip), a refused move keeps the contacts with
    their grip, and the expert's moves replay CubeGait-v0's expert episode exactly."""
    import gymnasium as gym

    from grasp_env.envs.gait import GaitExpert

    env = gym.make(MOVES_ID, terminate_on_slip=False)
    task = env.unwrapped.task
    values = task.solution.values
    assert env.action_space == gym.spaces.Discrete(task.n_moves)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    scored = refused = 0
    for t in range(len(PAPER_TURN)):
        # mostly keep, sometimes any move: long episodes that still change their contacts
        move = int(rng.integers(task.n_moves)) if rng.random() < 0.3 else 0
        _, reward, terminated, truncated, info = env.step(move)
        refused += info["refused"]
        if not info["lost"].any():
            loaded = tuple(sorted(int(s) for s in info["contacts"][info["loaded"]]))
            margin = values.margin[t, values.sets.index(loaded)]
            assert abs(reward - margin) < 1e-6, (t, move, reward, margin)
            scored += 1
        if terminated or truncated:
            break
    assert scored >= 20 and refused >= 1
    # the expert's moves on the moves env: the expert's episode of the full env
    expert, moves, full = GaitExpert(), GaitExpert(optimal_grip=True), make_gait()
    env = gym.make(MOVES_ID)
    (obs, _), _ = env.reset(seed=0), full.reset(seed=0)
    done = False
    while not done:
        action = expert.predict(obs)[0]
        move = moves.predict(obs)[0]
        assert move == np.argmax(action[task.n_pairs :]) and env.action_space.contains(move)
        got = env.step(move)
        want = full.step(action)
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1:4] == want[1:4]
        for key, value in want[4].items():
            np.testing.assert_array_equal(got[4][key], value)
        obs, done = got[0], got[2] or got[3]
    assert want[3] and not want[2]  # held to the end


def test_moves_env_vector_equals_single_envs_and_refuses_bad_moves():
    import gymnasium as gym

    num = 3
    envs = gym.make_vec(MOVES_ID, num_envs=num, vectorization_mode="vector_entry_point")
    singles = [gym.make(MOVES_ID) for _ in range(num)]
    obs, _ = envs.reset(seed=0)
    single_obs = [s.reset(seed=0)[0] for s in singles]
    rng = np.random.default_rng(1)
    restart = np.zeros(num, bool)
    ended = 0
    for _ in range(150):
        np.testing.assert_array_equal(obs, np.stack(single_obs))
        moves = np.where(rng.random(num) < 0.2, rng.integers(0, 31, num), 0)
        obs, reward, terminated, truncated, info = envs.step(moves)
        for i, single in enumerate(singles):
            if restart[i]:  # NEXT_STEP: this step resets it
                single_obs[i] = single.reset()[0]
                continue
            o, r, te, tr, inf = single.step(moves[i])
            assert (r, te, tr) == (reward[i], terminated[i], truncated[i])
            np.testing.assert_array_equal(inf["k"], info["k"][i])
            single_obs[i] = o
        restart = terminated | truncated
        ended += restart.sum()
    assert ended >= num  # autoresets were compared too
    for bad in (31, -1, 2.0, True, np.array([1, 2]), "3"):
        with pytest.raises(ValueError, match=r"move"):
            singles[0].reset()
            singles[0].step(bad)
    for bad in (np.array([0, 1]), np.array([0.0, 1.0, 2.0]), np.array([0, 1, 31])):
        with pytest.raises(ValueError, match=r"move"):
            envs.step(bad)


def test_gait_expert_earns_the_certified_margin():
    from grasp_env.envs.gait import GaitExpert, GreedyGait

    env = make_gait()
    solution = env.unwrapped.task.solution
    expert = GaitExpert()
    rewards, infos, terminated = play(env, lambda o: expert.predict(o)[0])
    assert len(rewards) == len(PAPER_TURN) and not terminated
    # the certified optimum, to float32 rounding of the action
    np.testing.assert_allclose(rewards, solution.optimal.margins, atol=1e-6)
    assert abs(rewards.min() - solution.optimal.margin) < 1e-6
    moves = sum(info["move"] != 0 for info in infos)
    assert moves == solution.optimal.changes and not any(info["refused"] for info in infos)
    # the greedy baseline from the same start loses a contact and drops the cube
    greedy = GreedyGait()
    rewards, infos, terminated = play(env, lambda o: greedy.predict(o)[0])
    assert terminated and rewards.min() < 0 and len(rewards) < len(PAPER_TURN)
    assert infos[-1]["lost"].any()


def test_gait_env_is_sequential():
    """A policy that never moves a finger (the best it can do at gamma = 0 wherever the
    current contacts hold) loses a contact; the expert, which plans, holds throughout."""
    env = make_gait(terminate_on_slip=False)
    task = env.unwrapped.task
    from grasp_env.envs.gait import GaitExpert

    expert = GaitExpert()

    def keep(obs):
        action = expert.predict(obs)[0]
        action[task.n_pairs :] = -1.0
        action[task.n_pairs] = 1.0  # move 0: keep
        return action

    rewards, infos, terminated = play(env, keep)
    assert terminated and infos[-1]["lost"].any()  # dropped: fewer than three fingers left
    assert np.isclose(rewards[-1], task.limit - np.pi / 2)


def test_gait_env_rules():
    env = make_gait(terminate_on_slip=False)
    task = env.unwrapped.task
    P, N = task.n_pairs, task.n_sites
    obs, _ = env.reset()
    start = task.table.states[task.start]  # three fingers touch
    assert (start >= 0).sum() == 3

    def move(m):
        action = np.zeros(P + task.n_moves, np.float32)
        action[P + m] = 1.0
        return action

    toggle = lambda f, s: 1 + f * N + s  # noqa: E731
    touching = int(np.flatnonzero(start >= 0)[0])
    _, _, _, _, info = env.step(move(toggle(touching, int(start[touching]))))
    assert info["refused"] and info["move"] == 0  # a lift would leave two fingers
    free = int(np.flatnonzero(start < 0)[0])
    taken = int(start[touching])
    _, _, _, _, info = env.step(move(toggle(free, taken)))
    assert info["refused"]  # the site is taken
    reach = task.solution.reach[2]
    far = [s for s in range(N) if not reach[free, s] and s not in start]
    if far:
        _, _, _, _, info = env.step(move(toggle(free, far[0])))
        assert info["refused"]  # out of reach
    # observation: contacts one-hot and reach flags
    obs, _ = env.reset()
    F = task.n_fingers
    width = task.pose_size()
    contacts = obs[width : width + F * N].reshape(F, N)
    for f in range(F):
        assert contacts[f].sum() == (start[f] >= 0) and (start[f] < 0 or contacts[f, start[f]])
    np.testing.assert_array_equal(obs[width + F * N :].reshape(F, N), task.solution.reach[0])


def test_gait_vector_env_equals_single_envs():
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    from grasp_env.envs.gait import GaitExpert

    expert = GaitExpert()
    num = 3
    for mode in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
        envs = gym.make_vec(
            GAIT_ID, num_envs=num, vectorization_mode="vector_entry_point",
            autoreset_mode=mode, terminate_on_slip=False,
        )  # fmt: skip
        singles = [make_gait(terminate_on_slip=False) for _ in range(num)]
        obs, _ = envs.reset(seed=0)
        single_obs = [s.reset(seed=0)[0] for s in singles]
        rng = np.random.default_rng(0)
        restart = np.zeros(num, bool)
        for _ in range(200):
            np.testing.assert_array_equal(obs, np.stack(single_obs))
            actions = expert.predict(obs)[0]
            noisy = rng.random(num) < 0.3  # some sub-environments act at random
            actions[noisy] = rng.uniform(-1, 1, actions[noisy].shape)
            obs, reward, terminated, truncated, info = envs.step(actions)
            for i, single in enumerate(singles):
                if restart[i]:  # NEXT_STEP: this step resets it
                    single_obs[i] = single.reset()[0]
                    assert reward[i] == 0
                    continue
                o, r, te, tr, inf = single.step(actions[i])
                assert r == reward[i] and te == terminated[i] and tr == truncated[i]
                np.testing.assert_array_equal(inf["theta"], info["theta"][i])
                single_obs[i] = o
                if (te or tr) and mode == AutoresetMode.SAME_STEP:
                    np.testing.assert_array_equal(info["final_obs"][i], o)
                    single_obs[i] = single.reset()[0]
            restart = (terminated | truncated) & (mode == AutoresetMode.NEXT_STEP)


def test_gait_env_other_trajectory_and_bad_keywords():
    env = make_gait(trajectory={"axis": (0, 0, 1), "alpha_start_deg": -180, "alpha_end_deg": 180})
    task = env.unwrapped.task
    assert task.n_poses == 361 and task.solution.optimal.margin > np.deg2rad(8)
    for kwargs, match in [
        ({"cone_deg": 0}, "cone_deg"),
        ({"mu": True}, "mu"),
        ({"start": (0, 0, 1, 2, -1)}, "no state"),
        ({"trajectory": {"axis": (0, 0, 0)}}, "axis"),
        ({"trajectory": "x"}, "trajectory must be a mapping"),
        ({"start": "x"}, "start must be a site"),
        ({"start": 3}, "start must be a site"),
        ({"start": (True, -1, 3, 4, -1)}, "start must be a site"),  # not converted to site 1
        ({"start": (2.7, -1, 3, 4, -1)}, "start must be a site"),
        ({"start": ("2", "-1", "3", "4", "-1")}, "start must be a site"),
        ({"start": (np.inf, -1, 3, 4, -1)}, "start must be a site"),
        ({"start": (2**70, -1, 3, 4, -1)}, "start must be a site"),
        ({"start": (5, -1, 3, 4, -1)}, r"out of reach .*\(0, 5\)"),  # finger 0 cannot push on +z
        ({"terminate_on_slip": 1}, "terminate_on_slip"),
        ({"cone_deg": 10.0}, "no gait"),
    ]:
        with pytest.raises(ValueError, match=match):
            make_gait(**kwargs)
    env = make_gait()
    env.reset()
    P = env.unwrapped.task.n_pairs
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(P))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.full(env.action_space.shape, np.nan, np.float32))
    rewards = []
    for dtype in (np.float16, np.float32, np.longdouble):  # the grasp envs' dtypes too
        env.reset()
        rewards.append(env.step(np.full(env.action_space.shape, 0.25, dtype))[1])
    assert rewards[0] == rewards[1] == rewards[2]


def test_gait_env_refusals_of_start_name_it():
    """Every refusal of ``start`` names it, the environment's and the mechanics' alike."""
    for start, match in [
        ((6, 1, 3, 4, -1), r"^start must give each of the 5 fingers a site in \[-1, 5\]"),
        ((0, 1, 3), r"^start must give each of the 5 fingers"),
        ((0, 0, 3, 4, -1), r"^start \[0, 0, 3, 4, -1\] is no state of the hand"),
        ((0, -1, -1, 4, -1), r"^start \[0, -1, -1, 4, -1\] is no state"),
        # within reach at the first pose, but every gait from it drops (the default start holds)
        ((4, 2, 3, -1, -1), r"^no gait from start \[4, 2, 3, -1, -1\] keeps three fingers"),
    ]:
        with pytest.raises(ValueError, match=match):
            make_gait(start=start)
    reach = np.ones((2, 4, 4), bool)
    margin = np.zeros((2, len(site_sets(4))))
    for start in ([2.7, 0, 1, -1], [[0, 1], [2]], [0, 1, 4, -1]):  # 2.7 is not truncated
        with pytest.raises(ValueError, match=r"^start must give each of the 4 fingers"):
            optimal_gait(margin, reach, start=start)
        with pytest.raises(ValueError, match=r"^start must give"):
            greedy_gait(margin, reach, start=start)


def test_gait_env_through_sb3_make_vec_env():
    """SB3's make_vec_env asks for render_mode="rgb_array", and the gait environment takes it;
    its observations are the single environment's."""
    from stable_baselines3.common.env_util import make_vec_env

    envs = make_vec_env(GAIT_ID, n_envs=2, seed=0)
    assert envs.render_mode == "rgb_array"
    single = make_gait()
    np.testing.assert_array_equal(envs.reset()[0], single.reset(seed=0)[0])


def test_gait_env_pickles():
    import pickle

    env = make_gait()
    env.reset(seed=1)
    action = np.zeros(env.action_space.shape, np.float32)
    clone = pickle.loads(pickle.dumps(env))
    a = env.step(action)
    b = clone.step(action)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]


# ------------------------------------------------------------------------------- physics


def test_certified_gait_holds_in_mujoco():
    """The optimal gait along alpha in [-60, 0] deg (61 poses, five phase changes: fingers
    lifted with zero force and placed with none) carried through one continuous MuJoCo
    rollout: the object stays put and the analytic verdict agrees.

    The rollout takes a Scene of at most four contacts, so it models the window's four sites
    (-x, -y, -z, +x; which finger holds a site is immaterial to the physics), each touched
    where some finger touches it."""
    from grasp_env.physics.rollout import TrajectoryChecker

    solution = solve_gait()
    gait = solution.optimal
    alphas = list(PAPER_TURN.alphas_deg)
    window = slice(alphas.index(-60.0), alphas.index(0.0) + 1)
    contacts = gait.contacts[window]
    sites = sorted({int(s) for s in contacts.ravel() if s >= 0})
    assert len(sites) == 4 and np.count_nonzero(gait.moves[window]) == 5
    finger_forces = solution.forces(gait)[window]
    forces = np.zeros((len(contacts), 4, 3))
    touching = np.zeros((len(contacts), 4), bool)
    for t, row in enumerate(contacts):
        for f, s in enumerate(row):
            if s >= 0:
                forces[t, sites.index(s)] = finger_forces[t, f]
                touching[t, sites.index(s)] = True
    assert np.any(touching & (np.linalg.norm(forces, axis=-1) == 0))  # zero-force touches
    report = TrajectoryChecker(solution.scene.scene(sites)).check(
        solution.trajectory.rotations()[window], forces, touching
    )
    assert report.predicted_holds and report.holds, report.as_dict()
    assert abs(report.margin_deg - np.rad2deg(gait.margins[window].min())) < 0.01


def test_gait_env_through_the_sb3_adapter_and_not_grasp_env_train():
    """SB3VecEnv drives the gait's vector env (PPO learns on it); grasp-env train, whose runs
    are evaluated on held-out grasp scenes, refuses it and says where it trains."""
    from stable_baselines3 import PPO

    from grasp_env.envs.sb3 import SB3VecEnv
    from grasp_env_agents.run.config import config_from_dict

    for env_id in (GAIT_ID, MOVES_ID):  # a Box action and a Discrete one
        venv = SB3VecEnv(env_id, num_envs=4)
        venv.seed(0)
        np.testing.assert_array_equal(venv.reset()[0], make_gait().reset(seed=0)[0])
        PPO("MlpPolicy", venv, n_steps=16, batch_size=64, n_epochs=1, seed=0).learn(64)
    for env_id in (GAIT_ID, MOVES_ID):
        with pytest.raises(ValueError, match="trains with rl-zoo3"):
            config_from_dict({"env_id": env_id, "total_timesteps": 64})


def test_gait_expert_refuses_observations_outside_the_space():
    """A phase outside [0, 1] is no pose of the run (a negative one indexed from the end)."""
    from grasp_env.envs.gait import GaitExpert

    expert = GaitExpert()
    env = make_gait()
    obs, _ = env.reset(seed=0)
    phase = env.unwrapped.task.pose_size() - 1
    assert env.observation_space.low[phase] == 0.0 and env.observation_space.high[phase] == 1.0
    expert.predict(obs)  # inside: fine
    for value in (-0.01, 1.5):
        bad = obs.copy()
        bad[phase] = value
        with pytest.raises(ValueError, match=r"phase \(entry \d+\) must be within \[0, 1\]"):
            expert.predict(bad)
        with pytest.raises(ValueError, match="phase"):
            expert.predict(np.stack([obs, bad]))
    bad = obs.copy()
    bad[env.unwrapped.task.pose_size() :] = 0.0  # no finger touches
    with pytest.raises(ValueError, match="no state of the hand"):
        expert.predict(bad)
