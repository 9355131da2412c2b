"""The coke can's finger gait (docs/gait.md, "The can") carried out in MuJoCo (docs/physics.md,
"Gaits").

The can's gait places each finger again and again on new points of its side: every
*placement* (a finger touching from the pose it is placed at, age 0, until it lifts) is one
point fixed in the can's frame. :func:`can_gait_schedule` turns a window of a
:class:`~grasp_env.mechanics.gait.can_programme.CanGaitSolution`'s gait into the sites of
:func:`~grasp_env.physics.gait.check_gait` (one site per placement, object frame) with each
finger's certified minimax force (eq. 2, 4) at every pose, and :func:`check_can_gait` runs it
in one continuous rollout with one fingertip per *finger*
(:func:`~grasp_env.physics.gait.check_finger_gait`): each tip's contact point in the can's
frame is its finger's placement at each pose (:attr:`CanSchedule.points`), so a lifted tip is
parked off the side and moves to its finger's new point when placed again. The whole turn
(37 poses, 16 placements for the default hand) runs in one rollout; ``start`` and ``stop``
take a window of it.

    rollout = check_can_gait(solve_can_gait())
    rollout.report.holds, rollout.report.predicted_holds, rollout.report.first_failure
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from grasp_env.mechanics import Scene
from grasp_env.mechanics.forces import grasp, load_wrench
from grasp_env.mechanics.gait.can import contact_points
from grasp_env.mechanics.gait.can_programme import CanGait, CanGaitSolution

from .gait import GaitRollout, check_finger_gait, first_points

#: Largest difference, radians, between a finger's friction angle recomputed from the
#: solution's k and the angle the solver reported: more means a gait of another solution.
ANGLE_TOL = 1e-7


@dataclass(frozen=True)
class CanSchedule:
    """A window [start, stop) of the can's gait as sites and per-finger forces.

    Attributes:
        sites: (N, 3) one object-frame point per placement in the window.
        contacts: (T, F) the site each finger touches (-1: none).
        finger_forces: (T, F, 3) each finger's world-frame force, newtons (0 where it touches
            unloaded, being placed or lifted; NaN where it touches nothing).
        rotations: (T, 3, 3) the can's poses.
        alphas_deg: (T,) the turn angle at each pose.
    """

    sites: np.ndarray
    contacts: np.ndarray
    finger_forces: np.ndarray
    rotations: np.ndarray
    alphas_deg: np.ndarray

    @property
    def points(self) -> np.ndarray:
        """(T, F, 3) the object-frame point each finger touches at each pose (its placement's
        site), metres; NaN where it touches nothing."""
        points = self.sites[np.maximum(self.contacts, 0)]
        points[self.contacts < 0] = np.nan
        return points


def _window(n_poses: int, start: int, stop: int | None) -> tuple[int, int]:
    stop = n_poses if stop is None else stop
    for name, value in (("start", start), ("stop", stop)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
            raise ValueError(f"{name} must be an integer pose index, got {value!r}")
    if not 0 <= start < stop <= n_poses or stop - start < 2:
        raise ValueError(
            f"the window [start, stop) = [{start}, {stop}) must hold at least two poses"
            f" within [0, {n_poses}]"
        )
    return int(start), int(stop)


def can_gait_schedule(
    solution: CanGaitSolution,
    gait: CanGait | None = None,
    start: int = 0,
    stop: int | None = None,
    cg_height: float = 0.0,
) -> CanSchedule:
    """The sites and forces of poses [start, stop) of ``gait`` (default the optimal one).

    Each finger's force at a pose is the certified grip of the configuration loaded there
    (k from the solver, P = F + sum k_ij e_ij, eq. 1), turned with the can. The recomputed
    friction angles are checked against the solver's to :data:`ANGLE_TOL` (a gait from another
    solution fails it). ``cg_height`` is the centre of gravity's height on the axis; with the
    weight along the axis it moves no grip, so it sets only the MuJoCo model's centre of
    gravity. A ValueError names a bad window or a gait that drops inside it.
    """
    if not isinstance(solution, CanGaitSolution):
        raise ValueError(f"solution must be a CanGaitSolution, got {type(solution).__name__}")
    gait = solution.optimal if gait is None else gait
    if not isinstance(gait, CanGait):
        raise ValueError(f"gait must be a CanGait, got {type(gait).__name__}")
    start, stop = _window(len(gait.configs), start, stop)
    if np.any(gait.configs[start:stop] < 0):
        t = start + int(np.flatnonzero(gait.configs[start:stop] < 0)[0])
        raise ValueError(f"the gait drops at pose {t}: a window must end before its drop")
    hand, step = solution.hand, solution.turn.step_deg
    alphas = solution.turn.alphas_deg[start:stop]
    rotations = solution.turn.rotations()[start:stop]
    ages = gait.ages[start:stop]
    T, F = ages.shape
    contacts = np.full((T, F), -1, np.intp)
    sites: list[np.ndarray] = []
    for f in range(F):
        for t in range(T):
            if ages[t, f] < 0:
                continue
            if t == 0 or ages[t - 1, f] < 0 or ages[t, f] != ages[t - 1, f] + 1:
                point, _ = contact_points(
                    solution.can, hand, step, [f], np.where(ages[t] < 0, 0, ages[t])
                )
                sites.append(rotations[t].T @ point[0])  # the world point in the can's frame
                contacts[t, f] = len(sites) - 1
            else:
                contacts[t, f] = contacts[t - 1, f]
    forces = np.full((T, F, 3), np.nan)
    forces[contacts >= 0] = 0.0
    cg = np.array([0.0, 0.0, float(cg_height)])
    wrench = load_wrench(solution.weight)
    for t in range(T):
        config = int(gait.configs[start + t])
        k, angles = solution.values.grip(config)
        fingers = np.array([f for f, _ in solution.values.configs[config]])
        all_ages = np.where(ages[t] < 0, 0, ages[t])
        points, normals = contact_points(solution.can, hand, step, fingers, all_ages)
        g = grasp(points - cg, normals, np.eye(3), wrench, solution.friction_limit)
        if np.max(np.abs(g.angles(k) - angles)) > ANGLE_TOL:
            raise ValueError(
                f"the grip at pose {start + t} does not reproduce the solver's friction angles:"
                " pass the gait of this solution and the cg_height it was solved with"
            )
        forces[t, fingers] = g.forces(k)
    return CanSchedule(np.array(sites), contacts, forces, rotations, alphas)


def check_can_gait(
    solution: CanGaitSolution,
    gait: CanGait | None = None,
    start: int = 0,
    stop: int | None = None,
    cg_height: float = 0.0,
    **settings: float,
) -> GaitRollout:
    """Carry poses [start, stop) of the can's gait (default: the whole turn) through one
    continuous MuJoCo rollout: :func:`can_gait_schedule`, then
    :func:`~grasp_env.physics.gait.check_finger_gait` with one tip per finger, each at its
    placement's point (:attr:`CanSchedule.points`), waiting before its first placement where
    it is first placed. ``settings`` override :data:`~grasp_env.physics.SETTINGS`. A
    ValueError names a bad window, a gait that drops inside it, or a finger that touches
    nothing in it (its tip has no place to wait: take a longer window)."""
    schedule = can_gait_schedule(solution, gait, start, stop, cg_height)
    points = schedule.points
    scene = Scene(
        shape=solution.can, contacts=first_points(points), weight=solution.weight,
        mu=solution.mu, cg_offset=[0.0, 0.0, float(cg_height)],
    )  # fmt: skip
    return check_finger_gait(scene, schedule.rotations, points, schedule.finger_forces, **settings)


__all__ = ["ANGLE_TOL", "CanSchedule", "can_gait_schedule", "check_can_gait"]
