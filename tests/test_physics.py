"""MuJoCo against the analytic friction cone: pose checks and continuous rollouts (docs/physics.md).

The pose check and the rollout are one engine (:mod:`grasp_env.physics.motion` plans the steps,
:mod:`grasp_env.physics.simulation` runs them): the tests hold both against the analytic verdict
on grips that hold, grips that slip, grips that cross the limit only between poses, released
fingers and fingers phased out and in; and they pin down determinism and the refusals.
"""

from __future__ import annotations

import dataclasses
import itertools
import json

import mujoco
import numpy as np
import pytest

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    PHI,
    START_ROTATION,
    Scene,
    Trajectory,
    friction_angles,
    n_pairs,
    pose_rotation,
    scene_grasp,
    solve_gait,
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
from grasp_env.physics.rollout import rollout_report
from grasp_env.physics.simulation import PhysicsModel, available_cores
from grasp_env_agents.cli import main
from grasp_env_agents.studies import agreement, trajectory_agreement
from grasp_env_agents.studies.agreement import (
    ForceSet,
    check_sets,
    force_set_k,
    released_sets,
    summarise,
)
from grasp_env_agents.studies.trajectory_agreement import (
    CROSSINGS_DEG,
    check_cases,
    coarse_steps_case,
    gait_cases,
    gait_windows,
    perturbed_k,
    summarise_trajectories,
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


def forces_at_angle(scene: Scene, alpha_deg: float, angle_deg: float, seed: int = 0):
    """A force set on ``scene`` whose max friction angle is ``angle_deg`` exactly."""
    rotation = pose_rotation(PAPER_AXIS, np.radians(alpha_deg))
    grasp = scene_grasp(scene, rotation)
    optimum = solve_minimax(grasp, 2 * scene.weight)
    target = np.radians(angle_deg)
    k = force_set_k(
        grasp, optimum.k, np.array([target]), np.random.default_rng(seed), 4 * scene.weight
    )[0]
    assert np.all(np.isfinite(k)), "no force set found at the target angle"
    assert np.degrees(grasp.angles(k).max()) == pytest.approx(angle_deg, abs=1e-9)
    return rotation, grasp.forces(k)


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


# --------------------------------------------------------------------- the continuous rollout


def paper_grips(mu: float):
    """The paper's scene at ``mu`` along its trajectory: the optimum and the equal-k grip."""
    scene = Scene(mu=mu)
    rotations = Trajectory().rotations()
    grasp = scene_grasp(scene, rotations)
    optimum = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    equal_k = grasp.forces(scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(3))
    return scene, rotations, optimum, equal_k


def test_rollout_carries_the_optimal_grip_through_the_whole_trajectory():
    scene, rotations, optimum, _ = paper_grips(0.05)
    report = TrajectoryChecker(scene).check(rotations, optimum)
    assert report.holds and report.predicted_holds, report.as_dict()
    assert report.pose_holds.all() and report.pose_predicted.all()
    assert report.first_failure is None and report.predicted_first_failure is None
    # The optimum is 0 deg at every pose; k*(alpha) is smooth but not linear, so the grip
    # interpolated between poses 1 deg apart leans a little (1.3e-3 deg at most).
    assert report.max_angle_deg.max() < 0.01
    assert report.margin_deg == pytest.approx(np.degrees(np.arctan(0.05)), abs=0.01)
    assert report.slip.max() < 0.1 * SETTINGS["slip_threshold"]
    assert report.drift.max() < 1e-4 and report.rotation_deg.max() < 1e-3
    # One simulation: the poses follow each other, the load turns through 30 deg.
    motion = report.motion
    assert np.all(np.diff(motion.pose) >= 0) and motion.n_poses == len(rotations)
    turned = np.degrees(np.arccos(np.clip(motion.load[0, :3] @ motion.load[-1, :3], -1, 1)))
    assert turned == pytest.approx(30.0, abs=1e-6)
    json.dumps(report.as_dict())
    assert not report.diverged and report.as_dict()["diverged"] is False


def test_a_rollout_that_diverged_fails_at_its_last_pose_and_says_so():
    # The same run's measurements, as if MuJoCo had stopped it on a warning at its end.
    scene, rotations, optimum, _ = paper_grips(0.05)
    checker = TrajectoryChecker(scene)
    held = checker.check(rotations[:4], optimum[:4])
    trace = dataclasses.replace(held.trace, diverged=True)
    report = rollout_report(scene, held.motion, trace, checker.settings)
    assert held.holds and not held.diverged
    assert report.diverged and not report.holds and report.predicted_holds
    assert report.pose_holds.tolist() == [True, True, True, False]
    assert report.as_dict()["diverged"] is True


def test_rollout_of_a_slipping_grip_fails_where_the_analytic_verdict_does():
    # mu = 0.1 (5.71 deg): the equal-k grip passes the limit for |alpha| >~ 9 deg.
    scene, rotations, _, equal_k = paper_grips(0.1)
    report = TrajectoryChecker(scene).check(rotations, equal_k)
    assert not report.holds and not report.predicted_holds
    assert report.predicted_first_failure == 0.0 and report.first_failure == 0.0
    assert not report.pose_holds[0] and not report.pose_predicted[0]
    assert report.pose_predicted[15]
    # The same grip from the middle of the trajectory out: it holds until the limit is passed.
    middle = slice(15, 31)
    later = TrajectoryChecker(scene).check(rotations[middle], equal_k[middle])
    assert not later.holds and not later.predicted_holds
    assert later.first_failure == pytest.approx(later.predicted_first_failure, abs=0.25)
    assert later.pose_holds[: int(later.predicted_first_failure)].all()


def test_a_grip_that_crosses_the_limit_mid_trajectory_slips_there():
    scene = Scene.on_faces(
        PAPER_FACES, [[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]], cg_offset=(0.05, -0.03, 0.02)
    )
    trajectory = Trajectory(alpha_start_deg=-8.0, alpha_end_deg=8.0)
    rotations, alphas = trajectory.rotations(), trajectory.alphas_deg
    grasp = scene_grasp(scene, rotations)
    k = solve_minimax(grasp, 2 * scene.weight).k
    limit = float(np.degrees(grasp.angles(k).max())) + 3.0
    scene = Scene.on_faces(
        PAPER_FACES,
        [[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]],
        cg_offset=(0.05, -0.03, 0.02),
        mu=float(np.tan(np.radians(limit))),
    )
    checker = TrajectoryChecker(scene)
    reports = {}
    for name, offset in (("crossing", 0.3), ("inside", -0.3)):
        perturbed = perturbed_k(
            scene, rotations, alphas, k, np.radians(limit + offset), np.random.default_rng(1)
        )
        assert perturbed is not None
        reports[name] = checker.check(rotations, grasp.forces(perturbed))
        assert reports[name].margin_deg == pytest.approx(-offset, abs=1e-6)
    crossing, inside = reports["crossing"], reports["inside"]
    assert inside.holds and inside.predicted_holds, inside.as_dict()
    assert not crossing.holds and not crossing.predicted_holds
    start = crossing.predicted_first_failure
    assert 0.0 < start < len(rotations) - 1  # the bump crosses mid-trajectory
    assert start <= crossing.first_failure <= start + 0.5
    assert crossing.pose_holds[: int(start)].all()


def test_a_grip_that_holds_at_every_pose_can_slip_between_two():
    # Coarse steps (30 deg apart): the expert's grip holds at each of the three poses, in the
    # pose check and analytically, but the grip interpolated between the second and third
    # passes the limit by 2.1 deg: the continuous rollout sees it, both verdicts alike.
    case = coarse_steps_case()
    grasp = scene_grasp(case.scene, case.rotations)
    angles = np.degrees(friction_angles(case.forces, grasp.normals))
    assert np.all(angles <= np.degrees(case.scene.friction_limit) - 0.5)
    poses = StabilityChecker(case.scene).check_batch(case.rotations, case.forces)
    assert all(r.holds for r in poses)
    report = TrajectoryChecker(case.scene).check(case.rotations, case.forces)
    assert not report.predicted_holds and not report.holds
    assert 1.0 < report.predicted_first_failure < 2.0
    assert 1.0 < report.first_failure < 2.0
    assert report.margin_deg == pytest.approx(-2.05, abs=0.01)


def phasing_grip():
    """Four fingers along alpha in [-10, 10] deg; the thumb (+z) ramps to zero between poses 5
    and 6, is out of contact at poses 7 to 13 and is placed again with no force at 14, whence
    its force ramps up: the three-finger optimum while it is off, the four-finger one else."""
    offsets = np.array([[0.2, -0.1], [-0.15, 0.2], [0.1, 0.1], [-0.2, -0.25]])
    cg = (0.03, -0.02, 0.04)
    rotations = Trajectory(alpha_start_deg=-10.0, alpha_end_deg=10.0).rotations()
    four = Scene.on_faces(FOUR_FINGER_FACES, offsets, cg_offset=cg)
    three = Scene.on_faces(PAPER_FACES, offsets[:3], cg_offset=cg)
    grip4, grip3 = scene_grasp(four, rotations), scene_grasp(three, rotations)
    forces = grip4.forces(solve_minimax(grip4, 2 * four.weight).k)
    forces[6:15] = 0.0
    forces[6:15, :3] = grip3.forces(solve_minimax(grip3, 2 * three.weight).k)[6:15]
    contact = np.ones((len(rotations), 4), dtype=bool)
    contact[7:14, 3] = False
    scene = Scene.on_faces(FOUR_FINGER_FACES, offsets, cg_offset=cg, mu=0.3)  # 16.7 deg
    return scene, rotations, forces, contact


def test_a_finger_phased_out_ramps_to_zero_lifts_and_is_placed_again():
    scene, rotations, forces, contact = phasing_grip()
    report = TrajectoryChecker(scene).check(rotations, forces, contact)
    assert report.holds and report.predicted_holds, report.as_dict()
    assert report.slip.max() < SETTINGS["slip_threshold"]
    motion = report.motion
    thumb = np.linalg.norm(motion.forces[:, 3], axis=-1)
    leaving = (motion.pose > 5) & (motion.pose < 6)
    joining = (motion.pose > 14) & (motion.pose < 15)
    assert np.all(np.diff(thumb[leaving]) < 0) and np.all(np.diff(thumb[joining]) > 0)
    assert thumb[(motion.pose >= 6) & (motion.pose <= 14)].max() < 1e-12
    touching = motion.contact[:, 3]
    # Touching while it pushes; lifted once its force is spent (near pose 6: the timing slows
    # the last of the ramp, so the steps below released_force x w come before pose 6), placed
    # as it starts to push again (after pose 14).
    pushing = thumb > SETTINGS["released_force"]  # motion forces are in units of w
    for ramp in (leaving, joining):
        assert np.array_equal(touching[ramp], pushing[ramp]) and pushing[ramp].mean() > 0.5
    assert not touching[(motion.pose >= 6) & (motion.pose <= 14)].any()
    # The others hold on throughout: no finger slid, the object stayed put.
    assert report.drift.max() < SETTINGS["drift_threshold"]
    # A finger out of contact that is commanded to push is refused.
    bad = forces.copy()
    bad[10, 3] = [0.0, 0.0, -1.0]
    with pytest.raises(ValueError, match="finger 3 is out of contact at pose 10"):
        TrajectoryChecker(scene).check(rotations, bad, contact)


def test_rollouts_are_the_same_alone_in_a_batch_and_on_any_number_of_threads():
    scene, rotations, optimum, equal_k = paper_grips(0.1)
    checker = TrajectoryChecker(scene)
    grips = [
        (rotations[:8], optimum[:8], None),
        (rotations[:8], equal_k[:8], None),
        (rotations[3:6], equal_k[3:6], None),  # more grips than threads: taken in turn
    ]
    alone = [checker.check(*grip).as_dict() for grip in grips]
    for threads in sorted({1, 2, available_cores()}):
        assert [r.as_dict() for r in checker.check_batch(grips, threads=threads)] == alone


@pytest.mark.fast
def test_rollout_refuses_bad_input():
    scene, rotations, optimum, _ = paper_grips(0.3)
    checker = TrajectoryChecker(scene)
    with pytest.raises(ValueError, match=r"shape \(31, 3, 3\)"):
        checker.check(rotations, optimum[:30])
    with pytest.raises(ValueError, match="in_contact must be a boolean array of shape"):
        checker.check(rotations, optimum, np.ones((31, 2), bool))
    with pytest.raises(ValueError, match="more than"):
        TrajectoryChecker(scene, time_per_degree=1e4).check(rotations, optimum)
    # A force rate so small that the timing would ask for more steps than an int64 holds (or
    # divide by an underflowed zero): the same error, before anything is allocated.
    changing = optimum.copy()
    changing[1] *= 3.0
    for force_rate in (1e-9, 1e-300, 5e-324):
        with pytest.raises(ValueError, match="more than 2000000 steps"):
            TrajectoryChecker(scene, force_rate=force_rate).plan(rotations[:3], changing[:3])
    # Times too long for the step (counted before any integer could overflow), in either check.
    for setting in (
        {"time_per_degree": 1e300},
        {"min_segment_time": 1e17},
        {"pose_hold_time": 1e300},
        {"hold_time": 1e300},
        {"settle_time": 1e300},
        {"timestep": 1e-300},
    ):
        with pytest.raises(ValueError, match="more than 2000000 steps"):
            TrajectoryChecker(scene, **setting).plan(rotations[:3], optimum[:3])
        if "hold_time" in setting or "settle_time" in setting or "timestep" in setting:
            with pytest.raises(ValueError, match="more than 2000000 steps"):
                StabilityChecker(scene, **setting).check(rotations[0], optimum[0])
    with pytest.raises(ValueError, match="orthonormal"):
        checker.check(2 * rotations, optimum)


def test_trajectory_study_cases_hit_their_margins_and_agree_with_mujoco():
    # A tiny version of the study (its 200 scenes give about 600 trajectories): a three-finger
    # scene on the paper's trajectory and a four-finger one on a random axis, each with the
    # expert's grip and grips perturbed to cross the limit or stay inside by 0.05 and 0.1 deg.
    cases = trajectory_cases(seed=0, scenes=2)
    kinds = [c.kind for c in cases]
    assert kinds[:6] == ["expert", "crossing", "inside"] * 2
    assert kinds.count("expert") == 2 and kinds.count("equal-k") == 8
    assert kinds[-1] == "coarse steps"
    assert {c.scene.n_contacts for c in cases} == {3, 4}
    reports = check_cases(cases)
    for index in (1, 2, 4, 5):  # scene s perturbs by CROSSINGS_DEG[s], past or inside the edge
        offset = CROSSINGS_DEG[index // 3]
        expected = -offset if cases[index].kind == "crossing" else offset
        assert reports[index].margin_deg == pytest.approx(expected, abs=1e-6)
    for case, report in zip(cases, reports, strict=True):
        assert report.agrees, (case.kind, report.as_dict())
    summary = summarise_trajectories(reports)
    assert summary.overall == 1.0 and summary.n_sets == len(cases)
    assert summary.confusion.sum() == len(cases)
    assert summary.confusion[0, 0] == sum(r.predicted_holds for r in reports)


def test_gait_windows_touch_at_most_four_sites_and_cover_the_gait():
    # fingers 0 to 2 hold sites 0 to 2 throughout; finger 3 walks over sites 3, 4, 5 and back
    walk = np.repeat([3, -1, 4, -1, 5, 3], 10)
    contacts = np.column_stack([np.zeros(60), np.ones(60), np.full(60, 2), walk]).astype(int)
    windows = gait_windows(contacts, longest=25)
    assert windows[0] == slice(0, 20) and windows[-1].stop == 60
    assert all(a.stop == b.start for a, b in itertools.pairwise(windows))
    for window in windows:
        assert 0 < window.stop - window.start <= 25
        assert len({int(s) for s in contacts[window].ravel() if s >= 0}) <= 4


def test_the_polish_stops_where_a_secant_would_leave_the_bisected_scale():
    """A secant across a nearly flat stretch once jumped from the bisected scale c = 0.34 to
    forces of 212 w, which the MuJoCo check refuses: the 200-scene study failed. Where the
    polish does not converge the perturbation is refused: its margin on the steps run is not
    the target (seed 1's study had an "inside" grip 0.084 deg outside its cone)."""
    from grasp_env_agents.studies.trajectory_agreement import _polished

    asked = []

    def largest(c: float) -> float:  # just above the target at c = 1, nearly flat
        asked.append(c)
        return 0.5 + 1e-8 - 1e-8 * (c - 1.0)

    assert _polished(1.0, largest, 0.5) is None  # no convergence nearby
    assert max(asked) < 1.01  # the jump to c = 2 was never run

    def steep(c: float) -> float:
        asked.append(c)
        return 0.5 + 1e-8 - 1e-3 * (c - 1.0)

    assert abs(_polished(1.0, steep, 0.5) - 1.00001) <= 1e-12  # a near root is still polished


def test_gait_cases_hold_slip_and_agree_with_mujoco(monkeypatch):
    """The certified gait on a short trajectory (four contacts in the model, one of them
    placed on the way), and perturbed to cross the limit or stay inside by 0.05 deg: the
    margins are the targets, the in_contact schedule places the finger, and the verdicts agree."""
    monkeypatch.setattr(trajectory_agreement, "GAIT_TRAJECTORIES", SHORT_GAIT)
    cases = gait_cases(seed=0)
    assert [c.kind for c in cases] == ["gait", "gait crossing", "gait inside"]
    gait = cases[0]
    assert gait.scene.n_contacts == 4 and gait.in_contact.shape == (31, 4)
    assert not gait.in_contact[0].all() and gait.in_contact[-1].all()  # one finger placed
    reports = check_cases(cases)
    solution = solve_gait(trajectory=SHORT_GAIT[0])
    assert reports[0].margin_deg == pytest.approx(np.degrees(solution.optimal.margin), abs=0.01)
    assert reports[1].margin_deg == pytest.approx(-CROSSINGS_DEG[0], abs=1e-6)
    assert reports[2].margin_deg == pytest.approx(CROSSINGS_DEG[0], abs=1e-6)
    for case, report in zip(cases, reports, strict=True):
        assert report.agrees, (case.kind, report.as_dict())
    assert reports[0].holds and not reports[1].holds
    # a perturbation keeps the forces balanced and the fingers away without force
    assert np.all(cases[1].forces[~gait.in_contact] == 0)
    assert np.allclose(cases[1].forces.sum(axis=1), gait.forces.sum(axis=1), atol=1e-9)


# ----------------------------------------------------------------------- grasp-env verify


def test_verify_equal_k_grip_slips_at_the_trajectory_ends(tmp_path, capsys):
    # mu = 0.1 (5.71 deg): the equal-k grip's max angle passes it for |alpha| >= 10 deg or so.
    status = main(["verify", "--policy", "equal-k", "--mu", "0.1", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert status == 0
    assert (tmp_path / "verify.png").stat().st_size > 10_000
    rows = [line for line in out.splitlines() if line.startswith("│")]
    assert len(rows) == 31
    ends, middle = rows[0] + rows[-1], rows[15]
    assert ends.count("slips") == 4  # predicted and MuJoCo, at both ends
    assert middle.count("holds") == 2
    assert "agree at 31/31" in out


def test_verify_trajectory_carries_the_expert_grip_in_one_rollout(tmp_path, capsys):
    status = main(["verify", "--trajectory", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert status == 0
    rows = [line for line in out.splitlines() if line.startswith("│")]
    assert len(rows) == 31 and all(row.count("holds") == 2 for row in rows)
    verdict = out.strip().splitlines()[-1]
    assert verdict.startswith("trajectory: analytic holds, MuJoCo holds (agree); margin +26.5")
    assert (tmp_path / "rollout.png").stat().st_size > 10_000
    report = json.loads((tmp_path / "rollout.json").read_text())
    assert report["policy"] == "expert" and len(report["alphas_deg"]) == 31
    assert report["holds"] and all(report["pose_holds"]) and report["first_failure"] is None


def test_verify_trajectory_reports_where_the_equal_k_grip_first_slips(tmp_path, capsys):
    # mu = 0.1 (5.71 deg): the equal-k grip is past the limit from the start (9.3 deg at -15).
    argv = ["verify", "--trajectory", "--policy", "equal-k", "--mu", "0.1", "--out", str(tmp_path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "trajectory: analytic slips, MuJoCo slips (agree); margin -3.6" in out
    assert "first failure, analytic: alpha = -15.00 deg, MuJoCo: alpha = -15.00 deg" in " ".join(
        out.split()
    )
    report = json.loads((tmp_path / "rollout.json").read_text())
    assert report["predicted_first_failure"] == 0.0 and not report["holds"]
    assert not report["pose_predicted"][0] and report["pose_predicted"][15]


#: A short gait for the tests: the paper's axis from -15 to 15 deg, one window, one finger
#: placed (at alpha = -9 deg).
SHORT_GAIT = (Trajectory(tuple(PAPER_AXIS), -15.0, 15.0, 1.0),)


def test_verify_trajectory_agreement_on_one_scene(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(trajectory_agreement, "GAIT_TRAJECTORIES", SHORT_GAIT)
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "1", "--out", str(tmp_path)]
    status = main(argv)
    out = capsys.readouterr().out
    # One scene gives the expert's grip and two perturbed ones, plus 8 equal-k, coarse steps
    # and the gait with its two perturbations.
    assert out.strip().splitlines()[-1].startswith("agreement: 100.00% overall (15 trajectories)")
    assert status == 0
    assert "coarse steps" in out and "gait crossing" in out and "MuJoCo slips" in out
    assert (tmp_path / "trajectory_agreement.png").stat().st_size > 10_000


def test_verify_refuses_scenes_outside_the_trajectory_study(tmp_path, capsys):
    assert main(["verify", "--scenes", "3", "--out", str(tmp_path)]) == 2
    assert "--agreement --trajectory" in capsys.readouterr().err
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "0", "--out", str(tmp_path)]
    with pytest.raises(SystemExit, match="2"):
        main(argv)
    error = capsys.readouterr().err
    assert "argument --scenes: must be an integer in [1, 100000], got '0'" in error


def test_verify_and_gait_say_which_path_they_cannot_write(tmp_path, capsys):
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    # the video's folder is created as --out's is, unless a file is in the way
    video = blocked / "videos" / "x.mp4"
    assert main(["verify", "--video", str(video), "--out", str(tmp_path)]) == 2
    assert f"--video {video}: cannot write it (Not a directory)" in capsys.readouterr().err
    assert main(["verify", "--video", str(tmp_path / "x.txt"), "--out", str(tmp_path)]) == 2
    assert "the video is an MP4, name it FILE.mp4" in capsys.readouterr().err
    assert not (tmp_path / "x.txt").exists()  # refused before anything is written
    with pytest.raises(SystemExit, match="2"):  # refused before the gait is solved
        main(["gait", "--out", str(blocked / "out")])
    assert "argument --out: " in (err := capsys.readouterr().err)
    assert "a file is in the way" in err


def test_verify_states_the_current_settings():
    from grasp_env_agents.commands import verify

    def num(value: float) -> str:
        return f"{value:g}".replace("e-0", "e-")

    doc = " ".join(verify.__doc__.split())
    for phrase in (
        f"{num(SETTINGS['settle_time'])} s settle at mu = {num(SETTINGS['settle_mu'])}",
        f"{num(SETTINGS['hold_time'])} s hold",
        f"more than {num(SETTINGS['slip_threshold'])} L",
        f"faster than {num(SETTINGS['slip_speed'])} L/s",
        f"at most {num(SETTINGS['drift_threshold'])} L",
        f"at most {num(SETTINGS['rotation_threshold_deg'])} deg",
        f"at most {num(SETTINGS['released_force'])} w is released",
        f"{num(SETTINGS['pose_hold_time'])} s dwell",
        f"{num(SETTINGS['time_per_degree'])} s per degree",
    ):
        assert phrase in doc, phrase


@pytest.mark.slow  # about 13 s, most of it importing Stable-Baselines3 and building PPO
def test_verify_runs_a_saved_model(tmp_path, capsys):
    import gymnasium as gym
    from stable_baselines3 import PPO

    import grasp_env  # noqa: F401

    path = tmp_path / "model.zip"
    PPO("MlpPolicy", gym.make("grasp_env/CubeGrasp-v0"), seed=0, device="cpu").save(path)
    status = main(["verify", "--policy", str(tmp_path), "--out", str(tmp_path)])  # a run dir
    out = capsys.readouterr().out
    assert status == 0
    assert "MuJoCo: holds at" in out
    assert len([line for line in out.splitlines() if line.startswith("│")]) == 31
    argv = ["verify", "--trajectory", "--policy", str(path), "--out", str(tmp_path)]
    assert main(argv) == 0
    assert "trajectory: analytic" in capsys.readouterr().out
    assert json.loads((tmp_path / "rollout.json").read_text())["policy"].startswith("learned (")


@pytest.mark.slow  # about 40 s: Stable-Baselines3, PPO and a small trajectory study
def test_verify_trajectory_agreement_adds_a_saved_models_grips(tmp_path, capsys, monkeypatch):
    import gymnasium as gym
    from stable_baselines3 import PPO

    import grasp_env  # noqa: F401

    monkeypatch.setattr(trajectory_agreement, "GAIT_TRAJECTORIES", SHORT_GAIT)
    PPO("MlpPolicy", gym.make("grasp_env/CubeGrasp-v0"), seed=0, device="cpu").save(
        tmp_path / "model.zip"
    )
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "2", "--policy", str(tmp_path)]
    main([*argv, "--out", str(tmp_path)])
    out = capsys.readouterr().out
    # Of the two scenes, the first has three fingers (the environment's): one learned grip.
    assert "(19 trajectories)" in out.strip().splitlines()[-1]
    assert "learned" in out
    argv = ["verify", "--agreement", "--trajectory", "--policy", "equal-k"]
    assert main([*argv, "--out", str(tmp_path)]) == 2
    assert "saved model" in capsys.readouterr().err


def test_verify_drives_a_run_with_its_own_env_kwargs(tmp_path, capsys):
    from grasp_env_agents.run.config import config_from_dict, save_config
    from grasp_env_agents.studies.grips import model_env, model_setup

    run = tmp_path / "run"
    run.mkdir()
    config = {"env_id": "grasp_env/CubeGrasp4-v0", "env_kwargs": {"k_max_ratio": 10.0}}
    config["total_timesteps"] = 1024
    save_config(config_from_dict(config), run / "config.yaml")
    model = model_setup(run, None, None)
    env = model_env(model)
    # the grip the model commands is the one its run trained with (k_max = 10 w)
    assert (model.env_id, env.unwrapped.k_max_ratio) == ("grasp_env/CubeGrasp4-v0", 10.0)
    assert not env.unwrapped.terminate_on_slip  # the whole trajectory is verified
    # the paper's three fingers cannot be placed on its four: refused, not ignored
    argv = ["verify", "--policy", str(run), "--offsets", "0.1,0,0,0,0,0", "--out", str(tmp_path)]
    assert main(argv) == 2
    assert "--offsets places the paper's three fingers" in capsys.readouterr().err
    # a study whose scenes have none of its four fingers says so before any rollout
    argv = ["verify", "--agreement", "--trajectory", "--scenes", "1", "--policy", str(run)]
    assert main([*argv, "--out", str(tmp_path)]) == 2
    assert "no scene of the study has the model's 4 fingers" in capsys.readouterr().err


def test_verify_rejects_a_missing_model(tmp_path, capsys):
    status = main(["verify", "--policy", str(tmp_path / "none.zip"), "--out", str(tmp_path)])
    assert status == 2
    assert "is not a file" in capsys.readouterr().err


def test_an_agreement_study_that_misses_says_why_it_exits_1(capsys):
    from grasp_env_agents.commands.verify import _verdict
    from grasp_env_agents.studies.agreement import agreement

    holds = np.array([True, True, False, False])
    far = np.array([1.0, 1.0, 1.0, 0.01])  # deg from the edge
    assert _verdict(agreement(holds, holds, far)) == 0
    assert capsys.readouterr().out == ""
    assert _verdict(agreement(holds, np.array([True, False, False, True]), far)) == 1
    assert "exit 1: 1 of the 3 verdicts at >= 0.05 deg from the edge disagree" in (
        capsys.readouterr().out
    )
