"""The numpy mechanics core: rotations, scenes, trajectory, forces (docs/design.md, "Mechanics")."""

import math
import time

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
    grasp_matrix,
    load_wrench,
    matrix_quaternion,
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
def test_axis_angle_is_a_rotation_about_its_axis(axis, angle):
    rotation = axis_angle_matrix(axis, angle)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation @ axis, axis, atol=1e-9 * np.linalg.norm(axis))
    cos = (np.trace(rotation) - 1) / 2  # the rotation angle, independently of eq. 5
    assert cos == pytest.approx(math.cos(angle), abs=1e-9)


def test_eq5_entries_match_the_paper():
    """Eq. 5's first row, written out: r_x^2 V + C, r_x r_y V - r_z S, r_x r_z V + r_y S."""
    r, phi = np.array([0.6, -0.8, 0.0]), 0.7
    c, s, v = math.cos(phi), math.sin(phi), 1 - math.cos(phi)
    row = [r[0] ** 2 * v + c, r[0] * r[1] * v - r[2] * s, r[0] * r[2] * v + r[1] * s]
    np.testing.assert_allclose(axis_angle_matrix(r, phi)[0], row, atol=1e-15)


@given(arrays(float, 4, elements=finite).filter(lambda q: np.linalg.norm(q) > 1e-3))
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


def test_rotations_are_batched():
    axes = np.random.default_rng(0).normal(size=(4, 5, 3))
    angles = np.linspace(-3, 3, 20).reshape(4, 5)
    batched = axis_angle_matrix(axes, angles)
    assert batched.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(batched[2, 3], axis_angle_matrix(axes[2, 3], angles[2, 3]))
    q = matrix_quaternion(batched)
    np.testing.assert_allclose(quaternion_matrix(q), batched, atol=1e-12)


@pytest.mark.parametrize("bad", [[0, 0, 0], [np.nan, 1, 0], [np.inf, 0, 0]])
def test_bad_rotation_inputs(bad):
    with pytest.raises(ValueError, match="axis"):
        axis_angle_matrix(bad, 0.1)
    with pytest.raises(ValueError, match="quaternion"):
        quaternion_matrix([*bad, 0])


# --- trajectory ----------------------------------------------------------------------------


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
    ],
)
def test_bad_trajectory(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Trajectory(**kwargs)


def test_the_longest_trajectory_has_max_poses():
    from grasp_env.mechanics.trajectory import MAX_POSES

    turn = {"alpha_start_deg": -180, "alpha_end_deg": 180}
    assert len(Trajectory(**turn, alpha_step_deg=360 / (MAX_POSES - 1))) == MAX_POSES
    with pytest.raises(ValueError, match=r"make 10,001: raise alpha_step_deg"):
        Trajectory(**turn, alpha_step_deg=360 / MAX_POSES)


# --- forces -------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(scenes(), alphas, st.data())
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


def test_paper_equilibrating_forces_at_alpha_zero():
    """With no torque each contact carries a third of the weight (the paper's 'escape')."""
    grasp = scene_grasp(Scene(weight=5), pose_rotation(PAPER_AXIS, 0.0))
    np.testing.assert_allclose(grasp.equilibrating, [[0, 0, 5 / 3]] * 3, atol=1e-12)


def test_eq8_grip_gives_zero_friction_angles():
    """k = w tan(phi) / (3 sqrt 3) (eq. 8) turns every contact force onto its normal."""
    for weight in (1.0, 5.0, 17.0):
        grasp = scene_grasp(Scene(weight=weight), pose_rotation(PAPER_AXIS, 0.0))
        k = weight * math.tan(PHI) / (3 * math.sqrt(3))
        assert np.abs(grasp.angles(np.full(3, k))).max() <= 1e-12
    assert 5 * math.tan(PHI) / (3 * math.sqrt(3)) == pytest.approx(1.3608, abs=5e-5)


def test_friction_angles_range_and_accuracy():
    normal = np.array([0.0, 0.0, 1.0])
    for angle in (0.0, 1e-9, 0.3, math.pi / 2, 2.5, math.pi):
        force = np.array([math.sin(angle), 0.0, math.cos(angle)]) * 3.0
        assert friction_angles(force, normal) == pytest.approx(angle, abs=1e-15)


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
        ({"contacts": np.zeros((5, 3))}, "shape"),
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
    ],
)
def test_bad_scenes(kwargs, match):
    if match is None:
        Scene(**kwargs)  # layouts that look odd but are valid must construct
        return
    with pytest.raises(ValueError, match=match):
        Scene(**kwargs)


def test_collinear_contacts_rejected():
    # a line meets a convex box's surface in two points unless it runs along a face
    with pytest.raises(ValueError, match="collinear"):
        Scene(contacts=[[-0.5, -0.2, 0.1], [-0.5, 0.0, 0.1], [-0.5, 0.2, 0.1]])


def test_bad_face_points():
    with pytest.raises(ValueError, match="unknown face"):
        face_point("+w")
    with pytest.raises(ValueError, match="offset"):
        face_point("-x", (1.0, 0.0))
    with pytest.raises(ValueError, match="offsets must have shape"):
        Scene.on_faces(PAPER_FACES, offsets=np.zeros((2, 2)))


def test_scene_defaults_are_the_papers():
    scene = Scene()
    np.testing.assert_allclose(scene.contacts, [[-0.5, 0, 0], [0, -0.5, 0], [0, 0, -0.5]])
    np.testing.assert_allclose(scene.normals, np.eye(3))
    assert scene.weight == 5.0
    assert scene.friction_limit == pytest.approx(math.atan(0.5))


def test_in_parts_covers_the_batch_in_order():
    from grasp_env.mechanics.threads import in_parts

    for count, parts in ((7, 1), (1001, 2), (1001, 3), (0, 2), (2, 5)):
        done = in_parts("test-parts", count, lambda lo, hi: list(range(lo, hi)), parts)
        assert len(done) == max(1, min(parts, count))
        assert [i for part in done for i in part] == list(range(count))
    finished = []

    def part(lo: int, hi: int) -> None:
        if lo == 0:
            raise RuntimeError("the first part fails")
        time.sleep(0.05)
        finished.append(lo)

    with pytest.raises(RuntimeError, match="first part fails"):
        in_parts("test-parts", 10, part, 2)
    assert finished == [5]  # the other part ran to its end before the error came back
