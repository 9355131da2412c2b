"""A convex mesh: the convex hull of its vertices, its coplanar facets merged into faces (see
:mod:`grasp_env.mechanics.objects`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..checks import is_integer, real_array
from .shape import SIZE_RANGE, Shape, _numbers, _read_only

if TYPE_CHECKING:
    from scipy.spatial import ConvexHull

#: The MJCF name of a convex mesh's ``<mesh>`` asset, which its geom refers to.
MESH_NAME = "object"

# Hull facets whose outward normals differ by at most this (and whose planes lie within
# _TOL of the extent) are one face of a convex mesh.
_COPLANAR = 1e-9
# A convex mesh whose hull has under this fraction of its bounding box's volume is flat.
_FLAT = 1e-9


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


__all__ = ["MESH_NAME", "ConvexMesh"]
