"""A hand with reach: which contacts each finger can push on, pose by pose (docs/gait.md).

A fingertip pushes along its finger's last link. It can press on a face only while the face's
inward normal stays within a cone about that direction (its **approach**): further round, the
fingertip's pad rolls off and the finger's own links meet the face, or its joints run out of
range. The hand is fixed in the world while the object turns, so a contact that a finger holds
turns with the object and may leave its finger's cone: before it does, the finger must hand its
load to the others and lift (the paper's "phasing out").

The default hand is a palm below the object with four fingers around it, each pushing up and
inwards at the elevation of the grasped corner's faces (their inward normals at the start
pose, 90 deg - phi = 35.26 deg above the horizontal), a quarter turn apart; and a thumb above,
pushing straight down. Every finger's cone has the same half-angle, 60 deg by default.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .checks import real_array, real_number
from .trajectory import PHI

#: A normal exactly on a finger's cone is within reach: reach is n . a_f >= cos(cone) -
#: REACH_TOL (cosines; about 1.2e-12 rad of angle at a 60 deg cone). Rounding in the rotated
#: normals is about 1e-16; the tolerance is there because edges are met exactly: on the
#: paper's axis the -x and -y faces' normals reach their fingers' 60 deg cones exactly at
#: alpha = +-90 deg (cos = (1 + cos alpha) / 2), and the gait's 12 phase changes there count
#: those poses as within reach. A normal 1e-10 rad outside the cone is out of reach.
REACH_TOL = 1e-12


def cone_reach(approach: ArrayLike, cone_deg: float, normals: ArrayLike) -> np.ndarray:
    """Which of F fingers with unit approach directions ``approach`` (F, 3) and cones of
    half-angle ``cone_deg`` can push on contacts of inward world normals ``normals``
    (..., N, 3): (..., F, N) bool, n . a_f >= cos(cone) - :data:`REACH_TOL` (the cone's edge
    is within reach, deliberately; docs/gait.md, "The hand and its reach")."""
    approach = np.asarray(approach, dtype=float)
    normals = np.asarray(normals, dtype=float)
    if normals.ndim < 2 or normals.shape[-1] != 3:
        raise ValueError(f"normals must have shape (..., N, 3), got {normals.shape}")
    if not np.all(np.isfinite(normals)):
        raise ValueError("normals must be finite")
    cosine = np.einsum("fc,...nc->...fn", approach, normals)
    return cosine >= np.cos(np.deg2rad(cone_deg)) - REACH_TOL


#: Elevation of the default fingers' approach: that of the corner faces' inward normals at the
#: start pose (body diagonal vertical), 90 deg - phi.
FINGER_ELEVATION_DEG = 90.0 - float(np.rad2deg(PHI))


@dataclass(frozen=True)
class Hand:
    """Fingers that push along fixed world-frame approach directions, each within a cone.

    Finger f can push on a contact whose inward unit normal n (world frame) satisfies
    n . a_f >= cos(cone), a_f its approach direction (the direction in which it pushes); it
    sits on the side -a_f of the object. Fingers are numbered in the order below: first the
    fingers at ``finger_azimuths_deg``, then the thumb.

    Args:
        finger_azimuths_deg: azimuths (about world z, from world x) of the fingers'
            approach directions, degrees; at least one finger.
        finger_elevation_deg: elevation of the fingers' approach above the horizontal,
            degrees in [-90, 90] (> 0: they push upwards, from below).
        thumb: add a thumb that pushes straight down (approach (0, 0, -1)).
        cone_deg: half-angle of every finger's cone of normals, degrees in (0, 180).

    The angles must be finite real numbers and ``thumb`` True or False: strings, booleans as
    numbers and numbers as booleans are refused (a ValueError naming the field), not
    converted. At most 6 fingers in all.
    """

    finger_azimuths_deg: tuple[float, ...] = (-15.0, 75.0, 165.0, 255.0)
    finger_elevation_deg: float = FINGER_ELEVATION_DEG
    thumb: bool = True
    cone_deg: float = 60.0

    def __post_init__(self) -> None:
        must = "a sequence of at least one finite real number (degrees)"
        azimuths = real_array("finger_azimuths_deg", self.finger_azimuths_deg, must)
        if azimuths.ndim != 1 or azimuths.size == 0:
            raise ValueError(f"finger_azimuths_deg must be {must}, got {azimuths.tolist()}")
        object.__setattr__(self, "finger_azimuths_deg", tuple(azimuths.tolist()))
        elevation = real_number("finger_elevation_deg", self.finger_elevation_deg, -90.0, 90.0)
        object.__setattr__(self, "finger_elevation_deg", elevation)
        cone = real_number("cone_deg", self.cone_deg, 0.0, 180.0, open_low=True, open_high=True)
        object.__setattr__(self, "cone_deg", cone)
        if not isinstance(self.thumb, bool | np.bool_):  # "no" would be truthy
            raise ValueError(f"thumb must be True or False, got {self.thumb!r}")
        object.__setattr__(self, "thumb", bool(self.thumb))
        if self.n_fingers > 6:
            raise ValueError(f"a hand has at most 6 fingers, got {self.n_fingers}")

    @property
    def n_fingers(self) -> int:
        return len(self.finger_azimuths_deg) + int(self.thumb)

    @property
    def names(self) -> tuple[str, ...]:
        """``finger1``, ``finger2``, ... and ``thumb``."""
        fingers = tuple(f"finger{i + 1}" for i in range(len(self.finger_azimuths_deg)))
        return fingers + (("thumb",) if self.thumb else ())

    @property
    def approach(self) -> np.ndarray:
        """The fingers' unit approach directions a_f, world frame: (F, 3)."""
        azimuth = np.deg2rad(np.asarray(self.finger_azimuths_deg))
        elevation = np.deg2rad(self.finger_elevation_deg)
        fingers = np.stack(
            [
                np.cos(elevation) * np.cos(azimuth),
                np.cos(elevation) * np.sin(azimuth),
                np.full_like(azimuth, np.sin(elevation)),
            ],
            axis=-1,
        )
        return np.vstack([fingers, [[0.0, 0.0, -1.0]]]) if self.thumb else fingers

    def reach(self, normals: ArrayLike) -> np.ndarray:
        """Which finger can push on which contact: (..., F, N) bool from world-frame inward
        unit normals (..., N, 3) of N contacts."""
        return cone_reach(self.approach, self.cone_deg, normals)
