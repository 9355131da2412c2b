"""The certified gait problem along a trajectory, solved: :func:`solve_gait`."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike

from ..forces import Grasp, n_pairs
from ..hand import Hand
from ..trajectory import Trajectory
from .programme import (
    Gait,
    _follow,
    _policy_choices,
    best_fixed,
    bottleneck_bound,
    greedy_gait,
    optimal_gait,
)
from .sites import PAPER_TURN, GaitScene, SetValues, set_values, site_reach


@dataclass(frozen=True, eq=False)  # compared by identity: a record of solver output
class GaitSolution:
    """The certified gait problem along a trajectory, solved.

    Attributes:
        scene, hand, trajectory: the problem.
        values: every site set's certified minimax at every pose.
        reach: (T, F, N) which finger reaches which site.
        optimal: the optimal gait on the attained margins.
        bound: the programme's value on the certified upper bounds: no gait has a smallest
            margin above it; ``optimal.margin <= bound <= optimal.margin + gap +
            MARGIN_TOL`` (the optimal gait keeps the best margin to within MARGIN_TOL). -inf when no
            gait holds (:attr:`holds`).
        bound_gait: the gait the programme picks on the upper bounds (its attained margin
            agrees with the optimal gait's within the gap).
        greedy: the greedy baseline's gait.
        fixed: the best gait without moves.
    """

    scene: GaitScene
    hand: Hand
    trajectory: Trajectory
    values: SetValues
    reach: np.ndarray
    optimal: Gait
    bound: float
    bound_gait: Gait
    greedy: Gait
    fixed: Gait

    @property
    def holds(self) -> bool:
        """Whether some gait keeps the rules at every pose (three fingers on usable sites within
        reach). If not, ``bound`` and ``optimal.margin`` are -inf and ``optimal`` drops at the
        first pose: exactly, as reach and usable sets are no solver's estimates."""
        return self.optimal.margin > -np.inf

    @property
    def gap(self) -> float:
        """Certificate gap of the optimal gait's margin, radians (0 when no gait holds: both
        ends are -inf)."""
        return self.bound - self.optimal.margin if self.holds else 0.0

    def _poses(self, gait: Gait):
        """(t, fingers in the set's site order, grasp of the set at t, its optimal k) of every
        pose the gait holds."""
        for t in range(len(gait.margins)):
            if gait.sets[t] < 0:
                continue
            fingers = np.flatnonzero(gait.loaded[t])
            fingers = fingers[np.argsort(gait.contacts[t, fingers])]  # the set's sites increase
            group, column = self.values._locate(int(gait.sets[t]))
            g = group.grasp
            pose = Grasp(
                g.positions[t, column],
                g.normals[t, column],
                g.equilibrating[t, column],
                g.basis[t, column],
                g.friction_limit,
            )
            yield t, fingers, pose, group.optimum.k[t, column], group.optimum.angles[t, column]

    def grips(self, gait: Gait) -> tuple[np.ndarray, np.ndarray]:
        """The certified optimal grip of a gait at every pose, per finger pair and per finger:
        k (T, F (F - 1) / 2), pairs (f, g) f < g as
        :func:`~grasp_env.mechanics.contact_pairs` (F), 0 for pairs not both loaded, and
        friction angles (T, F), NaN for fingers not loaded; NaN rows after the gait breaks the
        rules."""
        F = self.hand.n_fingers
        pairs = {p: q for q, p in enumerate(combinations(range(F), 2))}
        T = len(gait.margins)
        k = np.where((gait.sets >= 0)[:, None], 0.0, np.nan) * np.ones((T, n_pairs(F)))
        angles = np.full((T, F), np.nan)
        for t, fingers, _, kt, at in self._poses(gait):
            angles[t, fingers] = at
            for q, (i, j) in enumerate(combinations(range(len(fingers)), 2)):
                k[t, pairs[tuple(sorted((fingers[i], fingers[j])))]] = kt[q]
        return k, angles

    def statuses(self, gait: Gait) -> np.ndarray:
        """The minimax :class:`~grasp_env.mechanics.Status` of the loaded set at every pose
        (T,) int8, -1 after the gait breaks the rules."""
        status = np.full(len(gait.margins), -1, np.int8)
        for t in np.flatnonzero(gait.sets >= 0):
            group, column = self.values._locate(int(gait.sets[t]))
            status[t] = group.optimum.status[t, column]
        return status

    def forces(self, gait: Gait) -> np.ndarray:
        """Each finger's contact force P_f on the object at the gait's grip, world frame,
        newtons: (T, F, 3), zero for fingers not loaded (a finger being lifted or placed
        touches with zero force), NaN after the gait breaks the rules."""
        T, F = gait.loaded.shape
        forces = np.where((gait.sets >= 0)[:, None, None], 0.0, np.nan) * np.ones((T, F, 3))
        for t, fingers, pose, kt, _ in self._poses(gait):
            forces[t, fingers] = pose.forces(kt)
        return forces

    def positions(self, gait: Gait) -> np.ndarray:
        """World-frame positions of the sites the fingers touch, relative to the centre of
        gravity, p = R (c - g): (T, F, 3), NaN where a finger touches nothing."""
        rotations = self.trajectory.rotations()
        relative = self.scene.sites - np.asarray(self.scene.cg_offset)
        world = np.einsum("tij,nj->tni", rotations, relative)  # (T, N, 3)
        sites = np.maximum(gait.contacts, 0)
        out = np.take_along_axis(world, sites[..., None], axis=1)
        out[gait.contacts < 0] = np.nan
        return out


def solve_gait(
    scene: GaitScene | None = None,
    hand: Hand | None = None,
    trajectory: Trajectory = PAPER_TURN,
    k_max: float | None = None,
    start: ArrayLike | None = None,
) -> GaitSolution:
    """The certified optimal gait, its bound, the greedy gait and the best fixed set along a
    trajectory (defaults: :class:`GaitScene`, :class:`~grasp_env.mechanics.Hand`,
    :data:`PAPER_TURN`, k_max = 2 w). Check :attr:`GaitSolution.holds`: where no gait holds
    there is no optimum to report."""
    scene = GaitScene() if scene is None else scene
    hand = Hand() if hand is None else hand
    for name, value, kind in (
        ("scene", scene, GaitScene),
        ("hand", hand, Hand),
        ("trajectory", trajectory, Trajectory),
    ):
        if not isinstance(value, kind):
            raise ValueError(f"{name} must be a {kind.__name__}, got {type(value).__name__}")
    rotations = trajectory.rotations()
    values = set_values(scene, rotations, k_max)
    reach = site_reach(scene, hand, rotations)
    optimal = optimal_gait(values.margin, reach, start)
    bound_gait = optimal_gait(values.margin_bound, reach, start)
    # the exact best bottleneck on the bounds (the bound's gait keeps it to within MARGIN_TOL)
    bound = bottleneck_bound(values.margin_bound, reach, start)
    # the bound's gait on the attained margins: the same moves, what its grips attain
    x = int(bound_gait.states[0])
    attained = bound_gait if x < 0 else _follow(
        bound_gait.table, x, _policy_choices(bound_gait.table, bound_gait.policy, x),
        values.margin, reach,
    )  # fmt: skip
    return GaitSolution(
        scene, hand, trajectory, values, reach, optimal, bound, attained,
        greedy_gait(values.margin, reach, start), best_fixed(values.margin, reach),
    )  # fmt: skip
