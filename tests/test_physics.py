"""The MuJoCo check agrees with the analytic friction cone; resets exactly; rejects bad input."""

from __future__ import annotations

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
    n_pairs,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)
from grasp_env.physics import SETTINGS, PhysicsReport, StabilityChecker
from grasp_env.physics.agreement import ForceSet, force_set_k, summarise
from grasp_env.physics.model import pose_qpos
from grasp_env_agents.cli import main

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


@pytest.mark.parametrize("name", EDGE_SCENES)
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


def test_paper_optimal_forces_hold_along_the_trajectory():
    # With mu = 0.05 (2.9 deg) the paper's optimum (zero friction angle at every pose, DESIGN.md
    # §1) still holds everywhere, while its equal-k grip (eq. 8) slips at the trajectory's ends:
    # the check tells the two apart.
    scene = Scene(mu=0.05)
    trajectory = Trajectory()
    rotations = trajectory.rotations()
    grasp = scene_grasp(scene, rotations)
    optimum = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    equal_k = grasp.forces(scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(n_pairs(3)))
    checker = StabilityChecker(scene)
    optimal_reports = [checker.check(r, f) for r, f in zip(rotations, optimum, strict=True)]
    ends = [0, len(trajectory) - 1]
    equal_k_reports = [checker.check(rotations[t], equal_k[t]) for t in ends]
    checker.close()
    assert all(r.holds for r in optimal_reports), [r.as_dict() for r in optimal_reports]
    assert max(r.slip.max() for r in optimal_reports) < 0.1 * SETTINGS["slip_threshold"]
    assert max(r.drift for r in optimal_reports) < 1e-4
    assert not any(r.holds for r in equal_k_reports)


def _state(checker: StabilityChecker) -> dict:
    """Every array of MuJoCo's data, its scalar counters, and the model's contact friction."""
    data = checker.data
    state = {}
    for name in dir(data):
        if not name.startswith("_"):
            value = getattr(data, name)
            if isinstance(value, np.ndarray):
                state[name] = value.copy()
    state.update(time=data.time, ncon=data.ncon, nefc=data.nefc)
    state["pair_friction"] = checker.model.pair_friction.copy()
    return state


def test_reset_restores_the_state_exactly(paper_checker):
    fresh = _state(paper_checker)
    rotation, forces = forces_at_angle(paper_checker.scene, 3.0, 30.0)  # slips: state moves
    report = paper_checker.check(rotation, forces)
    assert not report.holds
    moved = _state(paper_checker)
    assert not np.array_equal(moved["qpos"], fresh["qpos"])
    paper_checker.reset()
    after = _state(paper_checker)
    assert after.keys() == fresh.keys()
    for name, value in fresh.items():
        assert np.array_equal(after[name], value, equal_nan=True), name


def test_same_input_same_report_whatever_came_before(paper_checker):
    hold = forces_at_angle(paper_checker.scene, -4.0, 10.0)
    slip = forces_at_angle(paper_checker.scene, 7.0, 25.0, seed=1)
    first = paper_checker.check(*hold)
    paper_checker.check(*slip)
    again = paper_checker.check(*hold)
    assert first.holds
    assert first.as_dict() == again.as_dict()


def test_report_is_plain_data(paper_checker):
    report = paper_checker.check(*forces_at_angle(paper_checker.scene, 0.0, 5.0))
    assert isinstance(report, PhysicsReport)
    as_dict = report.as_dict()
    assert json.loads(json.dumps(as_dict)) == as_dict
    assert set(as_dict) >= {"holds", "slip", "contact_lost", "drift", "rotation_deg"}
    assert len(as_dict["slip"]) == len(as_dict["contact_lost"]) == 3


def test_pulling_finger_loses_contact(paper_checker):
    scene = paper_checker.scene
    grasp = scene_grasp(scene, START_ROTATION)
    # k = -w: the pairs pull apart, every finger's force points out of its face (> 90 deg).
    k = -scene.weight * np.ones(3)
    assert np.all(np.degrees(grasp.angles(k)) > 90)
    report = paper_checker.check(START_ROTATION, grasp.forces(k))
    assert not report.holds
    assert report.contact_lost.all()


def test_unbalanced_forces_do_not_hold(paper_checker):
    # 1.5 x a holding set: the same friction angles, but 50% more lift than the weight.
    rotation, forces = forces_at_angle(paper_checker.scene, 2.0, 5.0)
    report = paper_checker.check(rotation, 1.5 * forces)
    assert report.slip.max() < SETTINGS["slip_threshold"]
    assert report.drift > SETTINGS["drift_threshold"]
    assert not report.holds


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
def test_bad_inputs_raise_clear_errors(paper_checker, rotation, forces, message):
    with pytest.raises(ValueError, match=message):
        paper_checker.check(rotation, forces)


def test_bad_settings_raise_clear_errors():
    with pytest.raises(ValueError, match="unknown StabilityChecker settings"):
        StabilityChecker(Scene(), hold=1.0)
    with pytest.raises(ValueError, match="hold_time must be a finite number > 0"):
        StabilityChecker(Scene(), hold_time=-1.0)
    with pytest.raises(ValueError, match="scene must be"):
        StabilityChecker("paper")  # type: ignore[arg-type]


def test_closed_checker_refuses_to_check():
    checker = StabilityChecker(Scene())
    checker.close()
    with pytest.raises(ValueError, match="closed"):
        checker.check(START_ROTATION, np.zeros((3, 3)))


def test_model_carries_the_scene():
    scene = Scene.on_faces(
        PAPER_FACES, size=(1.0, 0.8, 0.6), weight=7.0, mu=0.4, cg_offset=(0.1, 0.0, -0.05)
    )
    checker = StabilityChecker(scene)
    model = checker.model
    body = model.body("object")
    assert model.body_mass[body.id] * -model.opt.gravity[2] == pytest.approx(7.0)
    np.testing.assert_allclose(model.body_ipos[body.id], scene.cg_offset)
    np.testing.assert_allclose(model.geom("box").size, np.array([1.0, 0.8, 0.6]) / 2)
    np.testing.assert_allclose(model.pair_friction[:, :2], 0.4)
    assert model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert model.opt.jacobian == mujoco.mjtJacobian.mjJAC_DENSE
    # The pose: the centre of gravity at the origin, each fingertip touching its contact point
    # from outside, along the contact's normal (so MuJoCo's contact is the analytic one).
    rotation = pose_rotation(PAPER_AXIS, np.radians(9.0))
    data = checker.data
    data.qpos[:] = pose_qpos(scene, rotation)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.xipos[body.id], 0.0, atol=1e-12)
    grasp = scene_grasp(scene, rotation)
    for i in range(3):
        tip = data.xpos[model.body(f"finger{i}").id]
        offset = tip - grasp.positions[i]
        np.testing.assert_allclose(np.cross(offset, grasp.normals[i]), 0.0, atol=1e-12)
        assert 0 < -offset @ grasp.normals[i] < model.geom(f"tip{i}").size[0]
    assert data.ncon == 3
    checker.close()


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


def test_verify_rejects_a_missing_model(tmp_path, capsys):
    status = main(["verify", "--policy", str(tmp_path / "none.zip"), "--out", str(tmp_path)])
    assert status == 2
    assert "is not a file" in capsys.readouterr().err
