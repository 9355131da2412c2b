"""The quasi-static trajectory (paper §II; docs/design.md, "Paper geometry")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .rotations import axis_angle_matrix

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
    """

    axis: tuple[float, float, float] = tuple(PAPER_AXIS)  # type: ignore[assignment]
    alpha_start_deg: float = -15.0
    alpha_end_deg: float = 15.0
    alpha_step_deg: float = 1.0

    def __post_init__(self) -> None:
        axis = np.asarray(self.axis, dtype=float)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-12:
            raise ValueError(f"trajectory axis must be a finite non-zero 3-vector, got {self.axis}")
        object.__setattr__(self, "axis", tuple(float(a) for a in axis / np.linalg.norm(axis)))
        values = (self.alpha_start_deg, self.alpha_end_deg, self.alpha_step_deg)
        if not all(np.isfinite(v) for v in values):
            raise ValueError(f"trajectory alphas must be finite, got {values}")
        if self.alpha_step_deg <= 0:
            raise ValueError(f"alpha_step_deg must be > 0, got {self.alpha_step_deg}")
        if self.alpha_end_deg < self.alpha_start_deg:
            raise ValueError(
                f"alpha_end_deg ({self.alpha_end_deg}) must be >= alpha_start_deg"
                f" ({self.alpha_start_deg})"
            )
        if abs(self.alpha_start_deg) > 180 or abs(self.alpha_end_deg) > 180:
            raise ValueError("trajectory alphas must lie in [-180, 180] deg")
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
