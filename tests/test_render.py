"""Offscreen rendering draws the grasp: not blank, pose-dependent, slip shown in colour.

Runs headless: ``grasp_env.physics`` picks MUJOCO_GL (OSMesa or EGL) before MuJoCo loads when
no display is set; CI installs libosmesa6 for it.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from grasp_env.mechanics import PAPER_AXIS, Scene, pose_rotation, scene_grasp, solve_minimax
from grasp_env.physics import GraspView
from grasp_env.physics.render import slip_colour

SCENE = Scene.on_faces(offsets=[[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]])  # mu = 0.5, 26.57 deg


@pytest.fixture(scope="module")
def view():
    view = GraspView(SCENE, width=320, height=240)
    yield view
    view.close()


def pose(alpha_deg: float):
    rotation = pose_rotation(PAPER_AXIS, np.radians(alpha_deg))
    return rotation, scene_grasp(SCENE, rotation)


def optimal_forces(alpha_deg: float):
    rotation, grasp = pose(alpha_deg)
    return rotation, grasp.forces(solve_minimax(grasp, 2 * SCENE.weight).k)  # 6 to 7 deg


def red_pixels(image: np.ndarray) -> int:
    r, g, b = (image[..., c].astype(int) for c in range(3))
    return int(np.sum((r > 150) & (g < 90) & (b < 90)))


def green_pixels(image: np.ndarray) -> int:
    r, g, b = (image[..., c].astype(int) for c in range(3))
    return int(np.sum((g > 120) & (r < 120) & (b < 120)))


def test_picture_is_not_blank(view):
    image = view.render(*optimal_forces(0.0))
    assert image.shape == (240, 320, 3)
    assert image.dtype == np.uint8
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 200
    # The translucent blue box fills the middle of the picture: blue dominates there.
    middle = image[80:160, 110:210].astype(int)
    assert np.mean(middle[..., 2] - middle[..., 0]) > 40
    assert green_pixels(image) > 100  # the friction cones of a safe grip


def test_picture_follows_the_pose(view):
    first = view.render(*optimal_forces(-15.0)).astype(int)
    second = view.render(*optimal_forces(15.0)).astype(int)
    changed = np.any(np.abs(first - second) > 30, axis=-1)
    assert changed.mean() > 0.02


def test_slipping_finger_is_drawn_red(view):
    rotation, grasp = pose(8.0)
    k = np.array([2.79471, 3.95029, 0.49405])  # angles 22.6, 7.8 and 30.1 deg: finger 3 slips
    angles = np.degrees(grasp.angles(k))
    assert angles[2] > np.degrees(SCENE.friction_limit) > angles[0] > angles[1]
    slipping = view.render(rotation, grasp.forces(k))
    safe = view.render(*optimal_forces(8.0))
    assert red_pixels(safe) == 0
    assert red_pixels(slipping) > 200


def test_slip_colour_scale():
    np.testing.assert_allclose(slip_colour(0.0), [0.15, 0.75, 0.2])
    np.testing.assert_allclose(slip_colour(1.0), [0.9, 0.1, 0.1])
    np.testing.assert_allclose(slip_colour(3.0), slip_colour(1.0))
    redness = [slip_colour(r)[0] - slip_colour(r)[1] for r in np.linspace(0, 1, 21)]
    assert np.all(np.diff(redness) > 0)  # redder as the finger nears its limit


def test_bad_arguments_raise_clear_errors(view):
    rotation, forces = optimal_forces(0.0)
    with pytest.raises(ValueError, match="render_mode must be one of"):
        GraspView(SCENE, render_mode="ansi")
    with pytest.raises(ValueError, match=r"width must be an integer in \[16, 4096\]"):
        GraspView(SCENE, width=0)
    with pytest.raises(ValueError, match="finite"):
        view.render(rotation, np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        view.render(rotation, forces[:2])
    for text in (5, "one line", [1.5]):
        with pytest.raises(ValueError, match="text must be a sequence of strings"):
            view.render(rotation, forces, text=text)
    # refused, not cast to bool (as the physics' checks refuse them): "no" is truthy
    for in_contact in (["no", "no", "no"], [0.5, 0, 2], [1, 1, 0], [True, False], [[True]] * 3):
        with pytest.raises(ValueError, match=r"in_contact must be a boolean array of shape \(3,\)"):
            view.render(rotation, forces, in_contact=in_contact)
    assert view.render(rotation, forces, in_contact=np.array([True, True, True])) is not None


def test_render_state_checks_its_inputs(view):
    """The lower-level entry (the continuous rollout's video draws through it) refuses what
    MuJoCo would take silently or fail on deep inside: a wrong qpos, a NaN force."""
    rotation, forces = optimal_forces(0.0)
    view.render(rotation, forces)  # builds the model
    qpos = view.data.qpos.copy()
    contact = np.ones(3, dtype=bool)
    w = SCENE.weight
    assert view.render_state(qpos, rotation, forces / w, contact) is not None
    cases = [
        ((qpos[:-1], rotation, forces / w, contact), rf"qpos must have shape \({qpos.size},\)"),
        ((np.full_like(qpos, np.nan), rotation, forces / w, contact), "qpos must be finite"),
        ((qpos, np.eye(2), forces / w, contact), r"rotation must be a \(3, 3\) matrix"),
        ((qpos, rotation, np.full((3, 3), np.inf), contact), "forces must be finite"),
        ((qpos, rotation, forces / w, [1, 1, 1]), r"contact must be a boolean array of shape"),
    ]
    for args, message in cases:
        with pytest.raises(ValueError, match=message):
            view.render_state(*args)
    with pytest.raises(ValueError, match="text must be a sequence of strings"):
        view.render_state(qpos, rotation, forces / w, contact, text="one line")


def test_closed_view_refuses_to_render():
    view = GraspView(SCENE, width=64, height=64)
    rotation, forces = optimal_forces(0.0)
    assert view.render(rotation, forces).shape == (64, 64, 3)
    view.close()
    with pytest.raises(ValueError, match="closed"):
        view.render(rotation, forces)


# No view is freed before exit: freeing one first would load the PyOpenGL handler that
# OSMesa's free needs, and hide the failure at shutdown.
UNCLOSED = """
import numpy as np
from grasp_env.mechanics import START_ROTATION, Scene
from grasp_env.physics import GraspView

view = GraspView(Scene(), width=32, height=32)  # never closed: freed at exit
print(view.render(START_ROTATION, np.zeros((3, 3))).shape)
"""


def test_a_view_never_closed_exits_cleanly():
    # Without the view freeing its renderer before interpreter shutdown, OSMesa's free fails
    # there and prints "Exception ignored in: <function Renderer.__del__ ...>" on stderr.
    result = subprocess.run(
        [sys.executable, "-c", UNCLOSED], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout == "(32, 32, 3)\n"
    assert result.stderr == ""
