"""Pictures of a grasp: the box, the fingertips, their forces and their friction cones.

Each finger's push is drawn as an arrow ending at its contact point, on the same scale for all
(an arrow half the box's smallest edge long is a force equal to the weight), and each friction
cone opens outwards from its contact, so an arrow lies inside its cone exactly when that finger
holds. Cone and arrow share a colour that says how near the finger is to slipping: green well
inside the cone, yellow past three quarters of the friction limit, red at or beyond it. A finger
out of contact is drawn grey, without an arrow. Images can carry a text overlay (top left).

Nothing is built until the first picture: a view costs nothing until :meth:`GraspView.render`
is called (environments create one per scene, and most never render). Without a display,
``render_mode="human"`` cannot open a window: the view then warns once and draws nothing
(:meth:`GraspView.render` returns None, as it does with a window), so that headless code paths
such as Gymnasium's ``check_env`` run; use ``"rgb_array"`` for pictures without a display.
"""

from __future__ import annotations

import os
import sys
import warnings
import weakref
from collections.abc import Sequence

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import START_ROTATION, Scene, friction_angles
from grasp_env.mechanics.checks import real_array

from .model import (
    build_mjcf,
    check_forces,
    check_rotation,
    model_contacts,
    model_size,
    world_qpos,
)

RENDER_MODES = ("rgb_array", "human")
#: Colours by theta_i / theta_lim: well inside, three quarters of the way, at the limit.
_GREEN, _YELLOW, _RED = (
    np.array([0.15, 0.75, 0.2]),
    np.array([0.95, 0.8, 0.1]),
    np.array([0.9, 0.1, 0.1]),
)
_GREY = np.array([0.55, 0.55, 0.55])
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


def display_available() -> bool:
    """Whether an interactive window can open here (GLFW initialises).

    Probed through the ``glfw`` package, which reports failure as a return value: MuJoCo's own
    viewer ends the process when GLFW cannot initialise.
    """
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return False
    try:
        import glfw
    except ImportError:
        return False
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return bool(glfw.init())
        except Exception:  # glfw raises on some platforms instead of returning False
            return False


class GraspView:
    """Renders ``scene`` at a given orientation under given contact forces.

    Args:
        scene: the grasp to draw.
        render_mode: ``"rgb_array"`` (offscreen; :meth:`render` returns an image) or
            ``"human"`` (an interactive MuJoCo window; :meth:`render` returns None; without a
            display, a warning and no window).
        width, height: image size in pixels for ``"rgb_array"``, 16 to 4096.

    The camera is fixed, looking at the contacts from outside the grip at the start pose, so
    successive poses of a trajectory show the box turning. The MuJoCo model and the renderer
    are built on the first :meth:`render`.
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
        self.width, self.height = int(width), int(height)
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self._renderer: mujoco.Renderer | None = None
        self._viewer = None
        self._headless = False
        self._closed = False
        self._size = float(np.min(model_size(scene)))
        self.camera = self._camera()

    # -- building, on first use ------------------------------------------------------------------

    def _build(self) -> None:
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(self.scene, visual=True))
        self.model.vis.global_.offwidth = max(self.width, self.model.vis.global_.offwidth)
        self.model.vis.global_.offheight = max(self.height, self.model.vis.global_.offheight)
        self.data = mujoco.MjData(self.model)
        n = self.scene.n_contacts
        self._cones = np.array([self.model.geom(f"cone{i}").id for i in range(n)])
        self._tips = np.array([self.model.geom(f"tip{i}").id for i in range(n)])
        self._tip_rgba = self.model.geom_rgba[self._tips].copy()
        if self.render_mode == "rgb_array":
            try:
                self._renderer = mujoco.Renderer(self.model, height=self.height, width=self.width)
            except Exception as error:  # the GL backend: say how to get one
                raise RuntimeError(
                    "MuJoCo could not create an offscreen OpenGL context. On a machine without"
                    " a display set MUJOCO_GL=egl, or MUJOCO_GL=osmesa after installing"
                    f" libosmesa6, before importing mujoco ({error})"
                ) from error
            # Free the GL context when the view goes, or at exit if it is never closed: left to
            # the renderer's __del__ at interpreter shutdown, OSMesa's free fails noisily
            # ("Exception ignored in Renderer.__del__"), its PyOpenGL half torn down already.
            self._free = weakref.finalize(self, self._renderer.close)
        elif not display_available():
            self._headless = True
            warnings.warn(
                "render_mode='human' needs a display and there is none: nothing is drawn (use"
                " render_mode='rgb_array' for images)",
                RuntimeWarning,
                stacklevel=3,
            )

    def _camera(self) -> mujoco.MjvCamera:
        """A free camera looking at the centre of gravity from outside the contacts' faces."""
        forward = (self.scene.normals @ START_ROTATION.T).sum(axis=0)  # towards the object
        horizontal = float(np.hypot(forward[0], forward[1]))
        camera = mujoco.MjvCamera()
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.lookat[:] = 0.0
        camera.distance = 2.8
        camera.azimuth = np.degrees(np.arctan2(forward[1], forward[0])) if horizontal > 1e-6 else 45
        camera.elevation = float(np.clip(np.degrees(np.arctan2(forward[2], horizontal)), -55, 55))
        return camera

    # -- drawing -----------------------------------------------------------------------------------

    def _colours(self, normals: np.ndarray, forces: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """Each finger's colour (n, 3); the cones and tips take theirs (before the scene is
        built)."""
        ratios = friction_angles(forces, normals) / self.scene.friction_limit
        colours = np.array([slip_colour(r) for r in ratios])
        colours[~contact] = _GREY
        alpha = np.where(~contact, 0.12, np.where(ratios >= 1, 0.6, 0.3))
        self.model.geom_rgba[self._cones] = np.column_stack([colours, alpha])
        tips = self._tip_rgba.copy()
        tips[~contact, :3] = _GREY
        self.model.geom_rgba[self._tips] = tips
        return colours

    def _draw(
        self,
        scene: mujoco.MjvScene,
        positions: np.ndarray,
        forces: np.ndarray,
        colours: np.ndarray,
        contact: np.ndarray,
    ) -> None:
        """Append the force arrows (on one scale: half the box's edge is the weight)."""
        scale = 0.5 * self._size  # model lengths per unit of w
        for position, force, colour, touching in zip(
            positions, forces, colours, contact, strict=True
        ):
            length = min(scale * np.linalg.norm(force), _MAX_ARROW * self._size)
            if not touching or length < 1e-9:
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

    def render(
        self,
        rotation: ArrayLike,
        contact_forces: ArrayLike,
        in_contact: ArrayLike | None = None,
        text: Sequence[str] = (),
    ) -> np.ndarray | None:
        """Draw the object at ``rotation`` (3, 3) under ``contact_forces`` (n, 3), world frame,
        newtons; ``in_contact`` (n,) bool (default: every finger); ``text``: overlay lines.

        Returns an RGB image (height, width, 3) of uint8 for ``"rgb_array"``, None for
        ``"human"``.
        """
        if self._closed:
            raise ValueError("this GraspView is closed")
        rotation = check_rotation(rotation)
        forces = check_forces(contact_forces, self.scene.n_contacts)
        n = self.scene.n_contacts
        contact = np.ones(n, dtype=bool) if in_contact is None else _check_contact(in_contact, n)
        qpos = world_qpos(self.scene, rotation, contact)
        return self.render_state(qpos, rotation, forces / self.scene.weight, contact, text)

    def render_state(
        self,
        qpos: ArrayLike,
        rotation: ArrayLike,
        forces: ArrayLike,
        contact: ArrayLike,
        text: Sequence[str] = (),
    ) -> np.ndarray | None:
        """Draw the model at positions ``qpos`` (world frame, model units) with the object's
        nominal orientation ``rotation`` (which turns the friction cones' normals), finger
        ``forces`` (n, 3, world frame, units of w) and ``contact`` (n,); see :meth:`render`.
        Each input is checked (a ValueError names the first that is wrong)."""
        if self._closed:
            raise ValueError("this GraspView is closed")
        n = self.scene.n_contacts
        rotation = check_rotation(rotation)
        forces = check_forces(forces, n, name="forces")
        contact = _check_contact(contact, n, "contact")
        # a lone string would be drawn a character per line
        if isinstance(text, str) or not (
            isinstance(text, Sequence) and all(isinstance(line, str) for line in text)
        ):
            raise ValueError(f"text must be a sequence of strings (overlay lines), got {text!r}")
        if self.model is None:
            self._build()
        qpos = real_array("qpos", qpos, f"finite real numbers of shape ({self.model.nq},)")
        if qpos.shape != (self.model.nq,):
            raise ValueError(f"qpos must have shape ({self.model.nq},), got {qpos.shape}")
        if self._headless:
            return None
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        rot = self.data.xmat[self.model.body("object").id].reshape(3, 3)
        origin = self.data.xpos[self.model.body("object").id]
        positions = origin + model_contacts(self.scene) @ rot.T
        colours = self._colours(self.scene.normals @ rotation.T, forces, contact)
        if self._renderer is not None:
            self._renderer.update_scene(self.data, camera=self.camera)
            self._draw(self._renderer.scene, positions, forces, colours, contact)
            image = self._renderer.render()
            return overlay(image, text) if text else image
        if self._viewer is None:
            from mujoco import viewer  # imported only for a window: it needs a display

            try:
                self._viewer = viewer.launch_passive(self.model, self.data)
            except Exception as error:
                raise RuntimeError(f"MuJoCo could not open a viewer window ({error})") from error
            for name in ("type", "distance", "azimuth", "elevation"):
                setattr(self._viewer.cam, name, getattr(self.camera, name))
            self._viewer.cam.lookat[:] = self.camera.lookat
        with self._viewer.lock():
            self._viewer.user_scn.ngeom = 0
            self._draw(self._viewer.user_scn, positions, forces, colours, contact)
        self._viewer.sync()
        return None

    def close(self) -> None:
        """Free the renderer's OpenGL context or close the window."""
        if self._renderer is not None:
            self._free()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self.model = self.data = None
        self._closed = True


def _check_contact(in_contact: ArrayLike, n: int, name: str = "in_contact") -> np.ndarray:
    """``in_contact`` as (n,) bool, refused rather than cast (as the physics' checks do: "no"
    and 0.5 are no answers); ``name`` is the argument's, for the message."""
    try:
        contact = np.asarray(in_contact)
    except (TypeError, ValueError):  # ragged
        contact = np.asarray(None)
    if contact.shape != (n,) or contact.dtype != bool:
        raise ValueError(
            f"{name} must be a boolean array of shape ({n},), got {contact.dtype}"
            f" {contact.shape}: {in_contact!r}"
        )
    return contact


def overlay(image: np.ndarray, lines: Sequence[str]) -> np.ndarray:
    """``image`` with ``lines`` of text in a dark box at its top left."""
    from PIL import Image, ImageDraw, ImageFont

    picture = Image.fromarray(image)
    size = max(10, image.shape[0] // 30)
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: a fixed bitmap font
        font = ImageFont.load_default()
    draw = ImageDraw.Draw(picture, "RGBA")
    boxes = [draw.textbbox((0, 0), line, font=font) for line in lines]
    step = max(b[3] - b[1] for b in boxes) + size // 3
    width = max(b[2] - b[0] for b in boxes)
    margin = size // 2
    draw.rectangle(
        (0, 0, width + 2 * margin, step * len(lines) + 2 * margin), fill=(20, 24, 32, 190)
    )
    for k, line in enumerate(lines):
        draw.text((margin, margin + k * step), line, font=font, fill=(255, 255, 255, 255))
    return np.asarray(picture)
