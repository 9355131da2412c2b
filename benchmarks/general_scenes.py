"""Seeded random grasp scenes with 3 to 8 contacts on every shape (box, cylinder, sphere,
convex mesh), for the general minimax solver's study, benchmark and tests.

    scenes = general_scenes(n=6, count=100, seed=0, force_limit=True)
    result = solve_minimax(scenes.grasp, scenes.k_max, scenes.f_max)

Each scene (docs/design.md §1, "Scene") is drawn as follows, its shape cycling through
:data:`SHAPES` so that every shape has a quarter of the scenes:

- **box**: edges U(0.05, 0.4) m each; every contact on a random face (faces may repeat)
  at offsets U(-0.85, 0.85) of the half-widths;
- **cylinder**: radius U(0.02, 0.2) m, height U(0.05, 0.4) m; a contact on the side (two in
  three) at a random angle and a height U(-0.85, 0.85) of the half-height, else on a random
  cap within 0.85 of the radius;
- **sphere**: radius U(0.03, 0.2) m, contacts along random directions;
- **mesh**: the hull of 10 to 20 Gaussian points (axes scaled by U(0.05, 0.2) m each), a
  contact on a random face at a random convex combination of its vertices (weights
  U(0.05, 1));

and then the centre of gravity strictly inside (a box's or a cylinder's within 0.6 of its
half-extents, a sphere's within 0.6 of its radius, a mesh's at 0.6 of a random convex
combination of its vertices, towards the centroid), weight U(0.5, 30) N, mu U(0.2, 1), a
uniformly random rotation, k_max = w x a log-uniform draw from K_RATIO (the box binds in
some scenes, not in others) and, with ``force_limit``, f_max = U(F_RATIO) x max_i |F_i|, the
largest equilibrating force (eq. 3; drawn without the solver, so that the scenes do not
depend on it: the limit binds in most scenes, and cannot be met in a few). Draws that
:class:`~grasp_env.mechanics.Scene` refuses (coincident or coplanar contacts, a contact on
an edge) are skipped and drawn again; the scenes are the same for the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from grasp_env.mechanics import (
    MAX_SCENE_CONTACTS,
    MIN_SCENE_CONTACTS,
    Box,
    ConvexMesh,
    Cylinder,
    Scene,
    Sphere,
    scene_grasp,
)
from grasp_env.mechanics.objects import CAPS, FACES
from grasp_env.mechanics.rotations import quaternion_matrix
from grasp_env_agents.benchmarks.study_solver import Scenes, stacked

#: The shapes, in the order the scenes cycle through them.
SHAPES: tuple[str, ...] = ("box", "cylinder", "sphere", "mesh")
#: k_max in units of the weight w (log-uniform between the two).
K_RATIO = (0.3, 30.0)
#: f_max in units of the largest equilibrating force max_i |F_i| (eq. 3).
F_RATIO = (1.0, 4.0)
#: Contact offsets, as fractions of the half-widths (half-height, radius): off the edges.
OFFSET = 0.85
#: The centre of gravity's offset, as a fraction of the shape's half-extents.
CG_FRACTION = 0.6
#: How many draws a scene may take before the generator gives up (a layout refused).
MAX_DRAWS = 1000


@dataclass(frozen=True)
class GeneralScenes(Scenes):
    """A batch of random grasps (leading axis: scene) with their limits and their kinds
    (:class:`~.study_solver.Scenes` with the scenes' metadata).

    Attributes:
        grasp: the grasps, one pose each, stacked along the first axis.
        k_max: (count,) the box half-widths, newtons.
        f_max: (count,) the force limits, newtons, or None (no force limit).
        shapes: each scene's shape, a name from :data:`SHAPES`.
        scenes: the :class:`Scene` of each grasp, and ``rotations`` (count, 3, 3) its pose.
    """

    shapes: tuple[str, ...]
    scenes: tuple[Scene, ...]
    rotations: np.ndarray

    @property
    def n(self) -> int:
        """The number of contacts."""
        return int(self.grasp.normals.shape[-2])

    @property
    def force_limit(self) -> bool:
        return self.f_max is not None


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation matrix (a normalised Gaussian quaternion)."""
    return quaternion_matrix(rng.normal(size=4))


def _box_scene(rng: np.random.Generator, n: int) -> tuple[Box, list[np.ndarray], np.ndarray]:
    box = Box(size=rng.uniform(0.05, 0.4, 3))
    faces = sorted(FACES)
    contacts = [
        box.face_point(faces[rng.integers(len(faces))], rng.uniform(-OFFSET, OFFSET, 2))
        for _ in range(n)
    ]
    cg = rng.uniform(-CG_FRACTION, CG_FRACTION, 3) * box.size / 2
    return box, contacts, cg


def _cylinder_scene(
    rng: np.random.Generator, n: int
) -> tuple[Cylinder, list[np.ndarray], np.ndarray]:
    can = Cylinder(radius=rng.uniform(0.02, 0.2), height=rng.uniform(0.05, 0.4))
    caps = sorted(CAPS)
    contacts = []
    for _ in range(n):
        if rng.uniform() < 2 / 3:
            angle, height = rng.uniform(0, 2 * np.pi), rng.uniform(-OFFSET, OFFSET)
            contacts.append(can.side_point(angle, height))
        else:
            radius, angle = OFFSET * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
            offset = radius * np.array([np.cos(angle), np.sin(angle)])
            contacts.append(can.cap_point(caps[rng.integers(2)], offset))
    radius, angle = CG_FRACTION * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
    cg = np.array(
        [
            can.radius * radius * np.cos(angle),
            can.radius * radius * np.sin(angle),
            rng.uniform(-CG_FRACTION, CG_FRACTION) * can.height / 2,
        ]
    )
    return can, contacts, cg


def _sphere_scene(rng: np.random.Generator, n: int) -> tuple[Sphere, list[np.ndarray], np.ndarray]:
    ball = Sphere(radius=rng.uniform(0.03, 0.2))
    contacts = [ball.point(rng.normal(size=3)) for _ in range(n)]
    direction = rng.normal(size=3)
    cg = ball.radius * CG_FRACTION * rng.uniform() * direction / np.linalg.norm(direction)
    return ball, contacts, cg


def _mesh_scene(
    rng: np.random.Generator, n: int
) -> tuple[ConvexMesh, list[np.ndarray], np.ndarray]:
    points = rng.normal(size=(int(rng.integers(10, 21)), 3)) * rng.uniform(0.05, 0.2, 3)
    mesh = ConvexMesh(vertices=points)
    contacts = []
    for _ in range(n):
        face = int(rng.integers(len(mesh.faces)))
        contacts.append(mesh.face_point(face, rng.uniform(0.05, 1.0, len(mesh.faces[face]))))
    weights = rng.uniform(0.05, 1.0, len(mesh.vertices))
    # a convex combination of the vertices lies in the hull, and the centroid (the origin)
    # inside it: the point between them, CG_FRACTION of the way out, is strictly inside
    cg = CG_FRACTION * (weights / weights.sum()) @ mesh.vertices
    return mesh, contacts, cg


_DRAW = {"box": _box_scene, "cylinder": _cylinder_scene, "sphere": _sphere_scene,
         "mesh": _mesh_scene}  # fmt: skip


def random_scene(rng: np.random.Generator, n: int, shape: str) -> Scene:
    """One random scene with ``n`` contacts on a ``shape`` (a name from :data:`SHAPES`),
    drawn again until :class:`Scene` accepts it (see the module doc)."""
    if shape not in _DRAW:
        raise ValueError(f"shape must be one of {SHAPES}, got {shape!r}")
    low, high = MIN_SCENE_CONTACTS, MAX_SCENE_CONTACTS
    if not (isinstance(n, int | np.integer) and low <= n <= high):
        raise ValueError(f"n must be an integer from {low} to {high} contacts, got {n!r}")
    for _ in range(MAX_DRAWS):
        try:
            solid, contacts, cg = _DRAW[shape](rng, int(n))
            return Scene(
                shape=solid,
                contacts=np.array(contacts),
                weight=rng.uniform(0.5, 30.0),
                mu=rng.uniform(0.2, 1.0),
                cg_offset=cg,
            )
        except ValueError:  # coincident or coplanar contacts, a point on an edge: draw again
            continue
    raise RuntimeError(f"no {shape} scene with {n} contacts in {MAX_DRAWS} draws")


def general_scenes(
    n: int,
    count: int,
    seed: int,
    *,
    force_limit: bool = False,
    shapes: tuple[str, ...] = SHAPES,
    k_ratio: tuple[float, float] = K_RATIO,
    f_ratio: tuple[float, float] = F_RATIO,
) -> GeneralScenes:
    """``count`` random scenes with ``n`` contacts, their shapes cycling through ``shapes``
    (see the module doc for the distribution), deterministic for ``seed``.

    k_max = w x a log-uniform draw from k_ratio; with ``force_limit``,
    f_max = U(f_ratio) x max_i |F_i|.
    """
    if count < 1:
        raise ValueError(f"count must be at least 1 scene, got {count}")
    unknown = sorted(set(shapes) - set(SHAPES))
    if not shapes or unknown:
        raise ValueError(f"shapes must be names from {SHAPES}, got {shapes!r}")
    rng = np.random.default_rng([seed, n, int(force_limit)])
    scenes, rotations, kinds, k_max, f_max = [], [], [], [], []
    for b in range(count):
        kind = shapes[b % len(shapes)]
        scene = random_scene(rng, n, kind)
        scenes.append(scene)
        rotations.append(random_rotation(rng))
        kinds.append(kind)
        k_max.append(np.exp(rng.uniform(*np.log(k_ratio))) * scene.weight)
        f_max.append(rng.uniform(*f_ratio))
    grasp = stacked([scene_grasp(s, r) for s, r in zip(scenes, rotations, strict=True)])
    limit = None
    if force_limit:
        largest = np.linalg.norm(grasp.equilibrating, axis=-1).max(axis=-1)
        limit = np.array(f_max) * largest
    return GeneralScenes(
        grasp=grasp,
        k_max=np.array(k_max),
        f_max=limit,
        shapes=tuple(kinds),
        scenes=tuple(scenes),
        rotations=np.array(rotations),
    )
