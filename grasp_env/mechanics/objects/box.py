"""A box, and the paper's unit cube ``Box()`` (see :mod:`grasp_env.mechanics.objects`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..checks import real_array
from .shape import SIZE_RANGE, Shape, _fractions, _numbers, _read_only

#: Box faces by name: the outward axis and its sign. A contact on face "-x" has inward normal +x.
FACES: dict[str, tuple[int, int]] = {
    "-x": (0, -1), "+x": (0, 1), "-y": (1, -1), "+y": (1, 1), "-z": (2, -1), "+z": (2, 1),
}  # fmt: skip


def box_size(size: ArrayLike) -> np.ndarray:
    """The edge lengths (3,) of ``size``: a number (a cube) or 3 of them, each a finite real
    number in :data:`SIZE_RANGE` metres, or a ValueError naming ``size``."""
    low, high = SIZE_RANGE
    must = f"a number or 3 numbers (the box's edge lengths, metres), each in [{low:g}, {high:g}]"
    array = real_array("size", size, must)
    if array.shape not in ((), (3,)) or np.any(array < low) or np.any(array > high):
        raise ValueError(f"size must be {must}, got {_shown(size)}")
    return np.array(np.broadcast_to(array, (3,)))


def _shown(value: ArrayLike) -> str:
    return repr(value.tolist() if isinstance(value, np.ndarray) else value)


@dataclass(frozen=True, eq=False, kw_only=True)
class Box(Shape):
    """A box of edge lengths ``size`` (a number for a cube, or 3 of them), metres, each in
    :data:`SIZE_RANGE`, centred at the origin with its edges along the axes. ``Box()`` is
    the paper's unit cube."""

    size: np.ndarray = 1.0  # type: ignore[assignment]

    kind: ClassVar[str] = "box"
    interior: ClassVar[str] = "|cg| < size / 2"

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", _read_only(box_size(self.size)))

    @property
    def extent(self) -> float:
        return float((self.size / 2).max())

    @property
    def bounding_size(self) -> np.ndarray:
        return self.size

    def face_point(self, face: str, offset: ArrayLike = (0.0, 0.0)) -> np.ndarray:
        """The point on ``face`` (a name from :data:`FACES`, e.g. "-x") moved from the face
        centre by ``offset`` = (u, v) along the face's two in-plane axes (in axis order, e.g.
        y then z for an x face), as fractions of the half-widths: |u|, |v| < 1."""
        if not isinstance(face, str) or face not in FACES:
            raise ValueError(f"unknown face {face!r}; expected one of {sorted(FACES)}")
        offset = _fractions("face offset", offset, 2)
        half = self.size / 2
        axis, sign = FACES[face]
        others = [a for a in range(3) if a != axis]
        point = np.zeros(3)
        point[axis] = sign * half[axis]
        point[others] = offset * half[others]
        return point

    def _normal(self, index: int, point: np.ndarray, tolerance: float) -> np.ndarray:
        distance = np.abs(point) - self.size / 2  # 0 on a face, < 0 inside
        if np.any(distance > tolerance):
            raise ValueError(
                f"{self._where(index, point)} lies outside the box {self.size.tolist()}"
            )
        on = np.flatnonzero(np.abs(distance) <= tolerance)
        if on.size == 0:
            raise ValueError(f"{self._where(index, point)} is not on a face of the box")
        if on.size > 1:
            raise ValueError(f"{self._where(index, point)} is on an edge: its normal is ambiguous")
        normal = np.zeros(3)
        normal[on[0]] = -np.sign(point[on[0]])
        return normal

    def _contains(self, point: np.ndarray) -> bool:
        return bool(np.all(np.abs(point) < self.size / 2))

    def mujoco_geom(self) -> dict[str, str]:
        return {"type": "box", "size": _numbers(self.size / 2)}

    def spec(self) -> str:
        x, y, z = self.size.tolist()
        return f"box:size={x!r}" if x == y == z else f"box:x={x!r},y={y!r},z={z!r}"


__all__ = ["FACES", "Box", "box_size"]
