"""A finger gait on a cylinder in one continuous MuJoCo rollout (grasp_env.physics.gait):
fingers phased out leave their sites, fingers phased in are placed at their new ones, and
the verdicts follow the margin (docs/physics.md, "Gaits")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from grasp_env.mechanics import (
    START_ROTATION,
    Cylinder,
    Scene,
    axis_angle_matrix,
    scene_grasp,
    solve_minimax,
)
from grasp_env.physics.gait import check_gait, site_schedule

CAN = Cylinder(radius=0.033, height=0.115)
SITES = np.array(
    [CAN.side_point(0.0, 0.2), CAN.side_point(2.1, -0.3), CAN.side_point(4.2, 0.1),
     CAN.cap_point("-z", (0.1, -0.2)), CAN.side_point(1.0, 0.5)]
)  # fmt: skip
T = 9


def can_gait() -> tuple[Scene, np.ndarray, np.ndarray, np.ndarray, float]:
    """Four fingers on the can's five sites along 9 poses (-8 to 8 deg about (1, -1, 0)):
    fingers 1 and 2 hold sites 1 and 2 throughout; finger 3 is phased in on site 3 at pose 2
    (touching with zero force there); finger 0 holds site 0, is phased out at pose 5 (zero
    force, gone from pose 6) and phased in on site 4 at pose 7. Each pose's loaded fingers
    push with the certified minimax optimum of their sites. Returns the scene (one contact per
    site), the poses, the fingers' sites and forces, and the largest friction angle."""
    scene = Scene(
        shape=CAN, contacts=SITES, weight=0.35 * 9.81, mu=1.0, cg_offset=(0.002, -0.001, 0.004)
    )
    axis = np.broadcast_to(np.array([1.0, -1.0, 0.0]) / np.sqrt(2), (T, 3))
    rotations = axis_angle_matrix(axis, np.radians(np.linspace(-8, 8, T))) @ START_ROTATION
    contacts = np.full((T, 4), -1)
    contacts[:, 1], contacts[:, 2] = 1, 2
    contacts[:6, 0], contacts[7:, 0], contacts[2:, 3] = 0, 4, 3
    loaded = contacts >= 0
    loaded[2, 3] = loaded[5, 0] = loaded[7, 0] = False  # placed, lifted, placed: zero force
    forces = np.zeros((T, 4, 3))
    largest = 0.0
    for t in range(T):
        fingers = np.flatnonzero(loaded[t])
        held = dataclasses.replace(scene, contacts=SITES[contacts[t, fingers]], size=None)
        grasp = scene_grasp(held, rotations[t])
        optimum = solve_minimax(grasp, 3 * scene.weight)
        forces[t, fingers] = grasp.forces(optimum.k)
        largest = max(largest, float(optimum.max_angle))
    return scene, rotations, contacts, forces, largest


@pytest.fixture(scope="module")
def gait():
    return can_gait()


def test_the_site_schedule_follows_the_fingers(gait):
    scene, _, contacts, forces, _ = gait
    site_forces, in_contact = site_schedule(contacts, forces, scene.n_contacts)
    assert in_contact[:, 1].all() and in_contact[:, 2].all()
    np.testing.assert_array_equal(in_contact[:, 0], np.arange(T) <= 5)
    np.testing.assert_array_equal(in_contact[:, 3], np.arange(T) >= 2)
    np.testing.assert_array_equal(in_contact[:, 4], np.arange(T) >= 7)
    np.testing.assert_array_equal(site_forces[6, 0], 0.0)  # lifted: no finger, no force
    np.testing.assert_array_equal(site_forces[8, 4], forces[8, 0])  # finger 0 on site 4


def test_a_can_gait_inside_its_cones_holds_in_one_rollout_with_fingers_lifted_and_placed(gait):
    scene, rotations, contacts, forces, largest = gait
    inside = dataclasses.replace(scene, mu=float(np.tan(largest + np.radians(2.0))))
    rollout = check_gait(inside, rotations, contacts, forces)
    report = rollout.report
    assert report.holds and report.predicted_holds
    assert report.margin_deg == pytest.approx(2.0, abs=0.05)  # the steps between poses too
    measured = report.trace.measured
    settle = report.motion.settle_steps
    pose = report.motion.pose
    # site 0's tip touches at the start and is parked from pose 6 on (earlier where the
    # four-finger optimum releases it: a force under released_force lifts the tip); sites 3
    # and 4 are placed as their forces ramp up from zero after poses 2 and 7, and touch to the end
    assert measured[settle, 0] and not measured[pose >= 6][:, 0].any()
    assert not measured[pose <= 2][:, 3].any() and measured[-1, 3]
    assert not measured[pose <= 7][:, 4].any() and measured[-1, 4]
    assert report.slip.max() < 1e-5 * 0.115  # every tip within the slip threshold (1e-5 L)


def test_a_can_gait_outside_its_cones_slips_where_the_analytic_verdict_fails(gait):
    scene, rotations, contacts, forces, largest = gait
    outside = dataclasses.replace(scene, mu=float(np.tan(largest - np.radians(2.0))))
    report = check_gait(outside, rotations, contacts, forces).report
    assert not report.holds and not report.predicted_holds
    assert report.first_failure == pytest.approx(report.predicted_first_failure, abs=0.5)


def test_gaits_name_bad_schedules(gait):
    scene, rotations, contacts, forces, _ = gait
    twice = contacts.copy()
    twice[4, 3] = 1
    with pytest.raises(ValueError, match="fingers 1 and 3 both touch site 1 at pose 4"):
        check_gait(scene, rotations, twice, forces)
    beyond = contacts.copy()
    beyond[0, 0] = 5
    with pytest.raises(ValueError, match=r"site index must be in \[-1, 4\]"):
        site_schedule(beyond, forces, 5)
    missing = forces.copy()
    missing[3, 1] = np.nan
    with pytest.raises(ValueError, match="finger 1 touches site 1 at pose 3 but its force"):
        site_schedule(contacts, missing, 5)
    with pytest.raises(ValueError, match="integers"):
        site_schedule(contacts.astype(float), forces, 5)
    with pytest.raises(ValueError, match="finger_forces must be real numbers of shape"):
        site_schedule(contacts, forces[:, :3], 5)
    with pytest.raises(ValueError, match="rotations 8"):
        check_gait(scene, rotations[:-1], contacts, forces)
    with pytest.raises(ValueError, match=r"scene must be a grasp_env\.mechanics\.Scene"):
        check_gait("can", rotations, contacts, forces)
    # a finger's NaN force where it touches nothing is ignored (a gait solution's rows)
    spare = forces.copy()
    spare[6, 0] = np.nan
    site_forces, _ = site_schedule(contacts, spare, 5)
    assert np.isfinite(site_forces).all()
