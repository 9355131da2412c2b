"""Scenes of any object: the shape, its contacts from surface coordinates, the load and the
motion, explicit (:func:`parse_scene`) or drawn (:class:`ObjectSampler`).

**Surface coordinates.** A contact is a sequence naming a point of the shape's surface
(object frame, :mod:`grasp_env.mechanics.objects`):

==============  ===========================================  ==================================
shape           coordinates                                  the point
==============  ===========================================  ==================================
box             ``(face, u, v)``, face "-x" ... "+z"         ``Box.face_point(face, (u, v))``
cylinder        ``("side", angle, height)``                  ``Cylinder.side_point(angle, height)``
cylinder        ``("-z" or "+z", x, y)``                     ``Cylinder.cap_point(cap, (x, y))``
sphere          ``("sphere", azimuth, elevation)``, radians  ``Sphere.point(direction)``
convex mesh     ``(face, *weights)``, face an index           ``ConvexMesh.face_point(face, w)``
any             ``(x, y, z)``, three numbers, metres          that point (on the surface)
==============  ===========================================  ==================================

Fractions (u, v, height, x, y) are of the half-widths, half-height and radius, each in
(-1, 1), so a point is never on an edge or rim.

**Units.** The scene's length L is the largest edge of the shape's bounding box
(``Scene.size.max()``; the unit cube's edge, 1 m): contacts, the centre of gravity and the
extra torque enter the episodes' arithmetic in units of L (and w L), forces in units of w,
so the mechanics of a scene do not depend on its scale.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from itertools import combinations
from typing import Any

import numpy as np

from ...mechanics import (
    MAX_SCENE_CONTACTS,
    MIN_SCENE_CONTACTS,
    Box,
    ConvexMesh,
    Cylinder,
    Scene,
    Shape,
    Sphere,
    Trajectory,
    parse_object,
)
from ...mechanics.checks import is_integer
from .. import spec
from ..validation import (
    MU_RANGE,
    TRAJECTORY_KEYS,
    WEIGHT_RANGE,
    check_array,
    check_integer,
    check_number,
    check_pose_count,
    check_trajectory,
)

SCENE_KEYS = ("contacts", "cg_offset", "weight", "mu", "extra_force", "extra_torque", "trajectory")
#: The shapes a random scene may be, by their :func:`parse_object` names.
SHAPE_KINDS = ("box", "cylinder", "sphere", "mesh")
#: A drawn convex mesh: the hull of this many directions, scaled by its three sizes.
MESH_VERTICES = 12
#: The smallest net load besides none, in units of w (w L for the torque), as the cube's.
MIN_LOAD = 1e-6


def object_shape(value: Any) -> Shape:
    """The shape ``value`` names: a :func:`~grasp_env.mechanics.parse_object` spec string
    (``"cube"``, ``"cylinder:r=0.033,h=0.115"``, ...) or a shape instance."""
    if isinstance(value, Shape):
        return value
    if isinstance(value, str):
        return parse_object(value)
    raise ValueError(
        "object must be an object spec string such as 'cylinder:r=0.033,h=0.115' or a Box,"
        f" Cylinder, Sphere or ConvexMesh (grasp_env.mechanics.objects), got {value!r}"
    )


def _numbers(name: str, values: Sequence[Any]) -> list[float]:
    return [check_number(name, v, -np.inf, np.inf) for v in values]


def surface_point(shape: Shape, coordinates: Any, index: int = 0) -> np.ndarray:
    """The object-frame point that surface ``coordinates`` name on ``shape`` (the module's
    table); a ValueError names contact ``index`` and the accepted forms."""
    name = f"contact {index}"
    if isinstance(coordinates, str) or not isinstance(coordinates, Sequence | np.ndarray):
        raise ValueError(f"{name} must be a sequence of surface coordinates, got {coordinates!r}")
    items = list(coordinates)
    head = items[0] if items else None
    try:
        if len(items) == 3 and not any(isinstance(v, str) for v in items):
            return check_array(name, items, (3,))
        if isinstance(shape, Box) and isinstance(head, str) and len(items) == 3:
            return shape.face_point(head, _numbers(name, items[1:]))
        if isinstance(shape, Cylinder) and isinstance(head, str) and len(items) == 3:
            if head == "side":
                angle, height = _numbers(name, items[1:])
                return shape.side_point(angle, height)
            return shape.cap_point(head, _numbers(name, items[1:]))
        if isinstance(shape, Sphere) and head == "sphere" and len(items) == 3:
            azimuth, elevation = _numbers(name, items[1:])
            direction = [
                np.cos(elevation) * np.cos(azimuth),
                np.cos(elevation) * np.sin(azimuth),
                np.sin(elevation),
            ]
            return shape.point(direction)
        if isinstance(shape, ConvexMesh) and is_integer(head):
            weights = _numbers(name, items[1:]) if len(items) > 1 else None
            return shape.face_point(int(head), weights)
    except ValueError as error:
        raise ValueError(f"{name} {items!r}: {error}") from None
    raise ValueError(
        f"{name} {items!r} names no point of the {shape.kind}: use (face, u, v) on a box,"
        " ('side', angle, height) or ('-z' | '+z', x, y) on a cylinder, ('sphere', azimuth,"
        " elevation) on a sphere, (face index, *weights) on a convex mesh, or (x, y, z) metres"
    )


def default_contacts(shape: Shape) -> list[tuple[Any, ...]]:
    """Three contacts whose normals meet at the shape's centre (the paper's corner grip on a
    box: the optimum is 0 deg with the centre of gravity there)."""
    if isinstance(shape, Box):
        return [("-x", 0.0, 0.0), ("-y", 0.0, 0.0), ("-z", 0.0, 0.0)]
    if isinstance(shape, Cylinder):
        return [("side", np.pi, 0.0), ("side", -np.pi / 2, 0.0), ("-z", 0.0, 0.0)]
    if isinstance(shape, Sphere):
        return [("sphere", np.pi, 0.0), ("sphere", -np.pi / 2, 0.0), ("sphere", 0.0, -np.pi / 2)]
    raise ValueError(f"a {shape.kind} has no default contacts: pass contacts")


def default_trajectory() -> dict[str, Any]:
    """The paper's motion: -15 to 15 deg by 1 deg about (1, -1, 0) / sqrt(2) from R0."""
    trajectory = Trajectory()
    return {key: getattr(trajectory, key) for key in TRAJECTORY_KEYS}


def load_ok(weight: float, extra_force: np.ndarray, extra_torque_l: np.ndarray) -> bool:
    """The net load (0, 0, -w) + f_d, tau_d is zero or at least :data:`MIN_LOAD` (largest
    component, units of w and w L; ``extra_torque_l`` is tau_d / L)."""
    force = np.asarray(extra_force, dtype=float) / weight
    force[2] -= 1.0
    size = max(np.abs(force).max(), np.abs(extra_torque_l).max() / weight)
    return bool(size == 0.0 or size >= MIN_LOAD)


@dataclass(frozen=True, eq=False)
class ObjectScene:
    """A scene and its motion, as the arrays the episodes read: the shape, the contacts c_i
    and their inward normals nu_i (object frame, metres), the centre of gravity, the load and
    the :class:`~grasp_env.mechanics.Trajectory` it is held along. :attr:`scene` is the
    mechanics :class:`~grasp_env.mechanics.Scene` (built on first use for drawn scenes, whose
    layout the sampler checks by the Scene's own rules)."""

    shape: Shape
    contacts: np.ndarray  # (n, 3)
    normals: np.ndarray  # (n, 3)
    cg: np.ndarray  # (3,)
    weight: float
    mu: float
    extra_force: np.ndarray  # (3,) world frame, newtons
    extra_torque: np.ndarray  # (3,) world frame, N m about the cg
    trajectory: Trajectory

    @classmethod
    def of(cls, scene: Scene, trajectory: Trajectory) -> ObjectScene:
        """The arrays of a checked mechanics ``scene``."""
        made = cls(
            scene.shape, scene.contacts, scene.normals, scene.cg_offset, scene.weight, scene.mu,
            scene.extra_force, scene.extra_torque, trajectory,
        )  # fmt: skip
        made.__dict__["scene"] = scene
        return made

    @cached_property
    def scene(self) -> Scene:
        return Scene(
            shape=self.shape,
            contacts=self.contacts,
            weight=self.weight,
            mu=self.mu,
            cg_offset=self.cg,
            extra_force=self.extra_force,
            extra_torque=self.extra_torque,
        )

    @property
    def n_contacts(self) -> int:
        return self.contacts.shape[0]

    @property
    def length(self) -> float:
        """L, metres: the largest edge of the shape's bounding box."""
        return float(self.shape.bounding_size.max())

    def relative_contacts(self) -> np.ndarray:
        """c_i - g (n, 3), object frame."""
        return self.contacts - self.cg


def make_scene(
    shape: Shape,
    contacts: Any,
    weight: Any,
    mu: Any,
    cg_offset: Any,
    extra_force: Any,
    extra_torque: Any,
    trajectory: Mapping[str, Any],
    label: str = "scene",
) -> ObjectScene:
    """A validated :class:`ObjectScene` (ValueErrors name ``label``'s key and its range)."""
    if isinstance(contacts, str) or not isinstance(contacts, Sequence | np.ndarray):
        raise ValueError(f"{label} 'contacts' must be a sequence of surface coordinates")
    low, high = MIN_SCENE_CONTACTS, MAX_SCENE_CONTACTS
    if not low <= len(contacts) <= high:
        raise ValueError(f"{label} 'contacts' must list {low} to {high}, got {len(contacts)}")
    points = np.array([surface_point(shape, c, i) for i, c in enumerate(contacts)])
    weight = check_number(f"{label} 'weight'", weight, *WEIGHT_RANGE)
    length = float(shape.bounding_size.max())
    force = check_array(f"{label} 'extra_force'", extra_force, (3,))
    torque = check_array(f"{label} 'extra_torque'", extra_torque, (3,))
    if np.any(np.abs(force) > weight) or np.any(np.abs(torque) > weight * length):
        raise ValueError(
            f"{label} 'extra_force' and 'extra_torque' must be at most w ({weight:g} N) and"
            f" w L ({weight * length:g} N m) per component, got {force.tolist()} and"
            f" {torque.tolist()}"
        )
    if not load_ok(weight, force, torque / length):
        raise ValueError(
            f"{label} 'extra_force' and 'extra_torque' nearly cancel the weight: the net load"
            f" must be zero or at least {MIN_LOAD:g} w (w L) in some component"
        )
    scene = Scene(
        shape=shape,
        contacts=points,
        weight=weight,
        mu=check_number(f"{label} 'mu'", mu, *MU_RANGE),
        cg_offset=check_array(f"{label} 'cg_offset'", cg_offset, (3,)),
        extra_force=force,
        extra_torque=torque,
    )
    if not isinstance(trajectory, Mapping):
        raise ValueError(f"{label} 'trajectory' must be a mapping with keys {TRAJECTORY_KEYS}")
    full = {**default_trajectory(), **trajectory}
    return ObjectScene.of(scene, check_trajectory(full))


def parse_scene(
    values: Mapping[str, Any] | None, defaults: Mapping[str, Any], shape: Shape
) -> ObjectScene:
    """:func:`make_scene` from a mapping with :data:`SCENE_KEYS`, missing keys from
    ``defaults`` (a reset option's ``{"scene": {...}}``)."""
    values = {} if values is None else values
    if not isinstance(values, Mapping):
        raise ValueError(f"a scene must be a mapping with keys {SCENE_KEYS}, got {values!r}")
    for key in values:
        if key not in SCENE_KEYS:
            raise ValueError(f"unknown scene key {key!r}; the scene keys are {SCENE_KEYS}")
    merged = {**defaults, **values}
    trajectory = merged["trajectory"]
    if isinstance(trajectory, Mapping):
        trajectory = {**defaults["trajectory"], **trajectory}
    keys = ("contacts", "weight", "mu", "cg_offset", "extra_force", "extra_torque")
    return make_scene(shape, *(merged[k] for k in keys), trajectory, "reset option 'scene'")


def parse_options(options: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
    """The scene mapping of ``reset(options=...)``; the only option is ``"scene"``."""
    if options is None:
        return None
    if not isinstance(options, Mapping):
        raise ValueError(f"options must be a mapping, got {options!r}")
    for key in options:
        if key != "scene":
            raise ValueError(f"unknown option {key!r}; the only option is 'scene'")
    return options.get("scene")


# ------------------------------------------------------------------------------ random scenes

#: Random numbers per contact of a candidate: the surface (face, cap or side), two
#: coordinates, and two for a sphere's direction.
_PER_CONTACT = 4
#: Random numbers per candidate besides its contacts: shape kind, 3 sizes, contact count, cg
#: (3), weight, mu, alpha start and end, extra force (3) and torque (3), the axis (2).
_PER_SCENE = 20


@dataclass(frozen=True)
class ObjectSampler:
    """Ranges of the random scenes (see :class:`~.env.ObjectGraspRandomEnv`).

    Each candidate is drawn from a fixed count of uniform numbers (:meth:`raw`, one call of
    the generator), so that a generator's candidates are the same however many are drawn at a
    time, and :meth:`scene` maps them to a scene (None where the draw makes no valid scene:
    coinciding, collinear or coplanar contacts, a load that nearly cancels the weight).
    """

    shapes: tuple[str, ...] = SHAPE_KINDS
    size_range: tuple[float, float] = (0.05, 0.3)
    contact_counts: tuple[int, ...] = (3, 4, 5, 6)
    contact_offset: float = spec.OBJECT_DEFAULTS["contact_offset"]
    cg_offset_max: float = spec.CG_OFFSET_MAX.default
    weight_range: tuple[float, float] = spec.WEIGHT_DRAWS.default
    mu_range: tuple[float, float] = spec.OBJECT_DEFAULTS["mu_range"]
    alpha_start_range_deg: tuple[float, float] = spec.OBJECT_DEFAULTS["alpha_start_range_deg"]
    alpha_end_range_deg: tuple[float, float] = spec.OBJECT_DEFAULTS["alpha_end_range_deg"]
    alpha_step_deg: float = spec.OBJECT_DEFAULTS["alpha_step_deg"]
    extra_force_max: float = spec.EXTRA_FORCE_MAX.default
    extra_torque_max: float = spec.EXTRA_TORQUE_MAX.default

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        shapes = self.shapes
        if isinstance(shapes, str) or not isinstance(shapes, Sequence) or not shapes:
            raise ValueError(
                f"shapes must be a non-empty sequence of {SHAPE_KINDS}, got {shapes!r}"
            )
        for kind in shapes:
            if kind not in SHAPE_KINDS:
                raise ValueError(f"unknown shape {kind!r} in shapes; the shapes are {SHAPE_KINDS}")
        set_(self, "shapes", tuple(shapes))
        counts = self.contact_counts
        if isinstance(counts, str) or not isinstance(counts, Sequence) or not counts:
            raise ValueError(f"contact_counts must be a non-empty sequence, got {counts!r}")
        set_(
            self,
            "contact_counts",
            tuple(
                sorted(
                    {
                        check_integer("contact_counts", c, MIN_SCENE_CONTACTS, MAX_SCENE_CONTACTS)
                        for c in counts
                    }
                )
            ),
        )
        from ..validation import check_range

        set_(self, "size_range", check_range("size_range", self.size_range, 1e-6, 1e6))
        for parameter in (
            spec.CG_OFFSET_MAX,
            spec.WEIGHT_DRAWS,
            spec.ALPHA_START_DRAWS,
            spec.ALPHA_END_DRAWS,
            spec.ALPHA_STEP,
            spec.EXTRA_FORCE_MAX,
            spec.EXTRA_TORQUE_MAX,
        ):
            set_(self, parameter.name, parameter.check(getattr(self, parameter.name)))
        set_(self, "mu_range", spec.MU_DRAWS.check(self.mu_range))
        set_(self, "contact_offset", spec.CONTACT_OFFSET.check(self.contact_offset))
        if self.alpha_start_range_deg[1] > self.alpha_end_range_deg[0]:
            raise ValueError(
                "alpha_start_range_deg must lie below alpha_end_range_deg, got"
                f" {self.alpha_start_range_deg} and {self.alpha_end_range_deg}"
            )
        check_pose_count("alpha_step_deg", self._span, self.alpha_step_deg)

    @property
    def _span(self) -> float:
        return self.alpha_end_range_deg[1] - self.alpha_start_range_deg[0]

    @property
    def max_contacts(self) -> int:
        return self.contact_counts[-1]

    @property
    def max_length(self) -> int:
        """The longest trajectory the ranges allow, in poses."""
        return check_pose_count("alpha_step_deg", self._span, self.alpha_step_deg)

    @property
    def width(self) -> int:
        """Uniform numbers per candidate."""
        return _PER_SCENE + _PER_CONTACT * MAX_SCENE_CONTACTS

    def raw(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """The uniform numbers of ``count`` candidates, (count, :attr:`width`): one call."""
        return rng.random((count, self.width))

    def shape(self, u: np.ndarray) -> Shape:
        """The shape of a candidate's numbers ``u[0:4]``."""
        kind = self.shapes[min(int(u[0] * len(self.shapes)), len(self.shapes) - 1)]
        low, high = self.size_range
        sizes = low + (high - low) * u[1:4]
        if kind == "box":
            return Box(size=sizes)
        if kind == "cylinder":
            return Cylinder(radius=sizes[0] / 2, height=sizes[1])
        if kind == "mesh":
            # the hull's directions from a generator seeded by the candidate's own numbers,
            # so that a candidate is the same however many are drawn at a time
            directions = _generator(u[1:4]).normal(size=(MESH_VERTICES, 3))
            directions /= np.linalg.norm(directions, axis=1, keepdims=True)
            return ConvexMesh(vertices=directions * sizes / 2)
        return Sphere(radius=sizes[0] / 2)

    def scene(self, u: np.ndarray) -> ObjectScene | None:
        """The candidate of one row of :meth:`raw`, or None where it is no valid scene.

        Contacts and normals are computed directly (the surface-coordinate maps of the
        module's table) and checked by :class:`~grasp_env.mechanics.Scene`'s rules (no point
        within its surface tolerance of an edge or rim; contacts apart, not collinear, not
        coplanar; the centre of gravity inside), so that the Scene built from them on demand
        is valid: building one per candidate cost more than the three-contact solves."""
        shape = self.shape(u)
        counts = self.contact_counts
        n = counts[min(int(u[4] * len(counts)), len(counts) - 1)]
        c = self.contact_offset
        p = u[_PER_SCENE:].reshape(MAX_SCENE_CONTACTS, _PER_CONTACT)[:n]
        tol = shape.tolerance()
        if isinstance(shape, Box):
            half = shape.size / 2
            axis = (p[:, 0] * 3).astype(np.int64) % 3
            sign = np.where(p[:, 3] < 0.5, -1.0, 1.0)
            rows = np.arange(n)
            fractions = (2 * p[:, 1:3] - 1) * c
            contacts = np.empty((n, 3))
            normals = np.zeros((n, 3))
            for i in range(n):
                others = [a for a in range(3) if a != axis[i]]
                contacts[i, axis[i]] = sign[i] * half[axis[i]]
                contacts[i, others] = fractions[i] * half[others]
                if np.any((1 - np.abs(fractions[i])) * half[others] <= tol):
                    return None
            normals[rows, axis] = -sign
        elif isinstance(shape, Cylinder):
            r, h = shape.radius, shape.height
            side = p[:, 0] < 0.7  # the side, about its share of a can's area
            angle = 2 * np.pi * np.where(side, p[:, 1], p[:, 2])
            fraction = np.where(side, (2 * p[:, 2] - 1) * c, c * np.sqrt(p[:, 1]))
            cap = np.where(p[:, 0] < 0.85, -1.0, 1.0)
            cos, sin = np.cos(angle), np.sin(angle)
            contacts = np.where(
                side[:, None],
                np.column_stack([r * cos, r * sin, fraction * h / 2]),
                np.column_stack([fraction * r * cos, fraction * r * sin, cap * h / 2]),
            )
            normals = np.where(
                side[:, None],
                np.column_stack([-cos, -sin, np.zeros(n)]),
                np.column_stack([np.zeros(n), np.zeros(n), -cap]),
            )
            room = np.where(side, (1 - np.abs(fraction)) * h / 2, (1 - fraction) * r)
            if np.any(room <= tol):
                return None
        elif isinstance(shape, ConvexMesh):
            # a face by its share of the faces, then a point inside it: the convex
            # combination with weights at least (1 - c) / k of its k corners' (c the offset)
            faces = np.minimum((p[:, 0] * len(shape.faces)).astype(np.int64), len(shape.faces) - 1)
            contacts = np.empty((n, 3))
            for i, face in enumerate(faces):
                corners = shape.vertices[list(shape.faces[face])]
                spread = _generator(p[i]).random(len(corners))
                weights = (1 - c) / len(corners) + c * spread / spread.sum()
                contacts[i] = weights @ corners
            normals = -shape.face_normals[faces]
            others = contacts @ shape.face_normals.T - shape.face_offsets  # > 0 outside
            others[np.arange(n), faces] = -np.inf
            if np.any(others.max(axis=1) >= -tol):  # on (or by) an edge: as Scene's rule
                return None
        else:  # uniform on the sphere
            z, angle = 2 * p[:, 2] - 1, 2 * np.pi * p[:, 3]
            rho = np.sqrt(np.maximum(1 - z * z, 0.0))
            direction = np.column_stack([rho * np.cos(angle), rho * np.sin(angle), z])
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            contacts, normals = shape.radius * direction, -direction
        half = shape.bounding_size / 2
        cg = (2 * u[5:8] - 1) * self.cg_offset_max * half
        (w0, w1), (m0, m1) = self.weight_range, self.mu_range
        weight = w0 + (w1 - w0) * u[8]
        mu = m0 + (m1 - m0) * u[9]
        (s0, s1), (e0, e1) = self.alpha_start_range_deg, self.alpha_end_range_deg
        start, end = s0 + (s1 - s0) * u[10], e0 + (e1 - e0) * u[11]
        length = float(shape.bounding_size.max())
        force = (2 * u[12:15] - 1) * self.extra_force_max * weight
        torque = (2 * u[15:18] - 1) * self.extra_torque_max * weight * length
        z, angle = 2 * u[18] - 1, 2 * np.pi * u[19]  # uniform on the sphere
        rho = np.sqrt(max(1 - z * z, 0.0))
        axis_ = np.array([rho * np.cos(angle), rho * np.sin(angle), z])
        if not (
            load_ok(weight, force, torque / length)
            and shape._contains(cg)
            and layout_ok(contacts, length)
        ):
            return None
        trajectory = Trajectory(tuple(axis_), start, end, self.alpha_step_deg)
        return ObjectScene(shape, contacts, normals, cg, weight, mu, force, torque, trajectory)


def _generator(numbers: np.ndarray) -> np.random.Generator:
    """A generator seeded by a candidate's uniform numbers (their bits)."""
    return np.random.default_rng(np.frombuffer(np.ascontiguousarray(numbers).tobytes(), np.uint32))


#: As :class:`~grasp_env.mechanics.Scene`'s layout rule: in units of the largest bounding edge.
_DEGENERATE = 1e-6


def layout_ok(contacts: np.ndarray, scale: float) -> bool:
    """Whether :class:`~grasp_env.mechanics.Scene` accepts the layout of ``contacts`` (n, 3):
    no two within 1e-6 ``scale``, three not collinear (1e-6 scale^2), four or more not all
    coplanar (some tetrahedron of contact 0 and three others of volume > 1e-6 scale^3)."""
    n = len(contacts)
    i, j = np.triu_indices(n, 1)
    if np.any(np.linalg.norm(contacts[i] - contacts[j], axis=1) <= _DEGENERATE * scale):
        return False
    d = contacts[1:] - contacts[0]
    if n == 3:
        return bool(np.linalg.norm(np.cross(d[0], d[1])) > _DEGENERATE * scale**2)
    triples = np.array(list(combinations(range(n - 1), 3)))
    return bool(np.any(np.abs(np.linalg.det(d[triples])) > _DEGENERATE * scale**3))


__all__ = [
    "SCENE_KEYS",
    "SHAPE_KINDS",
    "ObjectSampler",
    "ObjectScene",
    "default_contacts",
    "default_trajectory",
    "make_scene",
    "object_shape",
    "parse_options",
    "parse_scene",
    "surface_point",
]
