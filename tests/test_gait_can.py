"""The coke can's gait: the programme against brute force over all gaits on small cases, the
certificate, the can's mechanics (contacts that turn with it, grips that balance its weight)
and ``grasp-env gait --object can`` (docs/gait.md, "The can")."""

from __future__ import annotations

from itertools import combinations, product

import numpy as np
import pytest

from grasp_env.mechanics.gait import MARGIN_TOL
from grasp_env.mechanics.gait.can import CanHand, CanTurn, can_configs, can_values, contact_points
from grasp_env.mechanics.gait.can_programme import (
    best_fixed_can,
    can_bottleneck_bound,
    can_states,
    greedy_can_gait,
    optimal_can_gait,
    solve_can_gait,
)
from grasp_env.mechanics.minimax import Status

# ------------------------------------------------------------- brute force, all gaits


def brute_force(margin, F, H, L, start=None, tol=MARGIN_TOL):
    """(B, -fewest moves, largest sum) over every gait on the can, by enumeration, margins
    within ``tol`` of the best bottleneck B tied.

    Written from the rules of the can's module docstring, not from its tables: a state gives
    each finger an age (poses since placement) or none; at every pose every touching finger's
    age is at most H; the move keeps (every touching finger carries load), lifts a touching
    finger (zero force now, gone next) or places a free finger (age 0, zero force now); 3 to 5
    fingers touch and 3 to L carry load; every age grows by one a pose.
    """
    index = {c: i for i, c in enumerate(can_configs(F, H, L))}
    T = len(margin)
    outcomes = []

    def walk(t, ages, low, moves, total):
        if t == T:
            outcomes.append((low, moves, total))
            return
        touching = [f for f in range(F) if ages[f] >= 0]
        if any(ages[f] > H for f in touching):
            return  # a contact turned out of reach under load
        options = [(None, touching, ages)]
        for f in range(F):
            if ages[f] >= 0:
                rest = [g for g in touching if g != f]
                options.append(("lift", rest, (*ages[:f], -1, *ages[f + 1 :])))
            elif len(touching) < 5:
                options.append(("place", touching, (*ages[:f], 0, *ages[f + 1 :])))
        for move, loaded, after in options:
            if not 3 <= len(loaded) <= L:
                continue
            value = margin[t, index[tuple((g, ages[g]) for g in loaded)]]
            older = tuple(a + 1 if a >= 0 else -1 for a in after)
            walk(t + 1, older, min(low, value), moves + (move is not None), total + value)

    if start is not None:
        starts = [tuple(start)]
    else:
        starts = [
            s for s in product([-1, *range(1, H + 1)], repeat=F) if 3 <= sum(a >= 0 for a in s)
        ]
    for s in starts:
        walk(0, s, np.inf, 0, 0.0)
    if not outcomes:
        return (-np.inf, 0, 0.0)
    best = max(low for low, _, _ in outcomes)
    keep = [(m, s) for low, m, s in outcomes if low >= best - tol]
    fewest = min(m for m, _ in keep)
    return (best, -fewest, max(s for m, s in keep if m == fewest))


def random_case(rng):
    """Small problems: 3 to 5 fingers, contacts lasting 1 to 3 poses, short trajectories,
    integer margins (ties) that change from pose to pose, unusable configurations."""
    F = int(rng.integers(3, 6))
    H = int(rng.integers(1, 4 if F < 5 else 3))
    L = int(rng.integers(3, min(F, 5) + 1))
    T = int(rng.integers(1, 6 if F < 5 else 3))
    C = len(can_configs(F, H, L))
    margin = rng.integers(-2, 4, (T, C)).astype(float)
    margin[:, rng.random(C) < 0.1] = -np.inf
    return margin, F, H, L


def objective(gait):
    return (gait.margin, -gait.changes, float(gait.margins.sum()))


def test_can_programme_matches_brute_force_on_random_cases():
    rng = np.random.default_rng(41)
    feasible = 0
    for case in range(420):
        margin, F, H, L = random_case(rng)
        best = brute_force(margin, F, H, L)
        gait = optimal_can_gait(margin, F, H, None, L)
        assert gait.margin == best[0], case
        if best[0] == -np.inf:
            continue
        feasible += 1
        assert objective(gait) == best, (case, objective(gait), best)
        # from its own start, no gait beats it; the baselines do not either
        start = gait.table.states[gait.states[0]]
        assert brute_force(margin, F, H, L, start) == best
        assert greedy_can_gait(margin, F, H, None, L).margin <= gait.margin
        fixed = best_fixed_can(margin, F, H, L)
        assert fixed.margin <= gait.margin and fixed.changes == 0
    assert feasible >= 200  # the comparison is not vacuous


def test_can_programme_from_given_starts_and_near_ties():
    rng = np.random.default_rng(43)
    checked = 0
    for _ in range(120):
        margin, F, H, L = random_case(rng)
        margin = margin + rng.uniform(-0.4, 0.4, margin.shape) * MARGIN_TOL
        table = can_states(F, H, L)
        fresh = np.flatnonzero((table.states <= 1).all(axis=1))  # contacts just placed
        start = table.states[int(rng.choice(fresh))]
        best = brute_force(margin, F, H, L, start)
        gait = optimal_can_gait(margin, F, H, start, L)
        if best[0] == -np.inf:
            assert gait.margin == -np.inf
            continue
        checked += 1
        np.testing.assert_array_equal(table.states[gait.states[0]], start)
        assert best[0] - MARGIN_TOL <= gait.margin <= best[0]
        assert -gait.changes == best[1]
        assert best[2] - len(margin) * MARGIN_TOL <= gait.margins.sum() <= best[2]
    assert checked >= 40


def test_can_gait_keeps_the_rules():
    rng = np.random.default_rng(47)
    for _ in range(60):
        margin, F, H, L = random_case(rng)
        gait = optimal_can_gait(margin, F, H, None, L)
        if gait.margin == -np.inf:
            continue
        for t in range(len(margin)):
            touching = gait.ages[t] >= 0
            assert 3 <= gait.loaded[t].sum() <= L and touching.sum() <= 5
            assert np.all(gait.ages[t][touching] <= H)
            assert touching.sum() - gait.loaded[t].sum() <= 1  # one finger changing
            placed = gait.ages[t] == 0
            assert not gait.loaded[t][placed].any()  # a placed finger carries nothing yet
            if t:
                was = gait.ages[t - 1]
                kept = (was >= 0) & (gait.ages[t] >= 0) & (was != 0)
                assert np.all(gait.ages[t][kept] == was[kept] + 1)  # contacts turn on


def test_can_certificate_propagates():
    rng = np.random.default_rng(53)
    for _ in range(80):
        margin, F, H, L = random_case(rng)
        margin = margin + rng.uniform(0, 0.3, margin.shape)
        gap = rng.uniform(0, 0.05, margin.shape)
        best = optimal_can_gait(margin, F, H, None, L).margin
        bound = can_bottleneck_bound(margin + gap, F, H, None, L)
        if best == -np.inf:
            assert bound == -np.inf
            continue
        assert best <= bound <= best + gap.max() + MARGIN_TOL


def test_can_tables_refuse_bad_sizes():
    with pytest.raises(ValueError, match="3 to 5 fingers"):
        can_states(6, 2)
    with pytest.raises(ValueError, match="margin must be"):
        optimal_can_gait(np.zeros((2, 3)), 3, 1)
    with pytest.raises(ValueError, match="start must give"):
        optimal_can_gait(np.zeros((2, len(can_configs(3, 1)))), 3, 1, start=[1, 1, -1])
    with pytest.raises(ValueError, match="heights must differ"):
        CanHand(heights=(0.0,) * 5)
    with pytest.raises(ValueError, match="reach_deg"):
        CanHand(reach_deg=0.0)


# ------------------------------------------------------------------- the can itself


def test_reach_lasts_to_the_far_edge():
    """A contact lasts H = floor(2 c / delta) poses, the far edge within reach (2 x 60 / 10 is
    exactly 12)."""
    assert CanHand().max_age(10.0) == 12
    assert CanHand(reach_deg=30.0).max_age(10.0) == 6
    assert CanHand(reach_deg=30.0).max_age(10.0 + 1e-9) == 5


def test_can_contacts_turn_with_the_can_and_margins_do_not_depend_on_alpha():
    """A finger places at the upstream edge of its patch and its contact turns with the can;
    the same configuration turned about the axis has the same optimum (1e-9 rad)."""
    from grasp_env.mechanics import load_wrench, solve_minimax
    from grasp_env.mechanics.forces import grasp
    from grasp_env.mechanics.objects import parse_object

    hand = CanHand()
    can = parse_object("can")
    fingers = np.array([0, 2, 4])
    ages = np.array([3, 0, 0, 0, 7])
    points, normals = contact_points(can, hand, 10.0, fingers, ages)
    azimuth = np.rad2deg(np.arctan2(points[:, 1], points[:, 0]))
    expected = np.array(hand.azimuths_deg)[fingers] - 60.0 + ages[fingers] * 10.0
    np.testing.assert_allclose(np.mod(azimuth - expected + 180, 360) - 180, 0, atol=1e-9)
    np.testing.assert_allclose(normals[:, :2], -points[:, :2] / can.radius, atol=1e-12)
    wrench = load_wrench(3.4)
    limit = np.arctan(0.5)
    results = []
    for alpha in (0.0, 37.0, 250.0):
        a = np.deg2rad(alpha)
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        g = grasp(points @ R.T, normals @ R.T, np.eye(3), wrench, limit)
        results.append(float(solve_minimax(g, 6.8).max_angle))
    np.testing.assert_allclose(results, results[0], atol=1e-9)


@pytest.fixture(scope="module")
def small():
    """Four fingers, contacts lasting 9 poses, a half turn in 10 deg steps."""
    hand = CanHand(
        azimuths_deg=(-45.0, 45.0, 135.0, 225.0), heights=(0.4, 0.1, -0.2, -0.5), reach_deg=45.0
    )
    return solve_can_gait(hand, CanTurn(0.0, 180.0, 10.0), max_loaded=4)


def test_small_can_gait_is_certified_and_balances_the_weight(small):
    from grasp_env.mechanics import load_wrench
    from grasp_env.mechanics.forces import grasp

    assert small.holds and small.optimal.changes > 0
    assert small.optimal.margin <= small.bound <= small.optimal.margin + 1e-9 + MARGIN_TOL
    v = small.values
    assert np.all(v.margin <= v.margin_bound)
    _, status = small.grips(small.optimal)
    for t, c in enumerate(small.optimal.configs):
        config = v.configs[c]
        fingers = np.array([f for f, _ in config])
        ages = np.full(4, -1)
        ages[fingers] = [a for _, a in config]
        points, normals = contact_points(small.can, small.hand, 10.0, fingers, ages)
        g = grasp(points, normals, np.eye(3), load_wrench(3.4), small.friction_limit)
        k, reported = v.grip(int(c))
        P = g.forces(k)
        np.testing.assert_allclose(P.sum(axis=0), [0, 0, 3.4], atol=1e-9)
        np.testing.assert_allclose(np.cross(g.positions, P).sum(axis=0), 0, atol=1e-10)
        pushing = np.linalg.norm(P, axis=1) > 1e-6 * 3.4
        np.testing.assert_allclose(g.angles(k)[pushing], reported[pushing], atol=1e-9)
        assert np.isclose(small.friction_limit - reported.max(), small.optimal.margins[t])
        assert status[t] in (Status.INTERIOR, Status.BOUNDARY)
    # the contacts' points on the can: a finger placed again touches another point
    points = small.object_angles_deg(small.optimal)
    assert np.nanmax(points) < 360 and np.nanmin(points) >= 0


def test_five_loaded_fingers_are_solved_and_counted_honestly():
    """With five loaded fingers the conic solver answers; an UNCERTIFIED optimum keeps its
    attained margin (its grip attains it) below its certified bound, and is counted."""
    hand = CanHand(reach_deg=5.0)
    values = can_values(hand, 10.0, max_loaded=5)  # H = 1: one configuration per finger set
    assert len(values.configs) == 10 + 5 + 1
    assert np.all(values.margin <= values.margin_bound)
    five = values.optimum[-1]
    assert five.k.shape == (1, 10)
    uncertified = int(np.count_nonzero(five.status == Status.UNCERTIFIED))
    assert values.uncertified >= uncertified


def test_can_command(tmp_path, capsys):
    import csv

    from grasp_env_agents.cli import main

    out = tmp_path / "can"
    argv = ["gait", "--object", "can", "--reach", "30", "--alpha-end", "60", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "optimal gait: worst margin" in printed and "uncertified" in printed
    assert (out / "gait.png").stat().st_size > 10_000
    rows = list(csv.DictReader((out / "gait.csv").open()))
    assert [float(r["alpha_deg"]) for r in rows] == list(range(0, 61, 10))
    names = CanHand().names
    limit = np.rad2deg(np.arctan(0.5))
    for row in rows:
        loaded = [n for n in names if row[f"theta_{n}_deg"]]
        assert 3 <= len(loaded) <= 4 and all(row[f"point_{n}_deg"] for n in loaded)
        theta = max(float(row[f"theta_{n}_deg"]) for n in loaded)
        assert np.isclose(float(row["margin_deg"]), limit - theta, atol=1e-7)
    assert main(["gait", "--object", "can", "--cone", "30", "--no-plots"]) == 2
    assert "drop --cone" in capsys.readouterr().err
    assert main(["gait", "--object", "can", "--reach", "5", "--no-plots", "--out", str(out)]) == 2
    assert "no gait keeps three fingers on the can" in capsys.readouterr().err
    for option in (["--mujoco"], ["--reach", "30"], ["--video", str(out / "v.mp4")]):
        assert main(["gait", *option, "--no-plots", "--out", str(out)]) == 2  # the cube's gait
        assert f"{option[0]}: the can's options, given with --object can only" in (
            capsys.readouterr().err
        )


def test_combinations_of_the_tables_are_complete():
    """Every configuration a state's move can load is in the table (3 to L fingers)."""
    for F, H, L in ((3, 2, 3), (4, 2, 4), (5, 1, 5)):
        configs = can_configs(F, H, L)
        expected = sum(len(list(combinations(range(F), n))) * H**n for n in range(3, L + 1))
        assert len(configs) == expected == len(set(configs))
        table = can_states(F, H, L)
        assert table.config.max() < len(configs)
