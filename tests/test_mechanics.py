"""The numpy mechanics core: rotations, scenes, trajectory, forces (docs/design.md, "Mechanics")."""

import dataclasses
import math
import time
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    PHI,
    Scene,
    Trajectory,
    axis_angle_matrix,
    contact_pairs,
    equilibrating_forces,
    face_point,
    friction_angles,
    grasp,
    grasp_matrix,
    load_wrench,
    matrix_quaternion,
    n_pairs,
    pose_rotation,
    quaternion_matrix,
    scene_grasp,
)

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
offset = st.floats(-0.35, 0.35)


@st.composite
def scenes(draw) -> Scene:
    faces = draw(st.sampled_from([PAPER_FACES, FOUR_FINGER_FACES]))
    return Scene.on_faces(
        faces,
        offsets=draw(arrays(float, (len(faces), 2), elements=offset)),
        weight=draw(st.floats(1, 20)),
        cg_offset=draw(arrays(float, 3, elements=st.floats(-0.12, 0.12))),
        extra_force=draw(arrays(float, 3, elements=st.floats(-2, 2))),
        extra_torque=draw(arrays(float, 3, elements=st.floats(-0.5, 0.5))),
    )


alphas = st.floats(-math.radians(15), math.radians(15))


# --- rotations ---------------------------------------------------------------------------


@given(arrays(float, 3, elements=finite).filter(lambda a: np.linalg.norm(a) > 1e-3), finite)
@pytest.mark.fast
def test_axis_angle_is_a_rotation_about_its_axis(axis, angle):
    rotation = axis_angle_matrix(axis, angle)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation @ axis, axis, atol=1e-9 * np.linalg.norm(axis))
    cos = (np.trace(rotation) - 1) / 2  # the rotation angle, independently of eq. 5
    assert cos == pytest.approx(math.cos(angle), abs=1e-9)


@pytest.mark.fast
def test_eq5_entries_match_the_paper():
    """Eq. 5's first row, written out: r_x^2 V + C, r_x r_y V - r_z S, r_x r_z V + r_y S."""
    r, phi = np.array([0.6, -0.8, 0.0]), 0.7
    c, s, v = math.cos(phi), math.sin(phi), 1 - math.cos(phi)
    row = [r[0] ** 2 * v + c, r[0] * r[1] * v - r[2] * s, r[0] * r[2] * v + r[1] * s]
    np.testing.assert_allclose(axis_angle_matrix(r, phi)[0], row, atol=1e-15)


@given(arrays(float, 4, elements=finite).filter(lambda q: np.linalg.norm(q) > 1e-3))
@pytest.mark.fast
def test_quaternion_round_trip(q):
    rotation = quaternion_matrix(q)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    back = matrix_quaternion(rotation)
    expected = q / np.linalg.norm(q) * (1 if q[0] >= 0 else -1)
    # q and -q are the same rotation; compare the rotations and the w >= 0 convention
    np.testing.assert_allclose(quaternion_matrix(back), rotation, atol=1e-12)
    assert back[0] >= 0
    if abs(q[0]) > 1e-6 * np.linalg.norm(q):
        np.testing.assert_allclose(back, expected, atol=1e-9)


@pytest.mark.fast
def test_rotations_are_batched():
    axes = np.random.default_rng(0).normal(size=(4, 5, 3))
    angles = np.linspace(-3, 3, 20).reshape(4, 5)
    batched = axis_angle_matrix(axes, angles)
    assert batched.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(batched[2, 3], axis_angle_matrix(axes[2, 3], angles[2, 3]))
    q = matrix_quaternion(batched)
    np.testing.assert_allclose(quaternion_matrix(q), batched, atol=1e-12)


@pytest.mark.parametrize("bad", [[0, 0, 0], [np.nan, 1, 0], [np.inf, 0, 0]])
@pytest.mark.fast
def test_bad_rotation_inputs(bad):
    with pytest.raises(ValueError, match="axis"):
        axis_angle_matrix(bad, 0.1)
    with pytest.raises(ValueError, match="quaternion"):
        quaternion_matrix([*bad, 0])


@pytest.mark.parametrize("bad", ["1000", [True, 0, 0, 0], [1, 0, 0], [[1, 0], [0, 0]]])
def test_a_quaternion_is_four_real_numbers(bad):
    with pytest.raises(ValueError, match=r"quaternion \(w, x, y, z\) must be .*4-vectors"):
        quaternion_matrix(bad)


def test_a_quaternion_of_any_length_gives_its_rotation():
    half_turn = quaternion_matrix([0, 0, 0, 1])
    for scale in (1e-300, 1e300):
        np.testing.assert_array_equal(quaternion_matrix([0, 0, 0, scale]), half_turn)


def test_rotation_batches_must_broadcast_and_may_be_empty():
    with pytest.raises(
        ValueError,
        match=r"rotation axis \(\.\.\., 3\) and rotation angle \(\.\.\.\) must have batch "
        r"shapes that broadcast, got axis shape \(4, 3\) and angle shape \(3,\)",
    ):
        pose_rotation(np.tile(PAPER_AXIS, (4, 1)), np.zeros(3))
    for empty in (
        pose_rotation(np.zeros((0, 3)), 0.1),
        pose_rotation(PAPER_AXIS, np.zeros(0)),
        axis_angle_matrix(np.zeros((0, 3)), np.zeros(0)),
        quaternion_matrix(np.zeros((0, 4))),
    ):
        assert empty.shape == (0, 3, 3)
    assert matrix_quaternion(np.zeros((0, 3, 3))).shape == (0, 4)


@pytest.mark.parametrize(
    ("bad", "what"),
    [
        (np.full((3, 3), np.nan), "NaN or inf"),
        (-np.eye(3), "det = -1"),  # a reflection, not a rotation
        (np.zeros((3, 3)), "det = 0"),
        (2 * np.eye(3), "an entry 2"),
        (np.eye(4), r"shape \(4, 4\)"),
    ],
)
def test_matrix_quaternion_refuses_what_is_not_a_rotation(bad, what):
    with pytest.raises(ValueError, match=f"rotation must be .*proper rotation.*{what}"):
        matrix_quaternion(bad)


# --- trajectory ----------------------------------------------------------------------------


@pytest.mark.fast
def test_paper_trajectory():
    trajectory = Trajectory()
    np.testing.assert_allclose(trajectory.alphas_deg, np.arange(-15, 16))
    assert len(trajectory) == 31
    assert math.degrees(PHI) == pytest.approx(54.7356, abs=1e-4)
    rotations = trajectory.rotations()
    # alpha = 0: the body diagonal is vertical, the grasped corner at the bottom
    start = rotations[15]
    np.testing.assert_allclose(start @ np.ones(3) / math.sqrt(3), [0, 0, 1], atol=1e-12)
    corner = start @ np.array([-0.5, -0.5, -0.5])
    assert corner[2] == pytest.approx(-math.sqrt(3) / 2)
    # about the paper's own axis, R(alpha) = Rot(a, phi + alpha) (eq. 5)
    for alpha, rotation in zip(np.deg2rad(trajectory.alphas_deg), rotations, strict=True):
        np.testing.assert_allclose(rotation, axis_angle_matrix(PAPER_AXIS, PHI + alpha), atol=1e-12)


def test_trajectory_about_another_axis_starts_at_r0():
    rotations = Trajectory(axis=(0, 0, 1), alpha_start_deg=0, alpha_end_deg=90, alpha_step_deg=45)
    assert len(rotations) == 3
    np.testing.assert_allclose(rotations.rotations()[0], pose_rotation((1, 0, 0), 0.0))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"axis": (0, 0, 0)}, "axis"),
        ({"alpha_step_deg": 0}, "alpha_step_deg"),
        ({"alpha_start_deg": 5, "alpha_end_deg": -5}, "alpha_end_deg"),
        ({"alpha_end_deg": float("nan")}, "finite"),
        ({"alpha_end_deg": 400}, "180"),
        ({"alpha_step_deg": 1e-9}, "at most 10000 poses, but 30 deg in steps of 1e-09 deg"),
        # numbers are real numbers: no string or boolean is converted
        ({"alpha_start_deg": "0"}, r"alpha_start_deg must be a finite number in \[-180, 180\]"),
        ({"alpha_end_deg": True}, "alpha_end_deg must be a finite number"),
        ({"alpha_step_deg": "1"}, "alpha_step_deg must be a finite number > 0"),
        ({"axis": (True, 0, 0)}, "trajectory axis must be a finite non-zero 3-vector"),
        ({"axis": "abc"}, "trajectory axis must be a finite non-zero 3-vector"),
        ({"axis": (1, 0)}, r"trajectory axis .* got shape \(2,\)"),
        ({"axis": (np.inf, 0, 0)}, "trajectory axis must be a finite"),
    ],
)
@pytest.mark.fast
def test_bad_trajectory(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Trajectory(**kwargs)


def test_a_trajectory_axis_of_any_finite_length_is_normalised_without_overflow():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow or underflow warning either
        for axis, unit in (
            ((1e-300, 0, 0), (1, 0, 0)),
            ((5e-324, 0, -5e-324), (math.sqrt(0.5), 0, -math.sqrt(0.5))),
            ((1e300, 1e300, 0), (math.sqrt(0.5), math.sqrt(0.5), 0)),
            ((np.float64(1.7e308), -1.7e308, 1.7e308), np.array([1, -1, 1]) / math.sqrt(3)),
        ):
            trajectory = Trajectory(axis=axis)
            np.testing.assert_allclose(trajectory.axis, unit, atol=1e-15)
            rotations = trajectory.rotations()
            np.testing.assert_allclose(rotations, Trajectory(axis=unit).rotations(), atol=1e-14)
            np.testing.assert_allclose(axis_angle_matrix(axis, 0.3), axis_angle_matrix(unit, 0.3))
    # the paper's axis keeps its bits (the common case normalises by the norm directly)
    assert Trajectory().axis == tuple(PAPER_AXIS / np.linalg.norm(PAPER_AXIS))
    assert Trajectory(alpha_start_deg=np.int64(-3), alpha_end_deg=3).alpha_start_deg == -3.0


def test_the_longest_trajectory_has_max_poses():
    from grasp_env.mechanics.trajectory import MAX_POSES

    turn = {"alpha_start_deg": -180, "alpha_end_deg": 180}
    assert len(Trajectory(**turn, alpha_step_deg=360 / (MAX_POSES - 1))) == MAX_POSES
    with pytest.raises(ValueError, match=r"make 10,001: raise alpha_step_deg"):
        Trajectory(**turn, alpha_step_deg=360 / MAX_POSES)


# --- forces -------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(scenes(), alphas, st.data())
@pytest.mark.fast
def test_equilibrium_for_any_k(scene, alpha, data):
    grasp = scene_grasp(scene, pose_rotation(PAPER_AXIS, alpha))
    m = grasp.basis.shape[0]
    k = data.draw(arrays(float, m, elements=st.floats(-100, 100)))
    forces = grasp.forces(k)
    wrench = load_wrench(scene.weight, scene.extra_force, scene.extra_torque)
    total_force = forces.sum(axis=0) + wrench[:3]
    total_torque = np.cross(grasp.positions, forces).sum(axis=0) + wrench[3:]
    assert np.abs(total_force).max() <= 1e-9
    assert np.abs(total_torque).max() <= 1e-9


@settings(max_examples=60, deadline=None)
@given(scenes(), alphas)
@pytest.mark.fast
def test_interaction_forces_are_internal_and_equilibrating_forces_have_none(scene, alpha):
    grasp = scene_grasp(scene, pose_rotation(PAPER_AXIS, alpha))
    n = scene.n_contacts
    g = grasp_matrix(grasp.positions)
    basis = grasp.basis.reshape(-1, 3 * n)
    assert np.abs(g @ basis.T).max() <= 1e-12  # G e_ij = 0
    # the interaction directions span G's null space (dimension 3n - 6)
    assert np.linalg.matrix_rank(basis, tol=1e-9) == 3 * n - 6
    F = grasp.equilibrating
    for pair, (i, j) in enumerate(contact_pairs(n)):
        u = grasp.basis[pair, i]
        assert abs((F[i] - F[j]) @ u) <= 1e-9  # no squeeze along any pair's line
    # F is the minimum-norm solution: orthogonal to every interaction direction
    assert np.abs(basis @ F.ravel()).max() <= 1e-9


@pytest.mark.fast
def test_paper_equilibrating_forces_at_alpha_zero():
    """With no torque each contact carries a third of the weight (the paper's 'escape')."""
    grasp = scene_grasp(Scene(weight=5), pose_rotation(PAPER_AXIS, 0.0))
    np.testing.assert_allclose(grasp.equilibrating, [[0, 0, 5 / 3]] * 3, atol=1e-12)


@pytest.mark.fast
def test_eq8_grip_gives_zero_friction_angles():
    """k = w tan(phi) / (3 sqrt 3) (eq. 8) turns every contact force onto its normal."""
    for weight in (1.0, 5.0, 17.0):
        grasp = scene_grasp(Scene(weight=weight), pose_rotation(PAPER_AXIS, 0.0))
        k = weight * math.tan(PHI) / (3 * math.sqrt(3))
        assert np.abs(grasp.angles(np.full(3, k))).max() <= 1e-12
    assert 5 * math.tan(PHI) / (3 * math.sqrt(3)) == pytest.approx(1.3608, abs=5e-5)


@pytest.mark.fast
def test_friction_angles_range_and_accuracy():
    normal = np.array([0.0, 0.0, 1.0])
    for angle in (0.0, 1e-9, 0.3, math.pi / 2, 2.5, math.pi):
        force = np.array([math.sin(angle), 0.0, math.cos(angle)]) * 3.0
        assert friction_angles(force, normal) == pytest.approx(angle, abs=1e-15)


@pytest.mark.fast
def test_grasp_is_batched():
    scene = Scene.on_faces(FOUR_FINGER_FACES, offsets=np.full((4, 2), 0.2), weight=3)
    rotations = Trajectory().rotations()
    batched = scene_grasp(scene, rotations)
    assert batched.equilibrating.shape == (31, 4, 3)
    assert batched.basis.shape == (31, 6, 4, 3)
    single = scene_grasp(scene, rotations[7])
    np.testing.assert_allclose(batched.equilibrating[7], single.equilibrating, atol=1e-14)
    positions = batched.positions
    wrench = load_wrench(3.0)
    np.testing.assert_allclose(
        equilibrating_forces(positions, wrench), batched.equilibrating, atol=1e-14
    )


ROTATION = pose_rotation(PAPER_AXIS, 0.1)


@pytest.mark.parametrize(
    ("rotation", "match"),
    [
        (np.eye(2), r"rotation must be a \(3, 3\) matrix or an array of them, shape "
         r"\(\.\.\., 3, 3\), each a proper rotation \(finite, orthonormal, det = \+1\), got "
         r"shape \(2, 2\)"),
        (np.ones(9), r"got shape \(9,\)"),
        (2 * np.eye(3), r"proper rotation .*; got an entry 2"),
        (0.5 * np.eye(3), r"proper rotation .*; got \|R\^T R - I\| = 0\.75"),
        (np.full((3, 3), np.nan), "rotation must be .* got NaN or inf"),
        (np.diag([1.0, 1.0, -1.0]), r"det = -1"),
        (np.stack([ROTATION, ROTATION.T, 1.001 * ROTATION]), r"at pose \(2,\)"),
        (np.eye(3).astype(str), "got dtype <U"),
        (np.eye(3, dtype=bool), "got dtype bool"),
        ([[1, 0, 0], [0, 1, 0], [0, 0, True]], "got booleans"),
        (None, "rotation must be"),
    ],
)  # fmt: skip
def test_scene_grasp_refuses_what_is_not_a_rotation(rotation, match):
    with pytest.raises(ValueError, match=match):
        scene_grasp(Scene(), rotation)


def test_scene_grasp_takes_rotations_of_any_batch_shape_and_a_scene_only():
    rotations = Trajectory().rotations()
    grid = scene_grasp(Scene(), rotations.reshape(31, 1, 3, 3) @ rotations[:2])
    assert grid.equilibrating.shape == (31, 2, 3, 3)
    assert scene_grasp(Scene(), rotations[:0]).equilibrating.shape == (0, 3, 3)
    as_list = scene_grasp(Scene(), rotations[3].tolist())  # nested lists of numbers are fine
    np.testing.assert_array_equal(
        as_list.equilibrating, scene_grasp(Scene(), rotations[3]).equilibrating
    )
    with pytest.raises(
        ValueError, match=r"scene must be a grasp_env\.mechanics\.Scene, got NoneType"
    ):
        scene_grasp(None, np.eye(3))  # type: ignore[arg-type]


@pytest.mark.fast
def test_grasp_checks_its_inputs_and_a_grasp_its_unchecked_fields():
    scene = Scene()
    args = (scene.relative_contacts(), scene.normals, ROTATION, load_wrench(5.0), 0.4)
    np.testing.assert_array_equal(grasp(*args).basis, scene_grasp(scene, ROTATION).basis)
    for index, bad, match in (
        (2, 2 * ROTATION, "rotation must be"),
        (4, 2.0, r"friction_limit must be finite angles in \[0, pi/2\]"),
        (4, np.nan, "friction_limit must be finite angles"),
        (4, True, "friction_limit must be finite angles"),
        (0, args[0][:, :2], r"relative_contacts must have shape \(\.\.\., n, 3\)"),
        (1, args[1][:2], r"object_normals must have shape \(\.\.\., 3, 3\)"),
        (3, np.zeros(5), r"wrench must have shape \(\.\.\., 6\)"),
    ):
        with pytest.raises(ValueError, match=match):
            grasp(*args[:index], bad, *args[index + 1 :])
    with pytest.raises(ValueError, match=r"batch shapes must broadcast, got rotation \(2,\)"):
        grasp(args[0], args[1], np.stack([ROTATION] * 2), np.zeros((3, 6)), 0.4)
    # a Grasp made directly (the solver does not read these two; nothing else checks them)
    g = grasp(*args)
    for field, value, match in (
        ("friction_limit", np.float64(np.nan), "grasp friction_limit must be finite angles"),
        ("friction_limit", np.inf, "grasp friction_limit must be finite angles"),
        ("friction_limit", -1.0, r"grasp friction_limit .* got \[-1\.0\]"),
        ("friction_limit", np.array([0.3, 2.0]), r"got \[0\.3, 2\.0\]"),
        ("positions", g.positions * np.nan, "grasp positions must be finite"),
        ("normals", g.normals.astype(str), "grasp normals must be finite real numbers"),
    ):
        with pytest.raises(ValueError, match=match):
            dataclasses.replace(g, **{field: value})
    assert dataclasses.replace(g, friction_limit=0.0).margins(np.zeros(3)).shape == (3,)


def test_grasp_refuses_contacts_that_coincide_or_lie_on_one_line():
    scene = Scene()
    args = (scene.normals, np.eye(3), load_wrench(5.0), 0.4)
    corner = scene.relative_contacts()
    line = [[-0.5, -0.2, 0.1], [-0.5, 0.0, 0.1], [-0.5, 0.2, 0.1]]
    for contacts, match in (
        ([[-0.5, 0, 0], [-0.5, 0, 0], [0, 0, -0.5]], "relative_contacts 0 and 1 coincide"),
        (np.full((3, 3), 1e-300), "relative_contacts 0 and 1 coincide"),
        (line, "relative_contacts all lie on one line"),
        (np.stack([corner, line]), r"on one line \(within 1e-07 of their spread\) at batch index"
         r" \(1,\)"),
        (np.array(line) @ pose_rotation(PAPER_AXIS, 0.3).T * 1e-200, "all lie on one line"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            grasp(contacts, *args)
    with pytest.raises(ValueError, match=r"3 <= n <= 64 contacts \(two lie on one line\)"):
        grasp(corner[:2], scene.normals[:2], *args[1:])
    # what a Scene accepts, grasp does: here 3 contacts just beyond the Scene's "collinear"
    for size in (1e-6, 1.0, 1e6):
        height = 1.001e-6 / 0.9 * size  # |d_01 x d_02| = 0.9 size * height > 1e-6 size^2
        almost = Scene(
            contacts=[[-0.5 * size, -0.45 * size, 0], [-0.5 * size, 0.45 * size, 0],
                      [-0.5 * size, 0.3 * size, height]],
            size=size,
        )  # fmt: skip
        g = grasp(almost.relative_contacts(), almost.normals, *args[1:])
        assert np.isfinite(g.equilibrating).all() and np.isfinite(g.basis).all()


def scaled_scene(faces, offsets, cg, load, size: float, weight: float) -> Scene:
    """A scene scaled to ``size`` and ``weight``: ``cg`` and the extra ``load`` (6,) are in
    units of them."""
    return Scene.on_faces(
        faces, offsets=offsets, size=size, weight=weight, cg_offset=cg * size,
        extra_force=load[:3] * weight, extra_torque=load[3:] * weight * size,
    )  # fmt: skip


def test_equilibrating_forces_are_scale_free_at_any_size_and_load():
    """Sizes 1e-6 to 1e6 m and loads 1e-300 to 1e300 N: the same forces in units of the load,
    balanced to rounding (in metres and newtons the 3 x 3 solve's terms of order L^4 w L
    under- or overflow), and the same interaction directions."""
    rng = np.random.default_rng(7)
    rotation = pose_rotation(PAPER_AXIS, 0.25)
    for faces in (PAPER_FACES, FOUR_FINGER_FACES):
        n = len(faces)
        layout = rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(-0.1, 0.1, 3)
        load = rng.uniform(-0.3, 0.3, 6)
        unit = scene_grasp(scaled_scene(faces, *layout, load, 1.0, 1.0), rotation)
        for size in 10.0 ** np.arange(-6, 7, 3):
            for weight in 10.0 ** np.arange(-300, 301, 100):
                with warnings.catch_warnings():
                    warnings.simplefilter("error")  # no under- or overflow
                    g = scene_grasp(scaled_scene(faces, *layout, load, size, weight), rotation)
                forces, positions = g.equilibrating / weight, g.positions / size
                np.testing.assert_allclose(forces, unit.equilibrating, rtol=0, atol=1e-12)
                np.testing.assert_allclose(g.basis, unit.basis, rtol=0, atol=1e-12)
                wrench = load_wrench(1.0, load[:3], load[3:])
                balance = forces.sum(axis=0) + wrench[:3]
                moment = np.cross(positions, forces).sum(axis=0) + wrench[3:]
                assert np.abs(balance).max() <= 1e-13 and np.abs(moment).max() <= 1e-13


@pytest.mark.parametrize("count", [-1, 0, 1, 65, 2.5, 3.0, True, "3", None])
def test_contact_pairs_need_an_integer_count_of_contacts(count):
    for function in (contact_pairs, n_pairs):
        with pytest.raises(ValueError, match=r"n_contacts must be an integer in \[2, 64\]"):
            function(count)


def test_contact_pairs_of_numpy_integers_are_the_same():
    np.testing.assert_array_equal(contact_pairs(np.int64(4)), contact_pairs(4))
    assert n_pairs(np.int32(4)) == n_pairs(4) == len(contact_pairs(4)) == 6
    assert contact_pairs(2).tolist() == [[0, 1]]


# --- bad scenes ----------------------------------------------------------------------------


def paper_contacts():
    return np.array([face_point(f) for f in PAPER_FACES])


def with_contact(i, point, contacts=None):
    contacts = paper_contacts() if contacts is None else contacts
    contacts[i] = point
    return contacts


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"contacts": with_contact(1, [-0.5, 0, 0])}, "coincide"),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0, 0, 0.5]]}, None),  # valid: a sanity row
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0.1, 0, 0]]}, "not on a face"),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0, 0.5, 0]]}, None),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0.5, 0.2, 0]]}, None),
        ({"contacts": [[-0.5, -0.1, -0.1], [0.5, 0.1, 0.1], [0, 0.5, 0.5]]}, "edge"),
        ({"contacts": [[-0.5, 0.2, 0.2], [0, -0.5, 0], [0.2, 0.2, 0.5]]}, None),
        ({"contacts": [[-0.5, 0, 0], [0.5, 0, 0], [0, 0, 0.5], [0, 0, -0.5]]}, "coplanar"),
        ({"contacts": with_contact(0, [-0.6, 0, 0])}, "outside"),
        ({"contacts": with_contact(0, [-0.4, 0, 0])}, "not on a face"),
        ({"contacts": with_contact(0, [np.nan, 0, 0])}, "finite"),
        ({"contacts": np.zeros((2, 3))}, "shape"),
        ({"contacts": np.zeros((9, 3))}, "shape"),  # 3 to 8 contacts
        ({"weight": 0.0}, "weight"),
        ({"weight": -1.0}, "weight"),
        ({"weight": np.inf}, "weight"),
        ({"mu": 0.0}, "mu"),
        ({"mu": np.nan}, "mu"),
        ({"size": 0.0}, "size"),
        ({"size": [1, -1, 1]}, "size"),
        ({"cg_offset": [0.6, 0, 0]}, "inside the box"),
        ({"cg_offset": [np.inf, 0, 0]}, "finite"),
        ({"extra_force": [0, np.nan, 0]}, "finite"),
        ({"extra_torque": [0, 0, np.inf]}, "finite"),
        # the right shapes, real numbers (no string or boolean converted), documented ranges
        ({"size": (1, 2)}, r"size must be a number or 3 numbers .* got \(1, 2\)"),
        ({"size": True}, "size must be a number or 3 numbers"),
        ({"size": 1e7}, r"each in \[1e-06, 1e\+06\]"),
        ({"size": "1"}, "size must be"),
        ({"weight": "5"}, "weight must be a finite number > 0, got '5'"),
        ({"weight": True}, "weight must be a finite number > 0, got True"),
        ({"weight": np.True_}, "weight must be a finite number > 0"),
        ({"weight": [5.0]}, "weight must be a finite number > 0"),
        ({"mu": "0.5"}, "mu must be a finite number > 0"),
        ({"mu": 1j}, "mu must be a finite number > 0"),
        ({"cg_offset": (0.0, 0.0)}, r"cg_offset must be a 3-vector .* got shape \(2,\)"),
        ({"cg_offset": 0.0}, r"cg_offset must be a 3-vector .* got shape \(\)"),
        ({"cg_offset": (True, 0, 0)}, "cg_offset must be a 3-vector of finite real numbers"),
        ({"extra_force": ("0", "0", "0")}, "extra_force must be a 3-vector"),
        ({"extra_torque": None}, "extra_torque must be a 3-vector"),
        ({"contacts": [[-0.5, 0, 0], [0, -0.5, 0], [0, 0, "x"]]}, "contacts must be an"),
        ({"contacts": "abc"}, "contacts must be an"),
    ],
)
@pytest.mark.fast
def test_bad_scenes(kwargs, match):
    if match is None:
        Scene(**kwargs)  # layouts that look odd but are valid must construct
        return
    with pytest.raises(ValueError, match=match):
        Scene(**kwargs)


def test_scene_numbers_may_be_any_real_numbers_and_are_stored_as_floats():
    scene = Scene(weight=np.int64(5), mu=np.float32(0.5), size=np.array(1), cg_offset=[0, 0, 0])
    assert type(scene.weight) is float and scene.weight == 5.0
    assert type(scene.mu) is float and scene.mu == 0.5
    assert scene.size.dtype == np.float64 and scene.size.tolist() == [1.0] * 3
    offset = np.zeros(3)
    scene = Scene(cg_offset=offset)
    offset[0] = 0.1  # the scene keeps its own copy
    assert scene.cg_offset[0] == 0.0 and not scene.cg_offset.flags.writeable


def test_gait_scenes_check_their_numbers_as_scenes_do():
    from grasp_env.mechanics import GaitScene
    from grasp_env.mechanics.gait import set_values

    for kwargs, match in (
        ({"size": (1, 2)}, "size must be a number or 3 numbers"),  # was a numpy broadcast error
        ({"weight": "5"}, "weight must be a finite number > 0, got '5'"),
        ({"sites": np.eye(3).astype(bool)}, "sites must be an"),
    ):
        with pytest.raises(ValueError, match=match):
            GaitScene(**kwargs)
    rotations = Trajectory().rotations()[:2]
    with pytest.raises(ValueError, match="k_max must be a finite number > 0, got '10'"):
        set_values(GaitScene(), rotations, "10")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"rotations must be .* proper rotation"):
        set_values(GaitScene(), 2 * rotations)


@pytest.mark.fast
def test_collinear_contacts_rejected():
    # a line meets a convex box's surface in two points unless it runs along a face
    with pytest.raises(ValueError, match="collinear"):
        Scene(contacts=[[-0.5, -0.2, 0.1], [-0.5, 0.0, 0.1], [-0.5, 0.2, 0.1]])


def test_bad_face_points():
    with pytest.raises(ValueError, match="unknown face"):
        face_point("+w")
    with pytest.raises(ValueError, match="unknown face"):
        face_point(["-x"])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="size must be a number or 3 numbers"):
        face_point("-x", size=(1, 2))
    with pytest.raises(ValueError, match="face offset must be 2 finite fractions"):
        face_point("-x", ("0.1", 0.0))
    with pytest.raises(ValueError, match="faces must be a sequence of 3 or 4 face names"):
        Scene.on_faces("-x-y-z")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="offsets must be an array of shape"):
        Scene.on_faces(PAPER_FACES, offsets=[[0, 0], [0, 0], [0, True]])
    with pytest.raises(ValueError, match="offset"):
        face_point("-x", (1.0, 0.0))
    with pytest.raises(ValueError, match="offsets must have shape"):
        Scene.on_faces(PAPER_FACES, offsets=np.zeros((2, 2)))


@pytest.mark.fast
def test_scene_defaults_are_the_papers():
    scene = Scene()
    np.testing.assert_allclose(scene.contacts, [[-0.5, 0, 0], [0, -0.5, 0], [0, 0, -0.5]])
    np.testing.assert_allclose(scene.normals, np.eye(3))
    assert scene.weight == 5.0
    assert scene.friction_limit == pytest.approx(math.atan(0.5))


def test_in_parts_covers_the_batch_in_order():
    from grasp_env.mechanics import threads
    from grasp_env.mechanics.threads import in_parts

    cases = ((7, 1), (1001, 2), (1001, 3), (0, 2), (2, 5), (1001, 2), (10, 3))
    # the split learnt from the parts' timing, whatever it is: here from the calls themselves,
    # then pushed to either end (the pool starting a second late or early at 1 ns an item)
    for timing in (None, (1.0, 1e-9), (-1.0, 1e-9)):
        if timing is not None:
            threads._timing["test-parts"] = timing
        for count, parts in cases:
            done = in_parts("test-parts", count, lambda lo, hi: list(range(lo, hi)), parts)
            assert len(done) == max(1, min(parts, count))
            assert all(done) or count == 0  # no part empty
            assert [i for part in done for i in part] == list(range(count))
    # what was measured is there to read (the bench prints it), and only for split calls
    assert threads.hand_off("test-parts-unsplit") is None
    in_parts("test-parts-unsplit", 10, lambda lo, hi: None, 1)
    assert threads.hand_off("test-parts-unsplit") is None
    lag, per_item = threads.hand_off("test-parts")
    assert math.isfinite(lag) and per_item > 0
    threads._timing["test-parts"] = (1.0, 1e-9)
    assert [len(part) for part in in_parts("test-parts", 10, lambda lo, hi: range(lo, hi), 3)] == [
        8, 1, 1,
    ]  # fmt: skip
    finished = []

    def part(lo: int, hi: int) -> None:
        if lo == 0:
            raise RuntimeError("the first part fails")
        time.sleep(0.05)
        finished.append(lo)

    with pytest.raises(RuntimeError, match="first part fails"):
        in_parts("test-parts", 10, part, 2)
    assert len(finished) == 1 and finished[0] > 0  # the other part ran to its end first


# --- the grip along given force directions (mechanics.directions) ------------------------


def test_grip_along_realises_consistent_directions_on_a_scene():
    """The directions of the forces some grip k gives are realised by that k (float64, the
    paper's scene and a random grip inside the box)."""
    from grasp_env.mechanics import directions

    g = scene_grasp(Scene.on_faces(PAPER_FACES), pose_rotation(PAPER_AXIS, 0.2))
    k = np.array([[0.3, -0.2, 0.5]])
    net = g.forces(k[0])
    d = net / np.linalg.norm(net, axis=-1, keepdims=True)
    found, weights = directions.grip_along(
        d[None], g.equilibrating[None], g.basis[None], g.normals[None], 2.0
    )
    np.testing.assert_allclose(found, k, atol=1e-8)
    assert weights.shape == (1, 3) and np.all(weights > 0)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda a: {**a, "directions": a["directions"][:, :2]}, r"n >= 3 contacts"),
        (lambda a: {**a, "forces": a["forces"][:, :, :2]}, r"forces must have the directions"),
        (lambda a: {**a, "normals": np.full((4, 3, 3), np.nan)}, r"normals must be finite"),
        (lambda a: {**a, "basis": a["basis"][:, :, :2]}, r"basis must have shape \(4, m, 3, 3\)"),
        (lambda a: {**a, "basis": a["basis"][:, :0]}, r"with m >= 1"),
        (lambda a: {**a, "k_max": 0.0}, r"k_max must be a finite number > 0"),
        (lambda a: {**a, "solves": 0}, r"solves must be an integer >= 1"),
        (lambda a: {**a, "solves": True}, r"solves must be an integer >= 1"),
        (lambda a: {**a, "directions": "up"}, r"directions must be finite real numbers"),
    ],
)
def test_grip_along_refuses_what_its_kernel_cannot_read(change, match):
    """Shapes that do not agree would make the compiled kernel read past an array's end."""
    from grasp_env.mechanics import directions

    rng = np.random.default_rng(0)
    good = {
        "directions": rng.normal(size=(4, 3, 3)),
        "forces": rng.normal(size=(4, 3, 3)),
        "basis": rng.normal(size=(4, 3, 3, 3)),
        "normals": rng.normal(size=(4, 3, 3)),
        "k_max": 2.0,
        "solves": 3,
    }
    k, weights = directions.grip_along(**good)
    assert np.isfinite(k).all() and k.shape == (4, 3)
    with pytest.raises(ValueError, match=match):
        directions.grip_along(**change(good))
    # collinear contacts: every pair along x, and every direction too: no grip is determined
    collinear = {**good, "basis": np.zeros((4, 3, 3, 3)), "directions": np.zeros((4, 3, 3))}
    for q, (i, j) in enumerate(contact_pairs(3)):
        collinear["basis"][:, q, i, 0], collinear["basis"][:, q, j, 0] = 1.0, -1.0
    collinear["directions"][..., 0] = 1.0
    with pytest.raises(ValueError, match=r"singular for grasps \[0, 1, 2, 3\]"):
        directions.grip_along(**collinear)
    with pytest.raises(ValueError, match=r"grad_k must have shape \(4, 3\)"):
        directions.grip_along_gradient(
            good["directions"], good["forces"], good["basis"], weights, k, k[:, :2]
        )
