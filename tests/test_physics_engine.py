"""The rollout engine's shortcuts (batched pose plans, cached initial states, runs split
between threads, taken for speed) give the same runs as the plain path."""

from __future__ import annotations

import copy
import dataclasses
import itertools

import mujoco
import numpy as np
import pytest

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    Scene,
    Trajectory,
    friction_angles,
    scene_grasp,
    solve_minimax,
)
from grasp_env.mechanics.gait import PAPER_TURN, solve_gait
from grasp_env.physics import (
    SETTINGS,
    StabilityChecker,
    TrajectoryChecker,
    check_poses,
    check_trajectories,
)
from grasp_env.physics.batch import _tip_inertia
from grasp_env.physics.motion import path_settings, plan_motion, plan_poses
from grasp_env.physics.simulation import PhysicsModel, simulate
from grasp_env_agents.studies.trajectory_agreement import (
    check_cases,
    gait_window_case,
    gait_windows,
    perturbed_gait,
)

SIMULATION_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


@pytest.fixture(scope="module")
def paper():
    scene = Scene(mu=0.1)
    rotations = Trajectory().rotations()
    grasp = scene_grasp(scene, rotations)
    return scene, rotations, grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)


@pytest.mark.fast
def test_batched_pose_plans_are_the_one_pose_plans(paper):
    scene, rotations, forces = paper
    forces = forces.copy()
    forces[3, 1] = 1e-6 * scene.weight * np.array([0.0, 0.0, 1.0])  # released
    contact = np.ones((len(rotations), 3), dtype=bool)
    contact[5, 2] = False
    forces[5, 2] = 0.0
    batch = plan_poses(scene, rotations, forces, contact, SETTINGS)
    for b, motion in enumerate(batch):
        alone = plan_motion(scene, rotations[b : b + 1], forces[b : b + 1], contact[b : b + 1],
                            SETTINGS)  # fmt: skip
        assert motion.settle_steps == alone.settle_steps
        for name in ("forces", "load", "contact", "pose", "rotations"):
            np.testing.assert_array_equal(getattr(motion, name), getattr(alone, name), name)
    assert not batch[3].contact[:, 1].any() and not batch[5].contact[:, 2].any()
    with pytest.raises(ValueError, match="finger 1 is out of contact at pose 4"):
        bad = contact.copy()
        bad[4, 1] = False
        plan_poses(scene, rotations, forces, bad, SETTINGS)


@pytest.mark.parametrize("size", [None, 1, 3])
@pytest.mark.parametrize("threads", [1, 2, 3])
def test_parts_in_parallel_keep_the_items_order(threads, size):
    from grasp_env.physics.simulation import in_parallel

    calls = []

    def work(part):
        calls.append(len(part))
        return [10 * x for x in part]

    items = list(range(7))
    assert in_parallel(work, items, threads, size) == [10 * x for x in items]
    assert sum(calls) == 7 and (size is None or max(calls) <= size)
    assert in_parallel(work, [], threads, size) == []


def test_initial_states_are_cached_but_handed_out_as_copies(paper):
    scene = paper[0]
    physics = PhysicsModel(scene, SETTINGS["timestep"], SETTINGS["settle_mu"])
    contact = np.array([True, False, True])
    first = physics.initial_state(contact)
    first[:] = np.nan
    again = physics.initial_state(contact)
    assert np.all(np.isfinite(again))
    assert not np.array_equal(again, physics.initial_state(np.ones(3, dtype=bool)))


def test_runs_of_different_lengths_share_a_batch_unchanged(paper):
    # Padded runs are measured over their own steps only: the same traces as alone.
    scene, rotations, forces = paper
    checker = TrajectoryChecker(scene)
    motions = [checker.plan(rotations[:n], forces[:n]) for n in (2, 5, 3, 5)]
    batch = simulate([(checker.physics, m) for m in motions], threads=2)
    for motion, trace in zip(motions, batch, strict=True):
        (alone,) = simulate([(checker.physics, motion)], threads=1)
        assert len(trace.slip) == len(motion)
        for name in ("qpos", "slip", "speed", "gap", "drift", "rotation", "measured"):
            np.testing.assert_array_equal(getattr(trace, name), getattr(alone, name), name)
        assert trace.diverged == alone.diverged


def test_measured_rotations_are_quaternion_matrix_bit_for_bit():
    from grasp_env.mechanics import quaternion_matrix
    from grasp_env.physics.batch import _rotations

    rng = np.random.default_rng(3)
    quaternions = rng.normal(size=(4, 50, 4))
    quaternions[0, :10] = [1.0, 0.0, 0.0, 0.0]
    quaternions[1, :10, 1:] *= 1e-9  # near the identity, as a held grasp's
    rotations = _rotations(quaternions)
    expected = quaternion_matrix(quaternions)
    np.testing.assert_array_equal(rotations, expected)
    np.testing.assert_array_equal(np.signbit(rotations), np.signbit(expected))
    # The layout too: numpy may take another product kernel for another one.
    assert rotations.flags.c_contiguous
    np.testing.assert_array_equal(rotations @ [0.3, -0.2, 0.1], expected @ [0.3, -0.2, 0.1])


def unloading_grip(inside_deg: float):
    """Four fingers over the paper's first two poses (1 deg apart): the expert's grip, then one
    that unloads finger 0 from 0.45 w to 0.03 w pointing 40 deg off its normal (the others
    nearer theirs), with mu so that the run's largest friction angle is ``inside_deg`` inside
    the limit (negative: outside). The base timing unloads it in 25 steps."""
    scene = Scene.on_faces(FOUR_FINGER_FACES)
    rotations = Trajectory().rotations()[:2]
    grasp = scene_grasp(scene, rotations)
    start = solve_minimax(grasp, 2 * scene.weight).k[0]
    pairs = list(itertools.combinations(range(4), 2))
    own = [p for p, pair in enumerate(pairs) if 0 in pair]
    normal = grasp.normals[1, 0]
    tangent = np.cross(normal, [0.3, 0.5, 0.8])
    tangent /= np.linalg.norm(tangent)
    angle = np.radians(40.0)
    target = 0.03 * scene.weight * (np.cos(angle) * normal + np.sin(angle) * tangent)
    rng = np.random.default_rng(0)
    best = None
    for _ in range(2000):  # the other fingers' scalars nearest their normals
        k = np.zeros(6)
        k[[p for p in range(6) if p not in own]] = rng.uniform(-1, 1, 3) * scene.weight
        k[own] = np.linalg.solve(grasp.basis[1, own, 0].T, target - grasp.forces(k)[1, 0])
        worst = friction_angles(grasp.forces(k)[1, 1:], grasp.normals[1, 1:]).max()
        if best is None or worst < best[0]:
            best = (worst, k)
    forces = grasp.forces(np.stack([start, best[1]]))
    motion = plan_motion(scene, rotations, forces, None, SETTINGS)
    largest = motion.friction_angles(scene)[motion.settle_steps :].max()
    limit = largest + np.radians(inside_deg)
    return Scene.on_faces(FOUR_FINGER_FACES, mu=float(np.tan(limit))), rotations, forces


def normal_rates(motion, scene):
    """(N - 1, n) each finger's |dN/dt| / max(|P|, force_floor) between steps, per second,
    where it touches at both."""
    normal = np.einsum("knc,nc->kn", motion.forces, scene.normals)
    size = np.linalg.norm(motion.forces, axis=-1)
    size = np.maximum(np.minimum(size[1:], size[:-1]), SETTINGS["force_floor"])
    rate = np.abs(np.diff(normal, axis=0)) / (SETTINGS["timestep"] * size)
    return np.where(motion.contact[1:] & motion.contact[:-1], rate, 0.0)


def test_the_timing_keeps_the_force_path_and_bounds_the_normal_forces_rate(paper):
    # Without a turn the path is the straight line between the poses' forces: the timed steps
    # lie on it, slowed where finger 0's force falls, and it reaches finger 0's last force.
    scene, rotations, forces = unloading_grip(0.05)
    still = np.repeat(rotations[1:], 2, 0)
    ends = plan_motion(scene, still, forces, None, dict(SETTINGS, force_rate=np.inf))
    timed = plan_motion(scene, still, forces, None, SETTINGS)
    segment = (timed.pose > 0) & (timed.pose < 1)
    s = timed.pose[segment][:, None, None]
    pose_forces = ends.forces[[ends.settle_steps, -1]]
    np.testing.assert_allclose(
        timed.forces[segment], (1 - s) * pose_forces[0] + s * pose_forces[1], atol=1e-12
    )
    assert segment.sum() > 5 * ((ends.pose > 0) & (ends.pose < 1)).sum()
    # The bound, at every step of the turning run where a finger touches at both ends.
    motion = plan_motion(scene, rotations, forces, None, SETTINGS)
    assert normal_rates(motion, scene).max() <= 1.05 * SETTINGS["force_rate"]
    base = plan_motion(scene, rotations, forces, None, dict(SETTINGS, force_rate=np.inf))
    assert normal_rates(base, scene).max() > 10 * SETTINGS["force_rate"]
    # The same path: its largest friction angle is the densely sampled path's.
    dense = plan_motion(scene, rotations, forces, None, path_settings(SETTINGS, 64))
    for run in (motion, dense):
        assert run.friction_angles(scene)[run.settle_steps :].max() == pytest.approx(
            scene.friction_limit - np.radians(0.05), abs=np.radians(1e-3)
        )
    # A motion that is slow already is left alone: the paper's 31 poses keep their 2525 steps
    # (2375 and 5 more a segment for the eased ends).
    paper_scene, paper_rotations, paper_forces = paper
    assert len(plan_motion(paper_scene, paper_rotations, paper_forces, None, SETTINGS)) == len(
        plan_motion(paper_scene, paper_rotations, paper_forces, None,
                    dict(SETTINGS, force_rate=np.inf))
    ) == 2375 + 5 * (len(paper_rotations) - 1)  # fmt: skip


def test_the_segments_ends_are_eased_so_the_forces_rate_does_not_jump(paper):
    """Each segment's pace rises linearly from the dwell's standstill over ramp_time and falls
    back to it over the last ramp_time, which the segment runs longer by: the path
    coordinate's step grows from near zero by at most a fifth of the middle's pace per step
    (ramp_time 0.01 s, 5 steps), where unramped it jumps from zero to the full pace in one
    step; the middle keeps the unramped pace and the path's forces are the same."""
    scene, rotations, forces = paper
    ramp_steps = round(SETTINGS["ramp_time"] / SETTINGS["timestep"])
    assert ramp_steps == 5

    def paces(settings):
        motion = plan_motion(scene, rotations[:2], forces[:2], None, settings)
        first = motion.settle_steps + round(SETTINGS["pose_hold_time"] / SETTINGS["timestep"])
        last = int(np.flatnonzero(motion.pose == 1.0)[0])
        return motion, np.diff(motion.pose[first - 1 : last + 1])  # from the dwell's last step

    eased, eased_pace = paces(SETTINGS)
    unramped, unramped_pace = paces(dict(SETTINGS, ramp_time=1e-9))
    assert len(eased) == len(unramped) + ramp_steps
    assert len(eased_pace) == len(unramped_pace) + ramp_steps
    middle = unramped_pace[len(unramped_pace) // 2]
    assert np.ptp(unramped_pace) < 1e-6 * middle  # unramped: the full pace from the first step
    assert eased_pace[len(eased_pace) // 2] == pytest.approx(middle, rel=1e-6)
    for end in (eased_pace[:ramp_steps], eased_pace[::-1][:ramp_steps]):
        np.testing.assert_allclose(end, (np.arange(ramp_steps) + 0.5) / ramp_steps * middle,
                                   rtol=1e-6)  # fmt: skip
    assert np.abs(np.diff(np.concatenate([[0.0], eased_pace, [0.0]]))).max() <= (
        middle / ramp_steps * (1 + 1e-6)
    )
    # the same path: the forces at the eased steps are the path's at their coordinates
    segment = (eased.pose > 0) & (eased.pose < 1)
    dense = plan_motion(scene, rotations[:2], forces[:2], None, path_settings(SETTINGS, 64))
    on_path = (dense.pose > 0) & (dense.pose < 1)
    for finger in range(3):
        for c in range(3):
            expected = np.interp(eased.pose[segment], dense.pose[on_path],
                                 dense.forces[on_path, finger, c])  # fmt: skip
            np.testing.assert_allclose(eased.forces[segment, finger, c], expected, atol=1e-6)


def test_an_unloading_finger_near_its_edge_holds_and_one_outside_slips():
    # Finger 0's force falls 70-fold towards 0.05 deg inside its cone: it holds (before the
    # tips' inertia was fed forward it slid unless the timing slowed the fall). The same
    # unloading 0.5 deg outside the cone slips.
    inside = unloading_grip(0.05)
    outside = unloading_grip(-0.5)
    for checker in (TrajectoryChecker(inside[0]), TrajectoryChecker(inside[0], force_rate=1e12)):
        report = checker.check(*inside[1:])
        assert report.predicted_holds and report.holds, report.as_dict()
    crossing = TrajectoryChecker(outside[0]).check(*outside[1:])
    assert not crossing.predicted_holds and not crossing.holds


def contact_force_errors(physics, normal_forces, fed_forward):
    """One fingertip placed at rest on an immovable box, its motor pushing with the normal
    forces ``normal_forces`` (w, one per step), plus its inertia's share if ``fed_forward``
    (as the rollouts push): the contact's normal force against the commanded one, relative,
    after each step."""
    model = copy.deepcopy(physics.model)  # made immovable once per call, not cumulatively
    data = mujoco.MjData(model)
    model.body_mass[physics.object] *= 1e9
    model.body_inertia[physics.object] *= 1e9
    mujoco.mj_setState(
        model, data, physics.initial_state(np.array([True, False, False])), SIMULATION_STATE
    )
    steps = len(normal_forces)
    inertial = _tip_inertia(
        normal_forces[None, :, None],
        np.ones((1, steps, 1), bool),
        np.array([physics._response]),
        np.array([physics.rest_depth]),
        physics.timestep,
    )[0, :, 0]
    errors = []
    for k in range(steps):
        data.ctrl[:3] = (normal_forces[k] + fed_forward * inertial[k]) * physics.normals[0]
        mujoco.mj_step(model, data)
        contact = np.zeros(6)
        mujoco.mj_contactForce(model, data, 0, contact)
        errors.append(contact[0] / normal_forces[k] - 1.0)
    return np.array(errors)


def test_the_tips_inertia_is_fed_forward_so_its_contact_pushes_the_commanded_force(paper):
    # A tip placed at rest under a force growing from released_force (linearly or
    # exponentially) or falling and stopping at a small force: with the tip's inertia fed
    # forward the soft contact pushes within 0.6% of the commanded force; without it, off by
    # 2.4-4.9% for a few steps, which slid fingers placed (or unloaded) 0.05-0.2 deg inside
    # their cones.
    physics = PhysicsModel(paper[0], SETTINGS["timestep"], SETTINGS["settle_mu"])
    t = np.arange(80) * SETTINGS["timestep"]
    light = SETTINGS["released_force"]
    for normal_forces in (
        light + 0.5 * t,
        light * np.exp(30 * t),
        np.maximum(0.05 - 2 * t, 0.0065),
    ):
        fed = contact_force_errors(physics, normal_forces, True)
        plain = contact_force_errors(physics, normal_forces, False)
        assert np.abs(fed).max() < 0.006 and np.abs(plain).max() > 0.02
    steady = np.full((1, 200, 1), 0.01)
    inertial = _tip_inertia(
        steady, np.ones(steady.shape, bool), np.array([physics._response]),
        np.array([physics.rest_depth]), physics.timestep,
    )  # fmt: skip
    # a steady force: the tip settles at the static depth R N / (K I), needing no extra push
    assert abs(inertial[0, -1, 0]) < 1e-6 * 0.01 and abs(inertial[0, 0, 0]) > 1e-3 * 0.01


def test_fingers_placed_near_their_cones_edge_hold(monkeypatch):
    # The certified gait's third window along the paper's axis places a finger; perturbed to
    # stay 0.05 deg inside the limit, its freshly placed tip slid (up to 1.1e-3 L/s) before
    # the tips' inertia was fed forward.
    solution = solve_gait(trajectory=PAPER_TURN)
    window = gait_windows(solution.optimal.contacts)[2]
    case = gait_window_case(solution, window)
    target = solution.scene.friction_limit - np.radians(0.05)
    grips = [perturbed_gait(case, target, np.random.default_rng(seed)) for seed in (1, 2, 3)]
    reports = check_cases([dataclasses.replace(case, forces=forces) for forces in grips])
    for report in reports:
        contact = report.motion.contact[report.motion.settle_steps :]
        assert (contact[1:] & ~contact[:-1]).any()  # a finger is placed on the way
        assert report.margin_deg == pytest.approx(0.05, abs=1e-6)
        assert report.predicted_holds and report.holds, report.as_dict()
        assert report.trace.speed.max() < SETTINGS["slip_speed"]


@pytest.mark.parametrize("threads", [0, -1, 2.5, "2", True, np.float64(2.0)])
def test_threads_are_refused_when_a_checker_is_made_and_per_call(paper, threads):
    scene, rotations, forces = paper
    match = r"threads must be >= 1, an integer \(or None: every available core\), got"
    for checker in (StabilityChecker, TrajectoryChecker):
        with pytest.raises(ValueError, match=match):
            checker(scene, threads=threads)
    with pytest.raises(ValueError, match=match):
        StabilityChecker(scene).check_batch(rotations[:1], forces[:1], threads=threads)
    with pytest.raises(ValueError, match=match):
        TrajectoryChecker(scene).check_batch([(rotations[:2], forces[:2], None)], threads=threads)
    with pytest.raises(ValueError, match=match):
        check_poses([(scene, rotations[0], forces[0], None)], threads=threads)
    with pytest.raises(ValueError, match=match):
        check_trajectories([(scene, rotations[:2], forces[:2], None)], threads=threads)
    assert StabilityChecker(scene, threads=np.int64(1)).threads == 1


@pytest.mark.fast
def test_empty_and_malformed_batches_say_what_is_wrong(paper):
    scene, rotations, forces = paper
    at_least_one = r"rotations must hold at least one pose: .* got shape \(0, 3, 3\)"
    with pytest.raises(ValueError, match=at_least_one):
        StabilityChecker(scene).check_batch(rotations[:0], forces[:0])
    with pytest.raises(ValueError, match=at_least_one):
        TrajectoryChecker(scene).check(rotations[:0], forces[:0])
    with pytest.raises(ValueError, match=at_least_one):
        check_trajectories([(scene, rotations[:0], forces[:0], None)])
    # no case, no report (a vector env checks the trajectories of the episodes that ended)
    assert check_poses([]) == [] and check_trajectories([]) == []
    assert TrajectoryChecker(scene).check_batch([]) == []
    for cases, match in (
        ([(None, rotations[:2], forces[:2], None)], "case 0's scene must be a grasp_env"),
        ([(scene, rotations[:2])], r"case 0 must be a \(scene, rotations, contact_forces, in_"),
        ((scene, rotations[:2], forces[:2], None), "case 0 must be .* got a Scene"),  # no list
        (5, "cases must be a list of"),
    ):
        with pytest.raises(ValueError, match=match):
            check_trajectories(cases)
    with pytest.raises(ValueError, match=r"case 0's rotation must be a \(3, 3\) matrix"):
        check_poses([(scene, rotations[:2], forces[:2], None)])
    with pytest.raises(ValueError, match="case 1's scene must be"):
        check_poses(
            [(scene, rotations[0], forces[0], None), ("paper", rotations[0], forces[0], None)]
        )
    with pytest.raises(ValueError, match=r"grip 0 must be a \(rotations, contact_forces, in_c"):
        TrajectoryChecker(scene).check_batch([(rotations[:2], forces[:2])])
    with pytest.raises(ValueError, match="got dtype <U"):
        StabilityChecker(scene).check(rotations[0].astype(str), forces[0])
    with pytest.raises(ValueError, match=r"contact_forces must be finite real numbers .* dtype <U"):
        StabilityChecker(scene).check(rotations[0], forces[0].astype(str))


@pytest.mark.parametrize("value", ["0.2", True, None, [0.2]])
@pytest.mark.fast
def test_settings_are_real_numbers(value):
    with pytest.raises(ValueError, match="hold_time must be a finite number > 0, got"):
        StabilityChecker(Scene(), hold_time=value)
