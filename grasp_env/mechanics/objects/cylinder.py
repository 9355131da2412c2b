"""A solid cylinder, the paper's coke can among them (see :mod:`grasp_env.mechanics.objects`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..checks import real_array, real_number
from .shape import Shape, _length, _numbers, _read_only

#: A cylinder's two caps by name: the sign of their outward z.
CAPS: dict[str, int] = {"-z": -1, "+z": 1}


@dataclass(frozen=True, eq=False, kw_only=True)
class Cylinder(Shape):
    """A solid cylinder of ``radius`` and ``height``, metres, each in :data:`SIZE_RANGE`,
    centred at the origin with its axis along z: its side is x^2 + y^2 = r^2,
    |z| < h / 2, its caps z = +-h / 2. ``parse_object("can")`` is the paper's coke can."""

    radius: float
    height: float

    kind: ClassVar[str] = "cylinder"
    interior: ClassVar[str] = "x^2 + y^2 < r^2 and |z| < h / 2"

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius", _length("Cylinder radius", self.radius))
        object.__setattr__(self, "height", _length("Cylinder height", self.height))

    @property
    def extent(self) -> float:
        return max(self.radius, self.height / 2)

    @property
    def bounding_size(self) -> np.ndarray:
        d = 2 * self.radius
        return _read_only(np.array([d, d, self.height]))

    def side_point(self, angle: float, height: float = 0.0) -> np.ndarray:
        """The point on the side at ``angle`` radians about z from +x, at ``height`` as a
        fraction of the half-height, in (-1, 1) (the rims, at +-1, are excluded):
        (r cos a, r sin a, height h / 2). Its inward normal is -(cos a, sin a, 0)."""
        angle = real_number("side angle (radians)", angle)
        fraction = real_number(
            "side height (a fraction of the half-height)",
            height,
            -1.0,
            1.0,
            open_low=True,
            open_high=True,
        )
        r = self.radius
        return np.array([r * np.cos(angle), r * np.sin(angle), fraction * self.height / 2])

    def cap_point(self, cap: str, offset: ArrayLike = (0.0, 0.0)) -> np.ndarray:
        """The point on ``cap`` ("+z" or "-z") moved from its centre by ``offset`` = (x, y) as
        fractions of the radius, |offset| < 1 (the rim excluded). Its inward normal is -+z."""
        if not isinstance(cap, str) or cap not in CAPS:
            raise ValueError(f"unknown cap {cap!r}; expected one of {sorted(CAPS)}")
        must = "2 finite fractions of the radius, of length under 1"
        offset = real_array("cap offset", offset, must)
        if offset.shape != (2,) or np.hypot(*offset) >= 1:
            raise ValueError(f"cap offset must be {must}, got {offset.tolist()}")
        return np.array([*(offset * self.radius), CAPS[cap] * self.height / 2])

    def _normal(self, index: int, point: np.ndarray, tolerance: float) -> np.ndarray:
        rho = float(np.hypot(point[0], point[1]))
        side, cap = rho - self.radius, abs(float(point[2])) - self.height / 2  # 0 on, < 0 in
        if side > tolerance or cap > tolerance:
            raise ValueError(
                f"{self._where(index, point)} lies outside the cylinder (radius {self.radius},"
                f" height {self.height})"
            )
        on_side, on_cap = abs(side) <= tolerance and rho > 0, abs(cap) <= tolerance
        if on_side and on_cap:
            raise ValueError(
                f"{self._where(index, point)} is on the cylinder's rim, where its side meets a"
                " cap: its normal is ambiguous"
            )
        if on_cap:
            return np.array([0.0, 0.0, -np.sign(point[2])])
        if on_side:
            return np.array([-point[0] / rho, -point[1] / rho, 0.0]) + 0.0  # no -0.0
        raise ValueError(
            f"{self._where(index, point)} is not on the surface of the cylinder (it lies inside)"
        )

    def _contains(self, point: np.ndarray) -> bool:
        return bool(np.hypot(point[0], point[1]) < self.radius and abs(point[2]) < self.height / 2)

    def mujoco_geom(self) -> dict[str, str]:
        return {"type": "cylinder", "size": _numbers([self.radius, self.height / 2])}

    def spec(self) -> str:
        return f"cylinder:r={self.radius!r},h={self.height!r}"


__all__ = ["CAPS", "Cylinder"]
