"""The grasped object, its contacts and its load (docs/design.md, "Mechanics")."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from itertools import combinations
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .checks import real_array, real_number

#: Box faces by name: the outward axis and its sign. A contact on face "-x" has inward normal +x.
FACES: dict[str, tuple[int, int]] = {
    "-x": (0, -1), "+x": (0, 1), "-y": (1, -1), "+y": (1, 1), "-z": (2, -1), "+z": (2, 1),
}  # fmt: skip
#: The paper's grip: the three faces that meet at the corner (-1/2, -1/2, -1/2).
PAPER_FACES: tuple[str, ...] = ("-x", "-y", "-z")
#: The four-finger grip: the paper's three plus a "thumb" on the top face, pressing down.
FOUR_FINGER_FACES: tuple[str, ...] = ("-x", "-y", "-z", "+z")
#: Default friction coefficient (theta_lim = atan(0.5) = 26.57 deg).
DEFAULT_MU = 0.5
DEFAULT_WEIGHT = 5.0

#: Accepted box edge lengths, metres: within them a contact on a face is told from one on an
#: edge (to 1e-9 m, or 1e-9 of the edge beyond 1 m), and the grasp's arithmetic neither
#: overflows nor underflows.
SIZE_RANGE = (1e-6, 1e6)

# Relative tolerance for "on the face" and for degenerate contact layouts.
_TOL = 1e-9


def face_point(face: str, offset: ArrayLike = (0.0, 0.0), size: ArrayLike = 1.0) -> np.ndarray:
    """Object-frame point on ``face`` of a box of edge lengths ``size``, centred at the origin.

    ``offset`` = (u, v) moves the point from the face centre along the face's two in-plane axes
    (in axis order, e.g. y then z for an x face), as fractions of the half-widths: |u|, |v| < 1.
    """
    if not isinstance(face, str) or face not in FACES:
        raise ValueError(f"unknown face {face!r}; expected one of {sorted(FACES)}")
    half = box_size(size) / 2
    must = "2 finite fractions in (-1, 1)"
    offset = real_array("face offset", offset, must)
    if offset.shape != (2,) or np.any(np.abs(offset) >= 1):
        raise ValueError(f"face offset must be {must}, got {offset.tolist()}")
    axis, sign = FACES[face]
    point = np.zeros(3)
    point[axis] = sign * half[axis]
    point[[a for a in range(3) if a != axis]] = offset * half[[a for a in range(3) if a != axis]]
    return point


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
    equal fields (``np.array_equal``), and hashed to match. Declare it ``eq=False``, or the
    dataclass replaces both with its own, which fail on arrays."""

    def _values(self) -> tuple[Any, ...]:
        return tuple(getattr(self, f.name) for f in fields(self))  # type: ignore[arg-type]

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        pairs = zip(self._values(), other._values(), strict=True)  # type: ignore[attr-defined]
        return all(np.array_equal(a, b) for a, b in pairs)

    def __hash__(self) -> int:
        # by value as Python floats: -0.0 and 0.0 are equal, and so are their hashes
        values = map(np.asarray, self._values())
        return hash((type(self), *((v.shape, tuple(v.ravel().tolist())) for v in values)))


@dataclass(frozen=True, eq=False)
class Scene(ArrayRecord):
    """A box held by point contacts with Coulomb friction.

    All vectors are in the object frame, whose origin is the box centre, except the extra load
    (``extra_force``, ``extra_torque`` about the centre of gravity), which is in the world frame
    like the weight. ``Scene()`` is the paper's scene: the unit cube, face-centre contacts on
    the three faces meeting at the corner (-1/2, -1/2, -1/2), w = 5 N.

    Args:
        contacts: (n, 3) contact points on the box surface, n = 3 or 4, each on one face (not
            an edge); not coincident, not collinear (n = 3), not coplanar (n = 4).
        size: box edge lengths (a number for a cube), metres, each in :data:`SIZE_RANGE`.
        weight: weight w > 0, newtons, acting along world -z at the centre of gravity.
        mu: Coulomb friction coefficient > 0; the friction angle limit is atan(mu).
        cg_offset: (3,) centre of gravity relative to the box centre; must lie inside the box.
        extra_force, extra_torque: (3,) an optional extra wrench on the object (world frame).

    Every number must be a finite real number (Python or numpy ints and floats; booleans,
    strings and complex numbers are refused, not converted); anything else raises a
    ValueError naming the field and its accepted range. The scene stores its own read-only
    float arrays (and floats for ``weight`` and ``mu``), read-only in its pickles and copies
    too. Scenes compare by value: two are equal when every field is (``np.array_equal``), and
    equal scenes hash alike, so they serve as dictionary keys and set members.
    """

    contacts: np.ndarray = field(
        default_factory=lambda: np.array([face_point(f) for f in PAPER_FACES])
    )
    size: np.ndarray = 1.0  # type: ignore[assignment]
    weight: float = DEFAULT_WEIGHT
    mu: float = DEFAULT_MU
    cg_offset: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]
    extra_force: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]
    extra_torque: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]
    normals: np.ndarray = field(init=False, repr=False)

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

        must = "an (n, 3) array of finite real numbers, n = 3 or 4 contacts"
        contacts = real_array("contacts", self.contacts, must)
        if contacts.ndim != 2 or contacts.shape[1] != 3 or contacts.shape[0] not in (3, 4):
            raise ValueError(f"contacts must have shape (3, 3) or (4, 3), got {contacts.shape}")
        contacts = frozen("contacts", contacts)
        size = frozen("size", box_size(self.size))
        for name in ("weight", "mu"):
            value = real_number(name, getattr(self, name), 0.0, open_low=True)
            object.__setattr__(self, name, value)
        cg = vector("cg_offset")
        if np.any(np.abs(cg) >= size / 2):
            raise ValueError(f"cg_offset {cg.tolist()} must lie inside the box (|cg| < size / 2)")
        vector("extra_force")
        vector("extra_torque")

        normals = np.zeros_like(contacts)
        half = size / 2
        for i, c in enumerate(contacts):
            distance = np.abs(c) - half  # 0 on a face, < 0 inside
            scale = _TOL * max(1.0, float(half.max()))
            if np.any(distance > scale):
                raise ValueError(
                    f"contact {i} at {c.tolist()} lies outside the box {size.tolist()}"
                )
            on = np.flatnonzero(np.abs(distance) <= scale)
            if on.size == 0:
                raise ValueError(f"contact {i} at {c.tolist()} is not on a face of the box")
            if on.size > 1:
                raise ValueError(
                    f"contact {i} at {c.tolist()} is on an edge: its normal is ambiguous"
                )
            normals[i, on[0]] = -np.sign(c[on[0]])  # inward normal
        normals.flags.writeable = False
        object.__setattr__(self, "normals", normals)
        _check_layout(contacts, float(size.max()))

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


def _check_layout(contacts: np.ndarray, scale: float) -> None:
    """Reject layouts whose grasp matrix loses rank (docs/design.md, "Interaction forces")."""
    for i, j in combinations(range(len(contacts)), 2):
        if np.linalg.norm(contacts[i] - contacts[j]) <= 1e-6 * scale:
            raise ValueError(f"contacts {i} and {j} coincide")
    d = contacts[1:] - contacts[0]
    if len(contacts) == 3:
        area = np.linalg.norm(np.cross(d[0], d[1]))
        if area <= 1e-6 * scale**2:
            raise ValueError(
                "the 3 contacts are collinear: they cannot resist torque about that line"
            )
    else:
        volume = abs(np.linalg.det(d))
        if volume <= 1e-6 * scale**3:
            raise ValueError("the 4 contacts are coplanar: their interaction forces are dependent")
