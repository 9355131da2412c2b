"""The object environments' single envs (grasp_env/envs/object_grasp): scenes from object specs
and surface coordinates, the padded layout, the expert's certified optimum against actions, the
random draws (holdable, reproducible), refused inputs and Gymnasium's check_env with rendering.
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.object_grasp import ObjectGraspEnv, ObjectGraspRandomEnv, ObjectLayout
from grasp_env.envs.object_grasp.episodes import MAX_EXPERT_GAP, build_episodes, projection
from grasp_env.envs.object_grasp.scenes import ObjectSampler, surface_point
from grasp_env.mechanics import Box, ConvexMesh, Cylinder, Sphere, contact_pairs

EXPLICIT = "grasp_env/ObjectGrasp-v0"
RANDOM = "grasp_env/ObjectGraspRandom-v0"
#: A can held by five contacts: the conic solver's case (redundant pair directions).
CAN5 = {
    "object": "cylinder:r=0.04,h=0.12",
    "contacts": [
        ("side", 0.0, 0.2),
        ("side", 2.1, -0.3),
        ("side", 4.2, 0.0),
        ("+z", 0.1, 0.2),
        ("-z", 0.0, 0.3),
    ],
    "mu": 0.6,
    "cg_offset": (0.002, 0.0, 0.01),
    "max_contacts": 6,
}
#: Rounding of a step against the float64 optimum (radians), as the cube envs' tests.
ROUNDING = 1e-12


def run_actions(env: ObjectGraspEnv, actions) -> list[dict]:  # type: ignore[no-untyped-def]
    infos = []
    for a in actions:
        *_, terminated, truncated, info = env.step(a)
        infos.append(info)
        if terminated or truncated:
            break
    return infos


@pytest.mark.parametrize("spec", ["cube", "can", "sphere:r=0.05", "box:x=0.1,y=0.2,z=0.3"])
def test_default_contacts_meet_at_the_centre_so_the_optimum_is_zero(spec: str) -> None:
    env = ObjectGraspEnv(object=spec)
    env.reset()
    limit = np.arctan(0.5)
    np.testing.assert_allclose(env.episode.expert_reward, limit, atol=1e-9)
    np.testing.assert_array_equal(env.episode.expert_gap <= 1e-9, True)
    infos = run_actions(env, env.episode.expert_k_w / env.k_max_ratio)
    assert len(infos) == 31
    assert max(abs(i["optimality_gap"]) for i in infos) < 1e-9


def test_a_shape_instance_and_its_spec_give_the_same_episode() -> None:
    a = ObjectGraspEnv(object=Cylinder(radius=0.033, height=0.115))
    b = ObjectGraspEnv(object="can")
    a.reset()
    b.reset()
    np.testing.assert_array_equal(a.episode.observations, b.episode.observations)


def test_surface_coordinates_name_the_shapes_points() -> None:
    box, can, ball = Box(size=(0.1, 0.2, 0.3)), Cylinder(radius=0.1, height=0.4), Sphere(radius=2)
    np.testing.assert_allclose(surface_point(box, ("+y", 0.5, -0.5)), [0.025, 0.1, -0.075])
    np.testing.assert_allclose(
        surface_point(can, ("side", np.pi / 2, 0.5)), [0, 0.1, 0.1], atol=1e-15
    )
    np.testing.assert_allclose(surface_point(can, ("-z", 0.5, 0.0)), [0.05, 0, -0.2])
    np.testing.assert_allclose(
        surface_point(ball, ("sphere", 0.0, np.pi / 2)), [0, 0, 2], atol=1e-15
    )
    np.testing.assert_allclose(surface_point(ball, (0.0, -2.0, 0.0)), [0, -2, 0])
    mesh = ConvexMesh(vertices=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]))
    assert mesh.contains(surface_point(mesh, (0,)) * 0.999)
    with pytest.raises(ValueError, match="contact 2"):
        surface_point(box, ("side", 0.0, 0.0), 2)
    with pytest.raises(ValueError, match=r"contact 0 .*\(-1, 1\)"):
        surface_point(box, ("-x", 1.0, 0.0))


def test_the_layout_pads_contacts_and_pairs_with_a_mask() -> None:
    env = ObjectGraspEnv(object="can", max_contacts=6)
    obs, info = env.reset()
    layout = ObjectLayout(6)
    assert obs.shape == (layout.size,) == (56,) and env.action_space.shape == (15,)
    assert info == {"n_contacts": 3}
    np.testing.assert_array_equal(obs[layout.mask], [1, 1, 1, 0, 0, 0])
    np.testing.assert_array_equal(obs[layout.positions][9:], 0.0)
    np.testing.assert_array_equal(obs[layout.normals][9:], 0.0)
    # the pairs of padding are ignored: changing them changes nothing
    used = np.array([j < 3 for _, j in contact_pairs(6)])
    a = np.where(used, 0.3, 0.0).astype(np.float32)
    _, r1, *_, info1 = env.step(a)
    env.reset()
    _, r2, *_, info2 = env.step(np.where(used, 0.3, -0.9).astype(np.float32))
    assert r1 == r2
    np.testing.assert_array_equal(info1["k"], info2["k"])
    np.testing.assert_array_equal(info2["k"][~used], 0.0)
    np.testing.assert_array_equal(info2["theta"][3:], 0.0)
    np.testing.assert_array_equal(info2["margin"][3:], np.arctan(0.5))
    np.testing.assert_array_equal(info2["contact_forces"][3:], 0.0)
    assert not info2["slip"][3:].any()


def test_five_contacts_read_the_minimum_norm_grip_of_the_box() -> None:
    env = ObjectGraspEnv(**CAN5)
    env.reset()
    episode = env.episode
    p = projection(episode.scene, 6)
    np.testing.assert_allclose(p @ p, p, atol=1e-12)  # a projection
    assert np.linalg.matrix_rank(p) == 9  # 3n - 6 interaction forces
    np.testing.assert_allclose(p @ episode.expert_k_w.T, episode.expert_k_w.T, atol=1e-9)
    rng = np.random.default_rng(0)
    env.reset()
    for _ in range(3):
        *_, info = env.step(rng.uniform(-1, 1, 15).astype(np.float32))
        k = info["k"] / episode.weight
        assert np.abs(k).max() <= env.k_max_ratio * (1 + 1e-12)
        np.testing.assert_allclose(p @ k, k, atol=1e-12)
        env.reset()


@pytest.mark.parametrize("kwargs", [{"object": "cube"}, CAN5])
def test_no_action_beats_the_expert(kwargs: dict) -> None:
    """Random actions, the box's corners and the expert's own grip: optimality_gap >= 0 to
    rounding (>= -expert_gap where the optimum is certified to less than 1e-9 rad)."""
    env = ObjectGraspEnv(
        **{**kwargs, "terminate_on_slip": False, "cg_offset": (0.003, -0.002, 0.004)}
    )
    env.reset()
    rng = np.random.default_rng(1)
    m = env.action_space.shape[0]
    actions = [rng.uniform(-1, 1, m) for _ in range(10)] + [rng.choice([-1.0, 1.0], m)]
    gaps = []
    for t in range(len(env.episode)):
        env.reset()
        for _ in range(t):
            env.step(np.zeros(m, np.float32))
        for a in [*actions, env.episode.expert_k_w[t] / env.k_max_ratio]:
            env.reset()
            for _ in range(t):
                env.step(np.zeros(m, np.float32))
            *_, info = env.step(a)
            gaps.append(info["optimality_gap"] + info["expert_gap"])
        if t >= 3:
            break
    assert min(gaps) >= -ROUNDING
    assert max(env.episode.expert_gap) <= MAX_EXPERT_GAP


def test_random_draws_are_holdable_and_reproducible() -> None:
    env = ObjectGraspRandomEnv(terminate_on_slip=False)
    other = gym.make(RANDOM, terminate_on_slip=False)
    kinds, counts = set(), set()
    for seed in range(12):
        obs, info = env.reset(seed=seed)
        obs2, _ = other.reset(seed=seed)
        np.testing.assert_array_equal(obs, obs2)
        episode = env.episode
        kinds.add(episode.scene.shape.kind)
        # the drawn arrays are a valid mechanics Scene's (built on demand)
        np.testing.assert_allclose(episode.scene.scene.normals, episode.scene.normals, atol=1e-12)
        counts.add(info["n_contacts"])
        assert episode.solved[0]
        assert obs.shape == env.observation_space.shape == (56,)
        assert env.observation_space.contains(obs)
        assert obs[ObjectLayout(6).mask].sum() == info["n_contacts"]
        # the expert's grip holds at every pose (the poses pending at reset solved on the way)
        infos = run_actions(env, [episode.expert_k_w[0] / env.k_max_ratio] * len(episode))
        assert len(infos) == len(episode) and episode.solved.all()
        assert episode.expert_reward.min() >= env.min_expert_margin
        assert min(i["optimality_gap"] + i["expert_gap"] for i in infos) >= -ROUNDING
        # the pending poses' optimum is the optimum solved at reset (to the solver's gap)
        eager = build_episodes([episode.scene], env.k_max_ratio, 6)[0]
        np.testing.assert_allclose(episode.expert_reward, eager.expert_reward, atol=MAX_EXPERT_GAP)
    assert kinds == {"box", "cylinder", "sphere", "convex mesh"}
    assert counts <= {3, 4, 5, 6} and len(counts) >= 3  # 12 draws of 4 counts


def test_the_expert_holds_where_the_first_grip_does_not() -> None:
    """Drawn scenes whose first optimal grip slips later along the trajectory are kept only
    where the optimum there holds (those poses are solved at reset)."""
    env = ObjectGraspRandomEnv(contact_counts=(3,), mu_range=(0.3, 0.5))
    hard = 0
    for seed in range(30):
        env.reset(seed=seed)
        episode = env.episode
        solved = np.flatnonzero(episode.solved[1:]) + 1
        hard += len(solved)
        assert np.all(episode.expert_reward[solved] >= env.min_expert_margin)
    assert hard > 0


def test_a_reseed_restarts_the_stream_and_one_seed_gives_one_sequence() -> None:
    env = ObjectGraspRandomEnv(contact_counts=(3, 4))
    firsts = []
    for _ in range(2):
        env.reset(seed=7)
        seq = [env.episode.observations[0]]
        for _ in range(3):
            env.reset()
            seq.append(env.episode.observations[0])
        firsts.append(np.stack(seq))
    np.testing.assert_array_equal(firsts[0], firsts[1])
    assert not np.array_equal(firsts[0][0], firsts[0][1])


def test_candidates_do_not_depend_on_how_many_are_drawn_at_once() -> None:
    sampler = ObjectSampler()
    one = np.random.default_rng(3)
    many = np.random.default_rng(3)
    rows = np.concatenate([sampler.raw(one, 1) for _ in range(5)])
    np.testing.assert_array_equal(rows, sampler.raw(many, 5))


def test_a_scene_option_sets_one_episode() -> None:
    env = ObjectGraspEnv(object="can")
    env.reset()
    default = env.episode
    env.reset(options={"scene": {"mu": 0.9, "trajectory": {"alpha_end_deg": 0.0}}})
    assert len(env.episode) == 16
    np.testing.assert_allclose(env.episode.limit, np.arctan(0.9))
    env.reset()
    assert env.episode is default


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"object": "teapot"}, "unknown object"),
        ({"object": 3}, "object must be"),
        ({"contacts": [("-x", 0, 0), ("-y", 0, 0)]}, "3 to 8"),
        ({"contacts": [("-x", 0, 0), ("+x", 0, 0), ("-x", 0, 0)]}, "coincide"),
        ({"weight": 0.0}, "weight"),
        ({"mu": 1e4}, "mu"),
        ({"cg_offset": (0.6, 0, 0)}, "inside"),
        ({"extra_force": (0, 0, 6.0)}, "at most w"),
        ({"trajectory": {"alpha_step_deg": 0.0}}, "alpha_step_deg"),
        ({"max_contacts": 2}, "max_contacts"),
        ({"max_contacts": 9}, "max_contacts"),
        ({"render_mode": "video"}, "render_mode"),
    ],
)
def test_refused_keywords_name_the_input(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ObjectGraspEnv(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"shapes": ("torus",)}, "unknown shape"),
        ({"contact_counts": (2, 3)}, "contact_counts"),
        ({"contact_counts": (3, 9)}, "contact_counts"),
        ({"size_range": (0.3, 0.1)}, "size_range"),
        ({"max_contacts": 4}, "max_contacts"),
        ({"min_expert_margin_deg": 50.0}, "min_expert_margin_deg"),
    ],
)
def test_refused_random_keywords_name_the_input(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ObjectGraspRandomEnv(**kwargs)


def test_bad_actions_and_options_are_refused() -> None:
    env = ObjectGraspEnv()
    env.reset()
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="unknown scene key"):
        env.reset(options={"scene": {"size": 2}})
    with pytest.raises(ValueError, match="max_contacts"):
        four = [("-x", 0, 0), ("-y", 0, 0), ("-z", 0, 0), ("+z", 0.3, 0.2)]
        env.reset(options={"scene": {"contacts": four}})


@pytest.mark.parametrize("env_id", [EXPLICIT, RANDOM])
def test_check_env_passes_with_its_render_check(env_id: str) -> None:
    env = gym.make(env_id, render_mode="rgb_array")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # headless, check_env's "human" render warns once that it draws nothing (as every id)
        warnings.filterwarnings("ignore", "render_mode='human' needs a display", RuntimeWarning)
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8
    assert frame.std() > 1.0  # a picture, not a blank
    env.step(env.action_space.sample())
    assert env.render().shape == (480, 480, 3)
    env.close()
