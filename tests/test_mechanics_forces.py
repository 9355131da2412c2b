"""The numpy mechanics core: forces, friction angles and grasps (docs/design.md, "Mechanics")."""

import dataclasses
import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mechanics_helpers import alphas, scenes

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    PHI,
    Scene,
    Trajectory,
    contact_pairs,
    equilibrating_forces,
    friction_angles,
    grasp,
    grasp_matrix,
    load_wrench,
    n_pairs,
    pose_rotation,
    scene_grasp,
)


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
