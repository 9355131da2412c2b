"""MuJoCo physics: pose checks, continuous rollouts and rendering (docs/design.md §2).

Depends on ``grasp_env.mechanics`` only.

Offscreen rendering without a display: MuJoCo reads ``MUJOCO_GL`` once, when it is first
imported, and otherwise falls back on GLFW, which needs a display. On a Linux machine without
one and with ``MUJOCO_GL`` unset, this package picks an offscreen backend: EGL where there is a
GPU render node, else OSMesa (Mesa's software renderer, Debian's ``libosmesa6``) if it is
installed, else EGL (which Mesa also provides without a GPU). It sets ``MUJOCO_GL`` if MuJoCo
is not imported yet, and otherwise installs that backend's context in MuJoCo's renderer. Set
``MUJOCO_GL`` yourself to choose.
"""

from __future__ import annotations

import ctypes.util
import glob
import importlib
import os
import sys


def _headless_backend() -> str | None:
    """The offscreen GL backend to use, or None where MuJoCo's own choice stands."""
    display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    if not sys.platform.startswith("linux") or display or "MUJOCO_GL" in os.environ:
        return None
    gpu = bool(glob.glob("/dev/dri/renderD*"))
    osmesa = ctypes.util.find_library("OSMesa") is not None
    return "osmesa" if osmesa and not gpu else "egl"


def _choose_gl_backend() -> None:
    backend = _headless_backend()
    if backend is None:
        return
    if "mujoco" not in sys.modules:
        os.environ["MUJOCO_GL"] = backend
        return
    # MuJoCo came first and chose GLFW, which cannot work here: give its renderer the context
    # MUJOCO_GL would have given (glfw loads no PyOpenGL, so the platform is still free).
    from mujoco.rendering.classic import gl_context

    context = importlib.import_module(f"mujoco.{backend}").GLContext
    gl_context.GLContext = context
    sys.modules["mujoco"].GLContext = context


_choose_gl_backend()

from .can_gait import CanSchedule, can_gait_schedule, check_can_gait  # noqa: E402
from .gait import GaitRollout, check_finger_gait, check_gait  # noqa: E402
from .render import GraspView  # noqa: E402
from .rollout import RolloutReport, TrajectoryChecker, check_trajectories  # noqa: E402
from .stability import SETTINGS, PhysicsReport, StabilityChecker, check_poses  # noqa: E402

__all__ = [
    "SETTINGS",
    "CanSchedule",
    "GaitRollout",
    "GraspView",
    "PhysicsReport",
    "RolloutReport",
    "StabilityChecker",
    "TrajectoryChecker",
    "can_gait_schedule",
    "check_can_gait",
    "check_finger_gait",
    "check_gait",
    "check_poses",
    "check_trajectories",
]
