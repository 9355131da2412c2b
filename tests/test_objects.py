"""The grasped shapes (grasp_env.mechanics.objects) and Scenes holding any of them."""

from __future__ import annotations

import copy
import dataclasses
import math
import pickle

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    MAX_SCENE_CONTACTS,
    PAPER_FACES,
    Box,
    ConvexMesh,
    Cylinder,
    Scene,
    Sphere,
    face_point,
    parse_object,
    scene_grasp,
)
from grasp_env.mechanics.objects import FACES

CAN = Cylinder(radius=0.033, height=0.115)
PHI = (1 + math.sqrt(5)) / 2


def cube_corners(size=1.0, shift=(0.0, 0.0, 0.0)):
    half = np.broadcast_to(np.asarray(size, dtype=float) / 2, (3,))
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return signs * half + np.asarray(shift)


def icosahedron():
    points = []
    for a in (-1.0, 1.0):
        for b in (-1.0, 1.0):
            points += [(0.0, a, b * PHI), (a, b * PHI, 0.0), (b * PHI, 0.0, a)]
    return np.array(points)


def old_box_normals(contacts, size):
    """The box normals as scene.py computed them before shapes (the reference for Box)."""
    half = np.broadcast_to(np.asarray(size, dtype=float), (3,)) / 2
    normals = np.zeros_like(contacts)
    for i, c in enumerate(contacts):
        distance = np.abs(c) - half
        scale = 1e-9 * max(1.0, float(half.max()))
        on = np.flatnonzero(np.abs(distance) <= scale)
        assert not np.any(distance > scale) and on.size == 1
        normals[i, on[0]] = -np.sign(c[on[0]])
    return normals


def five_can_contacts(shape=CAN):
    return np.array(
        [
            shape.side_point(0.0, 0.2),
            shape.side_point(2.1, -0.4),
            shape.side_point(4.2, 0.6),
            shape.cap_point("-z", (0.2, -0.1)),
            shape.cap_point("+z", (-0.3, 0.25)),
        ]
    )


# --- box ------------------------------------------------------------------------------------


@pytest.mark.fast
def test_box_face_points_and_normals_are_the_scenes_old_ones():
    rng = np.random.default_rng(0)
    for size in (1.0, (0.1, 0.2, 0.3), (1e-6, 2e-6, 3e-6), (1e6, 5e5, 2e5)):
        box = Box(size=size)
        faces = list(FACES)
        offsets = rng.uniform(-0.99, 0.99, size=(6, 2))
        points = np.array([box.face_point(f, o) for f, o in zip(faces, offsets, strict=True)])
        # the thin alias gives the same points, bit for bit
        alias = np.array([face_point(f, o, size) for f, o in zip(faces, offsets, strict=True)])
        np.testing.assert_array_equal(points, alias)
        normals = box.inward_normals(points)
        np.testing.assert_array_equal(normals, old_box_normals(points, size))
        for face, normal in zip(faces, normals, strict=True):
            axis, sign = FACES[face]
            assert normal[axis] == -sign and np.count_nonzero(normal) == 1
        np.testing.assert_array_equal(box.bounding_size, box_size_of(size))
        assert box.extent == float(np.max(box_size_of(size))) / 2


def box_size_of(size):
    return np.broadcast_to(np.asarray(size, dtype=float), (3,))


def test_box_refuses_points_off_its_faces_naming_the_contact():
    box = Box(size=(1.0, 2.0, 3.0))
    good = [box.face_point("-x"), box.face_point("+y")]
    for point, match in (
        ([0.6, 0.0, 0.0], r"contact 2 at \[0\.6, 0\.0, 0\.0\] lies outside the box"),
        ([0.4, 0.0, 0.0], "contact 2 .* is not on a face of the box"),
        ([0.5, 1.0, 0.0], "contact 2 .* is on an edge: its normal is ambiguous"),
        ([0.5 + 2e-9, 0.0, 0.0], "contact 2 .* outside"),
    ):
        with pytest.raises(ValueError, match=match):
            box.inward_normals([*good, point])
    # within the tolerance (1e-9 m) counts as on the face
    np.testing.assert_array_equal(box.inward_normals([[0.5 - 5e-10, 0, 0]]), [[-1.0, 0, 0]])
    with pytest.raises(ValueError, match=r"points must be an \(n, 3\) array"):
        box.inward_normals(np.zeros((2, 2)))


def test_box_contains_strictly():
    box = Box(size=(1.0, 2.0, 3.0))
    assert box.contains([0.49, -0.99, 1.49])
    assert not box.contains([0.5, 0.0, 0.0])
    assert not box.contains([0.0, 0.0, -1.6])
    with pytest.raises(ValueError, match="point must be a 3-vector"):
        box.contains([0.0, 0.0])


# --- cylinder -------------------------------------------------------------------------------


@pytest.mark.fast
def test_cylinder_side_and_cap_points_lie_on_it_with_the_analytic_normals():
    rng = np.random.default_rng(1)
    angles = rng.uniform(-10, 10, size=20)
    heights = rng.uniform(-0.99, 0.99, size=20)
    side = np.array([CAN.side_point(a, h) for a, h in zip(angles, heights, strict=True)])
    np.testing.assert_allclose(np.hypot(side[:, 0], side[:, 1]), CAN.radius, rtol=1e-15)
    np.testing.assert_allclose(side[:, 2], heights * CAN.height / 2, rtol=1e-15)
    expected = -np.stack([np.cos(angles), np.sin(angles), np.zeros(20)], axis=1)
    np.testing.assert_allclose(CAN.inward_normals(side), expected, atol=1e-15)
    offsets = rng.uniform(-0.7, 0.7, size=(10, 2))
    for cap, sign in (("+z", 1.0), ("-z", -1.0)):
        caps = np.array([CAN.cap_point(cap, o) for o in offsets])
        np.testing.assert_allclose(caps[:, :2], offsets * CAN.radius, rtol=1e-15)
        np.testing.assert_array_equal(caps[:, 2], sign * CAN.height / 2)
        np.testing.assert_array_equal(CAN.inward_normals(caps), np.tile([0, 0, -sign], (10, 1)))


def test_cylinder_refuses_points_off_its_surface_or_on_its_rim():
    r, half = CAN.radius, CAN.height / 2
    good = [CAN.side_point(0.0), CAN.cap_point("-z")]
    for point, match in (
        ([1.01 * r, 0.0, 0.0], "contact 2 .* lies outside the cylinder"),
        ([0.0, 0.0, half * 1.01], "contact 2 .* lies outside the cylinder"),
        ([0.5 * r, 0.0, 0.0], r"contact 2 .* is not on the surface of the cylinder"),
        ([r, 0.0, half], "contact 2 .* on the cylinder's rim, .*: its normal is ambiguous"),
        ([0.0, -r, -half], "contact 2 .* rim"),
    ):
        with pytest.raises(ValueError, match=match):
            CAN.inward_normals([*good, point])
    with pytest.raises(ValueError, match=r"side height \(a fraction of the half-height\)"):
        CAN.side_point(0.0, 1.0)
    with pytest.raises(ValueError, match="side angle"):
        CAN.side_point(np.inf)
    with pytest.raises(ValueError, match="cap offset must be 2 finite fractions of the radius"):
        CAN.cap_point("+z", (0.8, 0.8))  # each under 1, its length not
    with pytest.raises(ValueError, match="unknown cap"):
        CAN.cap_point("+x")
    for kwargs, match in (
        ({"radius": 0.0, "height": 1.0}, r"Cylinder radius \(metres\) must be a finite number"),
        ({"radius": 1.0, "height": 1e7}, r"Cylinder height .* in \[1e-06, 1e\+06\]"),
        ({"radius": "1", "height": 1.0}, "Cylinder radius"),
    ):
        with pytest.raises(ValueError, match=match):
            Cylinder(**kwargs)
    assert CAN.contains([0.03, 0.0, 0.05]) and not CAN.contains([0.03, 0.02, 0.0])
    assert not CAN.contains([0.0, 0.0, half])


# --- sphere ---------------------------------------------------------------------------------


@pytest.mark.fast
def test_sphere_points_and_normals():
    sphere = Sphere(radius=0.05)
    directions = np.random.default_rng(2).normal(size=(12, 3)) * 10.0 ** np.arange(-6, 6)[:, None]
    points = np.array([sphere.point(d) for d in directions])
    np.testing.assert_allclose(np.linalg.norm(points, axis=1), 0.05, rtol=1e-15)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    np.testing.assert_allclose(sphere.inward_normals(points), -unit, atol=1e-15)
    for point, match in (
        ([0.051, 0, 0], "contact 0 .* lies outside the sphere"),
        ([0.049, 0, 0], "contact 0 .* is not on the surface of the sphere"),
    ):
        with pytest.raises(ValueError, match=match):
            sphere.inward_normals([point])
    with pytest.raises(ValueError, match="direction must be a nonzero 3-vector"):
        sphere.point([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"Sphere radius \(metres\)"):
        Sphere(radius=-1.0)
    assert sphere.contains([0.0, 0.03, 0.03]) and not sphere.contains([0.0, 0.04, 0.04])


# --- convex mesh ----------------------------------------------------------------------------


@pytest.mark.fast
def test_the_mesh_of_a_cubes_corners_is_the_box():
    for size in (1.0, (0.1, 0.2, 0.3)):
        box, mesh = Box(size=size), ConvexMesh(vertices=cube_corners(size))
        assert len(mesh.faces) == 6 and all(len(face) == 4 for face in mesh.faces)
        np.testing.assert_allclose(mesh.vertices, cube_corners(size), atol=1e-15)
        np.testing.assert_allclose(mesh.bounding_size, box.bounding_size, rtol=1e-15)
        rng = np.random.default_rng(3)
        for face in range(6):
            for weights in (None, rng.uniform(0.1, 1.0, size=4)):
                point = mesh.face_point(face, weights)
                np.testing.assert_allclose(
                    mesh.inward_normals([point]), box.inward_normals([point]), atol=1e-15
                )
        # its faces are the box's: one outward normal per axis and sign
        np.testing.assert_allclose(
            np.sort(mesh.face_normals, axis=0), np.sort(np.vstack([np.eye(3), -np.eye(3)]), 0)
        )
    mesh = ConvexMesh(vertices=cube_corners())
    assert mesh.mujoco_geom() == {"type": "mesh", "mesh": "object"}
    np.testing.assert_array_equal(
        np.array(mesh.mujoco_mesh()["vertex"].split(), float).reshape(-1, 3), mesh.vertices
    )


def test_a_mesh_is_centred_at_its_solid_centroid_and_keeps_its_hull_vertices_only():
    inner = [[0.0, 0.0, 0.0], [0.5, 0.1, 0.2], [0.2, 0.1, 0.1]]  # the centre, a face, inside
    cloud = np.vstack([cube_corners(), inner]) + np.array([1.0, 2.0, 3.0])
    mesh = ConvexMesh(vertices=cloud)
    np.testing.assert_allclose(mesh.vertices, cube_corners(), atol=1e-14)
    # a tetrahedron's solid centroid is its vertices' mean
    tetrahedron = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]])
    mesh = ConvexMesh(vertices=tetrahedron)
    np.testing.assert_allclose(mesh.vertices, tetrahedron - tetrahedron.mean(0), atol=1e-15)
    assert mesh.contains([0.0, 0.0, 0.0]) and not mesh.contains([1.0, 1.0, 1.0])


@pytest.mark.parametrize(
    "vertices",
    [icosahedron(), np.random.default_rng(4).normal(size=(60, 3)) * [0.1, 0.07, 0.05]],
    ids=["icosahedron", "random cloud"],
)
def test_mesh_faces_and_normals_are_the_hulls(vertices):
    mesh = ConvexMesh(vertices=vertices)
    hull = ConvexHull(mesh.vertices)
    rng = np.random.default_rng(5)
    for f, face in enumerate(mesh.faces):
        corners = mesh.vertices[list(face)]
        # the face's outward normal is its hull facets'; its vertices lie in its plane
        facets = np.flatnonzero(np.abs(hull.equations[:, :3] @ mesh.face_normals[f] - 1) < 1e-9)
        assert facets.size >= 1
        np.testing.assert_allclose(hull.equations[facets, :3], [mesh.face_normals[f]] * len(facets),
                                   atol=1e-12)  # fmt: skip
        np.testing.assert_allclose(corners @ mesh.face_normals[f], mesh.face_offsets[f],
                                   atol=1e-15 * 10)  # fmt: skip
        # counter-clockwise seen from outside
        turn = np.cross(corners[1] - corners[0], corners[2] - corners[1])
        assert turn @ mesh.face_normals[f] > 0
        for weights in (None, rng.uniform(0.1, 1.0, size=len(face))):
            point = mesh.face_point(f, weights)
            np.testing.assert_allclose(mesh.inward_normals([point])[0], -mesh.face_normals[f])
    if len(vertices) == 12:  # an icosahedron: 20 triangles, every vertex on 5 of them
        assert len(mesh.faces) == 20 and all(len(face) == 3 for face in mesh.faces)
        np.testing.assert_allclose(mesh.vertices, vertices, atol=1e-15)


def test_mesh_refuses_edges_vertices_and_points_off_it():
    mesh = ConvexMesh(vertices=icosahedron())
    face = mesh.faces[0]
    a, b = mesh.vertices[face[0]], mesh.vertices[face[1]]
    centre = mesh.face_point(0)
    outward = mesh.face_normals[0]
    good = [mesh.face_point(1), mesh.face_point(2)]
    for point, match in (
        ((a + b) / 2, r"contact 2 .* on an edge or vertex of the convex mesh \(faces \[.*\]"),
        (a, "contact 2 .* on an edge or vertex"),
        (centre + 1e-6 * outward, "contact 2 .* lies outside the convex mesh"),
        (0.9 * centre, "contact 2 .* is not on the surface of the convex mesh"),
    ):
        with pytest.raises(ValueError, match=match):
            mesh.inward_normals([*good, point])
    for face, weights, match in (
        (20, None, r"face must be an integer in \[0, 19\]"),
        (True, None, "face must be an integer"),
        (0, [1.0, 0.0, 1.0], "weights must be 3 finite numbers > 0"),
        (0, [1.0, 1.0], "weights must be 3"),
    ):
        with pytest.raises(ValueError, match=match):
            mesh.face_point(face, weights)


def test_mesh_refuses_flat_or_bad_vertex_sets():
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]], float)
    tilted = square @ [[1, 0, 0.3], [0, 1, 0.2], [0, 0, 1]]  # in the plane z = 0.3 x + 0.2 y
    for vertices, match in (
        (tilted, "vertices are flat"),
        (np.vstack([tilted, [[0.5, 0.5, 0.25 + 1e-11]]]), "vertices are flat"),
        (np.vstack([square, [[0.5, 0.5, 1e-7]]]), "bounding box whose edges"),
        (np.vstack([tilted, [[0.5, 0.5, 0.25 + 1e-9]]]), "vertices are flat"),
        (square[:3], r"vertices must be a \(V, 3\) array .* got shape \(3, 3\)"),
        (np.zeros((5, 2)), "vertices must be"),
        (cube_corners(1e7), r"bounding box whose edges are each in \[1e-06, 1e\+06\]"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.nan]], "NaN or inf"),
    ):
        with pytest.raises(ValueError, match=match):
            ConvexMesh(vertices=vertices)


def test_thin_but_solid_and_large_meshes_build():
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    tilted = square @ [[1, 0, 0.3], [0, 1, 0.2], [0, 0, 1]]
    pyramid = ConvexMesh(vertices=np.vstack([tilted, [[0.5, 0.5, 0.25 + 1e-6]]]))
    assert len(pyramid.faces) == 5 and pyramid.contains([0.0, 0.0, 0.0])
    # a cloud of 3000 points on and in a sphere: hundreds of faces, each a triangle
    rng = np.random.default_rng(10)
    directions = rng.normal(size=(3000, 3))
    cloud = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    cloud[:1000] *= rng.uniform(0.1, 0.99, size=(1000, 1))
    mesh = ConvexMesh(vertices=cloud)
    assert len(mesh.vertices) == 2000 and len(mesh.faces) == 2 * 2000 - 4
    points = np.array([mesh.face_point(f) for f in range(0, len(mesh.faces), 7)])
    np.testing.assert_allclose(
        mesh.inward_normals(points), -mesh.face_normals[::7], rtol=0, atol=1e-15
    )


def test_meshes_compare_pickle_and_hash_by_vertices():
    mesh = ConvexMesh(vertices=icosahedron())
    again = pickle.loads(pickle.dumps(mesh))
    assert again == mesh and hash(again) == hash(mesh) and again.faces == mesh.faces
    assert not again.vertices.flags.writeable and not again.face_normals.flags.writeable
    assert mesh != ConvexMesh(vertices=icosahedron() * 2) and mesh != Box()
    with pytest.raises(ValueError, match="no parse_object spec"):
        mesh.spec()


# --- the command line -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "shape"),
    [
        ("cube", Box()),
        ("box", Box()),
        (" Box ", Box()),
        ("box:size=0.1", Box(size=0.1)),
        ("box:x=0.1,y=0.2,z=0.3", Box(size=(0.1, 0.2, 0.3))),
        ("box: z = 0.3 , x=0.1,y=0.2", Box(size=(0.1, 0.2, 0.3))),
        ("cylinder:r=0.033,h=0.115", CAN),
        ("can", CAN),
        ("sphere:r=0.05", Sphere(radius=0.05)),
        ("sphere:r=5e-2", Sphere(radius=0.05)),
    ],
)
@pytest.mark.fast
def test_parse_object(spec, shape):
    parsed = parse_object(spec)
    assert parsed == shape and type(parsed) is type(shape)
    assert parse_object(parsed.spec()) == parsed


def test_specs_round_trip_exactly():
    for shape in (
        Box(size=(0.1, 0.2, 1 / 3)),
        Box(size=0.1),
        Cylinder(radius=1 / 7, height=0.3),
        Sphere(radius=2 / 3),
    ):
        assert parse_object(shape.spec()) == shape
    assert Box(size=0.1).spec() == "box:size=0.1"
    assert CAN.spec() == "cylinder:r=0.033,h=0.115"


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("torus", r"unknown object 'torus' .* the objects are \['box', 'can', 'cube', 'cylinder',"),
        ("", "unknown object ''"),
        ("box:w=1", r"'box' takes the keys \['size', 'x', 'y', 'z'\] as key=value, got 'w=1'"),
        ("box:", "'box' takes the keys"),
        ("box:size", "as key=value, got 'size'"),
        ("box:size=0.1,x=0.2", "either size or all of x, y and z"),
        ("box:x=0.1", r"'box' needs the keys \['x', 'y', 'z'\], missing \['y', 'z'\]"),
        ("cylinder:r=0.1", r"needs the keys \['r', 'h'\], missing \['h'\]"),
        ("sphere:r=abc", r"r must be a number \(metres\), got 'abc'"),
        ("sphere:r=-1", r"object 'sphere:r=-1': Sphere radius \(metres\) must be"),
        ("sphere:r=nan", "Sphere radius"),
        ("sphere:r=0.1,r=0.2", "key 'r' given twice"),
        ("cube:size=2", "'cube' takes no keys"),
        ("can:r=0.1", "'can' takes no keys"),
        (None, "object spec must be a string"),
    ],
)
@pytest.mark.fast
def test_parse_object_refuses_bad_specs(spec, match):
    with pytest.raises(ValueError, match=match):
        parse_object(spec)


def test_mujoco_geoms():
    assert Box().mujoco_geom() == {"type": "box", "size": "0.5 0.5 0.5"}
    assert Box(size=(0.1, 0.2, 0.3)).mujoco_geom()["size"] == "0.05 0.1 0.15"
    assert CAN.mujoco_geom() == {"type": "cylinder", "size": "0.033 0.0575"}
    assert Sphere(radius=0.05).mujoco_geom() == {"type": "sphere", "size": "0.05"}
    assert Box().mujoco_mesh() is None and CAN.mujoco_mesh() is None


def test_mujoco_compiles_every_shapes_geom_where_the_shape_says():
    import mujoco  # a declared dependency; imported here, as the mechanics never import it

    cloud = np.random.default_rng(6).normal(size=(30, 3)) * [0.1, 0.05, 0.02] + [1.0, 2.0, 3.0]
    for shape in (Box(size=(0.1, 0.2, 0.3)), CAN, Sphere(radius=0.05), ConvexMesh(vertices=cloud)):
        geom = " ".join(f'{key}="{value}"' for key, value in shape.mujoco_geom().items())
        mesh = shape.mujoco_mesh()
        asset = "" if mesh is None else "<asset><mesh " + " ".join(
            f'{key}="{value}"' for key, value in mesh.items()
        ) + "/></asset>"  # fmt: skip
        model = mujoco.MjModel.from_xml_string(
            f"<mujoco>{asset}<worldbody><body><geom {geom}/></body></worldbody></mujoco>"
        )
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        if mesh is None:
            np.testing.assert_allclose(data.geom_xpos[0], 0.0)
            sizes = {"box": shape.bounding_size / 2, "cylinder": [0.033, 0.0575, 0]}
            expected = sizes.get(shape.kind, [0.05, 0, 0])
            np.testing.assert_allclose(model.geom_size[0], expected, rtol=1e-15)
        else:  # the compiled mesh's vertices are where the shape's are (float32 in MuJoCo)
            vertices = model.mesh_vert[: model.mesh_vertnum[0]].astype(float)
            world = data.geom_xpos[0] + vertices @ data.geom_xmat[0].reshape(3, 3).T
            gaps = np.linalg.norm(world[:, None] - shape.vertices[None], axis=-1).min(axis=1)
            assert len(vertices) == len(shape.vertices) and gaps.max() < 1e-6


# --- scenes on any shape --------------------------------------------------------------------


@pytest.mark.fast
def test_default_and_box_scenes_are_unchanged():
    scene = Scene()
    corner = np.array([[-0.5, 0, 0], [0, -0.5, 0], [0, 0, -0.5]])
    np.testing.assert_array_equal(scene.contacts, corner)
    np.testing.assert_array_equal(scene.normals, np.eye(3))
    np.testing.assert_array_equal(scene.size, [1.0, 1.0, 1.0])
    assert scene.shape == Box() and scene == Scene(contacts=corner, size=1.0)
    assert scene == Scene(contacts=corner, shape=Box()) == Scene(contacts=corner, size=None)
    rng = np.random.default_rng(7)
    for faces in (PAPER_FACES, FOUR_FINGER_FACES):
        for size in (1.0, (0.3, 0.2, 0.1), 1e-6, 1e6):
            offsets = rng.uniform(-0.9, 0.9, size=(len(faces), 2))
            on = Scene.on_faces(faces, offsets, size, weight=3.0, cg_offset=[0, 0, 0])
            box = Box(size=size)
            contacts = np.array([box.face_point(f, o) for f, o in zip(faces, offsets, strict=True)])
            np.testing.assert_array_equal(on.contacts, contacts)
            np.testing.assert_array_equal(on.normals, old_box_normals(contacts, size))
            np.testing.assert_array_equal(on.size, box_size_of(size))
            assert on == Scene(contacts=contacts, shape=box, weight=3.0)
            assert on == Scene(contacts=contacts, size=size, weight=3.0)
            assert hash(on) == hash(Scene(contacts=contacts, shape=box, weight=3.0))


def test_a_cylinder_scene_with_five_contacts():
    scene = Scene(shape=CAN, contacts=five_can_contacts(), weight=3.3, cg_offset=[0, 0, 0.01])
    assert scene.n_contacts == 5 and scene.shape == CAN
    np.testing.assert_array_equal(scene.size, [0.066, 0.066, 0.115])
    np.testing.assert_allclose(scene.normals[3:], [[0, 0, 1], [0, 0, -1]])
    assert not scene.normals.flags.writeable and not scene.size.flags.writeable
    for again in (pickle.loads(pickle.dumps(scene)), copy.deepcopy(scene)):
        assert again == scene and hash(again) == hash(scene) and again is not scene
        assert again.shape == CAN and not again.normals.flags.writeable
    assert scene != Scene(shape=CAN, contacts=five_can_contacts(), weight=3.3)
    assert len({scene, pickle.loads(pickle.dumps(scene))}) == 1
    # dataclasses.replace passes the stored size back: it agrees with the shape
    lighter = dataclasses.replace(scene, weight=1.0)
    assert lighter.weight == 1.0 and lighter.shape == CAN
    ball = Sphere(radius=0.05)
    moved = [ball.point(d) for d in ([-1, 0, 0], [0, -1, 0], [0, 0, -1], [1, 1, 1])]
    on_ball = dataclasses.replace(scene, shape=ball, contacts=moved, size=None)
    assert on_ball.shape == ball and on_ball.size.tolist() == [0.1] * 3
    with pytest.raises(ValueError, match="disagrees with the sphere's bounding box"):
        dataclasses.replace(scene, shape=ball, contacts=moved)
    mesh = ConvexMesh(vertices=icosahedron() * 0.03)
    on_mesh = Scene(shape=mesh, contacts=[mesh.face_point(f) for f in (0, 5, 10, 15)])
    again = pickle.loads(pickle.dumps(on_mesh))
    assert again == on_mesh and hash(again) == hash(on_mesh) and again.shape.faces == mesh.faces


def test_scenes_refuse_bad_layouts_on_any_shape():
    contacts = five_can_contacts()
    sphere = Sphere(radius=0.05)
    on_cap = [CAN.cap_point("-z", o) for o in ((0, 0), (0.5, 0), (0, 0.5), (-0.5, 0), (0.3, 0.3))]
    many = np.array([sphere.point(d) for d in np.random.default_rng(8).normal(size=(9, 3))])
    for kwargs, match in (
        ({"shape": sphere, "contacts": many}, r"contacts must have shape \(n, 3\) with 3 <= n"),
        ({"shape": CAN, "contacts": contacts[:2]}, "3 <= n <= 8, got"),
        ({"shape": CAN, "contacts": on_cap}, "the 5 contacts are coplanar: .* null space"),
        ({"shape": CAN, "contacts": contacts, "cg_offset": [0.03, 0.03, 0]},
         r"cg_offset .* must lie inside the cylinder \(x\^2 \+ y\^2 < r\^2"),
        ({"shape": CAN, "contacts": contacts, "cg_offset": [0, 0, 0.0575]}, "inside the cylinder"),
        ({"shape": CAN, "contacts": [*contacts[:4], contacts[0]]}, "contacts 0 and 4 coincide"),
        ({"shape": CAN, "contacts": [*contacts[:4], [0.033, 0, 0.0575]]}, "contact 4 .* rim"),
        ({"shape": CAN, "contacts": contacts, "size": 1.0},
         r"size \[1\.0\] disagrees with the cylinder's bounding box \[0\.066, 0\.066, 0\.115\]"),
        ({"shape": Box(), "contacts": Scene().contacts, "size": 2.0}, "disagrees with the box's"),
        ({"shape": "can", "contacts": contacts}, "shape must be a Box, Cylinder, Sphere or Conv"),
        ({"shape": sphere, "contacts": many[:3], "cg_offset": [0.05, 0, 0]}, r"\|cg\| < r"),
        ({"contacts": [face_point(f) for f in ("-x", "+x", "-y", "+y")]}, "the 4 contacts are"
         " coplanar"),
        ({"contacts": [face_point("-x", (u, 0.1)) for u in (-0.5, 0, 0.5)]}, "collinear"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            Scene(**kwargs)
    # the most contacts there may be, and a non-coplanar five on the cap and one side point
    assert Scene(shape=sphere, contacts=many[:MAX_SCENE_CONTACTS]).n_contacts == 8
    assert Scene(shape=CAN, contacts=[*on_cap[:4], CAN.side_point(1.0)]).n_contacts == 5


@pytest.mark.parametrize(
    "scene",
    [
        Scene(shape=CAN, contacts=five_can_contacts(), weight=3.3, cg_offset=[0.005, 0, 0.01]),
        Scene(shape=CAN, contacts=five_can_contacts()[[0, 1, 3]], weight=2.0),
        Scene(
            shape=Sphere(radius=0.05),
            contacts=[Sphere(radius=0.05).point(d) for d in np.eye(3) * [-1, 1, -1]]
            + [Sphere(radius=0.05).point([1, 1, 1]), Sphere(radius=0.05).point([-1, -1, 2])],
            extra_force=[0.1, 0, 0],
            extra_torque=[0, 0.02, 0],
        ),
        Scene(
            shape=ConvexMesh(vertices=icosahedron() * 0.03),
            contacts=[ConvexMesh(vertices=icosahedron() * 0.03).face_point(f) for f in range(8)],
            cg_offset=[0.001, -0.002, 0.003],
        ),
    ],
    ids=["can, 5 contacts", "can, 3 contacts", "sphere, 5 contacts", "icosahedron, 8 contacts"],
)
@pytest.mark.fast
def test_equilibrating_forces_balance_the_load_on_any_shape(scene):
    rotations = [np.eye(3), np.linalg.qr(np.random.default_rng(9).normal(size=(3, 3)))[0]]
    for rotation in rotations:
        rotation = rotation * np.sign(np.linalg.det(rotation))  # proper
        grasp = scene_grasp(scene, rotation)
        forces, positions = grasp.equilibrating, grasp.positions
        load = np.array([0.0, 0.0, scene.weight]) - scene.extra_force
        scale = scene.weight
        np.testing.assert_allclose(forces.sum(axis=0), load, rtol=0, atol=1e-12 * scale)
        torque = np.cross(positions, forces).sum(axis=0) + scene.extra_torque
        length = float(np.abs(positions).max())
        np.testing.assert_allclose(torque, 0.0, atol=1e-12 * scale * length)
        np.testing.assert_allclose(grasp.normals, scene.normals @ rotation.T, rtol=0, atol=1e-15)
        assert grasp.basis.shape == (scene.n_contacts * (scene.n_contacts - 1) // 2,
                                     scene.n_contacts, 3)  # fmt: skip
