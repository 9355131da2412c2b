"""The grasp carried through a whole trajectory in one MuJoCo simulation (docs/physics.md).

One run settles the grasp at the first pose, then turns the load quasi-statically in the object's
frame from pose to pose while the finger forces follow the grip continuously
(:mod:`grasp_env.physics.motion`), and holds at the last pose. Slip, drift and rotation
accumulate over the whole run. The analytic side judges the very forces MuJoCo applies, at every
step (the intermediate alphas included), so the two verdicts are about the same motion.

The report gives, per pose (the steps nearer to that pose than to its neighbours), the analytic
verdict (every finger in contact within its cone) and MuJoCo's (no finger slid or lifted off
more than the slip threshold, and the object did not move or turn more than the drift and
rotation thresholds, within that interval); for the whole trajectory, the same with the
measures accumulated from the start; and where each verdict first failed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Scene

from .motion import Motion, plan_motion
from .simulation import Trace, check_threads, described, simulate_cases
from .stability import Checker, check_settings


@dataclass(frozen=True)
class RolloutReport:
    """The outcome of one continuous rollout of T poses.

    Attributes:
        holds: MuJoCo's verdict on the whole run: no fingertip in contact slid or lifted off
            more than the slip threshold since it was placed, and the object's drift and
            rotation since the settle stayed within their thresholds.
        predicted_holds: the analytic verdict: at every step, the forces balance the load and
            every finger in contact is within its friction cone.
        pose_holds: (T,) MuJoCo's verdict within each pose's interval (the increments there).
        pose_predicted: (T,) the analytic verdict within each pose's interval.
        max_angle_deg: (T,) the largest friction angle of a finger in contact over each pose's
            interval, degrees.
        margin_deg: atan(mu) minus the largest friction angle over the whole run, degrees.
        slip: (T, n) each fingertip's slide since it was placed, at the end of each pose's
            interval, metres.
        drift: (T,) the centre of gravity's displacement since the settle, metres.
        rotation_deg: (T,) the object's rotation since the settle, degrees.
        first_failure: the pose coordinate (t + s between poses t and t + 1) where MuJoCo's
            accumulated measures first crossed a threshold; None if they never did.
        predicted_first_failure: the pose coordinate where a friction angle first passed the
            limit (or the forces first missed balancing the load); None if none did.
        time: simulated seconds after the settle.
        motion, trace: the run's steps and measurements (for plots and video).

    ``diverged`` says whether MuJoCo stopped the run on a warning (an unstable simulation)
    before its end; such a run fails at its last pose.
    """

    holds: bool
    predicted_holds: bool
    pose_holds: np.ndarray
    pose_predicted: np.ndarray
    max_angle_deg: np.ndarray
    margin_deg: float
    slip: np.ndarray
    drift: np.ndarray
    rotation_deg: np.ndarray
    first_failure: float | None
    predicted_first_failure: float | None
    time: float
    motion: Motion = field(repr=False, compare=False)
    trace: Trace = field(repr=False, compare=False)

    @property
    def agrees(self) -> bool:
        return self.holds == self.predicted_holds

    @property
    def diverged(self) -> bool:
        return bool(self.trace.diverged)

    def as_dict(self) -> dict:
        """Plain Python values (the per-step motion and trace left out)."""
        return {
            "holds": bool(self.holds),
            "predicted_holds": bool(self.predicted_holds),
            "pose_holds": [bool(h) for h in self.pose_holds],
            "pose_predicted": [bool(h) for h in self.pose_predicted],
            "max_angle_deg": [float(a) for a in self.max_angle_deg],
            "margin_deg": float(self.margin_deg),
            "slip": self.slip.tolist(),
            "drift": [float(d) for d in self.drift],
            "rotation_deg": [float(r) for r in self.rotation_deg],
            "first_failure": self.first_failure,
            "predicted_first_failure": self.predicted_first_failure,
            "time": float(self.time),
            "diverged": self.diverged,
        }


def rollout_report(
    scene: Scene, motion: Motion, trace: Trace, settings: dict[str, float]
) -> RolloutReport:
    """The per-pose and trajectory verdicts of a run (see the module docstring)."""
    length = float(np.max(scene.size))
    limit = scene.friction_limit
    settle = motion.settle_steps
    poses = motion.pose_index
    n_poses = motion.n_poses
    angles = motion.friction_angles(scene)[settle:]
    largest = angles.max(axis=-1)
    slip, gap = trace.slip[settle:], trace.gap[settle:]
    drift, turn = trace.drift[settle:], trace.rotation[settle:]
    pose, index = motion.pose[settle:], poses[settle:]
    threshold = settings["slip_threshold"]
    rotation_limit = np.radians(settings["rotation_threshold_deg"])
    sliding = trace.speed[settle:] > settings["slip_speed"]
    failing = (
        (slip.max(axis=-1) > threshold)
        | sliding.any(axis=-1)
        | (gap.max(axis=-1) > threshold)
        | (drift > settings["drift_threshold"])
        | (turn > rotation_limit)
    )
    if trace.diverged:
        failing[-1] = True
    # The cones judge a grip: forces that do not balance the load (beyond the released
    # fingers' left out) fail the analytic verdict, as the object they push away fails MuJoCo's.
    unbalanced = motion.imbalance(scene)[settle:] > scene.n_contacts * settings["released_force"]
    passing_limit = (largest > limit) | unbalanced

    # Per pose: the steps of its interval (every pose has some: its dwell or the final hold),
    # measured from the step before it; each a reduction over the intervals at once.
    starts = np.searchsorted(index, np.arange(n_poses))
    ends = np.searchsorted(index, np.arange(n_poses), side="right")
    before = np.maximum(starts - 1, 0)

    def most(values: np.ndarray) -> np.ndarray:
        return np.maximum.reduceat(values, starts, axis=0)

    grew = most(slip) - np.where(trace.measured[settle + before], slip[before], 0)
    pose_holds = ~(
        np.any(grew > threshold, axis=-1)
        | most(sliding.any(axis=-1))
        | (most(gap.max(axis=-1)) > threshold)
        | (most(drift) - drift[before] > settings["drift_threshold"])
        | (most(turn) - turn[before] > rotation_limit)
        | (trace.diverged & (ends == len(index)))
    )
    max_angle = most(largest)
    pose_predicted = ~most(passing_limit)
    last = ends - 1

    def first(flags: np.ndarray) -> float | None:
        return float(pose[np.argmax(flags)]) if flags.any() else None

    return RolloutReport(
        holds=not failing.any(),
        predicted_holds=not passing_limit.any(),
        pose_holds=pose_holds,
        pose_predicted=pose_predicted,
        max_angle_deg=np.degrees(max_angle),
        margin_deg=float(np.degrees(limit - largest.max())),
        slip=length * np.maximum.accumulate(slip, axis=0)[last],
        drift=length * drift[last],
        rotation_deg=np.degrees(turn[last]),
        first_failure=first(failing),
        predicted_first_failure=first(passing_limit),
        time=len(pose) * settings["timestep"],
        motion=motion,
        trace=trace,
    )


class TrajectoryChecker(Checker):
    """Carries grips through trajectories of ``scene`` in MuJoCo (see the module docstring).

    Args:
        scene: the grasp to simulate.
        threads: threads for :meth:`check_batch`, an integer >= 1 (default: every available
            core).
        **settings: overrides of :data:`grasp_env.physics.SETTINGS`.
    """

    def plan(
        self,
        rotations: ArrayLike,
        contact_forces: ArrayLike,
        in_contact: ArrayLike | None = None,
        points: ArrayLike | None = None,
    ) -> Motion:
        """The steps a run of this grip takes (see :func:`grasp_env.physics.motion.plan_motion`)."""
        return plan_motion(self.scene, rotations, contact_forces, in_contact, self.settings, points)

    def check(
        self,
        rotations: ArrayLike,
        contact_forces: ArrayLike,
        in_contact: ArrayLike | None = None,
        points: ArrayLike | None = None,
    ) -> RolloutReport:
        """Carry ``contact_forces`` (T, n, 3; world frame, newtons, the fingers' forces on the
        object at each pose) along ``rotations`` (T, 3, 3) in one simulation. ``in_contact``
        (T, n) bool says which fingers touch at each pose (default: those commanded a force);
        ``points`` (T, n, 3) each tip's object-frame contact point at each pose, metres, for
        tips placed again elsewhere (default: the scene's contacts throughout); see
        :mod:`grasp_env.physics.motion` for how fingers leave and join."""
        return self.check_batch([(rotations, contact_forces, in_contact, points)], threads=1)[0]

    def check_batch(
        self,
        grips: Sequence[tuple[ArrayLike, ...]],
        threads: int | None = None,
    ) -> list[RolloutReport]:
        """:meth:`check` of several (rotations, contact_forces, in_contact[, points]) grips,
        in parallel on ``threads`` threads (an integer >= 1; default: the checker's). No grip,
        no report."""
        if isinstance(grips, str | bytes) or not isinstance(grips, Sequence):
            raise ValueError(
                "grips must be a list of (rotations, contact_forces, in_contact) tuples, got"
                f" {type(grips).__name__}"
            )
        for g, grip in enumerate(grips):
            if not isinstance(grip, tuple | list) or len(grip) not in (3, 4):
                raise ValueError(
                    f"grip {g} must be a (rotations, contact_forces, in_contact) tuple"
                    f" (in_contact may be None; a fourth item, points, optional), got"
                    f" {described(grip)}"
                )
        if threads is not None:
            check_threads(threads)

        def reports(part: Sequence[tuple]) -> list[RolloutReport]:
            motions = [self.plan(*grip) for grip in part]
            return [
                rollout_report(self.scene, m, t, self.settings)
                for m, t in zip(motions, self._simulate(motions), strict=True)
            ]

        # a grip at a time: one thread's planning and measuring overlap the other's stepping
        return self._in_parallel(reports, list(grips), threads, size=1)


def check_trajectories(
    cases: Sequence[tuple[Scene, ArrayLike, ArrayLike, ArrayLike | None]],
    threads: int | None = None,
    **settings: float,
) -> list[RolloutReport]:
    """Rollouts of (scene, rotations, contact_forces, in_contact) cases over many scenes, all in
    parallel (runs of the same model structure share rollout calls) on ``threads`` threads
    (an integer >= 1; default: every available core). Each case is a trajectory of T >= 1
    poses, as :meth:`TrajectoryChecker.check` takes it; no case, no report."""
    settings = check_settings(settings)
    return [
        rollout_report(scene, motion, trace, settings)
        for (scene, *_), (motion, trace) in zip(
            cases, simulate_cases(cases, settings, threads), strict=True
        )
    ]
