"""A solid sphere (see :mod:`grasp_env.mechanics.objects`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..checks import real_array
from .shape import Shape, _length, _numbers, _read_only


@dataclass(frozen=True, eq=False, kw_only=True)
class Sphere(Shape):
    """A solid sphere of ``radius``, metres, in :data:`SIZE_RANGE`, centred at the origin."""

    radius: float

    kind: ClassVar[str] = "sphere"
    interior: ClassVar[str] = "|cg| < r"

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius", _length("Sphere radius", self.radius))

    @property
    def extent(self) -> float:
        return self.radius

    @property
    def bounding_size(self) -> np.ndarray:
        return _read_only(np.full(3, 2 * self.radius))

    def point(self, direction: ArrayLike) -> np.ndarray:
        """The surface point r d / |d| along ``direction`` d, any nonzero finite 3-vector.
        Its inward normal is -d / |d|."""
        must = "a nonzero 3-vector of finite real numbers"
        d = real_array("direction", direction, must)
        if d.shape != (3,) or not np.any(d):
            raise ValueError(f"direction must be {must}, got {d.tolist()}")
        d = d / np.abs(d).max()  # |d| neither under- nor overflows
        return self.radius * d / np.linalg.norm(d)

    def _normal(self, index: int, point: np.ndarray, tolerance: float) -> np.ndarray:
        length = float(np.linalg.norm(point))
        if length - self.radius > tolerance:
            raise ValueError(
                f"{self._where(index, point)} lies outside the sphere (radius {self.radius})"
            )
        if length - self.radius < -tolerance:
            raise ValueError(
                f"{self._where(index, point)} is not on the surface of the sphere (it lies inside)"
            )
        return -point / length

    def _contains(self, point: np.ndarray) -> bool:
        return bool(np.linalg.norm(point) < self.radius)

    def mujoco_geom(self) -> dict[str, str]:
        return {"type": "sphere", "size": _numbers([self.radius])}

    def spec(self) -> str:
        return f"sphere:r={self.radius!r}"


__all__ = ["Sphere"]
