"""Finger gaits: the hand's reach and the object's sites (docs/gait.md, "The hand and its
reach", "Sites")."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_env.mechanics import (
    PAPER_TURN,
    START_ROTATION,
    GaitScene,
    Hand,
    Trajectory,
    solve_gait,
)
from grasp_env.mechanics.gait import REACH_TOL, cone_reach
from grasp_env.mechanics.hand import FINGER_ELEVATION_DEG

# ------------------------------------------------------------------------------ the hand


def test_default_hand():
    hand = Hand()
    assert hand.n_fingers == 5
    assert hand.names == ("finger1", "finger2", "finger3", "finger4", "thumb")
    a = hand.approach
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0)
    np.testing.assert_allclose(a[-1], [0, 0, -1])  # the thumb pushes straight down
    np.testing.assert_allclose(np.rad2deg(np.arcsin(a[:4, 2])), FINGER_ELEVATION_DEG)
    np.testing.assert_allclose(FINGER_ELEVATION_DEG, 35.26439, atol=1e-5)
    # at the start pose finger 1 pushes exactly along the corner face -x's inward normal
    np.testing.assert_allclose(START_ROTATION @ [1.0, 0.0, 0.0], a[0], atol=1e-12)


@pytest.mark.parametrize("cone", [10.0, 60.0, 120.0])
def test_reach_is_the_cone_of_normals(cone):
    hand = Hand(finger_azimuths_deg=(30.0,), finger_elevation_deg=20.0, thumb=False, cone_deg=cone)
    a = hand.approach[0]
    # normals at angles cone - 0.01 and cone + 0.01 deg from the approach, about any axis
    rng = np.random.default_rng(0)
    side = np.cross(a, rng.normal(size=(50, 3)))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    for delta, inside in ((-0.01, True), (0.01, False)):
        angle = np.deg2rad(cone + delta)
        normals = np.cos(angle) * a + np.sin(angle) * side
        assert np.all(hand.reach(normals)[0] == inside)
    assert hand.reach(a[None])[0, 0]


def test_reach_takes_the_cones_edge_deliberately():
    """cone_reach counts n . a >= cos(cone) - REACH_TOL: half the tolerance outside the edge is
    within reach, twice the tolerance is not (in cosines), and a normal 1e-10 rad outside the
    cone is out."""
    approach = np.array([[0.0, 0.0, 1.0]])
    edge = np.cos(np.deg2rad(60.0))
    for below, inside in ((0.0, True), (0.5 * REACH_TOL, True), (2 * REACH_TOL, False)):
        c = edge - below
        normal = np.array([[np.sqrt(1 - c * c), 0.0, c]])
        assert normal @ approach[0] == c  # the cosine is exactly the one meant
        assert cone_reach(approach, 60.0, normal)[0, 0] == inside
    angle = np.deg2rad(60.0) + 1e-10
    assert not cone_reach(approach, 60.0, [[np.sin(angle), 0.0, np.cos(angle)]])[0, 0]
    assert REACH_TOL == 1e-12


def test_paper_axis_gait_rests_on_the_cones_edge(monkeypatch):
    """On the paper's axis finger 1 meets the -x and +y sites exactly at its cone's edge at
    alpha = +-90 deg (cos = (1 + cos alpha) / 2 = 1/2) and the -z and +z sites at -45 and
    +45 deg: the gait's 12 phase changes count them within reach; with the edge excluded it
    takes 14."""
    from grasp_env.mechanics import hand as hand_module

    trajectory = Trajectory(PAPER_TURN.axis, -90.0, 90.0, 3.0)
    scene, hand = GaitScene(), Hand()
    rotations = trajectory.rotations()
    normals = np.einsum("tij,nj->tni", rotations, scene.normals)
    cosine = np.einsum("fc,tnc->tfn", hand.approach, normals)
    on_edge = np.argwhere(np.abs(cosine - np.cos(np.deg2rad(hand.cone_deg))) < 1e-14)
    assert sorted((trajectory.alphas_deg[t], f, s) for t, f, s in on_edge) == [
        (-90.0, 0, 0), (-90.0, 0, 4), (-45.0, 0, 2), (45.0, 0, 5), (90.0, 0, 0), (90.0, 0, 4)
    ]  # fmt: skip
    assert solve_gait(scene, hand, trajectory).optimal.changes == 12
    monkeypatch.setattr(hand_module, "REACH_TOL", -REACH_TOL)  # the edge just outside
    assert solve_gait(scene, hand, trajectory).optimal.changes == 14


def test_reach_is_batched():
    hand = Hand()
    normals = np.random.default_rng(1).normal(size=(7, 2, 6, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    reach = hand.reach(normals)
    assert reach.shape == (7, 2, 5, 6)
    cosine = normals @ hand.approach.T  # (7, 2, 6, 5)
    np.testing.assert_array_equal(reach, np.swapaxes(cosine, -1, -2) >= 0.5 - 1e-12)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cone_deg": 0.0}, "cone_deg"),
        ({"cone_deg": 180.0}, "cone_deg"),
        ({"finger_elevation_deg": 91.0}, "elevation"),
        ({"finger_azimuths_deg": ()}, "azimuths"),
        ({"finger_azimuths_deg": (0.0, np.nan)}, "azimuths"),
        ({"finger_azimuths_deg": "abc"}, "azimuths"),
        ({"finger_azimuths_deg": tuple(range(6))}, "at most 6"),
        # refused, not converted: "no" is truthy, "123" three fingers at 1, 2 and 3 deg
        ({"thumb": "no"}, "thumb must be True or False, got 'no'"),
        ({"thumb": 1}, "thumb must be True or False, got 1"),
        ({"finger_azimuths_deg": "123"}, "finger_azimuths_deg must be a sequence"),
        ({"finger_azimuths_deg": (0.0, True)}, r"finger_azimuths_deg must be .* booleans"),
        ({"finger_azimuths_deg": 30.0}, "finger_azimuths_deg must be a sequence"),
        ({"cone_deg": "60"}, r"cone_deg must be a finite number in \(0, 180\), got '60'"),
        ({"cone_deg": True}, r"cone_deg must be a finite number in \(0, 180\), got True"),
        ({"cone_deg": None}, r"cone_deg must be a finite number in \(0, 180\), got None"),
        ({"finger_elevation_deg": "30"}, r"finger_elevation_deg must be .* in \[-90, 90\]"),
    ],
)
def test_bad_hands(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Hand(**kwargs)


def test_hands_take_numpy_numbers():
    hand = Hand(np.array([0, 90, 180]), np.float32(30), np.bool_(False), np.int64(45))
    assert hand.finger_azimuths_deg == (0.0, 90.0, 180.0) and hand.thumb is False
    assert type(hand.finger_elevation_deg) is float and hand.cone_deg == 45.0


def test_bad_reach_inputs():
    with pytest.raises(ValueError, match="shape"):
        Hand().reach(np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        Hand().reach(np.full((2, 3), np.nan))


# ------------------------------------------------------------------------------ the scene


def test_default_scene_has_a_site_per_face():
    scene = GaitScene()
    assert scene.n_sites == 6
    np.testing.assert_array_equal(np.abs(scene.normals).sum(axis=1), 1)
    np.testing.assert_array_equal(np.abs(scene.normals).sum(axis=0), 2)  # +-x, +-y, +-z
    # the inward normal points into the box from the site's face
    assert np.all(np.sum(scene.normals * scene.sites, axis=1) < 0)


@pytest.mark.parametrize(
    ("sites", "match"),
    [
        (np.zeros((2, 3)), "shape"),
        (np.zeros((9, 3)), "shape"),
        ([[0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.7]], "face"),
        ([[0.5, 0, 0], [0, 0.5, 0], [0.5, 0.5, 0]], "face"),  # on an edge
        ([[0.5, 0, 0], [0, 0.5, 0], [0, 0.5, 0]], "coincide"),
        ([[0.5, 0, 0], [0, 0.5, 0], [0, 0, np.nan]], "finite"),
    ],
)
def test_bad_sites(sites, match):
    with pytest.raises(ValueError, match=match):
        GaitScene(sites=np.array(sites, dtype=float))


def test_bad_scene_values():
    with pytest.raises(ValueError, match="mu"):
        GaitScene(mu=0.0)
    with pytest.raises(ValueError, match="inside the box"):
        GaitScene(cg_offset=(0.6, 0, 0))
    # strings are refused, not converted to numbers
    with pytest.raises(ValueError, match=r"offsets must be an array of shape \(6, 2\)"):
        GaitScene.on_faces(offsets=[["0.1", "0.1"]] * 6)
    with pytest.raises(ValueError, match=r"offsets must be .* booleans"):
        GaitScene.on_faces(offsets=[[True, 0.1]] * 6)
    with pytest.raises(ValueError, match="faces must be a sequence"):
        GaitScene.on_faces(faces="-x-y-z", offsets=[])
