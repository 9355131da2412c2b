"""The base of the grasped shapes (:class:`Shape`), the read-only records they and the scenes
are built on, and the accepted lengths and tolerances (see :mod:`grasp_env.mechanics.objects`).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..checks import real_array, real_number

#: Accepted box edge lengths, metres: within them a contact on a face is told from one on an
#: edge (to 1e-9 m, or 1e-9 of the edge beyond 1 m), and the grasp's arithmetic neither
#: overflows nor underflows. The other shapes' lengths (radius, height, a mesh's bounding box
#: edges) must lie in it too.
SIZE_RANGE = (1e-6, 1e6)

# Relative tolerance for "on the surface" (and, in scene.py, for degenerate contact layouts).
_TOL = 1e-9


def _length(name: str, value: Any) -> float:
    """A length in metres: a finite real number in :data:`SIZE_RANGE`."""
    return real_number(f"{name} (metres)", value, *SIZE_RANGE)


def _fractions(name: str, value: ArrayLike, count: int) -> np.ndarray:
    """``count`` finite surface fractions, each in (-1, 1)."""
    must = f"{count} finite fractions in (-1, 1)"
    array = real_array(name, value, must)
    if array.shape != (count,) or np.any(np.abs(array) >= 1):
        raise ValueError(f"{name} must be {must}, got {array.tolist()}")
    return array


def _numbers(values: ArrayLike) -> str:
    """MJCF numbers: each float's shortest repr that reads back exactly."""
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


class ReadOnlyArrays:
    """For frozen dataclasses holding arrays: a pickled or (deep-)copied record keeps its
    read-only arrays read-only (numpy pickles no writeable flag)."""

    def __getstate__(self) -> tuple[dict[str, Any], tuple[str, ...]]:
        frozen = tuple(
            name
            for name, value in vars(self).items()
            if isinstance(value, np.ndarray) and not value.flags.writeable
        )
        return vars(self), frozen

    def __setstate__(self, state: tuple[dict[str, Any], tuple[str, ...]]) -> None:
        values, frozen = state
        vars(self).update(values)  # past the frozen dataclass's __setattr__, as unpickling does
        for name in frozen:
            values[name].flags.writeable = False


class ArrayRecord(ReadOnlyArrays):
    """A :class:`ReadOnlyArrays` record compared by value: equal when of the same class with
    equal fields (``np.array_equal``; a field holding a record, such as a Scene's shape,
    compares by its own value), and hashed to match. Declare it ``eq=False``, or the
    dataclass replaces both with its own, which fail on arrays."""

    def _values(self) -> tuple[Any, ...]:
        return tuple(getattr(self, f.name) for f in fields(self))  # type: ignore[arg-type]

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        pairs = zip(self._values(), other._values(), strict=True)  # type: ignore[attr-defined]
        return all(a == b if isinstance(a, ArrayRecord) else np.array_equal(a, b) for a, b in pairs)

    def __hash__(self) -> int:
        # by value as Python floats: -0.0 and 0.0 are equal, and so are their hashes
        def key(value: Any) -> Any:
            if isinstance(value, ArrayRecord):
                return hash(value)
            value = np.asarray(value)
            return value.shape, tuple(value.ravel().tolist())

        return hash((type(self), *map(key, self._values())))


class Shape(ArrayRecord):
    """What a :class:`~.scene.Scene` needs of the grasped object (object frame, metres).

    Subclasses are frozen dataclasses compared by value (so are the scenes that hold them),
    pickled with their arrays read-only: :class:`Box`, :class:`Cylinder`, :class:`Sphere`,
    :class:`ConvexMesh`.
    """

    #: The shape's name in messages and in :func:`parse_object` specs.
    kind: ClassVar[str] = "shape"
    #: The condition :meth:`contains` tests, in words (for messages).
    interior: ClassVar[str] = ""

    @property
    def extent(self) -> float:
        """The largest |coordinate| of a point of the shape, metres: half the largest edge of
        the smallest box centred at the origin that holds it (a box's largest half-edge, a
        sphere's radius). It scales the tolerances."""
        raise NotImplementedError

    @property
    def bounding_size(self) -> np.ndarray:
        """The edge lengths (3,) of the shape's axis-aligned bounding box, metres (a box's
        ``size``; a cylinder's (2r, 2r, h)): what ``Scene.size`` holds."""
        raise NotImplementedError

    def tolerance(self) -> float:
        """How far from the surface a point may be and count as on it: 1e-9 max(1, extent) m."""
        return _TOL * max(1.0, self.extent)

    def inward_normals(self, points: ArrayLike) -> np.ndarray:
        """The inward unit normals nu_i (n, 3) at ``points`` (n, 3) on the surface.

        A ValueError names contact i if it lies outside the shape, inside it (off the
        surface by more than :meth:`tolerance`), or where two surfaces meet (an edge, rim or
        ridge: its normal is ambiguous).
        """
        must = "an (n, 3) array of finite real numbers"
        points = real_array("points", points, must)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must be {must}, got shape {points.shape}")
        return self._inward_normals(points)

    def _inward_normals(self, points: np.ndarray) -> np.ndarray:
        """:meth:`inward_normals` of checked float64 ``points`` (n, 3)."""
        tolerance = self.tolerance()
        normals = np.zeros_like(points)
        for i, point in enumerate(points):
            normals[i] = self._normal(i, point, tolerance)
        return normals

    def _normal(self, index: int, point: np.ndarray, tolerance: float) -> np.ndarray:
        """The inward normal at one surface point, or a ValueError naming contact ``index``."""
        raise NotImplementedError

    def contains(self, point: ArrayLike) -> bool:
        """Whether ``point`` (3,) lies strictly inside the shape (the centre of gravity must)."""
        must = "a 3-vector of finite real numbers"
        point = real_array("point", point, must)
        if point.shape != (3,):
            raise ValueError(f"point must be {must}, got shape {point.shape}")
        return self._contains(point)

    def _contains(self, point: np.ndarray) -> bool:
        raise NotImplementedError

    def mujoco_geom(self) -> dict[str, str]:
        """The MJCF attributes of a geom of this shape, centred in its body: ``type`` and
        ``size`` (MuJoCo's half-sizes) or, for a mesh, ``mesh`` (see :meth:`mujoco_mesh`)."""
        raise NotImplementedError

    def mujoco_mesh(self) -> dict[str, str] | None:
        """The MJCF attributes of the ``<mesh>`` asset the geom needs (``name``, ``vertex``),
        or None for MuJoCo's primitive shapes."""
        return None

    def spec(self) -> str:
        """The :func:`parse_object` spec of this shape: ``parse_object(s.spec()) == s``."""
        raise NotImplementedError

    def _where(self, index: int, point: np.ndarray) -> str:
        return f"contact {index} at {point.tolist()}"


__all__ = ["SIZE_RANGE", "ArrayRecord", "ReadOnlyArrays", "Shape"]
