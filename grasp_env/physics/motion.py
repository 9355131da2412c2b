"""The motion a MuJoCo run carries out, step by step, in the model's frame and units.

Numpy and one numba kernel (no MuJoCo here): the same per-step forces are judged analytically
(friction angles) and simulated, so both verdicts judge the same forces (docs/physics.md, "The
motion").

A trajectory of T poses R_t with per-pose finger forces P_t (world frame) becomes:

1. a settle at pose 0 (``settle_time``; the simulation runs it at a high friction coefficient
   so that building up the contact forces cannot itself cause slip);
2. at each pose but the last, a dwell of ``pose_hold_time`` with the pose's grip (the policy acts
   at the poses: a grip that slips only at a pose slips while it dwells there), then a segment
   to the next pose lasting ``time_per_degree`` per degree turned (at least
   ``min_segment_time``): the orientation turns along the geodesic from R_t to R_{t+1} (for a
   trajectory about one axis, Rot(b, s da) R_t), so the load, fixed in the world, turns in the
   object's frame, and the finger forces follow the grip continuously;
3. a hold at the last pose (``hold_time``).

**The grip between poses.** In the object's frame the contacts are fixed, so the grasp matrix G
is constant and only the load turns. Each pose's forces split into the equilibrating part
F(t) = G^+ (-(f_t, tau_t)) (over the fingers in contact) and the rest, P_t - F(t), which lies in
G's null space (the interaction forces, sum k_ij e_ij, for forces that balance the load). Between
poses the equilibrating part is exact for the turned load and the rest is interpolated linearly:
P(s) = F(s) + (1 - s) (P_t - F(t)) + s (P_{t+1} - F(t+1)). So the forces balance the load at
every step, exactly as the analytic grasp does, and for the same finger set this is the linear
interpolation of the interaction scalars k. Forces that do not balance the load at the poses do
not at the steps between either (their residual is interpolated too).

**The timing between poses** (:func:`timed_segments`). The base timing runs each segment's path
coordinate s uniformly in time. Where a touching finger's normal force N_i would change faster
than ``force_rate`` x max(|P_i|, ``force_floor``) per second, the segment is slowed there: its
path is sampled ``FINE`` times per base step, each sample interval gets the time the bound
needs (at least its base time), and the steps are spaced evenly in that clock. Only the timing
changes: every step is a point of the same path P(s), so the forces judged (both verdicts)
are the path's. MuJoCo's soft contact needs it: the tip's penetration follows its normal
force, and a force that falls by a large fraction within a few contact time constants leaves
the contact's normal force below the commanded one (docs/physics.md, "The motion").

**Fingers in contact** (the hook for finger-phasing gaits): ``in_contact`` (T, n), default
all. A finger leaving contact between t and t + 1 ramps its force to zero over the segment and
is lifted at its end; a finger joining is placed at the segment's start and its force ramps up
from zero; the others hold.

**Released fingers.** A finger whose force at a step is at most ``released_force`` x w carries
no load worth the name (an optimum that releases a finger leaves it about 1e-11 w). Its tip is
lifted off the face, and its small force is applied to the object at its contact point as an
ideal force, so the load stays balanced; neither verdict judges it there, and it is not a lost
hold. (A fingertip pushing with a thousandth of the weight or less is at the mercy of every
tremor of the contact solver, and slides too slowly to show whether it slips.) So the
fingertips that touch are exactly those in contact and loaded: a finger leaving contact is
lifted once its force has ramped below ``released_force`` x w, and one joining is placed once
its force has ramped above it.

**Tips whose point changes** (a gait's fingers placed again and again on new points, one tip
per finger: ``points`` (T, n, 3), each tip's object-frame contact point at each pose, finite
where it is in contact). A tip keeps its point while it touches; out of contact it keeps the
point it last had (the scene's contact before its first), so a lifted tip is parked off the
point it left, and once placed it sits just inside the face at its new point. Within a segment
each tip has one point (its point at the segment's start if it touches there, else at its
end), so the grasp matrix of the load-sharing fingers is constant along each segment and the
grip between poses is as above; a tip may change its point between two poses where it touches
only if it carries no load at either (lifted at the first, placed at the second). The
motion's steps then carry their points and normals (:attr:`Motion.points`,
:attr:`Motion.normals`), which the simulation and both verdicts use; without ``points`` every
step has the scene's contacts, as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Scene, axis_angle_matrix, friction_angles, grasp_matrix
from grasp_env.mechanics import matrix_quaternion as _quaternion
from grasp_env.mechanics.forces import vector_norms

from .model import (
    MAX_FORCE,
    check_forces,
    check_rotations,
    length_unit,
    model_cg,
    model_contacts,
)

#: Largest number of simulation steps of one run (a guard against a mistyped setting).
MAX_STEPS = 2_000_000


@dataclass(frozen=True)
class Motion:
    """A run, step by step (N steps), in the model's frame and units.

    Attributes:
        forces: (N, n, 3) each finger's commanded force on the object, object frame, units of w.
        load: (N, 6) the load on the object about its centre of gravity, object frame: force in
            units of w, torque in units of w L.
        contact: (N, n) whether each fingertip touches (is placed) during the step: in contact
            and pushing with more than ``released_force`` x w. These are the fingers both
            verdicts judge; the others' forces act on the object as ideal forces.
        pose: (N,) the pose coordinate of the step: t + s between poses t and t + 1.
        rotations: (N, 3, 3) the world orientation of the object the step stands for.
        settle_steps: the first ``settle_steps`` steps are the settle at pose 0.
        points: (N, n, 3) each tip's contact point at each step, object frame, model units
            (relative to the box centre), for tips whose point changes (see the module
            docstring); None: the scene's contacts at every step.
        normals: (N, n, 3) the inward unit normals at ``points``; None with it.
    """

    forces: np.ndarray
    load: np.ndarray
    contact: np.ndarray
    pose: np.ndarray
    rotations: np.ndarray
    settle_steps: int
    points: np.ndarray | None = None
    normals: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.pose)

    @property
    def n_poses(self) -> int:
        return round(float(self.pose[-1])) + 1

    @property
    def pose_index(self) -> np.ndarray:
        """(N,) the pose whose interval each step belongs to (nearest pose); -1 while settling."""
        index = np.floor(self.pose + 0.5).astype(int)
        index[: self.settle_steps] = -1
        return index

    def friction_angles(self, scene: Scene) -> np.ndarray:
        """(N, n) the analytic friction angle of each finger's force at each step, radians; 0 for
        a finger that does not touch (out of contact or released)."""
        normals = scene.normals if self.normals is None else self.normals
        angles = friction_angles(self.forces, normals)
        return np.where(self.contact, angles, 0.0)

    def imbalance(self, scene: Scene) -> np.ndarray:
        """(N,) how far each step's forces miss balancing its load: the largest component of
        the net wrench, in w and w L. A grip balances it exactly (paper eq. 4), but for the
        released fingers' forces that the motion leaves out (each at most ``released_force``
        x w); forces given otherwise do not."""
        if self.points is None:
            positions = model_contacts(scene) - model_cg(scene)
            wrench = self.forces.reshape(len(self.forces), -1) @ grasp_matrix(positions).T
        else:  # each step's own contact points
            arms = self.points - model_cg(scene)
            wrench = np.concatenate(
                [self.forces.sum(axis=1), np.cross(arms, self.forces).sum(axis=1)], axis=-1
            )
        return np.abs(wrench + self.load).max(axis=-1)


def _load(scene: Scene, rotations: np.ndarray) -> np.ndarray:
    """The load (..., 6) in the object frame at world orientations (..., 3, 3), model units."""
    w, length = scene.weight, length_unit(scene)
    force = np.array([0.0, 0.0, -w]) + scene.extra_force
    # Row vectors: x @ R is R^T x, the world vector in the object's frame.
    return np.concatenate(
        [(force / w) @ rotations, (scene.extra_torque / (w * length)) @ rotations], axis=-1
    )


#: Path samples per base step from which a segment's timing is computed.
FINE = 8


@numba.njit(nogil=True, cache=True, error_model="numpy")
def timed_segments(
    terms: np.ndarray,
    angles: np.ndarray,
    base_steps: np.ndarray,
    normals: np.ndarray,
    touching: np.ndarray,
    timestep: float,
    released_force: float,
    force_floor: float,
    force_rate: float,
    max_steps: int,
    ramp_time: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The path coordinates s in (0, 1] of every segment's steps, one segment after another,
    each segment's number of steps, and whether they fit in ``max_steps`` (if not, nothing
    else is computed: empty arrays and False). The base timing (``base_steps`` x
    ``timestep`` seconds, s uniform in time) slowed wherever a touching finger's normal
    force N_i would change faster than ``force_rate`` x max(|P_i|, ``force_floor``) per
    second (|P_i| rather than N_i: a finger pushing nearly along its face is far outside its
    cone anyway, and must not stall the run). Each segment's path is sampled :data:`FINE`
    times per base step, its forces (units of w) there given by ``terms`` (S, 5, n x 3) as
    (cos phi, 1 - cos phi, sin phi, 1 - s, s) @ terms[t] with phi = s x ``angles``[t];
    ``normals`` (S, n, 3) are each segment's inward normals, ``touching`` (S, n) its fingers
    in contact. Each sample interval takes the time the bound needs (at least its base time),
    and the steps are spaced evenly in that clock (s interpolated between the samples).

    **Eased ends** (``ramp_time`` r, seconds). The path's pace then jumps at each segment's
    ends, from the dwell's standstill to the clock's pace and back, and a force whose rate of
    change jumps kicks the soft contact (a critically damped filter of the commanded force,
    5 ms): the tip's lag changes by about the jump times the time constant within a step,
    which is a slide for a finger near its cone's edge (docs/physics.md, "Agreement on every
    shape"). So each segment runs for r more seconds, its clock c taken up at a pace rising
    linearly from zero over the first r and falling to zero over the last r (c = tau^2 / 2r,
    then tau - r / 2, then C - (C + r - tau)^2 / 2r, for a clock of C seconds, r at most C):
    the force's rate of change is continuous and never faster than the bound, and the
    segment's middle keeps its pace. ``ramp_time`` 0 is the unramped timing.

    Only the timing changes: the steps are points of the same path, so the forces both
    verdicts judge are the path's. The soft contact needs this: a tip's penetration follows
    its normal force, and a light tip moved fast lags, so its contact's normal force falls
    below the commanded one (docs/physics.md). Compiled, and without the GIL: it is most of
    a rollout's planning, which threads then plan in parallel."""
    segments, n = len(base_steps), normals.shape[1]
    counts = np.empty(segments, dtype=np.int64)
    parts = []
    total = 0
    for t in range(segments):
        samples = FINE * base_steps[t] + 1
        x = np.linspace(0.0, 1.0, samples)
        normal = np.empty((samples, n))
        magnitude = np.empty((samples, n))
        for j in range(samples):
            phi = x[j] * angles[t]
            q = (np.cos(phi), 1.0 - np.cos(phi), np.sin(phi), 1.0 - x[j], x[j])
            for i in range(n):
                along, squared = 0.0, 0.0
                for c in range(3):
                    force = 0.0
                    for k in range(5):
                        force += q[k] * terms[t, k, 3 * i + c]
                    along += force * normals[t, i, c]
                    squared += force * force
                normal[j, i], magnitude[j, i] = along, np.sqrt(squared)
        clock = np.zeros(samples)
        duration = base_steps[t] * timestep
        for j in range(samples - 1):
            need = (x[j + 1] - x[j]) * duration
            for i in range(n):
                loaded = magnitude[j, i] > released_force or magnitude[j + 1, i] > released_force
                if touching[t, i] and loaded:  # in contact in the interval
                    size = max(min(magnitude[j, i], magnitude[j + 1, i]), force_floor)
                    need = max(need, abs(normal[j + 1, i] - normal[j, i]) / (force_rate * size))
            clock[j + 1] = clock[j] + need
        span = clock[-1]
        ramp = min(ramp_time, span)
        steps_needed = max(1.0, np.rint((span + ramp) / timestep))
        if total + steps_needed > max_steps:  # a mistyped setting: stop before allocating
            return np.empty(0), np.empty(0, dtype=np.int64), False
        steps = int(steps_needed)
        total += steps
        times = np.arange(1, steps + 1) * ((span + ramp) / steps)
        if ramp > 0.0:  # the clock taken up at a pace eased in and out over ramp seconds
            for k in range(steps):
                tau = times[k]
                if tau < ramp:
                    times[k] = tau * tau / (2.0 * ramp)
                elif tau > span:
                    times[k] = span - (span + ramp - tau) ** 2 / (2.0 * ramp)
                else:
                    times[k] = tau - 0.5 * ramp
        s = np.interp(times, clock, x)
        s[-1] = 1.0
        counts[t] = steps
        parts.append(s)
    out = np.empty(counts.sum())
    start = 0
    for t in range(segments):
        out[start : start + counts[t]] = parts[t]
        start += counts[t]
    return out, counts, True


def path_settings(settings: dict[str, float], density: int = 8) -> dict[str, float]:
    """Settings whose run samples the same force path uniformly (no timing by the forces),
    ``density`` times as finely as the base timing. The steps of a run timed by
    :func:`timed_segments` are points of this path, so its steps' forces are affine in the
    pose forces (as a bisection on a force change needs) and their largest friction angle is,
    to the sampling, the timed run's."""
    return dict(
        settings,
        time_per_degree=settings["time_per_degree"] * density,
        min_segment_time=settings["min_segment_time"] * density,
        force_rate=np.inf,
    )


def released(forces: np.ndarray, weight: float, released_force: float) -> np.ndarray:
    """Fingers whose force is at most ``released_force`` x w: they carry no load."""
    # in units of w first, where a grip's forces are of order 1 (a 1e-299 N force on a
    # 1e-300 N scene is no released one); beyond 1e150 w the square is inf: not released
    return np.linalg.norm(forces / weight, axis=-1) <= released_force


def _check_contact(
    scene: Scene, forces: np.ndarray, in_contact: ArrayLike | None, settings: dict[str, float]
) -> np.ndarray:
    """``in_contact`` (T, n) for ``forces`` (T, n, 3) (None: every finger), or a ValueError:
    a finger out of contact must carry no force, and none more than :data:`MAX_FORCE` w."""
    n_poses, n = forces.shape[:2]
    force = vector_norms(forces) / scene.weight
    if np.any(force > MAX_FORCE):
        t, i = np.argwhere(force > MAX_FORCE)[0]
        raise ValueError(
            f"finger {i}'s force at pose {t} is {force[t, i]:.4g} w: the MuJoCo contact"
            f" carries at most {MAX_FORCE:g} w a finger faithfully (a tip pressed harder sinks"
            " through the face)"
        )
    if in_contact is None:
        return np.ones((n_poses, n), dtype=bool)
    contact = np.asarray(in_contact)
    if contact.shape != (n_poses, n) or contact.dtype != bool:
        raise ValueError(
            f"in_contact must be a boolean array of shape ({n_poses}, {n}), got"
            f" {contact.dtype} {contact.shape}"
        )
    pushing = ~contact & ~released(forces, scene.weight, settings["released_force"])
    if np.any(pushing):
        t, i = np.argwhere(pushing)[0]
        raise ValueError(
            f"finger {i} is out of contact at pose {t} but its force is"
            f" {vector_norms(forces[t, i]):.6g} N: a finger out of contact carries none"
        )
    return contact


def tip_points(
    scene: Scene, points: ArrayLike, contact: np.ndarray, carrying: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each tip's contact point and inward normal at each of T poses, (T, n, 3) each, object
    frame, model units, from ``points`` (T, n, 3, metres, relative to the box centre; finite
    where ``contact`` (T, n), ignored elsewhere): a tip out of contact keeps the point it last
    had (the scene's contact before its first). ``carrying`` (T, n) says which tips carry
    load. A ValueError names the tip and the pose of a point that is not finite where the tip
    touches, not on the object's surface, or changed between two poses where the tip touches
    and carries load at either (it must be lifted and placed again with zero force)."""
    n_poses, n = contact.shape
    shape = (n_poses, n, 3)
    raw = np.asarray(points) if is_numeric(points) else None
    if raw is None or raw.shape != shape:
        raise ValueError(
            f"points must be real numbers of shape {shape}: each tip's object-frame contact"
            " point at each pose (NaN where it is out of contact)"
        )
    raw = raw.astype(float)
    bad = contact & ~np.all(np.isfinite(raw), axis=-1)
    if bad.any():
        t, i = np.argwhere(bad)[0]
        raise ValueError(f"tip {i} touches at pose {t} but its point is not finite: {raw[t, i]}")
    filled = np.empty(shape)
    last = np.asarray(scene.contacts, dtype=float)
    for t in range(n_poses):
        last = np.where(contact[t, :, None], raw[t], last)
        filled[t] = last
    unique, inverse = np.unique(filled.reshape(-1, 3), axis=0, return_inverse=True)
    try:
        normals = scene.shape.inward_normals(unique)[inverse.ravel()].reshape(shape)
    except ValueError as error:
        raise ValueError(f"points: a tip's point is off the {scene.shape.kind}: {error}") from None
    moved = np.any(filled[1:] != filled[:-1], axis=-1) & contact[1:] & contact[:-1]
    loaded_move = moved & (carrying[1:] | carrying[:-1])
    if loaded_move.any():
        t, i = np.argwhere(loaded_move)[0]
        raise ValueError(
            f"tip {i} changes its point between poses {t} and {t + 1} while it carries load:"
            f" lift it with zero force at pose {t} and place it with zero force at {t + 1}"
        )
    return filled / length_unit(scene), normals


def is_numeric(value: ArrayLike) -> bool:
    """Whether ``value`` is an array of integers or reals (no strings, booleans or objects)."""
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):
        return False
    return array.dtype.kind in "iuf"


def plan_poses(
    scene: Scene,
    rotations: ArrayLike,
    forces: ArrayLike,
    in_contact: ArrayLike | None,
    settings: dict[str, float],
    checked: bool = False,
) -> list[Motion]:
    """The one-pose runs (settle, then hold) of B poses at once: ``rotations`` (B, 3, 3),
    ``forces`` (B, n, 3, world frame, newtons), ``in_contact`` (B, n; None: every finger).
    Each is :func:`plan_motion` of that one pose (the same arrays), planned in one vectorised
    pass; ``checked``: the inputs are already validated float arrays."""
    if not checked:
        rotations = check_rotations(rotations, name="rotations")
        forces = check_forces(forces, scene.n_contacts, (len(rotations),))
    contact = _check_contact(scene, forces, in_contact, settings)
    dt = settings["timestep"]
    settle = max(1, round(settings["settle_time"] / dt))
    steps = settle + max(1, round(settings["hold_time"] / dt))
    if steps > MAX_STEPS:
        raise ValueError(
            f"the run would take more than {MAX_STEPS} steps: lower settle_time or hold_time,"
            " or raise timestep"
        )
    # Row vectors: P @ R is R^T P, the force in the object's frame; in units of w.
    pose_forces = np.einsum("tnc,tcd->tnd", forces, rotations) / scene.weight
    pose_forces[~contact] = 0.0
    pose_load = _load(scene, rotations)
    touching = contact & ~released(pose_forces, 1.0, settings["released_force"])
    # One array per quantity, each run's steps a view of it (the pose held throughout).
    every = {
        "forces": np.repeat(pose_forces[:, None], steps, 1),
        "load": np.repeat(pose_load[:, None], steps, 1),
        "contact": np.repeat(touching[:, None], steps, 1),
        "rotations": np.repeat(rotations[:, None], steps, 1),
    }
    pose = np.zeros(steps)
    return [
        Motion(**{name: value[b] for name, value in every.items()}, pose=pose.copy(),
               settle_steps=settle)
        for b in range(len(rotations))
    ]  # fmt: skip


def plan_motion(
    scene: Scene,
    rotations: ArrayLike,
    forces: ArrayLike,
    in_contact: ArrayLike | None,
    settings: dict[str, float],
    points: ArrayLike | None = None,
) -> Motion:
    """The run that carries ``forces`` (T, n, 3, world frame, newtons) along ``rotations``
    (T, 3, 3) with fingers ``in_contact`` (T, n; None: every finger), under ``settings``
    (``timestep``, ``settle_time``, ``hold_time``, ``pose_hold_time``, ``time_per_degree``,
    ``min_segment_time``, ``released_force``). ``points`` (T, n, 3): each tip's object-frame
    contact point at each pose, metres (:func:`tip_points`; see the module docstring, "Tips
    whose point changes"); None: the scene's contacts throughout."""
    rotations = check_rotations(rotations, name="rotations")
    n_poses, n = len(rotations), scene.n_contacts
    forces = check_forces(forces, n, (n_poses,))
    contact = _check_contact(scene, forces, in_contact, settings)
    dt = settings["timestep"]
    settle = max(1, round(settings["settle_time"] / dt))
    hold = max(1, round(settings["hold_time"] / dt))
    # Row vectors: P @ R is R^T P, the force in the object's frame; in units of w.
    pose_forces = np.einsum("tnc,tcd->tnd", forces, rotations) / scene.weight
    pose_forces[~contact] = 0.0
    pose_load = _load(scene, rotations)
    carrying = ~released(pose_forces, 1.0, settings["released_force"])
    if points is None:
        pose_points = pose_normals = None
    else:
        pose_points, pose_normals = tip_points(scene, points, contact, carrying)

    def equilibrating(pinv: np.ndarray, load: np.ndarray) -> np.ndarray:
        """G_A^+ (-load) over the active fingers, (S, |A|, 3): exact least squares for any A."""
        return (-load @ pinv.T).reshape(len(load), -1, 3)

    dwell = max(1, round(settings["pose_hold_time"] / dt))
    total = settle + hold + (n_poses - 1) * dwell
    # The turns between poses, each as a unit axis (zero for none) and an angle of at most pi
    # (from its quaternion with w >= 0), and each segment's base duration.
    relative = np.swapaxes(rotations[:-1], -1, -2) @ rotations[1:]
    quaternions = _quaternion(relative) if n_poses > 1 else np.zeros((0, 4))
    # |q_xyz| as the norm of each vector alone computes it (a dot product), bit for bit
    vectors = quaternions[:, None, 1:]
    sines = np.sqrt(vectors @ np.swapaxes(vectors, -1, -2))[:, 0, 0]
    angles = 2.0 * np.arctan2(sines, quaternions[:, 0])
    turning = sines >= 1e-15
    angles[~turning] = 0.0
    axes = np.zeros((n_poses - 1, 3))
    axes[turning] = quaternions[turning, 1:] / sines[turning, None]
    durations = np.maximum(
        settings["min_segment_time"], np.degrees(angles) * settings["time_per_degree"]
    )
    base_steps = np.maximum(1.0, np.round(durations / dt))
    if total + base_steps.sum() > MAX_STEPS:  # counted as floats: no integer overflows
        raise ValueError(
            f"the run would take more than {MAX_STEPS} steps: lower time_per_degree,"
            " min_segment_time, pose_hold_time, settle_time, hold_time or the number of poses,"
            " or raise timestep"
        )
    base_steps = base_steps.astype(np.int64)
    # Each segment's fingers sharing the load, and its contact points: a tip's at the
    # segment's start if it touches there, else at its end.
    active = carrying[:-1] | carrying[1:]  # (T - 1, n)
    if pose_points is None:
        segment_points = np.broadcast_to(model_contacts(scene), (n_poses - 1, n, 3))
        segment_normals = np.broadcast_to(scene.normals, (n_poses - 1, n, 3))
    else:
        starts = contact[:-1, :, None]
        segment_points = np.where(starts, pose_points[:-1], pose_points[1:])
        segment_normals = np.where(starts, pose_normals[:-1], pose_normals[1:])
    # For each set A of load-sharing fingers at the same points: its segments, G_A^+, and the
    # pose forces' parts in the null space of G_A (T, |A|, 3), interpolated along them.
    groups: dict[tuple[bytes, bytes], list[int]] = {}
    for t in np.flatnonzero(active.any(axis=1)):
        key = active[t]
        groups.setdefault((key.tobytes(), segment_points[t, key].tobytes()), []).append(t)
    shared = []
    cg = model_cg(scene)
    for segments in groups.values():
        key = active[segments[0]]
        pinv = np.linalg.pinv(grasp_matrix(segment_points[segments[0], key] - cg))
        null = pose_forces[:, key] - equilibrating(pinv, pose_load)
        shared.append((key, np.array(segments), null, pinv))

    def path(seg: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(orientations, load, forces) at the steps of segments ``seg`` at path coordinates
        ``s``: the load turned exactly, the equilibrating part recomputed for it, the rest
        interpolated. The fingers that carry load at either end share the turning load; a
        finger released at both ends (or out of contact) keeps its own (tiny or zero) force,
        interpolated."""
        turned = rotations[seg]
        turning = np.any(axes[seg] != 0.0, axis=1)
        if turning.any():
            turned[turning] = turned[turning] @ axis_angle_matrix(
                axes[seg[turning]], s[turning] * angles[seg[turning]]
            )
        load = _load(scene, turned)
        a = s[:, None, None]
        step_forces = (1 - a) * pose_forces[seg] + a * pose_forces[seg + 1]
        for key, segments, null, pinv in shared:
            rows = np.flatnonzero(np.isin(seg, segments))
            a_rows, seg_rows = a[rows], seg[rows]
            step_forces[np.ix_(rows, np.flatnonzero(key))] = (
                equilibrating(pinv, load[rows])
                + (1 - a_rows) * null[seg_rows]
                + a_rows * null[seg_rows + 1]
            )
        return turned, load, step_forces

    # The forces of :func:`path` along segment t (to rounding), in closed form for the timing:
    # terms[t]^T (cos phi, 1 - cos phi, sin phi, 1 - s, s) with phi = s x the segment's turn,
    # since the load turns as x @ R(phi) = cos phi x + (1 - cos phi) (k . x) k - sin phi
    # (k x x) (the transpose of eq. 5) and the equilibrating part is linear in it.
    start_load = pose_load[:-1].reshape(-1, 2, 3)  # force and torque at each segment's start
    along = np.einsum("sc,sjc->sj", axes, start_load)[..., None] * axes[:, None]
    across = -np.cross(axes[:, None], start_load)
    terms = np.zeros((n_poses - 1, 5, n, 3))
    terms[:, 3], terms[:, 4] = pose_forces[:-1], pose_forces[1:]
    for key, segments, null, pinv in shared:
        rows, cols = segments[:, None], np.flatnonzero(key)[None]
        for j, part in enumerate((start_load, along, across)):
            terms[rows, j, cols] = equilibrating(pinv, part[segments].reshape(-1, 6))
        terms[rows, 3, cols], terms[rows, 4, cols] = null[segments], null[segments + 1]
    # The timing: each segment's steps spaced so that no touching finger's normal force
    # changes faster than force_rate x max(N, force_floor).
    s, lengths, fits = timed_segments(
        terms.reshape(n_poses - 1, 5, 3 * n),
        angles,
        base_steps,
        np.ascontiguousarray(segment_normals, dtype=float),
        contact[:-1] | contact[1:],
        dt,
        settings["released_force"],
        settings["force_floor"],
        settings["force_rate"],
        MAX_STEPS - total,
        settings["ramp_time"],
    )
    if not fits:
        raise ValueError(
            f"the run would take more than {MAX_STEPS} steps: lower time_per_degree,"
            " min_segment_time, pose_hold_time, raise force_rate or lower the number"
            " of poses"
        )
    seg = np.repeat(np.arange(n_poses - 1), lengths)
    turned, load, step_forces = path(seg, s)
    # The run block by block: the settle, then each pose's dwell and the segment after it,
    # then the final hold. A step is a row of the poses (held) stacked on the segments' steps.
    counts = np.empty(2 * n_poses, dtype=int)
    first = np.empty(2 * n_poses, dtype=int)
    counts[0], counts[1:-1:2], counts[2:-1:2], counts[-1] = settle, dwell, lengths, hold
    first[0], first[1:-1:2], first[-1] = 0, np.arange(n_poses - 1), n_poses - 1
    first[2:-1:2] = n_poses + np.cumsum(lengths) - lengths
    stride = np.zeros(2 * n_poses, dtype=int)
    stride[2:-1:2] = 1  # a segment's steps are consecutive rows; a held pose is one row
    block_start = np.cumsum(counts) - counts
    within = np.arange(counts.sum()) - np.repeat(block_start, counts)
    row = np.repeat(first, counts) + np.repeat(stride, counts) * within
    steps = {
        "forces": np.concatenate([pose_forces, step_forces])[row],
        "load": np.concatenate([pose_load, load])[row],
        "contact": np.concatenate([contact, contact[seg] | contact[seg + 1]])[row],
        "pose": np.concatenate([np.arange(n_poses, dtype=float), seg + s])[row],
        "rotations": np.concatenate([rotations, turned])[row],
    }
    steps["contact"] &= ~released(steps["forces"], 1.0, settings["released_force"])
    if pose_points is not None:
        steps["points"] = np.concatenate([pose_points, segment_points[seg]])[row]
        steps["normals"] = np.concatenate([pose_normals, segment_normals[seg]])[row]
    return Motion(**steps, settle_steps=settle)
