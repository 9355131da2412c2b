"""The can's gait in one continuous MuJoCo rollout (grasp_env.physics.can_gait)."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_env.mechanics import Scene
from grasp_env.mechanics.gait.can_programme import solve_can_gait
from grasp_env.physics import can_gait_schedule, check_can_gait
from grasp_env.physics.gait import check_gait

#: Poses [0, 8) of the default full turn: seven placements, two lifts (poses 3 and 6) and
#: three placements (poses 2, 5 and 7).
WINDOW = (0, 8)


@pytest.fixture(scope="module")
def solution():
    return solve_can_gait()


def test_window_with_lifts_and_placements_holds(solution) -> None:
    events = [e for e in solution.optimal.events() if WINDOW[0] <= e[0] < WINDOW[1]]
    assert {kind for _, kind, _ in events} == {"in", "out"}
    rollout = check_can_gait(solution, start=WINDOW[0], stop=WINDOW[1])
    report = rollout.report
    assert report.holds and report.predicted_holds
    assert report.first_failure is None and report.predicted_first_failure is None
    # the optimal gait's margin over the window is no smaller than its bottleneck
    assert report.margin_deg >= np.degrees(solution.optimal.margin) - 1e-6
    assert np.nanmax(report.slip) < 1e-5 * solution.can.height


def test_sites_turn_with_the_can(solution) -> None:
    s = can_gait_schedule(solution, start=WINDOW[0], stop=WINDOW[1])
    assert len(s.sites) == 7
    # every site on the side of the can, at its radius
    radius = np.hypot(s.sites[:, 0], s.sites[:, 1])
    np.testing.assert_allclose(radius, solution.can.radius, rtol=0, atol=1e-12)
    # the forces balance the weight at every pose (to 1e-9 w)
    total = np.nansum(s.finger_forces, axis=1)
    np.testing.assert_allclose(total[:, 2], solution.weight, rtol=0, atol=1e-9 * solution.weight)


def test_a_grip_outside_its_cone_fails_at_its_pose(solution) -> None:
    s = can_gait_schedule(solution, start=WINDOW[0], stop=WINDOW[1])
    forces = s.finger_forces.copy()
    bad = 5  # from pose 5 on, one loaded finger pushes 20 deg outside its cone
    f = int(
        np.flatnonzero(
            np.isfinite(forces[bad, :, 0])
            & (np.linalg.norm(np.nan_to_num(forces[bad]), axis=1) > 0)
        )[0]
    )
    scene = Scene(shape=solution.can, contacts=s.sites, weight=solution.weight, mu=solution.mu)
    normal = scene.normals[s.contacts[bad, f]]
    for t in range(bad, len(forces)):
        world_n = s.rotations[t] @ normal
        p = forces[t, f]
        n_part = (p @ world_n) * world_n
        tangent = p - n_part
        tangent /= np.linalg.norm(tangent)
        angle = np.arctan(solution.mu) + np.radians(20.0)
        forces[t, f] = n_part + np.linalg.norm(n_part) * np.tan(angle) * tangent
    report = check_gait(scene, s.rotations, s.contacts, forces).report
    assert not report.holds and not report.predicted_holds
    assert bad - 1 < report.predicted_first_failure <= bad
    assert bad - 1 < report.first_failure <= bad + 1


def test_bad_input(solution) -> None:
    with pytest.raises(ValueError, match="CanGaitSolution"):
        check_can_gait("gait")
    with pytest.raises(ValueError, match="at least two poses"):
        check_can_gait(solution, start=3, stop=4)
    with pytest.raises(ValueError, match="integer pose index"):
        check_can_gait(solution, start=0.5)
    with pytest.raises(ValueError, match="place 16 contacts"):
        check_can_gait(solution)
    with pytest.raises(ValueError, match="must be an integer"):
        check_can_gait(solution, stop=True)


def test_gait_command_mujoco_and_video(tmp_path, capsys) -> None:
    from grasp_env_agents.cli import main

    out, video = tmp_path / "can", tmp_path / "can.mp4"
    argv = ["gait", "--object", "can", "--reach", "30", "--alpha-end", "60", "--no-plots"]
    assert main([*argv, "--out", str(out), "--video", str(video)]) == 0
    printed = capsys.readouterr().out
    assert "MuJoCo, alpha 0 to" in printed and ": holds; analytic: holds;" in printed
    assert video.stat().st_size > 10_000
    assert main([*argv, "--out", str(out), "--video", str(tmp_path / "can.avi")]) == 2
    assert "name it FILE.mp4" in capsys.readouterr().err
    assert main([*argv, "--out", str(out), "--mujoco-window", "0"]) == 2
    assert "two pose indices START,STOP" in capsys.readouterr().err
