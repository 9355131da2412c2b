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
    max_contacts_of,
    object_frame_set,
    pair_basis,
    transfer,
)

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


@pytest.mark.fast
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


@pytest.mark.fast
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


@pytest.mark.fast
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


@pytest.mark.fast
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


@pytest.mark.fast
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
