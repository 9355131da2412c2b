"""``grasp-env reproduce --object``: the paper's experiment on any object and 3 to 8 contacts.

The object (:func:`object_argument`: a :func:`~grasp_env.mechanics.objects.parse_object`
spec, or ``mesh:FILE``) is held by contacts given in its own surface coordinates
(:func:`parse_contacts`, or :func:`finger_contacts` for ``--fingers N``), turns along the
paper's quasi-static trajectory (§II), and at every pose the minimax problem
min_k max_i theta_i(k) (eqs. 2 and 4) is solved anew. The tables that ``grasp-env reproduce``
prints (:func:`~grasp_env_agents.commands.reproduce.print_object_tables`) give the optimum per
pose with its status and certificate gap, and each contact's friction angle theta_i, force
|P_i| and margin theta_lim - theta_i.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from grasp_env.mechanics import Scene
from grasp_env.mechanics.objects import (
    FACES,
    Box,
    ConvexMesh,
    Cylinder,
    Shape,
    Sphere,
    parse_object,
)

from ..cli import shown_text

#: The accepted form of one contact, by shape (for the messages and ``--help``).
CONTACT_FORMS: dict[type[Shape], str] = {
    Box: "FACE[:U,V] (FACE one of -x +x -y +y -z +z; U,V fractions of the half-widths)",
    Cylinder: (
        "side:ANGLE_DEG[,HEIGHT] (HEIGHT a fraction of the half-height), top[:X,Y] or"
        " bottom[:X,Y] (X,Y fractions of the radius)"
    ),
    Sphere: "AZIMUTH_DEG,ELEVATION_DEG",
    ConvexMesh: "FACE[:W1,W2,...] (a face index; weights > 0, one per vertex of the face)",
}
#: The object-frame point form, which every shape takes.
POINT_FORM = "@X,Y,Z (an object-frame point, metres)"
#: The cylinder's caps by the names a contact spec gives them.
CAP_NAMES = {"top": "+z", "bottom": "-z"}
#: The most bytes and vertices a ``mesh:FILE`` may hold.
MAX_MESH_BYTES, MAX_MESH_VERTICES = 1 << 20, 10_000

CONTACTS_HELP = """\
contacts (--contacts): 3 to 8, separated by ';', in the object's own surface coordinates.
Quote them, and write --contacts=... when the first one starts with '-':
  box       FACE[:U,V]          FACE -x +x -y +y -z +z; U,V move the contact from the face
                                centre along the face's other two axes, in axis order, as
                                fractions of the half-widths (default 0,0)
            e.g. --object cube --contacts='-x;-y:0.2,0.1;+z'
  cylinder  side:ANGLE_DEG[,HEIGHT]  on the side, ANGLE about z from +x, HEIGHT a fraction
                                of the half-height (default 0)
            top[:X,Y] bottom[:X,Y]   on a cap, X,Y fractions of the radius (default 0,0)
            e.g. --object can --contacts='side:0;side:72,0.3;top:0.2,0.1'
  sphere    AZIMUTH_DEG,ELEVATION_DEG
            e.g. --object sphere:r=0.05 --contacts='0,0;120,30;240,-30'
  mesh      FACE[:W1,W2,...]    a face's index: its centroid, or the mean of its vertices
                                with those weights (one per vertex, > 0)
            e.g. --object mesh:hull.txt --contacts='3;7;12'
  any shape @X,Y,Z              an object-frame point, metres (origin at the object's centre;
                                a mesh's solid centroid)
            e.g. --object cube --contacts='@-0.5,0,0;@0,-0.5,0;@0,0,-0.5'
--fingers N places N contacts evenly instead (and prints them as --contacts): a cylinder's
side at alternating heights, a sphere on two circles below the equator alternately, a box's
faces in the order -x -y -z +z +x +y (then -x and -y again, off centre), a mesh's faces
farthest apart. Objects: cube, can, box:size=S, box:x=X,y=Y,z=Z, cylinder:r=R,h=H,
sphere:r=R (metres) or mesh:FILE (a text file of vertices, one 'x y z' a line, metres; the
object is their convex hull). The object starts in the paper's start pose and turns about
--axis by alpha, as the cube does."""


def object_argument(text: str) -> Shape:
    """An argparse type for ``--object``: a :func:`parse_object` spec (``cube``, ``can``,
    ``box:x=..,y=..,z=..``, ``cylinder:r=..,h=..``, ``sphere:r=..``) or ``mesh:FILE``
    (:func:`read_mesh`); refused in one line naming the spec."""
    name, colon, rest = text.strip().partition(":")
    try:
        if colon and name.strip().lower() == "mesh":
            return read_mesh(Path(rest.strip()))
        return parse_object(text)
    except ValueError as error:
        message = str(error)
        if message.startswith("unknown object"):
            message += "; or mesh:FILE (a text file of vertices, one 'x y z' a line, metres)"
        raise argparse.ArgumentTypeError(message) from None


def read_mesh(path: Path) -> ConvexMesh:
    """The convex hull of the vertices in the text file ``path``: one vertex a line, three
    numbers (metres) separated by spaces or commas; blank lines and ``#`` comments skipped.
    At most :data:`MAX_MESH_BYTES` bytes and :data:`MAX_MESH_VERTICES` vertices."""
    if not str(path).strip():
        raise ValueError("mesh:FILE needs a file name")
    try:
        with path.open("rb") as file:
            data = file.read(MAX_MESH_BYTES + 1)
    except OSError as error:
        raise ValueError(f"mesh {path}: {error.strerror or error}") from None
    if len(data) > MAX_MESH_BYTES:
        raise ValueError(f"mesh {path}: larger than {MAX_MESH_BYTES >> 20} MiB; refused")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"mesh {path}: not a UTF-8 text file of vertices") from None
    vertices = []
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].replace(",", " ").split()
        if not fields:
            continue
        try:
            vertex = [float(v) for v in fields]
        except ValueError:
            vertex = []
        if len(vertex) != 3:
            raise ValueError(
                f"mesh {path}: line {number} must be a vertex 'x y z' (3 numbers, metres),"
                f" got {shown_text(line.strip())}"
            )
        vertices.append(vertex)
        if len(vertices) > MAX_MESH_VERTICES:
            raise ValueError(f"mesh {path}: more than {MAX_MESH_VERTICES:,} vertices; refused")
    try:
        return ConvexMesh(vertices=np.array(vertices).reshape(-1, 3))
    except ValueError as error:
        raise ValueError(f"mesh {path}: {error}") from None


def _numbers(text: str, low: int, high: int, what: str) -> list[float]:
    """``low`` to ``high`` comma-separated finite numbers, or a ValueError saying ``what``
    they are."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not low <= len(values) <= high or not np.all(np.isfinite(values)):
        count = str(low) if low == high else f"{low} to {high}"
        raise ValueError(
            f"expected {what} ({count} finite comma-separated numbers), got {shown_text(text)}"
        )
    return values


def contact_point(shape: Shape, item: str) -> np.ndarray:
    """The object-frame point one contact spec ``item`` names on ``shape`` (forms in
    :data:`CONTACT_FORMS`, or :data:`POINT_FORM` for any shape), checked on the surface and
    off its edges; a ValueError says what is wrong with it."""
    if item.startswith("@"):
        point = np.array(_numbers(item[1:], 3, 3, "X,Y,Z in metres"))
    elif isinstance(shape, Box):
        face, colon, rest = (part.strip() for part in item.partition(":"))
        if face not in FACES:
            raise ValueError(f"unknown face {face!r}, expected one of {' '.join(FACES)}")
        offset = _numbers(rest, 2, 2, "U,V") if colon else (0.0, 0.0)
        point = shape.face_point(face, offset)
    elif isinstance(shape, Cylinder):
        where, colon, rest = (part.strip() for part in item.partition(":"))
        if where == "side":
            if not colon:
                raise ValueError("side needs its angle: side:ANGLE_DEG[,HEIGHT]")
            angle, *height = _numbers(rest, 1, 2, "ANGLE_DEG[,HEIGHT]")
            point = shape.side_point(np.deg2rad(angle), *height)
        elif where in CAP_NAMES:
            offset = _numbers(rest, 2, 2, "X,Y") if colon else (0.0, 0.0)
            point = shape.cap_point(CAP_NAMES[where], offset)
        else:
            raise ValueError(f"unknown place {where!r}, expected side, top or bottom")
    elif isinstance(shape, Sphere):
        azimuth, elevation = np.deg2rad(_numbers(item, 2, 2, "AZIMUTH_DEG,ELEVATION_DEG"))
        if not abs(elevation) <= np.pi / 2:
            raise ValueError("the elevation must be in [-90, 90] deg")
        c = np.cos(elevation)
        point = shape.point([c * np.cos(azimuth), c * np.sin(azimuth), np.sin(elevation)])
    elif isinstance(shape, ConvexMesh):
        face, colon, rest = (part.strip() for part in item.partition(":"))
        if not re.fullmatch(r"\d{1,6}", face):
            raise ValueError(f"a face index must be an integer, got {face!r}")
        weights = _numbers(rest, 1, 1_000, "W1,W2,...") if colon else None
        point = shape.face_point(int(face), weights)
    else:
        raise ValueError(f"no contact syntax for a {type(shape).__name__}")
    try:
        shape.inward_normals(point[None])
    except ValueError as error:  # "contact 0 at [...] lies outside..."
        raise ValueError(str(error).removeprefix("contact 0 ")) from None
    return point


def parse_contacts(
    shape: Shape, text: str, option: str = "--contacts"
) -> tuple[np.ndarray, tuple[str, ...]]:
    """The contact points (n, 3), object frame, and their specs that ``text`` names on
    ``shape``: 3 to 8 contacts separated by ``;`` (forms in :data:`CONTACT_FORMS` and
    :data:`POINT_FORM`). A ValueError names ``option``, the contact (numbered from 1, as
    theta_1...) and its accepted form, e.g. ``--contacts: contact 2 'side:abc': expected
    ANGLE_DEG[,HEIGHT] ...``."""
    items = tuple(item.strip() for item in text.split(";"))
    form = f"a {shape.kind}'s contacts are {CONTACT_FORMS[type(shape)]} or {POINT_FORM}"
    if not 3 <= len(items) <= 8:
        raise ValueError(
            f"{option}: {len(items)} contact{'s' * (len(items) != 1)} given, a grasp takes 3 to 8"
            f" separated by ';'; {form}"
        )
    points = []
    for number, item in enumerate(items, 1):
        try:
            if not item:
                raise ValueError("empty")
            points.append(contact_point(shape, item))
        except ValueError as error:
            problem = str(error)
            joiner = " " if problem.startswith("at [") else ": "
            raise ValueError(
                f"{option}: contact {number} {shown_text(item)}{joiner}{problem}; {form}"
            ) from None
    return np.array(points), items


def object_scene(
    shape: Shape,
    contacts: str,
    *,
    weight: float,
    mu: float,
    cg_offset: Sequence[float],
    option: str = "--contacts",
) -> tuple[Scene, tuple[str, ...]]:
    """The :class:`Scene` of ``shape`` held at ``contacts`` (:func:`parse_contacts`), and the
    contacts' specs. A layout the Scene refuses (contacts that coincide, 3 collinear, 4 or
    more coplanar) is named by ``option`` and the contacts' numbers from 1; a centre of
    gravity outside the object by ``--cg-offset``."""
    points, items = parse_contacts(shape, contacts, option)
    try:
        scene = Scene(shape=shape, contacts=points, weight=weight, mu=mu, cg_offset=cg_offset)
    except ValueError as error:
        message = str(error)
        pair = re.fullmatch(r"contacts (\d+) and (\d+) coincide", message)
        if pair:
            i, j = (int(k) for k in pair.groups())
            message = (
                f"{option}: contacts {i + 1} {shown_text(items[i])} and {j + 1}"
                f" {shown_text(items[j])} coincide"
            )
        elif "collinear" in message or "coplanar" in message:
            message = f"{option}: {message}"
        elif message.startswith("cg_offset"):
            message = f"--cg-offset: {message}"
        raise ValueError(message) from None
    return scene, items


#: --fingers on a box: the faces in order (the paper's three, the four-finger grip's thumb,
#: the rest), then two more off the centres of -x and -y.
BOX_FINGERS = ("-x", "-y", "-z", "+z", "+x", "+y", "-x:0.5,0.5", "-y:0.5,0.5")


def finger_contacts(shape: Shape, count: int) -> str:
    """``count`` (3 to 8) contacts placed evenly around ``shape``, as a ``--contacts`` spec:
    a cylinder's side at azimuths 360 i / count deg and heights +-0.5 alternately, a sphere at
    those azimuths on the circles of elevation -20 and -45 deg alternately (all on one circle
    would be coplanar), a box's faces in :data:`BOX_FINGERS`'s order, a convex mesh's face
    centroids, each the farthest from those chosen (from face 0) off their line or plane."""
    if not 3 <= count <= 8:
        raise ValueError(f"--fingers must be 3 to 8, got {count}")
    azimuths = [f"{360 * i / count:g}" for i in range(count)]
    if isinstance(shape, Cylinder):
        items = [f"side:{a},{0.5 if i % 2 == 0 else -0.5:g}" for i, a in enumerate(azimuths)]
    elif isinstance(shape, Sphere):
        items = [f"{a},{-20 if i % 2 == 0 else -45}" for i, a in enumerate(azimuths)]
    elif isinstance(shape, Box):
        items = list(BOX_FINGERS[:count])
    elif isinstance(shape, ConvexMesh):
        centroids = np.array([shape.face_point(f) for f in range(len(shape.faces))])
        if count > len(centroids):
            raise ValueError(f"--fingers {count}: the mesh has only {len(centroids)} faces")
        chosen = [0]
        while len(chosen) < count:  # the centroid farthest from those chosen, off their plane
            gaps = np.linalg.norm(centroids[:, None] - centroids[chosen], axis=-1).min(axis=1)
            for face in np.argsort(-gaps, kind="stable").tolist():
                spread = centroids[[*chosen, face]] - centroids[chosen[0]]
                rank = np.linalg.matrix_rank(spread, tol=1e-6 * shape.extent)
                if face not in chosen and rank == min(len(chosen), 3):
                    chosen.append(face)
                    break
            else:
                raise ValueError(f"--fingers {count}: the mesh's faces lie too close together")
        items = [str(face) for face in chosen]
    else:
        raise ValueError(f"--fingers: no placement for a {type(shape).__name__}")
    return ";".join(items)


def shape_name(shape: Shape) -> str:
    """The shape's :func:`parse_object` spec (``cylinder:r=0.033,h=0.115``), or its kind."""
    try:
        return shape.spec()
    except ValueError:  # a convex mesh has none
        return shape.kind
