"""MuJoCo physics: the stability check of contact forces, and rendering (DESIGN.md §2).

Depends on ``grasp_env.mechanics`` only. MuJoCo reads ``MUJOCO_GL`` once, when it is first
imported; on a Linux machine without a display and with ``MUJOCO_GL`` unset, this package picks
an offscreen backend before that import: EGL where there is a GPU render node, else OSMesa
(Mesa's software renderer, Debian's ``libosmesa6``) if it is installed, else EGL (which Mesa
also provides without a GPU). Set ``MUJOCO_GL`` yourself to override, and import
``grasp_env.physics`` before anything else imports ``mujoco`` for the choice to take effect.
"""

from __future__ import annotations

import ctypes.util
import glob
import os
import sys


def _choose_gl_backend() -> None:
    headless = not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if (
        sys.platform.startswith("linux")
        and headless
        and "MUJOCO_GL" not in os.environ
        and "mujoco" not in sys.modules
    ):
        gpu = bool(glob.glob("/dev/dri/renderD*"))
        osmesa = ctypes.util.find_library("OSMesa") is not None
        os.environ["MUJOCO_GL"] = "osmesa" if osmesa and not gpu else "egl"


_choose_gl_backend()

from .render import GraspView  # noqa: E402
from .stability import SETTINGS, PhysicsReport, StabilityChecker  # noqa: E402

__all__ = ["SETTINGS", "GraspView", "PhysicsReport", "StabilityChecker"]
