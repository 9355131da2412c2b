"""Grasp stability checked in MuJoCo physics: do a set of contact forces hold the box at a pose?

One check (docs/physics.md): the box at rest with its centre of gravity at the
origin, the fingertips just inside its faces, the commanded forces and the load applied; a
settle with a high friction coefficient (so that building up the contact forces cannot itself
cause slip); then a hold at the scene's mu, measuring how far each fingertip slides along its
face. The grasp holds when no fingertip in contact slides more than ``slip_threshold``, none
leaves its face by more than that, and the object stays put: its centre of gravity moves at most
``drift_threshold`` and it turns at most ``rotation_threshold_deg`` (forces that do not balance
the load carry it away, fingers and all).

A finger whose commanded force is at most ``released_force`` x w (an optimum that releases it)
carries no load: its tip is lifted off the face (its small force acts on the object directly),
it is reported as released and not judged, so it is not a lost hold.

Checks of many poses run in parallel (``check_batch``): each thread plans, steps
(``mujoco.rollout``) and measures its part of the batch, and the verdicts do not depend on the
number of threads.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Scene
from grasp_env.mechanics.checks import real_number

from .model import check_forces, check_rotations
from .motion import Motion, plan_poses
from .simulation import (
    PhysicsModel,
    Trace,
    check_cases,
    check_threads,
    in_parallel,
    simulate,
    simulate_cases,
)

# Defaults of the check and of the continuous rollout (docs/physics.md), all overridable as
# StabilityChecker and TrajectoryChecker keywords. Lengths are in units of the box's largest
# edge L, forces in units of the weight w.
SETTINGS: dict[str, float] = {
    "timestep": 0.002,  #: seconds per MuJoCo step (at most 2.5 ms: half the contact's 5 ms)
    "settle_time": 0.05,  #: seconds at ``settle_mu`` before the real mu applies
    "settle_mu": 10.0,  #: friction coefficient while the contact forces build up
    "hold_time": 0.2,  #: seconds held at the (last) pose at the scene's mu
    "slip_threshold": 1e-5,  #: slide along a face (or lift off it) that counts as slipping, L
    "slip_speed": 1e-5,  #: sliding speed along a face that counts as slipping, L/s
    "drift_threshold": 1e-3,  #: distance the centre of gravity may move, L
    "rotation_threshold_deg": 0.1,  #: angle the object may turn, degrees
    "released_force": 1e-3,  #: a finger pushing at most this, in units of w, is released
    "pose_hold_time": 0.1,  #: rollout: seconds the grip dwells at each pose but the last
    "time_per_degree": 0.05,  #: rollout: seconds per degree the object turns between poses
    "min_segment_time": 0.05,  #: rollout: least seconds between two poses
    #: rollout: a touching finger's normal force changes by at most force_rate x
    #: max(|P|, force_floor) per second (segments slowed where needed; docs/physics.md)
    "force_rate": 10.0,
    "force_floor": 0.03,  #: rollout: the floor of that bound's |P|, in units of w
    #: rollout: seconds over which each segment's pace eases in and out (the forces' rate of
    #: change continuous at the segments' ends; motion.timed_segments)
    "ramp_time": 0.01,
}
#: The contact's time constant (model.SOLREF) must span at least two steps.
MAX_TIMESTEP = 0.0025


def check_settings(settings: dict[str, float]) -> dict[str, float]:
    """The defaults updated with ``settings``, or a ValueError naming a bad key or value."""
    unknown = set(settings) - set(SETTINGS)
    if unknown:
        raise ValueError(f"unknown physics settings {sorted(unknown)}; expected {sorted(SETTINGS)}")
    merged = dict(SETTINGS)
    for name, value in settings.items():  # real numbers: no string or boolean converted
        merged[name] = real_number(name, value, 0.0, open_low=True)
    if merged["timestep"] > MAX_TIMESTEP:
        raise ValueError(
            f"timestep must be in (0, {MAX_TIMESTEP}] s (the contact's time constant spans two"
            f" steps), got {merged['timestep']}"
        )
    return merged


@dataclass(frozen=True)
class PhysicsReport:
    """The outcome of one MuJoCo check.

    Attributes:
        holds: no fingertip in contact slid or lifted off more than the slip threshold, and the
            object stayed put (drift and rotation within their thresholds; more means the forces
            do not balance the load).
        slip: (n,) largest tangential slide of each fingertip along its face during the hold,
            metres (0 for a released finger).
        contact_lost: (n,) whether fingertip i, commanded to push, left its face.
        released: (n,) whether finger i carries no load (out of contact, or commanded at most
            ``released_force`` x w): not judged, not a failure.
        drift: largest displacement of the object's centre of gravity during the hold, metres.
        rotation_deg: largest rotation of the object during the hold, degrees.
        time: simulated seconds of hold.
    """

    holds: bool
    slip: np.ndarray
    contact_lost: np.ndarray
    released: np.ndarray
    drift: float
    rotation_deg: float
    time: float

    def as_dict(self) -> dict[str, bool | float | list[float] | list[bool]]:
        """Plain Python values, e.g. for a Gymnasium ``info`` dict."""
        return {
            "holds": bool(self.holds),
            "slip": [float(s) for s in self.slip],
            "contact_lost": [bool(c) for c in self.contact_lost],
            "released": [bool(r) for r in self.released],
            "drift": float(self.drift),
            "rotation_deg": float(self.rotation_deg),
            "time": float(self.time),
        }


def pose_report(
    scene: Scene, motion: Motion, trace: Trace, settings: dict[str, float]
) -> PhysicsReport:
    """The verdict of a one-pose run (see the module docstring); lengths back in metres."""
    length = float(np.max(scene.size))
    hold = slice(motion.settle_steps, None)
    slip = trace.slip[hold].max(axis=0)
    sliding = trace.speed[hold].max(axis=0) > settings["slip_speed"]
    lost = trace.gap[hold].max(axis=0) > settings["slip_threshold"]
    released = ~motion.contact[-1]
    drift = float(trace.drift[hold].max())
    rotation = float(np.degrees(trace.rotation[hold].max()))
    holds = (
        not trace.diverged
        and np.all(slip <= settings["slip_threshold"])
        and not np.any(sliding)
        and not np.any(lost)
        and drift <= settings["drift_threshold"]
        and rotation <= settings["rotation_threshold_deg"]
    )
    return PhysicsReport(
        holds=bool(holds),
        slip=length * slip,
        contact_lost=lost & ~released,
        released=released,
        drift=length * drift,
        rotation_deg=rotation,
        time=(len(motion) - motion.settle_steps) * settings["timestep"],
    )


class Checker:
    """What the pose checker and the trajectory checker share: the scene's model, the
    settings and the threads."""

    def __init__(self, scene: Scene, threads: int | None = None, **settings: float) -> None:
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a grasp_env.mechanics.Scene, got {type(scene)}")
        self.settings = check_settings(settings)
        self.scene = scene
        #: threads for check_batch: None (every available core at the time) or an int >= 1
        self.threads = None if threads is None else check_threads(threads)
        self.physics: PhysicsModel | None = PhysicsModel(
            scene, self.settings["timestep"], self.settings["settle_mu"]
        )

    def close(self) -> None:
        """Release the models (the checker is unusable afterwards)."""
        self.physics = None

    def _in_parallel(
        self,
        report: Callable[[Sequence], list],
        items: Sequence,
        threads: int | None,
        size: int | None = None,
    ) -> list:
        """``report`` of parts of ``items`` (of ``size``, see :func:`in_parallel`) on
        ``threads`` threads (default: the checker's)."""
        if self.physics is None:
            raise ValueError(f"this {type(self).__name__} is closed")
        return in_parallel(
            report, items, check_threads(self.threads if threads is None else threads), size
        )

    def _simulate(self, motions: Sequence[Motion]) -> list[Trace]:
        """The runs of ``motions`` on the calling thread."""
        return simulate([(self.physics, motion) for motion in motions], threads=1)


class StabilityChecker(Checker):
    """Checks contact forces on ``scene`` in MuJoCo (see the module docstring).

    Args:
        scene: the grasp to simulate.
        threads: threads for :meth:`check_batch`, an integer >= 1 (default: every available
            core).
        **settings: overrides of :data:`SETTINGS` (positive finite numbers).
    """

    @property
    def model(self):
        """The MuJoCo model at the scene's mu (the settle runs on a copy)."""
        return None if self.physics is None else self.physics.model

    def reset(self) -> None:
        """Nothing to do: every check starts from the same state, whatever came before."""

    def check(
        self,
        rotation: ArrayLike,
        contact_forces: ArrayLike,
        in_contact: ArrayLike | None = None,
    ) -> PhysicsReport:
        """Simulate ``contact_forces`` (n, 3), applied by the fingers on the object in the world
        frame, at orientation ``rotation`` (3, 3), and report whether the grasp holds.
        ``in_contact`` (n,) bool says which fingers touch (default: those commanded a force)."""
        rotation = check_rotations(rotation, single=True)
        forces = check_forces(contact_forces, self.scene.n_contacts)
        contact = None if in_contact is None else np.asarray(in_contact)[None]
        return self._check(rotation[None], forces[None], contact, threads=1)[0]

    def check_batch(
        self,
        rotations: ArrayLike,
        contact_forces: ArrayLike,
        in_contact: ArrayLike | None = None,
        threads: int | None = None,
    ) -> list[PhysicsReport]:
        """:meth:`check` of B >= 1 poses at once, (B, 3, 3) and (B, n, 3) (and (B, n)), in
        parallel on ``threads`` threads (an integer >= 1; default: the checker's)."""
        rotations = check_rotations(rotations, name="rotations")
        forces = check_forces(contact_forces, self.scene.n_contacts, (len(rotations),))
        if threads is not None:
            check_threads(threads)
        return self._check(rotations, forces, in_contact, threads)

    def _check(
        self,
        rotations: np.ndarray,
        forces: np.ndarray,
        in_contact: ArrayLike | None,
        threads: int | None,
    ) -> list[PhysicsReport]:
        """:meth:`check_batch` of validated rotations and forces (validated once, here)."""
        motions = plan_poses(self.scene, rotations, forces, in_contact, self.settings, checked=True)

        def reports(part: Sequence[Motion]) -> list[PhysicsReport]:
            return [
                pose_report(self.scene, m, t, self.settings)
                for m, t in zip(part, self._simulate(part), strict=True)
            ]

        return self._in_parallel(reports, motions, threads)


def check_poses(
    cases: Sequence[tuple[Scene, ArrayLike, ArrayLike, ArrayLike | None]],
    threads: int | None = None,
    **settings: float,
) -> list[PhysicsReport]:
    """Checks of (scene, rotation, contact_forces, in_contact) cases over many scenes, all in
    parallel (runs of the same model structure share rollout calls) on ``threads`` threads
    (an integer >= 1; default: every available core). Each case is one pose, as
    :meth:`StabilityChecker.check` takes it; no case, no report."""
    settings = check_settings(settings)
    threads = check_threads(threads)
    trajectories = [
        (scene, check_rotations(rotation, single=True, name=f"case {c}'s rotation")[None],
         check_forces(forces, scene.n_contacts, name=f"case {c}'s contact_forces")[None],
         None if contact is None else np.asarray(contact)[None])
        for c, (scene, rotation, forces, contact) in enumerate(check_cases(cases, "rotation"))
    ]  # fmt: skip
    return [
        pose_report(scene, motion, trace, settings)
        for (scene, *_), (motion, trace) in zip(
            cases, simulate_cases(trajectories, settings, threads), strict=True
        )
    ]
