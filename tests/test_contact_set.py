"""The contact-set policy: one network for any object and any number of contacts, equivariant
to the order of the fingers, usable from SB3."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from grasp_env.envs.object_grasp.env import ObjectGraspRandomEnv
from grasp_env.mechanics import contact_pairs
from grasp_env_agents.learning.contact_set import (
    ContactSetPolicy,
    expert_forces,
    grip_with_release,
    max_contacts_of,
    object_frame_set,
    pair_basis,
    release_set,
    reward_angles,
    set_grasp,
    transfer,
)
from grasp_env_agents.learning.contact_set_fit import fit_contact_set
from grasp_env_agents.learning.contact_set_tokens import EQUAL_K, mechanics_tokens

N = 6


@pytest.fixture(scope="module")
def draws():
    """An environment padded to six contacts, and first observations of 3 to 5 contacts."""
    env = ObjectGraspRandomEnv(contact_counts=(3, 4, 5), max_contacts=N)
    obs, infos = [], []
    env.reset(seed=0)
    for _ in range(10):
        o, _ = env.reset()
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
        obs.append(o)
        infos.append(info)
    return env, np.array(obs), infos


def policy_for(env, seed: int = 0) -> ContactSetPolicy:
    torch.manual_seed(seed)
    return ContactSetPolicy(env.observation_space, env.action_space, lambda _: 1e-3)


def permuted(env, obs: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """The observation with its first len(perm) contacts listed in the order ``perm``."""
    out, n, layout = obs.copy(), len(perm), env.layout
    for part in (layout.positions, layout.normals):
        rows = out[part].reshape(N, 3).copy()
        rows[:n] = rows[:n][perm]
        out[part] = rows.ravel()
    return out


def test_the_equilibrating_forces_are_those_of_the_environment(draws):
    """At k = 0 the contact forces are the equilibrating forces: the set's F_i, turned back to
    the world frame and scaled by the weight, are the environment's (float32 inputs: 1e-4 w)."""
    _, obs, infos = draws
    _, _, forces, mask, _ = object_frame_set(torch.as_tensor(obs), N)
    columns = obs[:, :6].reshape(-1, 2, 3)
    rotation = np.stack([columns[:, 0], columns[:, 1], np.cross(columns[:, 0], columns[:, 1])], -1)
    world = np.einsum("bij,bnj->bni", rotation, forces.double().numpy())
    for b, info in enumerate(infos):
        n = int(mask[b].sum())
        assert n == info["n_contacts"]
        expected = np.asarray(info["equilibrating_forces"])[:n]
        weight = np.linalg.norm(expected.sum(0))  # the load is the weight (no extra force)
        np.testing.assert_allclose(world[b, :n] * weight, expected, atol=1e-4 * weight)
        assert np.all(world[b, n:] == 0)


def test_the_mechanics_tokens_are_the_numpy_mechanics(draws):
    """The tokens' F_i and equal-k force P^eq_i (normal part, tangential size, friction angle,
    tangential part turned back to the world frame) against grasp_env.mechanics on the same
    float64 world-frame geometry and load (1e-7 of w and 1e-7 rad: the tokens are computed in
    the object's frame, whose float32 columns are orthonormal to about 1e-7; the tangential
    part 1e-6 w); against the environment playing the equal-k grip (float32 observation:
    1e-4 w, 1e-5 rad); zeros at padded contacts."""
    from grasp_env.mechanics.forces import (
        equilibrating_forces,
        friction_angles,
        interaction_basis,
        net_forces,
    )

    env, obs, _ = draws
    layout = env.layout
    positions, normals, forces, mask, _ = object_frame_set(torch.as_tensor(obs), N, double=True)
    tokens = mechanics_tokens(positions, normals, forces, mask).numpy()
    assert tokens.dtype == np.float64 and tokens.shape == (len(obs), N, 12)
    columns = obs[:, :6].astype(float).reshape(-1, 2, 3)
    rotation = np.stack([columns[:, 0], columns[:, 1], np.cross(columns[:, 0], columns[:, 1])], -1)
    for b in range(len(obs)):
        n = int(mask[b].sum())
        world_p = obs[b, layout.positions].astype(float).reshape(N, 3)[:n]
        world_n = obs[b, layout.normals].astype(float).reshape(N, 3)[:n]
        tail = obs[b, layout.tail].astype(float)
        f = equilibrating_forces(world_p, tail[:6])
        m = n * (n - 1) // 2
        p_eq = net_forces(f, interaction_basis(world_p), np.full(m, EQUAL_K))
        for part, force in ((slice(0, 6), f), (slice(6, 12), p_eq)):
            mine = tokens[b, :n, part]
            normal = np.sum(force * world_n, -1)
            tangential = force - normal[:, None] * world_n
            np.testing.assert_allclose(mine[:, 0], normal, atol=1e-7, rtol=0)
            across = np.linalg.norm(np.cross(force, world_n), axis=-1)  # eq. 2's |P x n|
            np.testing.assert_allclose(mine[:, 1], across, atol=1e-7, rtol=0)
            np.testing.assert_allclose(
                mine[:, 2], friction_angles(force, world_n), atol=1e-7, rtol=0
            )
            world_t = mine[:, 3:] @ rotation[b].T
            np.testing.assert_allclose(world_t, tangential, atol=1e-6, rtol=0)
        assert np.all(tokens[b, n:] == 0.0)
        # the environment's equal-k grip: the same forces, the same friction angles
        env.reset(seed=0)
        reset, _ = env.reset()
        for _ in range(b):
            reset, _ = env.reset()
        assert np.array_equal(reset, obs[b])
        action = np.full(env.action_space.shape, EQUAL_K / env.k_max_ratio, np.float32)
        info = env.step(action)[4]
        weight = np.linalg.norm(np.asarray(info["equilibrating_forces"]).sum(0))
        played = np.asarray(info["contact_forces"])[:n] / weight
        np.testing.assert_allclose(p_eq, played, atol=1e-4, rtol=0)
        np.testing.assert_allclose(tokens[b, :n, 8], np.asarray(info["theta"])[:n], atol=1e-5)


def test_the_latents_and_the_grip_do_not_depend_on_the_fingers_order(draws):
    env, obs, _ = draws
    policy = policy_for(env)
    pairs = contact_pairs(N)
    slot = {tuple(p): q for q, p in enumerate(pairs.tolist())}
    with torch.no_grad():
        for b in range(len(obs)):
            features = policy.extract_features(torch.as_tensor(obs[b : b + 1]))
            n = int(features[0, -N:].sum())
            perm = np.random.default_rng(b).permutation(n)
            other = policy.extract_features(torch.as_tensor(permuted(env, obs[b], perm)[None]))
            latent = policy.mlp_extractor.forward_actor(features)
            hidden = latent[0, : N * policy.width].reshape(N, -1)
            hidden_p = policy.mlp_extractor.forward_actor(other)[0, : N * policy.width]
            # the encoder: float32 attention, equivariant to rounding
            torch.testing.assert_close(
                hidden_p.reshape(N, -1)[:n], hidden[:n][perm], atol=1e-5, rtol=0
            )
            # the head on exactly permuted latents: the same grip, pair for pair
            exact = latent.clone()
            exact[0, : N * policy.width] = torch.cat([hidden[:n][perm], hidden[n:]]).flatten()
            exact[0, N * policy.width :] = other[0]
            k = policy.action_net(latent)[0].double().numpy()
            k_p = policy.action_net(exact)[0].double().numpy()
            scale = max(1.0, np.abs(k).max())
            for q, (i, j) in enumerate(pairs.tolist()):
                if j < n:
                    mine = slot[tuple(sorted((int(perm[i]), int(perm[j]))))]
                    assert abs(k_p[q] - k[mine]) <= 1e-5 * scale, (b, q)
                else:
                    assert k_p[q] == 0.0  # a pair with a padded contact is not used


def test_one_network_serves_any_padding(draws):
    """The weights do not depend on N: a policy for six contacts, moved into one for eight,
    grips a grasp padded to eight as it gripped it padded to six: the same interaction forces
    sum_j k_ij e_ij (with five or more contacts the k_ij are redundant, and the least squares'
    ridge, relative to the pair count, may pick another k for the same forces)."""
    env, obs, _ = draws
    policy = policy_for(env)
    wide = ObjectGraspRandomEnv(contact_counts=(3, 4, 5), max_contacts=8)
    other = policy_for(wide, seed=1)
    transfer(policy, other)
    with torch.no_grad():
        six = policy._predict(torch.as_tensor(obs), deterministic=True).numpy()
        padded = np.zeros((len(obs), wide.layout.size), np.float32)
        for name in ("positions", "normals", "mask"):
            rows = obs[:, getattr(env.layout, name)].reshape(len(obs), N, -1)
            target = padded[:, getattr(wide.layout, name)].reshape(len(obs), 8, -1)
            target[:, :N] = rows
            padded[:, getattr(wide.layout, name)] = target.reshape(len(obs), -1)
        padded[:, :6] = obs[:, :6]
        padded[:, wide.layout.tail] = obs[:, env.layout.tail]
        eight = other._predict(torch.as_tensor(padded), deterministic=True).numpy()
    positions, _, _, mask, _ = object_frame_set(torch.as_tensor(obs), N)
    wide_positions, _, _, wide_mask, _ = object_frame_set(torch.as_tensor(padded), 8)
    forces = np.einsum("bq,bqnc->bnc", six, pair_basis(positions, mask).numpy())
    wide_forces = np.einsum("bq,bqnc->bnc", eight, pair_basis(wide_positions, wide_mask).numpy())
    for b in range(len(obs)):
        scale = max(1.0, np.abs(forces[b]).max())
        np.testing.assert_allclose(wide_forces[b, :N], forces[b], atol=1e-4 * scale)
        assert np.all(wide_forces[b, N:] == 0)


def test_the_policy_refuses_what_it_cannot_read():
    from gymnasium import spaces

    with pytest.raises(ValueError, match="padded observation of 14 \\+ 7 N floats"):
        max_contacts_of(30)
    box = spaces.Box(-1, 1, (14 + 7 * 4,))
    with pytest.raises(ValueError, match="acts with their 6 pair scalars"):
        ContactSetPolicy(box, spaces.Box(-1, 1, (5,)), lambda _: 1e-3)
    with pytest.raises(ValueError, match="multiple of heads"):
        ContactSetPolicy(box, spaces.Box(-1, 1, (6,)), lambda _: 1e-3, width=30, heads=4)


def test_sb3_ppo_trains_and_reloads_it(tmp_path, draws):
    from stable_baselines3 import PPO

    env, obs, _ = draws
    model = PPO(ContactSetPolicy, env, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(64)
    model.save(tmp_path / "model.zip")
    loaded = PPO.load(tmp_path / "model.zip", device="cpu")
    assert loaded.policy.k_max_ratio == env.k_max_ratio
    np.testing.assert_array_equal(
        model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0]
    )


def test_padding_changes_neither_the_grip_nor_its_gradient(draws):
    """grip_along on a grasp padded with absent contacts: the real contacts' k and the
    gradient with respect to their directions are those of the unpadded grasp (1e-9)."""
    from grasp_env.mechanics.directions import grip_along, grip_along_gradient

    _, obs, _ = draws
    positions, normals, forces, mask, _ = object_frame_set(torch.as_tensor(obs), N)
    basis = pair_basis(positions, mask).double().numpy()
    rng = np.random.default_rng(0)
    for b in range(len(obs)):
        n = int(mask[b].sum())
        real = [q for q, (_, j) in enumerate(contact_pairs(N).tolist()) if j < n]
        d = normals[b].double().numpy() + 0.2 * rng.normal(size=(N, 3))
        d[n:] = 0.0
        d[:n] /= np.linalg.norm(d[:n], axis=1, keepdims=True)
        f, nn = forces[b].double().numpy(), normals[b].double().numpy()
        grasps = {
            "padded": (d[None], f[None], basis[b][None], nn[None]),
            "alone": (d[None, :n], f[None, :n], basis[b][real][:, :n][None], nn[None, :n]),
        }
        k, grad = {}, {}
        for name, grasp in grasps.items():
            k[name], weights = grip_along(*grasp, 2.0)
            upstream = np.ones_like(k[name])
            grad[name] = grip_along_gradient(*grasp[:3], weights, k[name], upstream)
        np.testing.assert_allclose(k["padded"][0, real], k["alone"][0], rtol=1e-9, atol=1e-12)
        assert np.all(np.delete(k["padded"][0], real) == 0)
        np.testing.assert_allclose(grad["padded"][0, :n], grad["alone"][0], rtol=1e-7, atol=1e-9)


@pytest.fixture(scope="module")
def releasing():
    """First poses of five- and six-contact scenes (padded to six), each with the expert's
    action (k* / k_max from the environment's info) and the environment's info for it."""
    env = ObjectGraspRandomEnv(contact_counts=(5, 6), max_contacts=N)
    obs, actions, infos = [], [], []
    for seed in range(12):
        o, _ = env.reset(seed=seed)
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
        weight = np.linalg.norm(np.asarray(info["equilibrating_forces"]).sum(0))
        action = (np.asarray(info["expert_k"]) / (weight * env.k_max_ratio)).astype(np.float32)
        again, _ = env.reset(seed=seed)
        assert np.array_equal(again, o)
        _, _, _, _, played = env.step(action)
        obs.append(o)
        actions.append(action)
        infos.append(played)
    return env, np.array(obs), np.array(actions), infos


def play(env, seed: int, action: np.ndarray) -> dict:
    """The environment's info for ``action`` at the first pose of the scene ``seed``."""
    env.reset(seed=seed)
    return env.step(action.astype(np.float32))[4]


def test_the_expert_releases_fingers_and_the_environment_counts_them_at_angle_0(releasing):
    """The diagnosis: on these scenes the certified optimum releases at least one finger in
    most poses, and the environment gives a released finger theta = 0 exactly."""
    env, obs, actions, infos = releasing
    grasp = set_grasp(torch.as_tensor(obs))
    _, released = expert_forces(torch.as_tensor(actions), grasp, env.k_max_ratio)
    assert released.any(1).float().mean() >= 0.5
    for b, info in enumerate(infos):
        theta = np.asarray(info["theta"])
        assert np.all(theta[released[b].numpy()] == 0.0)
        assert info["optimality_gap"] <= 1e-5  # the expert's own float32 action


def test_the_loss_is_the_environments_reward(releasing):
    """reward_angles gives the environment's largest friction angle, theta_lim - reward, to
    2e-6 rad on the expert's actions (released fingers), on random actions inside and beyond
    the box (clipped; five or more contacts: projected and scaled back), and per contact on
    the random ones."""
    env, obs, actions, infos = releasing
    grasp = set_grasp(torch.as_tensor(obs))
    rng = np.random.default_rng(1)
    for name, batch in (("expert", actions), ("random", rng.uniform(-1.5, 1.5, actions.shape))):
        theta = reward_angles(torch.as_tensor(batch, dtype=torch.float32), grasp, env.k_max_ratio)
        for b in range(len(obs)):
            info = infos[b] if name == "expert" else play(env, b, batch[b])
            expected = np.asarray(info["theta"])
            worst = float(theta[b].max())
            assert abs(worst - expected.max()) <= 2e-6, (name, b)
            if name == "random":
                np.testing.assert_allclose(theta[b].numpy(), expected, atol=2e-6, rtol=0)


def test_the_head_represents_the_experts_grip_with_its_released_fingers(releasing):
    """Given the expert's directions P*_i / |P*_i|, magnitudes |P*_i| and released set, the
    gated least squares returns a grip the environment finds as good as the expert's own
    action (optimality gaps <= 1e-4 deg; the grasp is rebuilt from the float32 observation),
    with the released fingers released (theta_i = 0 exactly); the ungated head cannot
    (the same directions, a released finger given its normal, slip on some scenes)."""
    env, obs, actions, _ = releasing
    grasp = set_grasp(torch.as_tensor(obs))
    forces, released = expert_forces(torch.as_tensor(actions), grasp, env.k_max_ratio)
    size = torch.linalg.vector_norm(forces, dim=-1)
    unit = forces / size.clamp_min(1e-300)[..., None]  # padded contacts: 0
    directions = torch.where(released[..., None], grasp.normals, unit)
    directions = directions * grasp.mask[..., None]
    magnitudes = torch.where(released, 0.0, size) * grasp.mask
    gaps = {}
    for gated in (True, False):
        k = grip_with_release(
            directions,
            magnitudes,
            released & gated,
            grasp.forces,
            grasp.basis,
            grasp.normals,
            env.k_max_ratio,
        )
        gaps[gated] = []
        for b in range(len(obs)):
            info = play(env, b, (k[b] / env.k_max_ratio).numpy())
            gaps[gated].append(np.rad2deg(info["optimality_gap"]))
            if gated:
                assert np.all(np.asarray(info["theta"])[released[b].numpy()] == 0.0)
    assert max(gaps[True]) <= 1e-4
    assert max(gaps[False]) > 1.0


def test_the_gate_releases_at_most_all_but_three_contacts():
    logits = torch.tensor([[2.0, 1.0, 3.0, -1.0, 0.5, 4.0], [1.0, 1.0, 1.0, 1.0, 0.0, 0.0]])
    mask = torch.tensor([[1.0, 1, 1, 1, 1, 0], [1, 1, 1, 0, 0, 0]])
    released = release_set(logits, mask)
    # five real contacts: two released, the largest logits among the real ones; three: none
    assert released.tolist() == [
        [True, False, True, False, False, False],
        [False, False, False, False, False, False],
    ]


def test_padding_changes_nothing_in_the_gated_grip(releasing):
    """grip_with_release on a grasp padded with absent contacts: the real pairs' k and the
    gradients with respect to the real contacts' directions and magnitudes are those of the
    unpadded grasp (1e-7 relative: the QR's rounding, through the released rows' weight), the
    padded pairs' k exactly 0."""
    env, obs, actions, _ = releasing
    grasp = set_grasp(torch.as_tensor(obs))
    _, released = expert_forces(torch.as_tensor(actions), grasp, env.k_max_ratio)
    rng = np.random.default_rng(2)
    pairs = contact_pairs(N).tolist()
    for b in range(len(obs)):
        n = int(grasp.mask[b].sum())
        real = [q for q, (_, j) in enumerate(pairs) if j < n]
        d = grasp.normals[b] + torch.as_tensor(rng.normal(size=(N, 3)) * 0.2)
        d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True) * grasp.mask[b][:, None]
        rho = torch.as_tensor(rng.uniform(0.5, 2.0, N)) * grasp.mask[b]
        upstream = torch.as_tensor(rng.normal(size=len(real)))
        out = {}
        for name, rows, slots in (("padded", slice(None), slice(None)), ("alone", slice(n), real)):
            dd = d[rows].clone()[None].requires_grad_(True)
            rr = rho[rows].clone()[None].requires_grad_(True)
            k = grip_with_release(
                dd,
                rr,
                released[b, rows][None],
                grasp.forces[b, rows][None],
                grasp.basis[b][slots][:, rows][None],
                grasp.normals[b, rows][None],
                env.k_max_ratio,
            )[0]
            on_real = k[real] if name == "padded" else k
            (on_real * upstream).sum().backward()
            out[name] = k.detach(), dd.grad[0, :n], rr.grad[0, :n]
        k_padded, k_alone = out["padded"][0], out["alone"][0]
        np.testing.assert_allclose(k_padded[real].numpy(), k_alone.numpy(), rtol=1e-7, atol=1e-9)
        assert np.all(np.delete(k_padded.numpy(), real) == 0.0)
        for mine, alone in zip(out["padded"][1:], out["alone"][1:], strict=True):
            np.testing.assert_allclose(mine.numpy(), alone.numpy(), rtol=1e-6, atol=1e-8)


def test_the_fit_learns_the_experts_forces_and_refuses_nothing_to_fit(releasing):
    """fit_contact_set on twelve states: the imitation loss falls by a third in 40 epochs,
    and with the reward's gradient the loss is finite; no weights, or no expert actions for
    imitation, are refused."""
    env, obs, actions, _ = releasing
    policy = policy_for(env)
    generator = torch.Generator().manual_seed(0)
    losses = fit_contact_set(policy, obs, actions, 40, 4, 3e-3, generator)
    assert losses[-1] < 0.67 * losses[0]
    both = fit_contact_set(policy, obs, actions, 1, 4, 1e-4, generator, reward_weight=1.0)
    assert np.isfinite(both).all()
    with pytest.raises(ValueError, match="not both 0"):
        fit_contact_set(policy, obs, actions, 1, imitation_weight=0.0)
    with pytest.raises(ValueError, match="expert's actions"):
        fit_contact_set(policy, obs, None, 1)
