"""MuJoCo against the analytic friction cone at single poses: verdicts at the cone's edge, released
fingers, determinism, the refusals and the model (docs/physics.md)."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
from physics_helpers import forces_at_angle

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_FACES,
    PHI,
    START_ROTATION,
    Scene,
    Trajectory,
    n_pairs,
    scene_grasp,
    solve_minimax,
)
from grasp_env.physics import (
    SETTINGS,
    PhysicsReport,
    StabilityChecker,
    TrajectoryChecker,
    check_poses,
)
from grasp_env.physics.model import G, build_mjcf, model_cg, model_contacts
from grasp_env.physics.motion import released as motion_released
from grasp_env.physics.simulation import PhysicsModel
from grasp_env_agents.studies import agreement
from grasp_env_agents.studies.agreement import (
    ForceSet,
    check_sets,
    force_set_k,
    released_sets,
    summarise,
)
from grasp_env_agents.studies.trajectory_agreement import (
    trajectory_cases,
)

EDGE_SCENES = {
    "paper grip, mu = tan 10 deg": (
        Scene(mu=float(np.tan(np.radians(10.0)))),
        5.0,
    ),
    "moved contacts and cg, mu = tan 20 deg": (
        Scene.on_faces(
            PAPER_FACES,
            [[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]],
            mu=float(np.tan(np.radians(20.0))),
            cg_offset=(0.05, -0.03, 0.02),
            weight=12.0,
        ),
        -12.0,
    ),
    "four fingers, mu = tan 30 deg": (
        Scene.on_faces(
            FOUR_FINGER_FACES,
            [[0.2, -0.1], [-0.15, 0.2], [0.1, 0.1], [-0.2, -0.25]],
            mu=float(np.tan(np.radians(30.0))),
        ),
        10.0,
    ),
}


@pytest.fixture(scope="module")
def paper_checker():
    checker = StabilityChecker(Scene(mu=0.3))
    yield checker
    checker.close()


# ------------------------------------------------------------------------------ the pose check


@pytest.mark.parametrize("name", EDGE_SCENES)
@pytest.mark.fast
def test_verdict_flips_at_the_cone_edge(name):
    scene, alpha = EDGE_SCENES[name]
    limit = np.degrees(scene.friction_limit)
    checker = StabilityChecker(scene)
    inside = checker.check(*forces_at_angle(scene, alpha, limit - 1.0))
    outside = checker.check(*forces_at_angle(scene, alpha, limit + 1.0))
    checker.close()
    assert inside.holds, inside
    assert inside.slip.max() < 0.1 * SETTINGS["slip_threshold"]
    assert not outside.holds, outside
    assert outside.slip.max() > SETTINGS["slip_threshold"]
    assert not inside.contact_lost.any()


@pytest.mark.fast
def test_paper_optimal_forces_hold_along_the_trajectory():
    # With mu = 0.05 (2.9 deg) the paper's optimum (zero friction angle at every pose,
    # docs/design.md §1) still holds everywhere, while its equal-k grip (eq. 8) slips at the
    # trajectory's ends: the check tells the two apart.
    scene = Scene(mu=0.05)
    trajectory = Trajectory()
    rotations = trajectory.rotations()
    grasp = scene_grasp(scene, rotations)
    optimum = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    equal_k = grasp.forces(scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(n_pairs(3)))
    checker = StabilityChecker(scene)
    optimal_reports = checker.check_batch(rotations, optimum)
    ends = [0, len(trajectory) - 1]
    equal_k_reports = checker.check_batch(rotations[ends], equal_k[ends])
    checker.close()
    assert all(r.holds for r in optimal_reports), [r.as_dict() for r in optimal_reports]
    assert max(r.slip.max() for r in optimal_reports) < 0.1 * SETTINGS["slip_threshold"]
    assert max(r.drift for r in optimal_reports) < 1e-4
    assert not any(r.holds for r in equal_k_reports)


def test_same_report_alone_in_a_batch_and_on_any_number_of_threads(paper_checker):
    scene = paper_checker.scene
    cases = [
        forces_at_angle(scene, -4.0, 10.0),
        forces_at_angle(scene, 7.0, 25.0, seed=1),  # slips: a neighbour that moves
        forces_at_angle(scene, 3.0, 16.0, seed=2),
    ]
    rotations = np.array([r for r, _ in cases])
    forces = np.array([f for _, f in cases])
    alone = [paper_checker.check(r, f) for r, f in cases]
    again = paper_checker.check(*cases[0])
    assert alone[0].as_dict() == again.as_dict()  # whatever came before
    assert [r.holds for r in alone] == [True, False, True]
    for threads in (1, 2):
        batch = paper_checker.check_batch(rotations, forces, threads=threads)
        assert [r.as_dict() for r in batch] == [r.as_dict() for r in alone]


def test_report_is_plain_data(paper_checker):
    report = paper_checker.check(*forces_at_angle(paper_checker.scene, 0.0, 5.0))
    assert isinstance(report, PhysicsReport)
    as_dict = report.as_dict()
    assert json.loads(json.dumps(as_dict)) == as_dict
    assert set(as_dict) >= {"holds", "slip", "contact_lost", "released", "drift", "rotation_deg"}
    assert len(as_dict["slip"]) == len(as_dict["contact_lost"]) == 3


@pytest.mark.fast
def test_pulling_finger_loses_contact(paper_checker):
    scene = paper_checker.scene
    grasp = scene_grasp(scene, START_ROTATION)
    # k = -w: the pairs pull apart, every finger's force points out of its face (> 90 deg).
    k = -scene.weight * np.ones(3)
    assert np.all(np.degrees(grasp.angles(k)) > 90)
    report = paper_checker.check(START_ROTATION, grasp.forces(k))
    assert not report.holds
    assert report.contact_lost.all()


@pytest.mark.fast
def test_unbalanced_forces_do_not_hold(paper_checker):
    # 1.5 x a holding set: the same friction angles, but 50% more lift than the weight.
    rotation, forces = forces_at_angle(paper_checker.scene, 2.0, 5.0)
    report = paper_checker.check(rotation, 1.5 * forces)
    assert report.slip.max() < SETTINGS["slip_threshold"]
    assert report.drift > SETTINGS["drift_threshold"]
    assert not report.holds


def test_released_fingers_are_not_lost_holds():
    # Four-finger optima that release a finger (its force about 1e-11 w): the checker before
    # the rollout engine counted every one of them as "contact lost" (52 of these 52).
    sets = released_sets(seed=0, scenes=60)
    assert len(sets) >= 8
    for case in sets:
        report = StabilityChecker(case.scene).check(case.rotation, case.forces)
        assert report.holds, report.as_dict()
        assert report.released.any() and not report.contact_lost.any()
        force = np.linalg.norm(case.forces, axis=-1) / case.scene.weight
        np.testing.assert_array_equal(report.released, force <= SETTINGS["released_force"])


def test_the_pose_study_judges_loaded_fingers_only():
    # Seed 11 draws a four-finger layout whose optimum lets a finger go (about 3e-11 w, its
    # direction arbitrary): counting that finger's angle made 128 sets "slip" analytically,
    # far from the edge, where MuJoCo (which ignores released fingers) held them.
    sets = agreement.agreement_sets(seed=11)
    weight = np.array([case.scene.weight for case in sets])
    force = np.array([np.linalg.norm(case.forces, axis=-1).min() for case in sets]) / weight
    releasing = [case for case, f in zip(sets, force, strict=True) if f <= 1e-6]
    assert len(releasing) >= 100
    reports = check_sets(releasing)
    assert all(r.holds == case.predicted_holds for r, case in zip(reports, releasing, strict=True))


def test_the_analytic_verdict_needs_forces_that_balance_the_load():
    # The cones judge a grip (equilibrating plus interaction forces); forces that do not
    # balance the load push the object away, and the analytic verdict says so too.
    scene, rotations = Scene(mu=1.0), Trajectory().rotations()[:3]
    grasp = scene_grasp(scene, rotations)
    grip = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    checker = TrajectoryChecker(scene)
    assert checker.check(rotations, grip).predicted_holds
    for forces in (np.zeros_like(grip), 0.5 * grip):
        report = checker.check(rotations, forces)
        assert not report.predicted_holds and not report.holds
        assert report.predicted_first_failure == 0.0 and not report.pose_predicted.any()


def test_batch_checks_and_study_generators_name_bad_arguments():
    for forces, message in (
        ([[1, 2, 3], [1, 2], [1, 2, 3]], "case 0's contact_forces must be finite real numbers"),
        (np.zeros((2, 3, 3)), r"case 0's contact_forces must have shape \(3, 3\)"),
    ):
        with pytest.raises(ValueError, match=message):
            check_poses([(Scene(), START_ROTATION, forces, None)])
    for call, message in (
        (lambda: agreement.agreement_sets(directions=1.5), "directions must be an integer >= 1"),
        (lambda: agreement.agreement_sets(seed=-1), "seed must be an integer >= 0"),
        (lambda: trajectory_cases(scenes=-3), "scenes must be an integer >= 0"),
        (lambda: released_sets(scenes=True), "scenes must be an integer >= 0"),
    ):
        with pytest.raises(ValueError, match=message):
            call()


def test_thin_boxes_and_extreme_forces_are_named():
    with pytest.raises(ValueError, match=r"smallest edge is at least 0.05 x their largest"):
        StabilityChecker(Scene.on_faces(size=(0.01, 1.0, 1.0)))
    with pytest.raises(ValueError, match="smallest edge"):
        TrajectoryChecker(Scene.on_faces(size=(1.0, 1.0, 1e-4)))
    StabilityChecker(Scene.on_faces(size=(0.05, 1.0, 1.0))).close()
    # magnitudes without squares: neither inf for 1e300 N nor "released" for 1e-299 N at w 1e-300
    with pytest.raises(ValueError, match=r"is 3.464e\+299 w"):
        StabilityChecker(Scene()).check(START_ROTATION, np.full((3, 3), 1e300))
    tiny = np.full((1, 3, 3), 1e-299)
    assert not motion_released(tiny, 1e-300, SETTINGS["released_force"]).any()


def test_tiny_and_huge_scales_and_friction_build_well_conditioned_models():
    # Units of w and L: a 1e-9 N, 1 mm box is the same model as the paper's (in newtons and
    # metres MuJoCo would refuse its masses, below mjMINVAL); so is a 1e9 N, 50 m one; and a
    # tiny mu builds (the settle's and the drawn cone's).
    tiny = Scene.on_faces(PAPER_FACES, size=1e-3, weight=1e-9)
    huge = Scene.on_faces(PAPER_FACES, size=50.0, weight=1e9, mu=40.0)
    for scene in (tiny, huge):
        physics = PhysicsModel(scene, SETTINGS["timestep"], SETTINGS["settle_mu"])
        assert physics.model.body_mass[physics.object] == pytest.approx(1 / G)
        checker = StabilityChecker(scene)
        holds = checker.check(*forces_at_angle(scene, 5.0, 10.0))
        assert holds.holds, holds.as_dict()
        assert holds.slip.max() < 0.1 * SETTINGS["slip_threshold"] * scene.size.max()
        assert holds.drift < 1e-4 * scene.size.max()
    scene = Scene(mu=1e-6)
    mujoco.MjModel.from_xml_string(build_mjcf(scene, visual=True))
    assert not StabilityChecker(scene).check(*forces_at_angle(scene, 5.0, 10.0)).holds


@pytest.mark.parametrize(
    ("rotation", "forces", "message"),
    [
        (START_ROTATION, np.full((3, 3), np.nan), "finite"),
        (START_ROTATION, np.array([[np.inf, 0, 0], [0, 0, 0], [0, 0, 0]]), "finite"),
        (START_ROTATION, np.zeros((3, 2)), r"shape \(3, 3\)"),
        (START_ROTATION, np.zeros((4, 3)), r"shape \(3, 3\)"),
        (START_ROTATION, np.zeros(9), r"shape \(3, 3\)"),
        (np.eye(4), np.zeros((3, 3)), r"\(3, 3\) matrix"),
        (np.full((3, 3), np.nan), np.zeros((3, 3)), "finite"),
        (2 * np.eye(3), np.zeros((3, 3)), "orthonormal"),
        (np.diag([1.0, 1.0, -1.0]), np.zeros((3, 3)), "det = \\+1"),
    ],
)
@pytest.mark.fast
def test_bad_inputs_raise_clear_errors(paper_checker, rotation, forces, message):
    with pytest.raises(ValueError, match=message):
        paper_checker.check(rotation, forces)


@pytest.mark.fast
def test_bad_settings_raise_clear_errors():
    with pytest.raises(ValueError, match="unknown physics settings"):
        StabilityChecker(Scene(), hold=1.0)
    with pytest.raises(ValueError, match="hold_time must be a finite number > 0"):
        StabilityChecker(Scene(), hold_time=-1.0)
    with pytest.raises(ValueError, match=r"timestep must be in \(0, 0.0025\]"):
        TrajectoryChecker(Scene(), timestep=0.01)
    with pytest.raises(ValueError, match="scene must be"):
        StabilityChecker("paper")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="threads must be >= 1"):
        StabilityChecker(Scene()).check_batch(START_ROTATION[None], np.zeros((1, 3, 3)), threads=0)


def test_forces_up_to_the_contacts_limit_are_judged_and_larger_ones_refused():
    """MuJoCo's soft contact sinks a tip pressed much harder than MAX_FORCE through the face
    (a grip deep inside its cones then 'slips' metres): the checker holds to the limit and
    refuses beyond it, naming the finger."""
    from grasp_env.physics.model import MAX_FORCE

    scene = Scene(mu=1000.0)  # every cone 89.9 deg wide: an equal squeeze holds at any size
    grasp = scene_grasp(scene, START_ROTATION)
    squeeze = grasp.basis.sum(axis=0)  # P_i - F_i for k = 1 N on every pair
    per_newton = np.linalg.norm(squeeze, axis=-1).max() / scene.weight  # |F_i| is about 1 w
    checker = StabilityChecker(scene)
    try:
        near = grasp.equilibrating + squeeze * (0.97 * MAX_FORCE / per_newton)
        assert checker.check(START_ROTATION, near).holds
        beyond = grasp.equilibrating + squeeze * (1.05 * MAX_FORCE / per_newton)
        with pytest.raises(ValueError, match=r"finger \d's force at pose 0 is 15\d\.?\d* w"):
            checker.check(START_ROTATION, beyond)
    finally:
        checker.close()


def test_closed_checker_refuses_to_check():
    checker = StabilityChecker(Scene())
    checker.close()
    with pytest.raises(ValueError, match="closed"):
        checker.check(START_ROTATION, np.zeros((3, 3)))


def test_model_carries_the_scene():
    # The model is the scene in the hand's frame and in units of w and L (docs/physics.md): the
    # box at rest, its centre of gravity at the origin, zero gravity (the load is applied), each
    # fingertip touching its contact point along the contact's normal.
    scene = Scene.on_faces(
        PAPER_FACES, size=(2.0, 1.6, 1.2), weight=7.0, mu=0.4, cg_offset=(0.2, 0.0, -0.1)
    )
    physics = PhysicsModel(scene, SETTINGS["timestep"], SETTINGS["settle_mu"])
    model = physics.model
    body = model.body("object")
    assert model.body_mass[body.id] == pytest.approx(1 / G)
    np.testing.assert_allclose(model.opt.gravity, 0.0)
    np.testing.assert_allclose(model.body_ipos[body.id], np.array([0.2, 0.0, -0.1]) / 2)
    np.testing.assert_allclose(model.geom("box").size, np.array([1.0, 0.8, 0.6]) / 2)
    np.testing.assert_allclose(model.pair_friction[:, :2], 0.4)
    np.testing.assert_allclose(physics.settle_model.pair_friction[:, :2], SETTINGS["settle_mu"])
    assert model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert model.opt.jacobian == mujoco.mjtJacobian.mjJAC_DENSE
    assert model.opt.timestep == SETTINGS["timestep"]
    data = mujoco.MjData(model)
    mujoco.mj_setState(
        model, data, physics.initial_state(np.ones(3, bool)), mujoco.mjtState.mjSTATE_FULLPHYSICS
    )
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.xipos[body.id], 0.0, atol=1e-12)
    np.testing.assert_allclose(data.xmat[body.id].reshape(3, 3), np.eye(3))
    contacts = model_contacts(scene) - model_cg(scene)
    for i in range(3):
        tip = data.xpos[model.body(f"finger{i}").id]
        offset = tip - contacts[i]
        np.testing.assert_allclose(np.cross(offset, scene.normals[i]), 0.0, atol=1e-12)
        assert 0 < -offset @ scene.normals[i] < model.geom(f"tip{i}").size[0]
    assert data.ncon == 3
    for contact in data.contact[: data.ncon]:  # geom1 the tip, geom2 the box: normal inward
        i = int(model.geom(contact.geom1).name.removeprefix("tip"))
        np.testing.assert_allclose(contact.frame[:3], scene.normals[i], atol=1e-9)


def test_force_sets_hit_their_target_and_summary_counts():
    scene = Scene.on_faces(PAPER_FACES, [[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]])
    grasp = scene_grasp(scene, START_ROTATION)
    start = solve_minimax(grasp, 2 * scene.weight)
    targets = np.radians([10.0, 20.0, 35.0])
    ks = force_set_k(grasp, start.k, targets, np.random.default_rng(3), 4 * scene.weight)
    np.testing.assert_allclose(grasp.angles(ks).max(-1), targets, atol=1e-12)
    limit = np.degrees(scene.friction_limit)  # 26.57 deg
    sets = [
        ForceSet(scene, 0.0, START_ROTATION, grasp.forces(k), float(np.degrees(a)))
        for k, a in zip(ks, targets, strict=True)
    ]
    assert [s.predicted_holds for s in sets] == [True, True, False]
    assert sets[2].edge_distance_deg == pytest.approx(35.0 - limit)
    summary = summarise(sets, np.array([True, False, False]))
    np.testing.assert_array_equal(summary.confusion, [[1, 1], [0, 1]])
    assert summary.overall == pytest.approx(2 / 3)
    assert summary.n_far == 3


def test_check_sets_reports_each_set_through_the_progress_wrapper():
    scene = Scene.on_faces(PAPER_FACES, [[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]], mu=0.3)
    limit = np.degrees(scene.friction_limit)
    sets = []
    for offset in (-1.0, 1.0):
        rotation, forces = forces_at_angle(scene, 4.0, limit + offset)
        sets.append(ForceSet(scene, 4.0, rotation, forces, limit + offset))
    wrapped = []
    reports = check_sets(sets, progress=lambda s: wrapped.append(s) or iter(s))
    assert wrapped == [sets]  # e.g. tqdm wraps the iteration once
    assert [r.holds for r in reports] == [True, False]
    alone = StabilityChecker(scene).check(sets[1].rotation, sets[1].forces)
    assert reports[1].as_dict() == alone.as_dict()
