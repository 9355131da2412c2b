"""The grasped object's shape: a box, a cylinder, a sphere or a convex mesh (docs/design.md §1).

A :class:`~.scene.Scene` holds one of these shapes by 3 to 8 point contacts. A shape answers
what the mechanics asks of the object:

- where a contact lies, from surface coordinates (:meth:`Box.face_point`,
  :meth:`Cylinder.side_point`, :meth:`Cylinder.cap_point`, :meth:`Sphere.point`,
  :meth:`ConvexMesh.face_point`);
- the inward unit normal nu_i at each contact c_i (:meth:`Shape.inward_normals`), from which
  the friction angle theta_i is measured (paper eq. 2; design §1, "Friction angle"), refusing
  a point off the surface or on an edge, rim or ridge, where the normal is ambiguous;
- whether a point lies strictly inside (:meth:`Shape.contains`: the centre of gravity must);
- a characteristic length (:attr:`Shape.extent`) that scales the tolerances;
- the attributes of a MuJoCo geom of the same shape (:meth:`Shape.mujoco_geom`; strings only,
  mujoco is not imported here).

**Frames and units.** Every shape lives in its object frame, whose origin is the shape's
geometric centre: a box's, cylinder's or sphere's centre, a convex mesh's solid centroid (its
vertices are translated there). A box's edges run along the axes; a cylinder's axis is z.
Lengths are metres. Surface coordinates are fractions, as the box's always were: a face
offset (u, v) is in half-widths, a cylinder's side height in half-heights and its cap offset
in radii, each strictly inside (-1, 1) (a cap offset's length below 1), so that a point is
never on an edge or rim.

**Tolerances.** A point is on the surface when within ``1e-9 max(1, extent)`` metres of it
(1e-9 m, or 1e-9 of the extent beyond 1 m), the tolerance a Scene has always used for boxes.

The paper's object, and the default everywhere, is the unit cube ``Box()`` (edge 1 m); the
command line names shapes with :func:`parse_object` (``"cube"``, ``"can"``, ``"box:size=0.1"``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from .checks import is_integer, real_array, real_number

if TYPE_CHECKING:
    from scipy.spatial import ConvexHull

#: Accepted box edge lengths, metres: within them a contact on a face is told from one on an
#: edge (to 1e-9 m, or 1e-9 of the edge beyond 1 m), and the grasp's arithmetic neither
#: overflows nor underflows. The other shapes' lengths (radius, height, a mesh's bounding box
#: edges) must lie in it too.
SIZE_RANGE = (1e-6, 1e6)

#: Box faces by name: the outward axis and its sign. A contact on face "-x" has inward normal +x.
FACES: dict[str, tuple[int, int]] = {
    "-x": (0, -1), "+x": (0, 1), "-y": (1, -1), "+y": (1, 1), "-z": (2, -1), "+z": (2, 1),
}  # fmt: skip
#: A cylinder's two caps by name: the sign of their outward z.
CAPS: dict[str, int] = {"-z": -1, "+z": 1}
#: The MJCF name of a convex mesh's ``<mesh>`` asset, which its geom refers to.
MESH_NAME = "object"
#: The paper's coke can, as ``"can"`` names it: a 330 ml can, 66 mm across and 115 mm tall.
CAN_RADIUS, CAN_HEIGHT = 0.033, 0.115

# Relative tolerance for "on the surface" (and, in scene.py, for degenerate contact layouts).
_TOL = 1e-9
# Hull facets whose outward normals differ by at most this (and whose planes lie within
# _TOL of the extent) are one face of a convex mesh.
_COPLANAR = 1e-9
# A convex mesh whose hull has under this fraction of its bounding box's volume is flat.
_FLAT = 1e-9


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


@dataclass(frozen=True, eq=False, kw_only=True)
class ConvexMesh(Shape):
    """The convex hull of ``vertices`` (V, 3), metres (scipy.spatial.ConvexHull).

    The mesh keeps the hull's vertices only (points inside it, or inside its faces, are
    dropped), in their given order, translated so that the solid's centroid, the centre of
    gravity of a uniform solid, is the origin. Hull facets in one plane (Qhull triangulates)
    are merged into one face. Its bounding box's edges must each lie in :data:`SIZE_RANGE`,
    and a flat set (its hull's volume under 1e-9 of its bounding box's) is refused.

    Attributes (derived, read-only):
        faces: per face, the indices of its vertices, counter-clockwise seen from outside.
        face_normals: (F, 3) outward unit normals; the inward normal on face f is the negative.
        face_offsets: (F,) the faces' distances from the origin: face f is the plane
            face_normals[f] . x = face_offsets[f].

    Meshes compare and hash by their vertices.
    """

    vertices: np.ndarray
    faces: tuple[tuple[int, ...], ...] = field(init=False, repr=False)
    face_normals: np.ndarray = field(init=False, repr=False)
    face_offsets: np.ndarray = field(init=False, repr=False)

    kind: ClassVar[str] = "convex mesh"
    interior: ClassVar[str] = "on the inner side of every face"

    def __post_init__(self) -> None:
        must = "a (V, 3) array of finite real numbers, V >= 4 (not all in one plane)"
        points = real_array("vertices", self.vertices, must)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) < 4:
            raise ValueError(f"vertices must be {must}, got shape {points.shape}")
        edges = np.ptp(points, axis=0)
        low, high = SIZE_RANGE
        if np.any(edges < low) or np.any(edges > high):
            raise ValueError(
                f"vertices must span a bounding box whose edges are each in [{low:g}, {high:g}]"
                f" metres, got edges {edges.tolist()}"
            )
        flat = (
            f"vertices are flat (all in one plane, to {_FLAT:g} of their bounding box's"
            " volume): a convex mesh needs a solid hull"
        )
        # imported here: scipy.spatial takes longer to import than the rest of the mechanics
        from scipy.spatial import ConvexHull, QhullError

        try:
            hull = ConvexHull(points)
        except QhullError:
            raise ValueError(flat) from None
        if not hull.volume > _FLAT * np.prod(edges):
            raise ValueError(flat)
        keep = np.sort(hull.vertices)
        new_index = np.full(len(points), -1)
        new_index[keep] = np.arange(len(keep))
        points = points[keep]
        points = points - _solid_centroid(points, new_index[hull.simplices])
        object.__setattr__(self, "vertices", _read_only(points))
        hull = ConvexHull(points)  # in the object frame
        faces, normals, offsets = _merge_facets(points, hull, self.tolerance())
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "face_normals", _read_only(normals))
        object.__setattr__(self, "face_offsets", _read_only(offsets))

    def _values(self) -> tuple[Any, ...]:
        return (self.vertices,)  # the rest derives from them

    @property
    def extent(self) -> float:
        return float(np.abs(self.vertices).max())

    @property
    def bounding_size(self) -> np.ndarray:
        return _read_only(np.ptp(self.vertices, axis=0))

    def face_point(self, face: int, weights: ArrayLike | None = None) -> np.ndarray:
        """A point strictly inside ``face`` (an index into :attr:`faces`): the convex
        combination of its vertices with ``weights`` (one per vertex, each > 0, normalised
        to sum 1), or by default the face's centroid (of its area)."""
        count = len(self.faces)
        if not is_integer(face) or not 0 <= face < count:
            raise ValueError(f"face must be an integer in [0, {count - 1}], got {face!r}")
        corners = self.vertices[list(self.faces[face])]
        if weights is None:
            return _polygon_centroid(corners)
        must = f"{len(corners)} finite numbers > 0 (one per vertex of face {face})"
        weights = real_array("weights", weights, must)
        if weights.shape != (len(corners),) or not np.all(weights > 0):
            raise ValueError(f"weights must be {must}, got {weights.tolist()}")
        weights = weights / weights.max()  # their sum neither under- nor overflows
        return (weights / weights.sum()) @ corners

    def _distances(self, point: np.ndarray) -> np.ndarray:
        """Signed distances of ``point`` from the faces' planes: > 0 outside."""
        return self.face_normals @ point - self.face_offsets

    def _normal(self, index: int, point: np.ndarray, tolerance: float) -> np.ndarray:
        distance = self._distances(point)
        if np.any(distance > tolerance):
            raise ValueError(f"{self._where(index, point)} lies outside the convex mesh")
        on = np.flatnonzero(np.abs(distance) <= tolerance)
        if on.size == 0:
            raise ValueError(
                f"{self._where(index, point)} is not on the surface of the convex mesh"
                " (it lies inside)"
            )
        if on.size > 1:
            raise ValueError(
                f"{self._where(index, point)} is on an edge or vertex of the convex mesh"
                f" (faces {on.tolist()} meet there): its normal is ambiguous"
            )
        return -self.face_normals[on[0]]

    def _contains(self, point: np.ndarray) -> bool:
        return bool(np.all(self._distances(point) < 0))

    def mujoco_geom(self) -> dict[str, str]:
        return {"type": "mesh", "mesh": MESH_NAME}

    def mujoco_mesh(self) -> dict[str, str]:
        """``{"name": MESH_NAME, "vertex": "x0 y0 z0 x1 ..."}``, object frame, metres.

        MuJoCo places a mesh where its vertices say (it moves the geom by the offset it takes
        out of them), so the geom needs no ``pos`` or ``quat``.
        """
        return {"name": MESH_NAME, "vertex": _numbers(self.vertices)}

    def spec(self) -> str:
        raise ValueError("a ConvexMesh has no parse_object spec: build it from its vertices")


def _solid_centroid(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The centroid of the solid bounded by ``triangles`` (T, 3) of ``points``: the volume
    weighted centroids of the tetrahedra joining each triangle to an interior point."""
    inner = points.mean(axis=0)
    a, b, c = (points[triangles[:, k]] - inner for k in range(3))
    volumes = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))  # 6 x each tetrahedron's
    centroids = (a + b + c) / 4  # of each tetrahedron, relative to ``inner``
    return inner + volumes @ centroids / volumes.sum()


def _merge_facets(
    points: np.ndarray, hull: ConvexHull, tolerance: float
) -> tuple[tuple[tuple[int, ...], ...], np.ndarray, np.ndarray]:
    """The faces (vertex indices, counter-clockwise from outside), outward unit normals and
    offsets of ``hull``'s facets merged by plane: on a convex hull, the facets in one
    supporting plane make one face, connected through neighbours in that plane."""
    equations = hull.equations  # n . x + e = 0, n outward
    count = len(equations)
    facets = np.repeat(np.arange(count), 3)
    neighbours = hull.neighbors.ravel()
    same = (np.abs(equations[facets, :3] - equations[neighbours, :3]).max(axis=1) <= _COPLANAR) & (
        np.abs(equations[facets, 3] - equations[neighbours, 3]) <= tolerance
    )
    root = list(range(count))  # union-find over the facets joined to a neighbour in-plane

    def find(f: int) -> int:
        while root[f] != f:
            root[f] = root[root[f]]
            f = root[f]
        return f

    for f, g in zip(facets[same].tolist(), neighbours[same].tolist(), strict=True):
        root[find(f)] = find(g)
    members: dict[int, list[int]] = {}
    for f in range(count):
        members.setdefault(find(f), []).append(f)
    groups = list(members.values())  # in the order of their first facet
    faces, normals, offsets = [], [], []
    for group in groups:
        normal = equations[group, :3].mean(axis=0)
        normal /= np.linalg.norm(normal)
        indices = np.unique(hull.simplices[group])
        corners = points[indices]
        middle = corners.mean(axis=0)
        u = corners[np.argmax(np.linalg.norm(corners - middle, axis=1))] - middle
        u -= (u @ normal) * normal
        u /= np.linalg.norm(u)
        w = np.cross(normal, u)  # u x w = normal: increasing angle is counter-clockwise
        angles = np.arctan2((corners - middle) @ w, (corners - middle) @ u)
        faces.append(tuple(int(i) for i in indices[np.argsort(angles)]))
        normals.append(normal)
        offsets.append(float((corners @ normal).mean()))
    return tuple(faces), np.array(normals), np.array(offsets)


def _polygon_centroid(corners: np.ndarray) -> np.ndarray:
    """The area centroid of a convex polygon of ``corners`` (k, 3), in order."""
    a, b, c = corners[0], corners[1:-1], corners[2:]
    areas = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    return areas @ ((a + b + c) / 3) / areas.sum()


# ---------------------------------------------------------------------- command-line specs

#: The shapes :func:`parse_object` names, and the keys each accepts (lengths in metres).
OBJECT_KEYS: dict[str, tuple[str, ...]] = {
    "box": ("size", "x", "y", "z"),
    "cube": (),
    "cylinder": ("r", "h"),
    "sphere": ("r",),
    "can": (),
}

_SPEC_HELP = (
    "an object spec is a name, optionally followed by ':' and key=value pairs joined by ','"
    " (lengths in metres): 'cube' (the paper's unit cube), 'box' (the same), 'box:size=0.1',"
    " 'box:x=0.1,y=0.2,z=0.3', 'cylinder:r=0.033,h=0.115', 'sphere:r=0.05', 'can' (a 330 ml"
    " coke can)"
)


def parse_object(spec: str) -> Shape:
    """The shape a command-line ``spec`` names:

    - ``"cube"`` or ``"box"``: the paper's unit cube, ``Box()``;
    - ``"box:size=0.1"``: a cube of edge 0.1 m; ``"box:x=0.1,y=0.2,z=0.3"``: a box of those
      edge lengths (all three);
    - ``"cylinder:r=0.033,h=0.115"``: ``Cylinder(radius=0.033, height=0.115)``;
    - ``"sphere:r=0.05"``: ``Sphere(radius=0.05)``;
    - ``"can"``: the paper's coke can, a 330 ml can: ``Cylinder(radius=0.033, height=0.115)``.

    Lengths are metres. Anything else raises a ValueError listing the accepted names and keys.
    :meth:`Shape.spec` writes a shape's spec back.
    """
    if not isinstance(spec, str):
        raise ValueError(f"object spec must be a string, got {spec!r}; {_SPEC_HELP}")
    name, colon, rest = spec.strip().partition(":")
    name = name.strip().lower()
    if name not in OBJECT_KEYS:
        raise ValueError(
            f"unknown object {name!r} in {spec!r}: the objects are {sorted(OBJECT_KEYS)};"
            f" {_SPEC_HELP}"
        )
    accepted = OBJECT_KEYS[name]
    values: dict[str, float] = {}
    for item in rest.split(",") if colon else ():
        key, equals, text = (part.strip() for part in item.partition("="))
        if key not in accepted or not equals:
            keys = f"the keys {list(accepted)}" if accepted else "no keys"
            raise ValueError(
                f"object {spec!r}: {name!r} takes {keys} as key=value, got {item.strip()!r}"
            )
        if key in values:
            raise ValueError(f"object {spec!r}: key {key!r} given twice")
        try:
            values[key] = float(text)
        except ValueError:
            raise ValueError(
                f"object {spec!r}: {key} must be a number (metres), got {text!r}"
            ) from None
    try:
        return _build(name, values)
    except ValueError as error:
        raise ValueError(f"object {spec!r}: {error}") from None


def _build(name: str, values: dict[str, float]) -> Shape:
    def need(*keys: str) -> list[float]:
        missing = [k for k in keys if k not in values]
        if missing:
            raise ValueError(f"{name!r} needs the keys {list(keys)}, missing {missing}")
        return [values[k] for k in keys]

    if name == "can":
        return Cylinder(radius=CAN_RADIUS, height=CAN_HEIGHT)
    if name == "cylinder":
        radius, height = need("r", "h")
        return Cylinder(radius=radius, height=height)
    if name == "sphere":
        (radius,) = need("r")
        return Sphere(radius=radius)
    if "size" in values:
        if len(values) > 1:
            raise ValueError("'box' takes either size or all of x, y and z, not both")
        return Box(size=values["size"])
    return Box(size=need("x", "y", "z")) if values else Box()


__all__ = [
    "CAN_HEIGHT",
    "CAN_RADIUS",
    "CAPS",
    "FACES",
    "MESH_NAME",
    "OBJECT_KEYS",
    "SIZE_RANGE",
    "ArrayRecord",
    "Box",
    "ConvexMesh",
    "Cylinder",
    "ReadOnlyArrays",
    "Shape",
    "Sphere",
    "box_size",
    "parse_object",
]
