"""The grasped object (any shape of :mod:`.objects`), its 3 to 8 contacts and its load
(docs/design.md §1, "Mechanics")."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike

from .checks import real_array, real_number
from .objects import (
    FACES,
    SIZE_RANGE,
    ArrayRecord,
    Box,
    ReadOnlyArrays,
    Shape,
    box_size,
)

#: The paper's grip: the three faces that meet at the corner (-1/2, -1/2, -1/2).
PAPER_FACES: tuple[str, ...] = ("-x", "-y", "-z")
#: The four-finger grip: the paper's three plus a "thumb" on the top face, pressing down.
FOUR_FINGER_FACES: tuple[str, ...] = ("-x", "-y", "-z", "+z")
#: Default friction coefficient (theta_lim = atan(0.5) = 26.57 deg).
DEFAULT_MU = 0.5
DEFAULT_WEIGHT = 5.0
#: The fewest and most contacts a Scene may have (the solver's range).
MIN_SCENE_CONTACTS, MAX_SCENE_CONTACTS = 3, 8

# Relative tolerance for degenerate contact layouts, in units of the object's largest
# bounding box edge (coincident: 1e-6 of it; collinear, coplanar: 1e-6 of its square, cube).
_DEGENERATE = 1e-6

__all__ = [
    "DEFAULT_MU",
    "DEFAULT_WEIGHT",
    "FACES",
    "FOUR_FINGER_FACES",
    "MAX_SCENE_CONTACTS",
    "MIN_SCENE_CONTACTS",
    "PAPER_FACES",
    "SIZE_RANGE",
    "ArrayRecord",
    "ReadOnlyArrays",
    "Scene",
    "box_size",
    "face_point",
]


def face_point(face: str, offset: ArrayLike = (0.0, 0.0), size: ArrayLike = 1.0) -> np.ndarray:
    """Object-frame point on ``face`` of a box of edge lengths ``size``, centred at the origin:
    ``Box(size=size).face_point(face, offset)`` (:meth:`.objects.Box.face_point`).

    ``offset`` = (u, v) moves the point from the face centre along the face's two in-plane axes
    (in axis order, e.g. y then z for an x face), as fractions of the half-widths: |u|, |v| < 1.
    """
    if not isinstance(face, str) or face not in FACES:  # named first, as it always was
        raise ValueError(f"unknown face {face!r}; expected one of {sorted(FACES)}")
    return Box(size=size).face_point(face, offset)


@dataclass(frozen=True, eq=False)
class Scene(ArrayRecord):
    """An object held by point contacts with Coulomb friction (docs/design.md §1, "Scene").

    The object is a :class:`~.objects.Shape`: by default a box of edge lengths ``size``, or
    any ``shape`` (:class:`~.objects.Box`, :class:`~.objects.Cylinder`,
    :class:`~.objects.Sphere`, :class:`~.objects.ConvexMesh`). All vectors are in the object
    frame, whose origin is the shape's centre, except the extra load (``extra_force``,
    ``extra_torque`` about the centre of gravity), which is in the world frame like the
    weight. ``Scene()`` is the paper's scene: the unit cube, face-centre contacts on the three
    faces meeting at the corner (-1/2, -1/2, -1/2), w = 5 N.

    Contacts on any shape come from its surface coordinates, e.g.
    ``can = Cylinder(radius=0.033, height=0.115)``, then
    ``Scene(shape=can, contacts=[can.side_point(0.0), can.cap_point("-z"), ...])``;
    :meth:`on_faces` is the short way for a box.

    Args:
        contacts: (n, 3) contact points on the object's surface, :data:`MIN_SCENE_CONTACTS`
            <= n <= :data:`MAX_SCENE_CONTACTS`, each on one face (not an edge, rim or ridge);
            not coincident, not collinear (n = 3), not all coplanar (n >= 4).
        size: box edge lengths (a number for a cube), metres, each in :data:`SIZE_RANGE`;
            without a ``shape``, the box is ``Box(size=size)`` (default 1.0, the unit cube).
            With a ``shape`` leave it out: given, it must equal the shape's bounding box (as
            ``dataclasses.replace`` passes it back; to replace the shape, pass ``size=None``).
            Stored, it is always the edge lengths (3,) of the shape's axis-aligned bounding
            box: a box's size, a cylinder's (2r, 2r, h), a sphere's (2r, 2r, 2r), a mesh's
            vertices' extents.
        weight: weight w > 0, newtons, acting along world -z at the centre of gravity.
        mu: Coulomb friction coefficient > 0; the friction angle limit is atan(mu).
        cg_offset: (3,) centre of gravity relative to the shape's centre; must lie strictly
            inside the shape (:meth:`~.objects.Shape.contains`).
        extra_force, extra_torque: (3,) an optional extra wrench on the object (world frame).
        shape: the grasped object (keyword only); default ``Box(size=size)``.

    The contacts' inward normals ``normals`` (n, 3) come from
    :meth:`~.objects.Shape.inward_normals`. Every number must be a finite real number (Python
    or numpy ints and floats; booleans, strings and complex numbers are refused, not
    converted); anything else raises a ValueError naming the field and its accepted range. The
    scene stores its own read-only float arrays (and floats for ``weight`` and ``mu``),
    read-only in its pickles and copies too. Scenes compare by value: two are equal when every
    field is (``np.array_equal``; the shapes by their own value), and equal scenes hash alike,
    so they serve as dictionary keys and set members.
    """

    contacts: np.ndarray = field(
        default_factory=lambda: np.array([face_point(f) for f in PAPER_FACES])
    )
    size: np.ndarray = None  # type: ignore[assignment]
    weight: float = DEFAULT_WEIGHT
    mu: float = DEFAULT_MU
    cg_offset: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]
    extra_force: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]
    extra_torque: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]
    normals: np.ndarray = field(init=False, repr=False)
    shape: Shape = field(default=None, kw_only=True)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        def frozen(name: str, array: np.ndarray) -> np.ndarray:
            array = np.array(array)  # the scene's own copy, read-only
            array.flags.writeable = False
            object.__setattr__(self, name, array)
            return array

        def vector(name: str) -> np.ndarray:
            must = "a 3-vector of finite real numbers"
            array = real_array(name, getattr(self, name), must)
            if array.shape != (3,):
                raise ValueError(f"{name} must be {must}, got shape {array.shape}")
            return frozen(name, array)

        low, high = MIN_SCENE_CONTACTS, MAX_SCENE_CONTACTS
        must = f"an (n, 3) array of finite real numbers, n = {low} to {high} contacts"
        contacts = real_array("contacts", self.contacts, must)
        if contacts.ndim != 2 or contacts.shape[1] != 3 or not low <= len(contacts) <= high:
            raise ValueError(
                f"contacts must have shape (n, 3) with {low} <= n <= {high}, got {contacts.shape}"
            )
        contacts = frozen("contacts", contacts)
        shape = self._shape()
        object.__setattr__(self, "shape", shape)
        frozen("size", shape.bounding_size)
        for name in ("weight", "mu"):
            value = real_number(name, getattr(self, name), 0.0, open_low=True)
            object.__setattr__(self, name, value)
        cg = vector("cg_offset")
        if not shape._contains(cg):  # checked here: a finite 3-vector
            raise ValueError(
                f"cg_offset {cg.tolist()} must lie inside the {shape.kind} ({shape.interior})"
            )
        vector("extra_force")
        vector("extra_torque")
        frozen("normals", shape._inward_normals(contacts))  # checked contacts
        _check_layout(contacts, float(self.size.max()))

    def _shape(self) -> Shape:
        """The shape the arguments name: ``shape``, or ``Box(size=size)``."""
        shape, size = self.shape, self.size
        if shape is None:
            return Box(size=1.0 if size is None else size)
        if not isinstance(shape, Shape):
            raise ValueError(
                "shape must be a Box, Cylinder, Sphere or ConvexMesh"
                f" (grasp_env.mechanics.objects), got {type(shape).__name__}"
            )
        if size is not None and not np.array_equal(box_size(size), shape.bounding_size):
            raise ValueError(
                f"size {_listed(size)} disagrees with the {shape.kind}'s bounding box"
                f" {shape.bounding_size.tolist()}: give a shape or a size, not both"
                " (Box(size=...) for a box)"
            )
        return shape

    @classmethod
    def on_faces(
        cls,
        faces: tuple[str, ...] = PAPER_FACES,
        offsets: ArrayLike | None = None,
        size: ArrayLike = 1.0,
        **kwargs: float | ArrayLike,
    ) -> Scene:
        """One contact per named face, moved by ``offsets`` (see :func:`face_point`)."""
        if isinstance(faces, str) or not isinstance(faces, Sequence) or len(faces) not in (3, 4):
            raise ValueError(
                f"faces must be a sequence of 3 or 4 face names from {sorted(FACES)}, got {faces!r}"
            )
        shape = (len(faces), 2)
        must = f"an array of shape {shape} of finite fractions in (-1, 1)"
        offsets = np.zeros(shape) if offsets is None else real_array("offsets", offsets, must)
        if offsets.shape != shape:
            raise ValueError(f"offsets must have shape {shape}, got {offsets.shape}")
        contacts = np.array([face_point(f, o, size) for f, o in zip(faces, offsets, strict=True)])
        return cls(contacts=contacts, size=size, **kwargs)  # type: ignore[arg-type]

    @property
    def n_contacts(self) -> int:
        return self.contacts.shape[0]

    @property
    def friction_limit(self) -> float:
        """theta_lim = atan(mu), radians."""
        return float(np.arctan(self.mu))

    def relative_contacts(self) -> np.ndarray:
        """Contact points relative to the centre of gravity, object frame: c_i - g."""
        return self.contacts - self.cg_offset


def _listed(value: ArrayLike) -> list[float]:
    return np.ravel(np.asarray(value, dtype=float)).tolist()


def _check_layout(contacts: np.ndarray, scale: float) -> None:
    """Reject layouts whose grasp matrix loses rank, or whose pair squeezes e_ij do not span
    its null space (docs/design.md §1, "Interaction forces"). ``scale`` is the object's
    largest bounding box edge."""
    for i, j in combinations(range(len(contacts)), 2):
        if np.linalg.norm(contacts[i] - contacts[j]) <= _DEGENERATE * scale:
            raise ValueError(f"contacts {i} and {j} coincide")
    d = contacts[1:] - contacts[0]
    if len(contacts) == 3:
        area = np.linalg.norm(np.cross(d[0], d[1]))
        if area <= _DEGENERATE * scale**2:
            raise ValueError(
                "the 3 contacts are collinear: they cannot resist torque about that line"
            )
        return
    # all coplanar iff every tetrahedron of contact 0 and three others is flat (n = 4: one)
    for triple in combinations(range(len(d)), 3):
        if abs(np.linalg.det(d[list(triple)])) > _DEGENERATE * scale**3:
            return
    raise ValueError(
        f"the {len(contacts)} contacts are coplanar: their interaction forces are dependent"
        " (the pair squeezes along lines joining contacts in one plane make no force out of"
        " it, so they do not span the grasp matrix's null space)"
    )
