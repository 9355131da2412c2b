"""The numpy mechanics core: rotations (eq. 5) and the trajectory (docs/design.md, "Mechanics")."""

import math
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis.extra.numpy import arrays
from mechanics_helpers import finite

from grasp_env.mechanics import (
    PAPER_AXIS,
    PHI,
    Trajectory,
    axis_angle_matrix,
    matrix_quaternion,
    pose_rotation,
    quaternion_matrix,
)


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
