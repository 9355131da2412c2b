"""Pictures of a grasp: the box, the fingertips, their forces and their friction cones.

Each finger's push is drawn as an arrow ending at its contact point, on the same scale for all
(an arrow half the box's smallest edge long is a force equal to the weight), and each friction
cone opens outwards from its contact, so an arrow lies inside its cone exactly when that finger
holds. Cone and arrow share a colour that says how near the finger is to slipping: green well
inside the cone, yellow past three quarters of the friction limit, red at or beyond it.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import START_ROTATION, Scene, friction_angles

from .model import build_mjcf, check_forces, check_rotation, pose_qpos

RENDER_MODES = ("rgb_array", "human")
#: Colours by theta_i / theta_lim: well inside, three quarters of the way, at the limit.
_GREEN, _YELLOW, _RED = (
    np.array([0.15, 0.75, 0.2]),
    np.array([0.95, 0.8, 0.1]),
    np.array([0.9, 0.1, 0.1]),
)
#: Longest arrow drawn, in box sizes (a huge force would otherwise leave the picture).
_MAX_ARROW = 1.5


def slip_colour(ratio: float) -> np.ndarray:
    """RGB for a finger using ``ratio`` = theta_i / theta_lim of its friction limit."""
    ratio = float(np.clip(ratio, 0.0, 1.0))
    if ratio >= 1.0:
        return _RED
    if ratio <= 0.75:
        return _GREEN + (_YELLOW - _GREEN) * ratio / 0.75
    return _YELLOW + (_RED - _YELLOW) * (ratio - 0.75) / 0.25


class GraspView:
    """Renders ``scene`` at a given orientation under given contact forces.

    Args:
        scene: the grasp to draw.
        render_mode: ``"rgb_array"`` (offscreen; :meth:`render` returns an image) or
            ``"human"`` (an interactive MuJoCo window; :meth:`render` returns None).
        width, height: image size in pixels for ``"rgb_array"``, 16 to 4096.

    The camera is fixed, looking at the contacts from outside the grip at the start pose, so
    successive poses of a trajectory show the box turning.
    """

    def __init__(
        self, scene: Scene, render_mode: str = "rgb_array", width: int = 480, height: int = 480
    ) -> None:
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a grasp_env.mechanics.Scene, got {type(scene)}")
        if render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
        for name, value in (("width", width), ("height", height)):
            if not isinstance(value, (int, np.integer)) or not 16 <= value <= 4096:
                raise ValueError(f"{name} must be an integer in [16, 4096], got {value!r}")
        self.scene = scene
        self.render_mode = render_mode
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(scene))
        self.model.vis.global_.offwidth = max(width, self.model.vis.global_.offwidth)
        self.model.vis.global_.offheight = max(height, self.model.vis.global_.offheight)
        self.data = mujoco.MjData(self.model)
        self._cones = np.array([self.model.geom(f"cone{i}").id for i in range(scene.n_contacts)])
        self._size = float(np.min(scene.size))
        self.camera = self._camera()
        self._renderer: mujoco.Renderer | None = None
        self._viewer = None
        if render_mode == "rgb_array":
            try:
                self._renderer = mujoco.Renderer(self.model, height=height, width=width)
            except Exception as error:  # the GL backend: say how to get one
                raise RuntimeError(
                    "MuJoCo could not create an offscreen OpenGL context. On a machine without"
                    " a display set MUJOCO_GL=egl, or MUJOCO_GL=osmesa after installing"
                    f" libosmesa6, before importing mujoco ({error})"
                ) from error

    def _camera(self) -> mujoco.MjvCamera:
        """A free camera looking at the centre of gravity from outside the contacts' faces."""
        outward = -(self.scene.normals @ START_ROTATION.T).sum(axis=0)
        forward = -outward  # from the camera towards the object
        horizontal = float(np.hypot(forward[0], forward[1]))
        camera = mujoco.MjvCamera()
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.lookat[:] = 0.0
        camera.distance = 2.8 * float(np.max(self.scene.size))
        camera.azimuth = np.degrees(np.arctan2(forward[1], forward[0])) if horizontal > 1e-6 else 45
        camera.elevation = float(np.clip(np.degrees(np.arctan2(forward[2], horizontal)), -55, 55))
        return camera

    def _colours(self, rotation: np.ndarray, forces: np.ndarray) -> np.ndarray:
        """Each finger's colour (n, 3); the cones take theirs (before the scene is built)."""
        normals = self.scene.normals @ rotation.T
        ratios = friction_angles(forces, normals) / self.scene.friction_limit
        colours = np.array([slip_colour(r) for r in ratios])
        alpha = np.where(ratios >= 1, 0.6, 0.3)
        self.model.geom_rgba[self._cones] = np.column_stack([colours, alpha])
        return colours

    def _draw(
        self, scene: mujoco.MjvScene, rotation: np.ndarray, forces: np.ndarray, colours: np.ndarray
    ) -> None:
        """Append the force arrows (on one scale: half the box's edge is the weight)."""
        positions = self.scene.relative_contacts() @ rotation.T
        scale = 0.5 * self._size / self.scene.weight  # metres per newton
        for position, force, colour in zip(positions, forces, colours, strict=True):
            length = min(scale * np.linalg.norm(force), _MAX_ARROW * self._size)
            if length < 1e-9:
                continue
            direction = force / np.linalg.norm(force)
            self._arrow(scene, position - length * direction, position, colour)
        weight = np.array([0.0, 0.0, -0.5 * self._size])
        self._arrow(scene, np.zeros(3), weight, np.array([0.3, 0.3, 0.3]))

    def _arrow(
        self, scene: mujoco.MjvScene, start: np.ndarray, end: np.ndarray, colour: np.ndarray
    ) -> None:
        if scene.ngeom >= scene.maxgeom:
            return
        geom = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(
            geom,
            mujoco.mjtGeom.mjGEOM_ARROW,
            np.zeros(3),
            np.zeros(3),
            np.eye(3).ravel(),
            np.array([*colour, 1.0], dtype=np.float32),
        )
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_ARROW, 0.02 * self._size, start, end)
        scene.ngeom += 1

    def render(self, rotation: ArrayLike, contact_forces: ArrayLike) -> np.ndarray | None:
        """Draw the object at ``rotation`` (3, 3) under ``contact_forces`` (n, 3), world frame.

        Returns an RGB image (height, width, 3) of uint8 for ``"rgb_array"``, None for
        ``"human"``.
        """
        if self.model is None:
            raise ValueError("this GraspView is closed")
        rotation = check_rotation(rotation)
        forces = check_forces(contact_forces, self.scene.n_contacts)
        self.data.qpos[:] = pose_qpos(self.scene, rotation)
        mujoco.mj_kinematics(self.model, self.data)
        colours = self._colours(rotation, forces)
        if self._renderer is not None:
            self._renderer.update_scene(self.data, camera=self.camera)
            self._draw(self._renderer.scene, rotation, forces, colours)
            return self._renderer.render()
        if self._viewer is None:
            from mujoco import viewer  # imported only for a window: it needs a display

            self._viewer = viewer.launch_passive(self.model, self.data)
            self._viewer.cam.type = self.camera.type
            self._viewer.cam.lookat[:] = self.camera.lookat
            self._viewer.cam.distance = self.camera.distance
            self._viewer.cam.azimuth = self.camera.azimuth
            self._viewer.cam.elevation = self.camera.elevation
        with self._viewer.lock():
            self._viewer.user_scn.ngeom = 0
            self._draw(self._viewer.user_scn, rotation, forces, colours)
        self._viewer.sync()
        return None

    def close(self) -> None:
        """Free the renderer's OpenGL context or close the window."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self.model = self.data = None  # type: ignore[assignment]
