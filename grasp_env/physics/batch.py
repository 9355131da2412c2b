"""The arrays of a batch of runs, built and read in whole-batch passes: the controls that go
into ``mujoco.rollout`` (the touching fingertips' motor forces, their inertia fed forward by
:func:`_tip_inertia`; the load and the other fingers' forces on the object), the fingers moved
between chunks, and the measurements taken from the states it returns (:class:`Trace`). The
engine that runs them is :mod:`grasp_env.physics.simulation`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from grasp_env.mechanics import quaternion_matrix

if TYPE_CHECKING:
    from .motion import Motion
    from .simulation import PhysicsModel


@numba.njit(nogil=True, cache=True)
def _tip_inertia(
    normal: np.ndarray,
    contact: np.ndarray,
    response: np.ndarray,
    rest_depth: np.ndarray,
    timestep: float,
) -> np.ndarray:
    """The motor force beyond the commanded normal force N that keeps a touching fingertip's
    contact pushing with N itself, (B, N, n) in w for B runs' normal forces ``normal`` (B, N,
    n) and ``contact`` (B, N, n); ``response`` (B, 4) and ``rest_depth`` (B,) per run.

    MuJoCo's soft contact pushes with f = (B v + K I d + A u) / (A + R) under a motor force u
    (v and d the tip's inward speed and depth). So f = N for u = N + a / A, where
    a = R N - B v - K I d is then the tip's inward acceleration: the force its mass needs to
    follow N. The depth is integrated along N as MuJoCo integrates it (semi-implicit Euler),
    from a placed tip's: at rest, ``rest_depth`` into the face. Without it, wherever N bends
    (a placement, a force that stops falling) the contact's force differs from N for a few
    steps by the tip's mass times its acceleration, and near the cone's edge that is a slip
    (docs/physics.md, "The tip's inertia")."""
    count, steps, n = normal.shape
    out = np.zeros((count, steps, n))
    for r in range(count):
        stiffness, damping, regulariser, inertia = response[r]
        for i in range(n):
            depth, speed = rest_depth[r], 0.0
            for k in range(steps):
                if not contact[r, k, i]:
                    depth, speed = rest_depth[r], 0.0  # placed again at rest
                    continue
                acceleration = regulariser * normal[r, k, i] - damping * speed - stiffness * depth
                out[r, k, i] = acceleration / inertia
                speed += timestep * acceleration
                depth += timestep * speed
    return out


@dataclass(frozen=True)
class Trace:
    """What a run measured, step by step (the state after each of its N steps).

    Lengths in the model's units (the box's largest edge L), angles in radians.

    Attributes:
        qpos: (N, nq) the model's positions (the object's free joint, then the fingertips).
        slip: (N, n) each fingertip's slide along its face since it was placed (the end of the
            settle for the fingers placed at the start); 0 while it does not touch.
        speed: (N, n) each fingertip's sliding speed along its face during the step, L/s (0
            at the step it is placed and while it does not touch).
        gap: (N, n) how far each fingertip's surface is off its face (negative: pressed in);
            0 while it does not touch.
        drift: (N,) displacement of the object's centre of gravity since the settle.
        rotation: (N,) rotation of the object since the settle.
        measured: (N, n) whether fingertip i touched (and was judged) at the step.
        diverged: MuJoCo stopped on a warning (an unstable simulation) before the end.
    """

    qpos: np.ndarray
    slip: np.ndarray
    speed: np.ndarray
    gap: np.ndarray
    drift: np.ndarray
    rotation: np.ndarray
    measured: np.ndarray
    diverged: bool


def _rotation_angle(relative: np.ndarray) -> np.ndarray:
    """The angle of rotation matrices (..., 3, 3), radians (accurate near zero)."""
    skew = np.stack(
        [
            relative[..., 2, 1] - relative[..., 1, 2],
            relative[..., 0, 2] - relative[..., 2, 0],
            relative[..., 1, 0] - relative[..., 0, 1],
        ],
        -1,
    )
    trace = relative[..., 0, 0] + relative[..., 1, 1] + relative[..., 2, 2]
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), 0.5 * (trace - 1.0))


# The rotation matrix of a unit quaternion q = (w, x, y, z), entry by entry (row-major), as
# base + scale (q_a q_b + sign q_c q_d): e.g. R_00 = 1 - 2 (y y + z z), R_01 = 2 (x y - w z).
# Indices into the flattened outer product q q^T (4 a + b for q_a q_b).
_Q_AB = 4 * np.array([2, 1, 1, 1, 1, 2, 1, 2, 1]) + np.array([2, 2, 3, 2, 1, 3, 3, 3, 1])
_Q_CD = 4 * np.array([3, 0, 0, 0, 3, 0, 0, 0, 2]) + np.array([3, 3, 2, 3, 3, 1, 2, 1, 2])
_Q_SIGN = np.array([1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, 1.0, 1.0])
_Q_SCALE = np.array([-2.0, 2.0, 2.0, 2.0, -2.0, 2.0, 2.0, 2.0, -2.0])
_Q_BASE = np.eye(3).ravel()


def _rotations(quaternions: np.ndarray) -> np.ndarray:
    """:func:`~grasp_env.mechanics.quaternion_matrix` of MuJoCo's (finite, unit) quaternions
    (..., 4): the same products and sums, gathered from the quaternion's outer product in a few
    whole-array operations (no checks, no stacking)."""
    q = quaternions / np.linalg.norm(quaternions, axis=-1, keepdims=True)
    outer = (q[..., :, None] * q[..., None, :]).reshape(*q.shape[:-1], 16)
    terms = outer[..., _Q_AB] + _Q_SIGN * outer[..., _Q_CD]
    # C-contiguous (..., 3, 3), as numpy's matrix products downstream expect for the same
    # arithmetic (another layout can take another product kernel).
    rotation = np.ascontiguousarray(_Q_BASE + _Q_SCALE * terms)
    return rotation.reshape(*quaternions.shape[:-1], 3, 3)


def _constant(physics: list[PhysicsModel], name: str) -> np.ndarray:
    """A per-scene constant of a batch's runs: the one array if they share their model, else
    (B, 1, ...) stacked to broadcast over (B, N, ...)."""
    if all(p is physics[0] for p in physics):
        return np.asarray(getattr(physics[0], name))
    return np.stack([np.asarray(getattr(p, name)) for p in physics])[:, None]


def _measure(
    physics: list[PhysicsModel],
    motions: list[Motion],
    place: np.ndarray,
    qpos: np.ndarray,
    diverged: np.ndarray,
) -> list[Trace]:
    """The measurements of B runs of one length N (sharing the settle) from their positions
    after every step, (B, N, nq), in one vectorised pass."""
    settle = motions[0].settle_steps
    count, steps = qpos.shape[:2]
    n = physics[0].n
    position = qpos[..., :3]
    rotation = _rotations(qpos[..., 3:7])  # (B, N, 3, 3), object to model world
    tips = qpos[..., 7:].reshape(count, steps, n, 3)
    # Row vectors: (x - p) @ R is R^T (x - p), the fingertips in the object's frame.
    offset = tips - position[..., None, :]
    local = sum(offset[..., c, None] * rotation[..., None, c, :] for c in range(3))
    normals = _constant(physics, "normals")
    contacts = _constant(physics, "contacts")
    gap = -np.sum((local - contacts) * normals, -1) - _constant(physics, "radius")[..., None]
    measured = np.stack([motion.contact for motion in motions])
    measured[:, :settle] = False
    # Each finger's slide is measured from where it was placed: for the fingers placed at the
    # start, from where the settle left them.
    start = measured.copy()
    start[:, 1:] &= ~measured[:, :-1]
    if place.any():
        since = np.maximum.accumulate(np.where(start, np.arange(steps)[:, None], 0), axis=1)
        placed = np.take_along_axis(place, since, axis=1)
        anchor = np.where(
            placed[..., None], _constant(physics, "placed"), local[:, settle - 1, None]
        )
    else:  # no finger placed after the start: all from where the settle left them
        anchor = local[:, settle - 1, None]
    moved = local - anchor
    along = moved - np.sum(moved * normals, -1, keepdims=True) * normals
    slip = np.where(measured, np.linalg.norm(along, axis=-1), 0.0)
    speed = np.zeros_like(slip)
    speed[:, 1:] = np.linalg.norm(np.diff(along, axis=1), axis=-1) / physics[0].timestep
    speed[:, 1:] = np.where(measured[:, 1:] & measured[:, :-1], speed[:, 1:], 0.0)
    cg = _constant(physics, "cg")
    if cg.ndim == 1:
        cg = position + rotation @ cg
    else:
        cg = position + (rotation @ cg[..., None])[..., 0]
    drift = np.linalg.norm(cg - cg[:, settle - 1, None], axis=-1)
    turn = _rotation_angle(rotation @ np.swapaxes(rotation[:, settle - 1, None], -1, -2))
    finite = (
        np.isfinite(slip).all(axis=(1, 2))
        & np.isfinite(speed).all(axis=(1, 2))
        & np.isfinite(drift).all(axis=1)
    )
    diverged = diverged | ~finite
    gap = np.where(measured, gap, 0.0)
    return [
        Trace(
            qpos=qpos[r],
            slip=slip[r],
            speed=speed[r],
            gap=gap[r],
            drift=drift[r],
            rotation=turn[r],
            measured=measured[r],
            diverged=bool(diverged[r]),
        )
        for r in range(count)
    ]


def _controls(
    physics: list[PhysicsModel], forces: np.ndarray, load: np.ndarray, contact: np.ndarray
) -> np.ndarray:
    """(B, N, ncontrol) rows of ctrl then xfrc_applied of B runs of N steps, (B, N, n, 3),
    (B, N, 6) and (B, N, n): the touching fingertips' forces as motor forces; the load, and the
    forces of fingers that do not touch (at their contact points), on the object. A touching
    fingertip's motor also carries its own inertia along the normal (:func:`_tip_inertia`), so
    that its contact pushes with the commanded force."""
    count, steps = contact.shape[:2]
    physics0 = physics[0]
    controls = np.zeros((count, steps, physics0.ncontrol))
    nu, start = physics0.nu, physics0.wrench_start
    touching = contact[..., None]
    normals = _constant(physics, "normals")
    inertial = _tip_inertia(
        np.sum(forces * normals, axis=-1),
        np.ascontiguousarray(contact),
        np.array([p._response for p in physics]),
        np.array([p.rest_depth for p in physics]),
        physics0.timestep,
    )
    pushed = forces + inertial[..., None] * normals
    controls[..., :nu] = np.where(touching, pushed, 0.0).reshape(count, steps, nu)
    lever = np.array([p.lever for p in physics])
    if lever.any():  # the contacts' lever arms restored, on every shape (PhysicsModel.lever)
        applied = np.where(touching, forces, 0.0)
        normal = np.sum(applied * normals, axis=-1, keepdims=True)
        shift = lever[:, None, None, None] * normal * normals  # MuJoCo's contact point - c_i
        load = load.copy()
        load[..., 3:] -= np.cross(shift, applied).sum(axis=-2)
    if contact.all():  # no ideal forces: the load alone
        controls[..., start : start + 6] = load
        return controls
    ideal = np.where(touching, 0.0, forces)
    arms = _constant(physics, "arms")
    controls[..., start : start + 6] = load + np.concatenate(
        [ideal.sum(axis=-2), np.cross(arms, ideal).sum(axis=-2)], axis=-1
    )
    return controls


def _move_fingers(
    physics: PhysicsModel, state: np.ndarray, place: np.ndarray, lift: np.ndarray
) -> None:
    """Place (at the contact, just inside the face) or lift (to the parking place) fingers in
    the full physics ``state``, moving with the object (its velocity at that point)."""
    nq = physics.nq
    qpos, qvel = state[1 : 1 + nq], state[1 + nq : 1 + nq + physics.nv]
    position, rotation = qpos[:3], quaternion_matrix(qpos[3:7])
    velocity, spin = qvel[:3], rotation @ qvel[3:6]  # free joint: angular velocity is local
    for i in np.flatnonzero(place | lift):
        local = physics.placed[i] if place[i] else physics.parked[i]
        tip = position + rotation @ local
        qpos[7 + 3 * i : 10 + 3 * i] = tip
        qvel[6 + 3 * i : 9 + 3 * i] = velocity + np.cross(spin, tip - position)


def _moves(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Where fingertips are placed and lifted, (N, n) each."""
    contact = motion.contact
    place = np.zeros_like(contact)
    place[1:] = contact[1:] & ~contact[:-1]
    lift = np.zeros_like(contact)
    lift[1:] = ~contact[1:] & contact[:-1]
    return place, lift


__all__ = ["Trace"]
