"""Shared by the tests of the certified minimax optimiser (tests/test_minimax_*.py): the accuracy
required, the certificate's gap, random scenes and stacked grasps.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_FACES,
    Grasp,
    Scene,
)

DEG = np.pi / 180


TOLERANCE = 1e-6 * DEG  # the accuracy required: the optimum within 1e-6 deg of the reference


GAP = 1e-9  # radians: the certificate the solver promises


def random_scene(rng: np.random.Generator, n: int) -> tuple[Scene, float]:
    """A scene near the paper's (contact offsets up to 0.35 of the face half-width, weight 1 to
    20 N, centre-of-gravity offsets up to 0.12), and alpha (radians) in [-15, 15] deg on the
    paper's trajectory."""
    faces = PAPER_FACES if n == 3 else FOUR_FINGER_FACES
    scene = Scene.on_faces(
        faces,
        offsets=rng.uniform(-0.35, 0.35, (n, 2)),
        weight=rng.uniform(1.0, 20.0),
        cg_offset=rng.uniform(-0.12, 0.12, 3),
    )
    return scene, np.deg2rad(rng.uniform(-15.0, 15.0))


def stack_of(g: Grasp, count: int) -> Grasp:
    return Grasp(*(np.stack([getattr(g, f.name)] * count) for f in fields(Grasp)))
