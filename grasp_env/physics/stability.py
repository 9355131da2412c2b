"""Grasp stability checked in MuJoCo physics: does a set of contact forces hold the box?

One check (DESIGN.md §2): place the box at the given orientation with its centre of gravity at
the world origin and the fingertips just inside its faces; drive the fingertips with the
commanded forces; settle briefly with a high friction coefficient (so that building up the
contact forces cannot itself cause slip); switch to the scene's mu; hold, and measure how far
each fingertip slides along its face. The grasp holds when no fingertip slides more than
``slip_threshold``, every fingertip stays in contact, and the object stays put (moves at most
``drift_threshold``: forces that do not balance the load carry it away, fingers and all).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Scene, matrix_quaternion

from .model import build_mjcf, check_forces, check_rotation, pose_qpos

# Defaults of the check (DESIGN.md §2), all overridable as StabilityChecker keywords.
SETTINGS: dict[str, float] = {
    "settle_time": 0.05,  #: seconds at ``settle_mu`` before the real mu applies
    "settle_mu": 10.0,  #: friction coefficient while the contact forces build up
    "hold_time": 0.5,  #: seconds held at the scene's mu
    "slip_threshold": 1e-4,  #: metres of tangential slip along a face that count as slipping
    "drift_threshold": 1e-3,  #: metres the object may move: more means forces out of balance
    "check_interval": 0.05,  #: seconds between slip checks (the check stops at the first slip)
}


@dataclass(frozen=True)
class PhysicsReport:
    """The outcome of one MuJoCo check.

    Attributes:
        holds: no fingertip slid more than the slip threshold, none lost contact, and the object
            stayed put (drift within the drift threshold; more means the forces do not balance
            the load).
        slip: (n,) tangential slide of each fingertip along its face during the hold, metres.
        contact_lost: (n,) whether fingertip i was out of contact at the end.
        drift: displacement of the object's centre of gravity during the hold, metres.
        rotation_deg: rotation of the object during the hold, degrees.
        time: simulated seconds of hold (shorter than the full hold when it slipped early).
    """

    holds: bool
    slip: np.ndarray
    contact_lost: np.ndarray
    drift: float
    rotation_deg: float
    time: float

    def as_dict(self) -> dict[str, bool | float | list[float] | list[bool]]:
        """Plain Python values, e.g. for a Gymnasium ``info`` dict."""
        return {
            "holds": bool(self.holds),
            "slip": [float(s) for s in self.slip],
            "contact_lost": [bool(c) for c in self.contact_lost],
            "drift": float(self.drift),
            "rotation_deg": float(self.rotation_deg),
            "time": float(self.time),
        }


class StabilityChecker:
    """Checks contact forces on ``scene`` in MuJoCo (see the module docstring).

    Args:
        scene: the grasp to simulate.
        **settings: overrides of :data:`SETTINGS` (positive finite numbers).
    """

    def __init__(self, scene: Scene, **settings: float) -> None:
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a grasp_env.mechanics.Scene, got {type(scene)}")
        unknown = set(settings) - set(SETTINGS)
        if unknown:
            raise ValueError(
                f"unknown StabilityChecker settings {sorted(unknown)}; expected {sorted(SETTINGS)}"
            )
        self.settings = {**SETTINGS, **{k: float(v) for k, v in settings.items()}}
        for name, value in self.settings.items():
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        self.scene = scene
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(scene))
        self.data = mujoco.MjData(self.model)
        n = scene.n_contacts
        self._object = self.model.body("object").id
        self._fingers = np.array([self.model.body(f"finger{i}").id for i in range(n)])
        self._pairs = np.array([self.model.pair(f"contact{i}").id for i in range(n)])
        self._tips = np.array([self.model.geom(f"tip{i}").id for i in range(n)])
        self._friction = self.model.pair_friction.copy()
        dt = self.model.opt.timestep
        self._settle_steps = max(1, round(self.settings["settle_time"] / dt))
        self._chunk_steps = max(1, round(self.settings["check_interval"] / dt))
        self._chunks = max(1, round(self.settings["hold_time"] / (self._chunk_steps * dt)))

    def reset(self) -> None:
        """Restore MuJoCo's model and data exactly to their state after construction."""
        mujoco.mj_resetData(self.model, self.data)
        self.model.pair_friction[:] = self._friction

    def close(self) -> None:
        """Release the model and data (the checker is unusable afterwards)."""
        self.model = self.data = None  # type: ignore[assignment]

    def check(self, rotation: ArrayLike, contact_forces: ArrayLike) -> PhysicsReport:
        """Simulate ``contact_forces`` (n, 3), applied by the fingers on the object in the world
        frame, at orientation ``rotation`` (3, 3), and report whether the grasp holds."""
        if self.model is None:
            raise ValueError("this StabilityChecker is closed")
        rotation = check_rotation(rotation)
        forces = check_forces(contact_forces, self.scene.n_contacts)
        model, data = self.model, self.data
        self.reset()
        data.qpos[:] = pose_qpos(self.scene, rotation)
        data.ctrl[:] = forces.ravel()
        data.xfrc_applied[self._object] = np.concatenate(
            [self.scene.extra_force, self.scene.extra_torque]
        )
        model.pair_friction[self._pairs, :2] = self.settings["settle_mu"]
        mujoco.mj_step(model, data, nstep=self._settle_steps)
        model.pair_friction[self._pairs, :2] = self._friction[self._pairs, :2]
        # Measure from here: the settle only pressed the fingertips into the faces.
        anchor = self._tips_in_object_frame()
        start_com = data.xipos[self._object].copy()
        start_rot = data.xmat[self._object].reshape(3, 3).copy()

        slip = np.zeros(self.scene.n_contacts)
        lost = np.zeros(self.scene.n_contacts, dtype=bool)
        steps = 0
        for _ in range(self._chunks):
            mujoco.mj_step(model, data, nstep=self._chunk_steps)
            steps += self._chunk_steps
            moved = self._tips_in_object_frame() - anchor
            along = (
                moved - np.sum(moved * self.scene.normals, -1, keepdims=True) * self.scene.normals
            )
            slip = np.linalg.norm(along, axis=-1)
            lost = ~self._in_contact()
            if not np.all(np.isfinite(slip)):
                raise FloatingPointError("MuJoCo diverged: non-finite state in the check")
            if np.any(slip > self.settings["slip_threshold"]) or np.any(lost):
                break  # the verdict is certain: no need to simulate the rest of the hold

        turn = matrix_quaternion(data.xmat[self._object].reshape(3, 3) @ start_rot.T)
        drift = float(np.linalg.norm(data.xipos[self._object] - start_com))
        holds = (
            np.all(slip <= self.settings["slip_threshold"])
            and not np.any(lost)
            and drift <= self.settings["drift_threshold"]
        )
        return PhysicsReport(
            holds=bool(holds),
            slip=slip,
            contact_lost=lost,
            drift=drift,
            rotation_deg=float(np.degrees(2 * np.arctan2(np.linalg.norm(turn[1:]), turn[0]))),
            time=steps * model.opt.timestep,
        )

    def _tips_in_object_frame(self) -> np.ndarray:
        data = self.data
        rot = data.xmat[self._object].reshape(3, 3)
        return (data.xpos[self._fingers] - data.xpos[self._object]) @ rot

    def _in_contact(self) -> np.ndarray:
        """Whether each fingertip touches the box now (an active contact of its pair)."""
        touching = np.zeros(self.scene.n_contacts, dtype=bool)
        geoms = self.data.contact.geom[: self.data.ncon]
        for i, tip in enumerate(self._tips):
            touching[i] = np.any(geoms == tip)
        return touching
