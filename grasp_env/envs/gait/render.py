"""Pictures of the gait environments: the cube at a pose, the fingers on their sites pushing.

:class:`GaitView` draws through :class:`~grasp_env.physics.GraspView`, the cube grasp ids'
view, with one contact per site of the cube (:func:`site_scene`): a site a finger touches shows
its fingertip, the finger's push as an arrow ending at the site and its friction cone coloured
by how near the finger is to slipping (green well inside, yellow past three quarters of
theta_lim, red at or beyond it; eq. 2); a free site (no finger on it, or a finger just lifted
off it) shows a faint grey cone and its fingertip lifted off the face, without an arrow. The
grey arrow from the centre of gravity is the weight, on the forces' scale. With Pillow
installed a caption (top left) gives the pose, the step's margin, which finger is on which
face and which fingers are lifted.

The camera is fixed (the cube turns under it), looking slightly down from the side of the
hand's fingers 3 and 4. Nothing is built until the first picture, and this module is imported
only then: environments that never render load no MuJoCo.
"""

from __future__ import annotations

import importlib.util

import numpy as np
from numpy.typing import ArrayLike

from ...mechanics import GaitScene, Scene
from ...physics import GraspView
from .kernels import _step, optimal_actions
from .tasks import GaitTask

#: The fixed camera: azimuth and elevation, degrees (negative: looking down), and its distance
#: as a multiple of GraspView's (farther: the pushes of fingers far from the camera fit in).
GAIT_CAMERA = (300.0, -20.0, 1.25)
#: A touching finger whose force is at most this fraction of the weight carries no load (it has
#: just been placed, or the grip releases it): it is drawn inside its cone (green), without an
#: arrow, as the reward counts it (angle 0; grasp_env.envs.kernels.RELEASE).
_UNLOADED = 1e-6


def site_scene(scene: GaitScene) -> Scene:
    """The :class:`~grasp_env.mechanics.Scene` with a contact on every site of ``scene`` (the
    view's model: one fingertip and one friction cone per site)."""
    return Scene(
        contacts=scene.sites,
        size=scene.size,  # type: ignore[arg-type]
        weight=scene.weight,
        mu=scene.mu,
        cg_offset=scene.cg_offset,  # type: ignore[arg-type]
        extra_force=scene.extra_force,  # type: ignore[arg-type]
        extra_torque=scene.extra_torque,  # type: ignore[arg-type]
    )


def site_faces(scene: GaitScene) -> tuple[str, ...]:
    """The face each site lies on, ``"-x"`` ... ``"+z"`` (its inward normal points the other
    way)."""
    faces = []
    for normal in scene.normals:
        axis = int(np.argmax(np.abs(normal)))
        faces.append(("+" if normal[axis] < 0 else "-") + "xyz"[axis])
    return tuple(faces)


def resting_grips(task: GaitTask, xs: ArrayLike, ts: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """What a frame shows before the first step of an episode: the contacts (B, F) of states
    ``xs`` at poses ``ts`` and the forces (B, F, 3), newtons, of the certified minimax grip of
    their fingers there (eq. 2, 4; the grip the optimal gait holds with when it keeps them)."""
    xs, ts = np.asarray(xs, np.int64), np.asarray(ts, np.int64)
    keep = np.zeros(len(xs), np.int64)
    out = _step(task, xs, ts, optimal_actions(task, xs, ts, keep), False)
    return out["contacts"].copy(), out["contact_forces"].copy()


class GaitView:
    """Draws a gait task's cube at a pose with fingers on sites (see the module docstring).

    Args:
        task: the environment's task (its scene, hand, trajectory).
        render_mode: ``"rgb_array"`` (:meth:`render` returns an image) or ``"human"`` (a
            MuJoCo window; without a display, a warning and nothing drawn), as for
            :class:`~grasp_env.physics.GraspView`.
        width, height: image size in pixels, 16 to 4096.
    """

    def __init__(
        self, task: GaitTask, render_mode: str = "rgb_array", width: int = 480, height: int = 480
    ) -> None:
        scene = task.solution.scene
        self.task = task
        self.view = GraspView(site_scene(scene), render_mode, width, height)
        camera = self.view.camera
        camera.azimuth, camera.elevation, farther = GAIT_CAMERA
        camera.distance *= farther
        self._rotations = task.solution.trajectory.rotations()
        self._faces = site_faces(scene)
        self._names = task.solution.hand.names
        self._caption = importlib.util.find_spec("PIL") is not None  # overlay() needs Pillow

    def caption(self, t: int, contacts: np.ndarray, margin: float | None) -> list[str]:
        """The overlay's lines: the pose (and the step's margin, radians, shown in degrees),
        the fingers on the faces, the fingers lifted."""
        first = f"alpha {self.task.alphas[t]:+.0f} deg"
        if margin is not None:
            first += f"   margin {np.degrees(margin):+.2f} deg"
        on = [f"{self._names[f]} {self._faces[s]}" for f, s in enumerate(contacts) if s >= 0]
        off = [self._names[f] for f, s in enumerate(contacts) if s < 0]
        lines = [first, "  ".join(on) if on else "no finger touches"]
        if len(on) < 3:
            lines.append("the cube drops")
        elif off:
            lines.append("lifted: " + ", ".join(off))
        return lines

    def render(
        self, t: int, contacts: ArrayLike, forces: ArrayLike, margin: float | None = None
    ) -> np.ndarray | None:
        """Draw pose ``t`` with ``contacts`` (F,) (the site each finger touches, -1: none) and
        the fingers' ``forces`` (F, 3), world frame, newtons; ``margin`` (radians, the step's
        reward) goes into the caption. An RGB image (height, width, 3) uint8 for
        ``"rgb_array"``, None for ``"human"``."""
        contacts = np.asarray(contacts, np.int64)
        forces = np.asarray(forces, float)
        n_sites = self.task.n_sites
        rotation = self._rotations[t]
        site_forces = np.zeros((n_sites, 3))
        touching = np.zeros(n_sites, bool)
        weight = self.task.weight
        for f, s in enumerate(contacts):
            if s < 0:
                continue
            touching[s] = True
            if np.linalg.norm(forces[f]) > _UNLOADED * weight:
                site_forces[s] = forces[f]
            else:  # a push along the inward normal too small to draw: angle 0, green
                site_forces[s] = 1e-12 * weight * (rotation @ self.task.solution.scene.normals[s])
        text = self.caption(t, contacts, margin) if self._caption else ()
        return self.view.render(rotation, site_forces, touching, text)

    def close(self) -> None:
        """Free the renderer's OpenGL context or close the window."""
        self.view.close()


__all__ = ["GAIT_CAMERA", "GaitView", "resting_grips", "site_faces", "site_scene"]
