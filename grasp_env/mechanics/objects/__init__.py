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

from .box import FACES, Box, box_size
from .cylinder import CAPS, Cylinder
from .mesh import MESH_NAME, ConvexMesh
from .shape import SIZE_RANGE, ArrayRecord, ReadOnlyArrays, Shape
from .spec import CAN_HEIGHT, CAN_RADIUS, OBJECT_KEYS, parse_object
from .sphere import Sphere

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
