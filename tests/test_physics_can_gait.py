"""The can's gait in one continuous MuJoCo rollout (grasp_env.physics.can_gait), one tip per
finger whose contact point changes at each placement (grasp_env.physics.gait.check_finger_gait)."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_env.mechanics import Scene
from grasp_env.mechanics.forces import grasp_matrix
from grasp_env.mechanics.gait.can_programme import solve_can_gait
from grasp_env.physics import can_gait_schedule, check_can_gait
from grasp_env.physics.gait import check_finger_gait, check_gait, first_points

#: Poses [0, 8) of the default full turn: seven placements, two lifts (poses 3 and 6) and
#: three placements (poses 2, 5 and 7), few enough for one tip per placement.
WINDOW = (0, 8)


@pytest.fixture(scope="module")
def solution():
    return solve_can_gait()


@pytest.fixture(scope="module")
def schedule(solution):
    return can_gait_schedule(solution)


def _scene(solution, contacts) -> Scene:
    return Scene(shape=solution.can, contacts=contacts, weight=solution.weight, mu=solution.mu)


def test_the_whole_turn_holds_in_one_rollout(solution, schedule) -> None:
    # the full turn places 16 times, twice the tips a model of one tip per placement can have
    assert len(schedule.sites) == 16 and len(schedule.rotations) == 37
    kinds = {kind for _, kind, _ in solution.optimal.events()}
    assert kinds == {"in", "out"} and solution.optimal.changes == 25
    rollout = check_can_gait(solution)
    report = rollout.report
    assert report.holds and report.predicted_holds
    assert report.first_failure is None and report.predicted_first_failure is None
    assert report.pose_holds.all() and report.pose_predicted.all()
    # the margin over every step is the certified bottleneck (8.893 deg), to 1e-6 deg
    assert report.margin_deg == pytest.approx(np.degrees(solution.optimal.margin), abs=1e-6)
    assert np.nanmax(report.slip) < 1e-5 * solution.can.height
    assert report.drift.max() < 1e-4 * solution.can.height
    # five tips, each placed on its finger's successive points: a tip in contact touches its
    # placement's point (pressed in by at most 2 % of the can's height, the soft contact)
    motion, trace = report.motion, report.trace
    assert trace.qpos.shape[1] == 7 + 3 * 5
    for f in range(5):
        placed = np.unique(motion.points[motion.contact[:, f], f], axis=0)
        assert len(placed) >= 3  # placed again at least twice, each on a new point
    assert np.all(np.abs(trace.gap[trace.measured]) < 0.02)
    # the tips lift and are placed where the gait unloads and loads its fingers
    loaded = solution.optimal.loaded
    lifts, places = (
        motion.contact[:-1] & ~motion.contact[1:],
        ~motion.contact[:-1] & motion.contact[1:],
    )
    assert lifts.sum() == np.sum(loaded[:-1] & ~loaded[1:]) == 13
    assert places.sum() == np.sum(~loaded[:-1] & loaded[1:]) == 12


def test_one_tip_per_finger_is_one_tip_per_site(solution) -> None:
    s = can_gait_schedule(solution, start=WINDOW[0], stop=WINDOW[1])
    sites = check_gait(_scene(solution, s.sites), s.rotations, s.contacts, s.finger_forces)
    fingers = check_can_gait(solution, start=WINDOW[0], stop=WINDOW[1])
    assert sites.report.holds and fingers.report.holds
    np.testing.assert_allclose(
        fingers.report.max_angle_deg, sites.report.max_angle_deg, rtol=0, atol=1e-9
    )
    assert np.nanmax(fingers.report.slip) == pytest.approx(np.nanmax(sites.report.slip), rel=1e-6)
    assert fingers.report.drift.max() == pytest.approx(sites.report.drift.max(), rel=1e-6)


def test_sites_turn_with_the_can(solution, schedule) -> None:
    s = schedule
    radius = np.hypot(s.sites[:, 0], s.sites[:, 1])
    np.testing.assert_allclose(radius, solution.can.radius, rtol=0, atol=1e-12)
    points = s.points
    np.testing.assert_array_equal(np.isnan(points[..., 0]), s.contacts < 0)
    # the forces balance the weight at every pose (to 1e-9 w)
    total = np.nansum(s.finger_forces, axis=1)
    np.testing.assert_allclose(total[:, 2], solution.weight, rtol=0, atol=1e-9 * solution.weight)


def _scaled(schedule, weight: float, start: int, scale: float) -> np.ndarray:
    """The schedule's forces with every loaded finger's interaction part (the force beyond the
    equilibrating one, in G's null space: eq. 1) scaled by ``scale`` from pose ``start`` on."""
    forces = schedule.finger_forces.copy()
    for t in range(start, len(forces)):
        loaded = np.flatnonzero(np.linalg.norm(np.nan_to_num(forces[t]), axis=1) > 0)
        arms = (schedule.points[t, loaded]) @ schedule.rotations[t].T
        pinv = np.linalg.pinv(grasp_matrix(arms))
        equilibrating = (pinv @ np.array([0.0, 0.0, weight, 0.0, 0.0, 0.0])).reshape(-1, 3)
        forces[t, loaded] = equilibrating + scale * (forces[t, loaded] - equilibrating)
    return forces


def test_a_grip_scaled_out_of_its_cones_fails_at_its_pose(solution, schedule) -> None:
    bad = 25  # after 13 of the 16 placements; from here on the squeeze is halved
    forces = _scaled(schedule, solution.weight, bad, 0.5)
    np.testing.assert_allclose(np.nansum(forces, axis=1)[:, 2], solution.weight, atol=1e-9)
    scene = _scene(solution, first_points(schedule.points))
    report = check_finger_gait(scene, schedule.rotations, schedule.points, forces).report
    assert not report.holds and not report.predicted_holds
    # the grip is halved along the segment before pose ``bad`` (where a finger is placed,
    # loaded from ``bad``): it leaves its cones there
    assert (
        report.pose_predicted[: bad - 1].all()
        and not report.pose_predicted[bad - 1 : bad + 1].any()
    )
    assert report.max_angle_deg[bad] > np.degrees(solution.friction_limit) + 1.0
    assert bad - 1 < report.predicted_first_failure <= bad
    assert bad - 1 < report.first_failure <= bad + 1
    # the same grip scaled the other way (a firmer squeeze) still holds in both verdicts
    firmer = _scaled(schedule, solution.weight, bad, 1.5)
    report = check_finger_gait(scene, schedule.rotations, schedule.points, firmer).report
    assert report.holds and report.predicted_holds


def test_bad_input(solution, schedule) -> None:
    with pytest.raises(ValueError, match="CanGaitSolution"):
        check_can_gait("gait")
    with pytest.raises(ValueError, match="at least two poses"):
        check_can_gait(solution, start=3, stop=4)
    with pytest.raises(ValueError, match="integer pose index"):
        check_can_gait(solution, start=0.5)
    with pytest.raises(ValueError, match="must be an integer"):
        check_can_gait(solution, stop=True)
    with pytest.raises(ValueError, match="finger 0 never touches"):
        check_can_gait(solution, start=0, stop=2)  # finger 0 is first placed at pose 2
    s, points = schedule, schedule.points
    scene = _scene(solution, first_points(points))
    with pytest.raises(ValueError, match=r"points must be real numbers of shape \(37, 5, 3\)"):
        check_finger_gait(scene, s.rotations, points[:, :4], s.finger_forces)
    off = points.copy()
    off[10, 1] *= 1.01  # off the side
    with pytest.raises(ValueError, match="off the cylinder"):
        check_finger_gait(scene, s.rotations, off, s.finger_forces)
    moved = points.copy()
    moved[12:28, 0] = solution.can.side_point(np.radians(200.0), 0.0)  # under load, elsewhere
    with pytest.raises(ValueError, match="tip 0 changes its point between poses 11 and 12"):
        check_finger_gait(scene, s.rotations, moved, s.finger_forces)


def test_gait_command_mujoco_and_video(tmp_path, capsys) -> None:
    from grasp_env_agents.cli import main

    out, video = tmp_path / "can", tmp_path / "can.mp4"
    argv = ["gait", "--object", "can", "--reach", "30", "--alpha-end", "60", "--no-plots"]
    assert main([*argv, "--out", str(out), "--video", str(video)]) == 0
    printed = capsys.readouterr().out
    assert "MuJoCo, alpha 0 to 60 deg" in printed and ": holds; analytic: holds;" in printed
    assert video.stat().st_size > 10_000
    assert main([*argv, "--out", str(out), "--video", str(tmp_path / "can.avi")]) == 2
    assert "name it FILE.mp4" in capsys.readouterr().err
    assert main([*argv, "--out", str(out), "--mujoco-window", "0"]) == 2
    assert "two pose indices START,STOP" in capsys.readouterr().err
