"""Finger gaits: the dynamic programme against brute force over all gaits, the baselines, the
certificate, ties within the margin tolerance and bad inputs (docs/gait.md, "The algorithm")."""

from __future__ import annotations

from itertools import combinations, permutations

import numpy as np
import pytest

from grasp_env.mechanics import (
    VERTICAL_TURN,
    best_fixed,
    bottleneck_bound,
    gait_states,
    greedy_gait,
    optimal_gait,
    site_sets,
    solve_gait,
)
from grasp_env.mechanics.gait import MARGIN_TOL, first_best
from grasp_env.mechanics.minimax.codes import GAP_TOL

# ----------------------------------------------------------------- brute force, all gaits


def touching(a):
    return [f for f, s in enumerate(a) if s >= 0]


def brute_force(margin, reach, start=None, tol=MARGIN_TOL):
    """The best (smallest margin, -moves, sum of margins) over every gait, by enumeration,
    margins compared to within ``tol``: the best smallest margin B, then the fewest moves and
    the largest sum among the gaits whose smallest margin is at least B - tol.

    Written from the rules in the gait module's docstring, not from its tables: at each pose
    every touching finger must reach its site; the move is to keep (all touching fingers
    carry load), lift a touching finger (zero force now, gone next) or place a free finger on
    a free site it reaches now (zero force now, loaded next); 3 or 4 fingers touch, 3 or 4
    carry load.
    """
    T, F, N = reach.shape
    index = {s: i for i, s in enumerate(site_sets(N))}
    outcomes = []

    def walk(t, a, low, moves, total):
        if t == T:
            outcomes.append((low, moves, total))
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
    return tolerant_best(outcomes, tol)


def tolerant_best(outcomes, tol):
    """(B, -fewest moves, largest sum) of (smallest margin, moves, sum) outcomes, margins
    within ``tol`` of B tied; (-inf, 0, 0.0) if there are none."""
    if not outcomes:
        return (-np.inf, 0, 0.0)
    best = max(low for low, _, _ in outcomes)
    keep = [(m, s) for low, m, s in outcomes if low >= best - tol]
    fewest = min(m for m, _ in keep)
    return (best, -fewest, max(s for m, s in keep if m == fewest))


def agrees(gait, best, tol=MARGIN_TOL):
    """The gait attains the brute force's best under the tolerance: its smallest margin within
    tol of B, the fewest moves, and the largest sum to within tol per pose."""
    poses = len(gait.margins)
    return (
        best[0] - tol <= gait.margin <= best[0]
        and -gait.changes == best[1]
        and best[2] - poses * tol <= float(gait.margins.sum()) <= best[2]
    )


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
            assert objective(gait) == best, case  # integer margins: exact
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
        assert best <= bound <= best + gap.max() + MARGIN_TOL
        # the bound's own gait, on the attained margins, is within the gap of the optimum
        sets = optimal_gait(upper, reach).sets
        attained = min(margin[t, s] for t, s in enumerate(sets))
        along = max(gap[t, s] for t, s in enumerate(sets))
        # (margin + gap) - gap: rounding; both gaits keep their bottleneck to within MARGIN_TOL
        assert bound - along - MARGIN_TOL - 1e-12 <= attained <= best + MARGIN_TOL


# --------------------------------------------------------------- ties, to within a tolerance


def test_margin_tolerance_is_the_certificate_gap():
    assert MARGIN_TOL == GAP_TOL == 1e-9
    assert first_best(np.array([1.0, 2.0 - 0.5e-9, 2.0, 2.0 + 0.5e-9])) == 1
    assert first_best(np.array([1.0, 2.0 - 2e-9, 2.0])) == 2
    assert first_best(np.full(3, -np.inf)) == 0


def test_programme_matches_brute_force_under_the_tolerance():
    """Near ties (integer margins moved by up to 0.8 x MARGIN_TOL): the programme's gait is
    the brute force's best under the tolerance, from the best start and from given ones."""
    rng = np.random.default_rng(29)
    feasible = 0
    for case in range(250):
        margin, reach = random_case(rng)
        margin = margin + rng.uniform(-0.4, 0.4, margin.shape) * MARGIN_TOL
        best = brute_force(margin, reach)
        gait = optimal_gait(margin, reach)
        if best[0] == -np.inf:
            assert gait.margin == -np.inf, case
            continue
        feasible += 1
        assert agrees(gait, best), (case, objective(gait), best)
        table = gait.table
        a = table.states[int(rng.integers(len(table.states)))]
        from_a = brute_force(margin, reach, a)
        if from_a[0] > -np.inf:
            assert agrees(optimal_gait(margin, reach, a), from_a), case
    assert feasible >= 150


def test_gaits_are_stable_under_rounding_noise():
    """Margins with exact ties, perturbed by 1e-12 rad of noise (the size of the solver's
    rounding), give the same gaits: states and moves of the optimal, greedy and fixed gaits."""
    rng = np.random.default_rng(31)
    compared = 0
    for _ in range(200):
        margin, reach = random_case(rng)
        noisy = margin + rng.uniform(-1e-12, 1e-12, margin.shape)
        for solve in (optimal_gait, greedy_gait, best_fixed):
            a, b = solve(margin, reach), solve(noisy, reach)
            np.testing.assert_array_equal(a.states, b.states)
            np.testing.assert_array_equal(a.moves, b.moves)
            compared += a.margin > -np.inf
    assert compared >= 200


@pytest.fixture(scope="module")
def vertical():
    return solve_gait(trajectory=VERTICAL_TURN)


def test_vertical_turn_decided_by_margins_not_noise(vertical):
    """About the vertical every set's margin is constant in exact arithmetic; the solver's
    values vary by about 1e-11 deg. Rounded to 1e-6 deg they give the same gaits, and the
    greedy gait drops at alpha = -74 deg after one change (its 20 changes and -16.7 deg came
    from 1e-15 deg ties)."""
    values, reach = vertical.values, vertical.reach
    usable = np.isfinite(values.margin)
    spread = np.ptp(np.where(usable, values.margin, 0.0), axis=0)
    assert np.rad2deg(spread.max()) < 1e-9  # constant but for rounding
    rounded = np.where(usable, np.round(values.margin, 8), -np.inf)  # 1e-8 rad: 6e-7 deg
    for solve, gait in ((optimal_gait, vertical.optimal), (greedy_gait, vertical.greedy)):
        again = solve(rounded, reach)
        np.testing.assert_array_equal(again.states, gait.states)
        np.testing.assert_array_equal(again.moves, gait.moves)
    greedy = vertical.greedy
    drop = np.flatnonzero(greedy.sets < 0)
    assert greedy.changes == 1 and VERTICAL_TURN.alphas_deg[drop[0]] == -74.0
    assert vertical.optimal.changes == 30
    # pass 2 keeps the largest sum among the 30-change gaits that keep the bottleneck
    assert np.rad2deg(vertical.optimal.margins.sum()) > 6372.0


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
