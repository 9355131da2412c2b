"""Compile the solver once, ahead of its first use: ``python -m grasp_env.mechanics.minimax.warm``.

The solver has two numba entry points (``driver.solve_batch`` and ``driver.solve_grasp``, for
one grasp; a single signature each), each linking every kernel of this package, and the conic
solver of five or more contacts a third (``conic.solve_batch``); compiling them
takes a minute or more of CPU, which a new user would
otherwise wait through at their first command. Building the wheel runs this module in the
build tree (``grasp_env/_build.py``), so the wheel carries numba's cache next to the sources
(``__pycache__``, keyed on the sources' SHA-256 by :mod:`.jit`). numba loads it where the
installed numba version and the CPU match the build's (a wheel built and installed on one
machine) and compiles as usual elsewhere; a read-only install still falls back to numba's own
cache locations.
"""

from __future__ import annotations

import time

import numpy as np


def warm() -> float:
    """Solve a few poses of a moved-contact scene (every path compiled); return the seconds."""
    from grasp_env.mechanics import PAPER_AXIS, Scene, pose_rotation, scene_grasp, solve_minimax
    from grasp_env.mechanics.objects import Box

    start = time.perf_counter()
    scene = Scene.on_faces(offsets=[[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]])
    rotations = np.stack([pose_rotation(PAPER_AXIS, np.radians(a)) for a in (-15.0, 0.0, 15.0)])
    solve_minimax(scene_grasp(scene, rotations), 2.0 * scene.weight)
    solve_minimax(scene_grasp(scene, rotations[0]), 2.0 * scene.weight)  # one grasp
    faces = (("-x", (0.3, -0.2)), ("-y", (0, 0)), ("-z", (0, 0)), ("+z", (0, 0)), ("+x", (0, 0.2)))
    five = Scene(contacts=[Box().face_point(face, offset) for face, offset in faces])
    solve_minimax(scene_grasp(five, rotations), 2.0 * five.weight)  # the conic solver
    return time.perf_counter() - start


if __name__ == "__main__":
    print(f"grasp_env's minimax solver compiled into numba's cache in {warm():.0f} s")
