"""The quasi-static trajectory (paper §II; docs/design.md, "Paper geometry")."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .checks import real_number
from .rotations import axis_angle_matrix, unit_vectors

#: The paper's rotation axis (1, -1, 0)/sqrt(2): it takes the body diagonal onto world z.
PAPER_AXIS = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
#: phi = acos(1/sqrt(3)) = 54.7356 deg (paper eq. 5; the paper's "57.4 deg" is a misprint).
PHI = float(np.arccos(1.0 / np.sqrt(3.0)))
#: Start pose: body diagonal vertical, the grasped corner (-1/2, -1/2, -1/2) at the bottom.
START_ROTATION = axis_angle_matrix(PAPER_AXIS, PHI)


#: The most poses a trajectory may have (a full turn in steps of 0.036 deg).
MAX_POSES = 10_000


@dataclass(frozen=True)
class Trajectory:
    """Rotation about the world-frame ``axis`` by alpha, from the start pose (alpha = 0).

    R(alpha) = Rot(axis, alpha) R0 with R0 = Rot(a, phi); for the paper's axis this is the
    paper's Rot(a, phi + alpha). The default is the paper's sweep, -15 to +15 deg by 1 deg.

    Accepted (anything else raises ValueError naming the field): ``axis`` a finite non-zero
    3-vector of any length (stored normalised); the alphas finite real numbers (not booleans
    or strings; stored as floats) in [-180, 180] deg with start <= end; a step > 0 deg; at
    most :data:`MAX_POSES` poses.
    """

    axis: tuple[float, float, float] = tuple(PAPER_AXIS)  # type: ignore[assignment]
    alpha_start_deg: float = -15.0
    alpha_end_deg: float = 15.0
    alpha_step_deg: float = 1.0

    def __post_init__(self) -> None:
        axis = unit_vectors("trajectory axis", self.axis, single=True)
        object.__setattr__(self, "axis", tuple(float(a) for a in axis))
        for name, low, high, open_low in (
            ("alpha_start_deg", -180.0, 180.0, False),
            ("alpha_end_deg", -180.0, 180.0, False),
            ("alpha_step_deg", 0.0, math.inf, True),
        ):
            value = real_number(name, getattr(self, name), low, high, open_low=open_low)
            object.__setattr__(self, name, value)
        if self.alpha_end_deg < self.alpha_start_deg:
            raise ValueError(
                f"alpha_end_deg ({self.alpha_end_deg}) must be >= alpha_start_deg"
                f" ({self.alpha_start_deg})"
            )
        span = self.alpha_end_deg - self.alpha_start_deg
        poses = np.floor(span / self.alpha_step_deg + 1e-9) + 1  # as alphas_deg counts them
        if poses > MAX_POSES:  # each pose is a solve, a MuJoCo check, a frame
            raise ValueError(
                f"a trajectory may have at most {MAX_POSES} poses, but {span:g} deg in steps of"
                f" {self.alpha_step_deg:g} deg make {poses:,.0f}: raise alpha_step_deg"
            )

    @property
    def alphas_deg(self) -> np.ndarray:
        """The poses' alpha values in degrees, start and end included."""
        count = int(
            np.floor((self.alpha_end_deg - self.alpha_start_deg) / self.alpha_step_deg + 1e-9)
        )
        return self.alpha_start_deg + self.alpha_step_deg * np.arange(count + 1)

    def __len__(self) -> int:
        return len(self.alphas_deg)

    def rotations(self) -> np.ndarray:
        """Object orientations R(alpha), shape (T, 3, 3)."""
        return pose_rotation(self.axis, np.deg2rad(self.alphas_deg))


def pose_rotation(axis: ArrayLike, alpha: ArrayLike) -> np.ndarray:
    """R(alpha) = Rot(axis, alpha) R0, batched over alpha (radians) and axis (..., 3)."""
    return axis_angle_matrix(axis, alpha) @ START_ROTATION
