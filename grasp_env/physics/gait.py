"""A finger gait carried out in one continuous MuJoCo rollout, on any shape (docs/physics.md,
"Gaits").

A gait (docs/gait.md, :mod:`grasp_env.mechanics.gait`) says, pose by pose, which finger
touches which of the object's N contact sites and with what force: fingers are phased out
(lifted at a pose where they touch with zero force, gone from the next) and phased in (placed
on a free site at a pose where they touch with zero force, loaded from the next). Which finger
holds a site is immaterial to the physics, so the model has one fingertip per *site*
(:class:`~grasp_env.mechanics.Scene` with the sites as its contacts, 3 to 8): a site is touched
at a pose where some finger touches it, with that finger's force.
:class:`~grasp_env.physics.TrajectoryChecker` then carries the whole gait in one simulation
(:mod:`grasp_env.physics.motion`, "Fingers in contact"): a tip whose force ramps to zero
(at most ``released_force`` x w) leaves its face and is parked off it, and a tip being phased
in is placed at its new site, just inside the face, once its force ramps up from zero.

    rollout = check_gait(scene, rotations, contacts, forces)
    rollout.report.holds, rollout.report.predicted_holds, rollout.report.first_failure
    write_video("gait.mp4", rollout.scene, alphas_deg, rollout.report)  # physics_plots

A gait that places its fingers on more sites than the model has tips (a can turned a full
turn places each finger again and again on new points) runs with one tip per *finger*
instead (:func:`check_finger_gait`): each tip's contact point in the object's frame is given
per pose, and the tip moves to its finger's new point when it is placed again
(:mod:`grasp_env.physics.motion`, "Tips whose point changes"). Both are the same rollout: a
site's tip is a tip whose point never changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Scene
from grasp_env.mechanics.checks import real_array

from .model import check_rotations
from .motion import is_numeric
from .rollout import RolloutReport, TrajectoryChecker


@dataclass(frozen=True)
class GaitRollout:
    """A gait's MuJoCo rollout and what it was made of.

    Attributes:
        scene: the object with one contact per site (the scene given).
        rotations: (T, 3, 3) the poses.
        forces: (T, N, 3) each site's force on the object (world frame, newtons): the force of
            the finger touching it, 0 where none does.
        in_contact: (T, N) whether some finger touches each site.
        report: the rollout's verdicts (:class:`~grasp_env.physics.RolloutReport`; its
            per-finger arrays are per tip: per site, or per finger for a finger gait).
        points: (T, n, 3) each tip's object-frame contact point at each pose (metres, NaN
            where it touches nothing) for a gait with one tip per finger
            (:func:`check_finger_gait`); None: one tip per site, at the scene's contacts.
    """

    scene: Scene
    rotations: np.ndarray
    forces: np.ndarray
    in_contact: np.ndarray
    report: RolloutReport
    points: np.ndarray | None = None


def site_schedule(
    contacts: ArrayLike, finger_forces: ArrayLike, n_sites: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-site forces (T, N, 3) and contacts (T, N) of a gait given per finger:
    ``contacts`` (T, F) the site each finger touches at each pose (-1: none; integers), and
    ``finger_forces`` (T, F, 3) its force on the object (world frame, newtons; finite where it
    touches, ignored where it does not, so a gait solution's NaN rows of fingers touching
    nothing may stay). A ValueError names the pose and the fingers if two fingers touch one
    site at once, a site index outside [-1, N - 1], or a touching finger's non-finite force."""
    raw = np.asarray(contacts)
    if raw.ndim != 2 or not (np.issubdtype(raw.dtype, np.integer) or raw.size == 0):
        raise ValueError(
            f"contacts must be a (T, F) array of integers (a site index per finger, -1 for"
            f" none), got {raw.dtype} {raw.shape}"
        )
    sites = raw.astype(np.intp)
    n_poses, n_fingers = sites.shape
    if n_poses < 1 or n_fingers < 1:
        raise ValueError(f"contacts must have at least one pose and one finger, got {sites.shape}")
    if np.any((sites < -1) | (sites >= n_sites)):
        t, f = np.argwhere((sites < -1) | (sites >= n_sites))[0]
        raise ValueError(
            f"finger {f} at pose {t} touches site {sites[t, f]}: a site index must be in"
            f" [-1, {n_sites - 1}] (-1: none)"
        )
    forces = np.asarray(finger_forces, dtype=float) if is_numeric(finger_forces) else None
    if forces is None or forces.shape != (n_poses, n_fingers, 3):
        raise ValueError(
            f"finger_forces must be real numbers of shape ({n_poses}, {n_fingers}, 3), one"
            " world-frame force per finger and pose"
        )
    touching = sites >= 0
    bad = touching & ~np.all(np.isfinite(forces), axis=-1)
    if bad.any():
        t, f = np.argwhere(bad)[0]
        raise ValueError(f"finger {f} touches site {sites[t, f]} at pose {t} but its force is"
                         f" not finite: {forces[t, f].tolist()}")  # fmt: skip
    site_forces = np.zeros((n_poses, n_sites, 3))
    in_contact = np.zeros((n_poses, n_sites), dtype=bool)
    for t in range(n_poses):
        for f in np.flatnonzero(touching[t]):
            s = sites[t, f]
            if in_contact[t, s]:
                other = int(np.flatnonzero(touching[t] & (sites[t] == s))[0])
                raise ValueError(f"fingers {other} and {f} both touch site {s} at pose {t}")
            in_contact[t, s] = True
            site_forces[t, s] = forces[t, f]
    return site_forces, in_contact


def check_gait(
    scene: Scene,
    rotations: ArrayLike,
    contacts: ArrayLike,
    finger_forces: ArrayLike,
    threads: int | None = None,
    **settings: float,
) -> GaitRollout:
    """Carry a finger gait through one continuous MuJoCo rollout (see the module docstring).

    Args:
        scene: the object (any shape) with its N sites as contacts, 3 <= N <= 8, and its load
            and mu (e.g. ``Scene(shape=can, contacts=sites, weight=..., mu=...)``).
        rotations: (T, 3, 3) the object's pose at each of T poses (proper rotations).
        contacts: (T, F) the site each of F fingers touches at each pose, -1 for none.
        finger_forces: (T, F, 3) each finger's force on the object, world frame, newtons:
            zero at a pose where it is being phased out or in, finite wherever it touches.
        threads: unused by a single rollout but checked (an integer >= 1 or None), as the
            checkers do.
        **settings: overrides of :data:`grasp_env.physics.SETTINGS` (e.g. ``hold_time``).

    Returns:
        The :class:`GaitRollout`: the per-site schedule and the rollout's report, whose
        ``holds`` is MuJoCo's verdict, ``predicted_holds`` the analytic one (every loaded
        finger within its cone at every step), ``first_failure`` where MuJoCo first failed.

    A ValueError names what is wrong: a scene that is no Scene, rotations that are not proper
    rotations, a site schedule :func:`site_schedule` refuses, a site with force but no finger
    touching it, or a force above the model's ``MAX_FORCE`` w.
    """
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a grasp_env.mechanics.Scene, got {type(scene).__name__}")
    rotations = check_rotations(rotations, name="rotations")
    forces, in_contact = site_schedule(contacts, finger_forces, scene.n_contacts)
    if len(forces) != len(rotations):
        raise ValueError(
            f"contacts and finger_forces have {len(forces)} poses, rotations {len(rotations)}:"
            " one per pose"
        )
    real_array("finger_forces", forces, "finite real numbers")
    checker = TrajectoryChecker(scene, threads=threads, **settings)
    try:
        report = checker.check(rotations, forces, in_contact)
    finally:
        checker.close()
    return GaitRollout(scene, rotations, forces, in_contact, report)


def check_finger_gait(
    scene: Scene,
    rotations: ArrayLike,
    points: ArrayLike,
    finger_forces: ArrayLike,
    threads: int | None = None,
    **settings: float,
) -> GaitRollout:
    """Carry a finger gait through one continuous MuJoCo rollout with one fingertip per
    finger, whose contact point may change at each placement (see the module docstring).

    Args:
        scene: the object (any shape), its load and mu, with one contact per finger
            (3 <= F <= 8): where each finger's tip waits before it is first placed
            (:func:`first_points` of ``points``, say).
        rotations: (T, 3, 3) the object's pose at each of T poses (proper rotations).
        points: (T, F, 3) the object-frame point each finger touches at each pose, metres,
            on the object's surface; NaN where it touches nothing. A finger keeps its point
            while it carries load; it may take another only between poses where it carries
            none (lifted with zero force, placed again with zero force).
        finger_forces: (T, F, 3) each finger's force on the object, world frame, newtons:
            finite wherever it touches (zero at a pose where it is lifted or placed), ignored
            where it does not.
        threads, **settings: as :func:`check_gait`.

    Returns:
        The :class:`GaitRollout` (``points`` the points given; its report's per-finger arrays
        per finger). A ValueError names a bad input: points or forces of the wrong shape, a
        touching finger's non-finite force, a point off the surface, a point changed under
        load (:func:`~grasp_env.physics.motion.tip_points`), or a force above ``MAX_FORCE`` w.
    """
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a grasp_env.mechanics.Scene, got {type(scene).__name__}")
    rotations = check_rotations(rotations, name="rotations")
    shape = (len(rotations), scene.n_contacts, 3)
    points = np.asarray(points, dtype=float) if is_numeric(points) else None
    if points is None or points.shape != shape:
        raise ValueError(
            f"points must be real numbers of shape {shape}: per pose, the object-frame point"
            f" each of the scene's {scene.n_contacts} fingers touches (NaN for none)"
        )
    touching = np.all(np.isfinite(points), axis=-1)
    contacts = np.where(touching, np.arange(scene.n_contacts), -1)
    forces, in_contact = site_schedule(contacts, finger_forces, scene.n_contacts)
    checker = TrajectoryChecker(scene, threads=threads, **settings)
    try:
        report = checker.check(rotations, forces, in_contact, points)
    finally:
        checker.close()
    return GaitRollout(scene, rotations, forces, in_contact, report, points)


def first_points(points: ArrayLike) -> np.ndarray:
    """(F, 3) each finger's first point of ``points`` (T, F, 3; NaN where it touches nothing),
    the scene's contacts for :func:`check_finger_gait`. A ValueError names a finger that
    touches nothing at any pose."""
    points = np.asarray(points, dtype=float) if is_numeric(points) else np.zeros(0)
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points must be real numbers of shape (T, F, 3), got {points.shape}")
    touching = np.all(np.isfinite(points), axis=-1)
    never = np.flatnonzero(~touching.any(axis=0))
    if len(never):
        raise ValueError(
            f"finger {never[0]} never touches: every finger needs a point at some pose (the"
            " place its tip waits)"
        )
    return points[touching.argmax(axis=0), np.arange(points.shape[1])]


__all__ = ["GaitRollout", "check_finger_gait", "check_gait", "first_points", "site_schedule"]
