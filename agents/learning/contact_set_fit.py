"""Training the contact-set policy (:mod:`.contact_set`) from the expert: the states and
actions of :func:`expert_states`, fitted by imitation of the expert's force directions,
magnitudes and released set, and optionally by the reward's exact gradient
(:func:`fit_contact_set`)."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from .contact_set import (
    ENV_ID,
    ContactSetPolicy,
    expert_forces,
    max_contacts_of,
    release_set,
    reward_angles,
    set_grasp,
)
from .envs import action_scale


def expert_states(
    env_kwargs: dict[str, Any], states: int, n_envs: int, seed: int, env_id: str = ENV_ID
) -> tuple[np.ndarray, np.ndarray]:
    """``states`` observations (float32) of the random objects' vector environment and the
    expert's actions k* / k_max there (float32; ``info["expert_k"]`` over k_max w, the
    certified optimum of the exact pose), visited with the zero grip along whole trajectories
    (slips do not end them: the states do not depend on the actions). The step that only
    resets a sub-environment (Gymnasium's next-step autoreset) is left out."""
    if states < 1 or n_envs < 1:
        raise ValueError(f"states and n_envs must be >= 1, got {states} and {n_envs}")
    envs = gym.make_vec(
        env_id,
        num_envs=n_envs,
        vectorization_mode="vector_entry_point",
        **{**env_kwargs, "terminate_on_slip": False},
    )
    try:
        k_max_ratio = action_scale(envs)
        big = max_contacts_of(envs.single_observation_space.shape[0])
        obs, _ = envs.reset(seed=seed)
        pending = np.zeros(n_envs, bool)
        zeros = np.zeros((n_envs, *envs.single_action_space.shape), np.float32)
        observations, actions, count = [], [], 0
        while count < states:
            following, _, terminated, truncated, info = envs.step(zeros)
            tail = 6 + 7 * big
            load = np.linalg.norm(obs[:, tail : tail + 3], axis=1)
            weight = np.linalg.norm(info["equilibrating_forces"].sum(1), axis=1) / np.where(
                load > 0, load, 1.0
            )
            scale = np.where(weight > 0, weight, 1.0)[:, None] * k_max_ratio
            action = np.clip(info["expert_k"] / scale, -1.0, 1.0).astype(np.float32)
            keep = ~pending
            observations.append(obs[keep])
            actions.append(action[keep])
            count += int(keep.sum())
            pending = terminated | truncated
            obs = following
    finally:
        envs.close()
    return np.concatenate(observations)[:states], np.concatenate(actions)[:states]


def _direction_error(directions: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The angle between unit directions and (non-zero) targets, (B, N): sqrt(2 (1 - cos)),
    smoothed at 0 by 1e-12 so that its gradient is finite there."""
    unit = target / torch.linalg.vector_norm(target, dim=-1, keepdim=True).clamp_min(1e-300)
    return torch.sqrt(2.0 * (1.0 - (directions.double() * unit).sum(-1)).clamp_min(0.0) + 1e-12)


def fit_contact_set(
    policy: ContactSetPolicy,
    obs: np.ndarray,
    expert_actions: np.ndarray | None,
    epochs: int,
    batch_size: int = 512,
    learning_rate: float = 1e-3,
    generator: torch.Generator | None = None,
    imitation_weight: float = 1.0,
    reward_weight: float = 0.0,
    gate_weight: float = 0.1,
) -> list[float]:
    """Fit the policy's actor on padded observations ``obs`` (B, 14 + 7N); returns each
    epoch's mean loss.

    The loss, per minibatch: ``imitation_weight`` x (the mean angle between d_i and the expert's
    force P*_i over the contacts it holds, + 0.1 x the mean squared error of log rho_i against log
    |P*_i| there, + ``gate_weight`` x the release gate's cross-entropy against the expert's released
    set, :func:`expert_forces`), plus ``reward_weight`` x the mean largest friction angle of the
    head's grip as the environment counts it (:func:`reward_angles`, radians: the reward's exact
    gradient, the released set as the head chose it). With ``imitation_weight`` 0 the expert's
    actions are not read (they may be None). Adam with a cosine decay of the learning rate to 1% and
    the gradient norm clipped at 1 (a finger whose force nearly vanishes has a huge angle gradient);
    only the actor is trained.
    """
    if gate_weight < 0:
        raise ValueError(f"gate_weight must be >= 0, got {gate_weight}")
    if imitation_weight < 0 or reward_weight < 0 or imitation_weight + reward_weight == 0:
        raise ValueError(
            f"imitation_weight and reward_weight must be >= 0 and not both 0, got"
            f" {imitation_weight} and {reward_weight}"
        )
    if imitation_weight > 0 and (expert_actions is None or len(expert_actions) != len(obs)):
        raise ValueError("imitation needs the expert's actions, one row per observation")
    if epochs < 1 or batch_size < 1:
        raise ValueError(f"epochs and batch_size must be >= 1, got {epochs} and {batch_size}")
    head = policy.action_net
    ratio = head.k_max_ratio
    with torch.no_grad():
        obs_t = torch.as_tensor(obs, dtype=torch.float32)
        features = policy.extract_features(obs_t, policy.pi_features_extractor)
        grasp = set_grasp(obs_t)
        if imitation_weight > 0:
            target, released = expert_forces(torch.as_tensor(expert_actions), grasp, ratio)
            real = grasp.mask > 0.5
            held = real & ~released
            size = torch.linalg.vector_norm(target, dim=-1).clamp_min(1e-6)
    actor = [*policy.mlp_extractor.actor.parameters(), *head.parameters()]
    optimizer = torch.optim.Adam(actor, lr=learning_rate)
    steps = epochs * math.ceil(len(obs) / batch_size)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: 0.01 + 0.99 * 0.5 * (1.0 + math.cos(math.pi * step / steps))
    )
    policy.set_training_mode(True)
    losses = []
    for _ in range(epochs):
        order = torch.randperm(len(obs), generator=generator)
        total = 0.0
        for start in range(0, len(obs), batch_size):
            index = order[start : start + batch_size]
            latent = policy.mlp_extractor.forward_actor(features[index])
            directions, magnitudes, logits, forces, basis, normals, mask = head.parts(latent)
            loss = torch.zeros((), dtype=torch.float64)
            if imitation_weight > 0:
                h, r = held[index], real[index]
                angle = _direction_error(directions, target[index])
                log_error = torch.log(magnitudes.double().clamp_min(1e-12)) - torch.log(size[index])
                gate = torch.nn.functional.binary_cross_entropy_with_logits(
                    logits[r], released[index][r].to(logits.dtype)
                )
                loss = loss + imitation_weight * (
                    angle[h].mean() + 0.1 * log_error[h].square().mean() + gate_weight * gate
                )
            if reward_weight > 0:
                chosen = release_set(logits, mask)
                action = head.grip(directions, magnitudes, chosen, forces, basis, normals)
                theta = reward_angles(action, grasp[index], ratio)
                loss = loss + reward_weight * theta.amax(1).mean()
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(actor, 1.0)
            optimizer.step()
            schedule.step()
            total += float(loss.detach()) * len(index)
        losses.append(total / len(obs))
    policy.set_training_mode(False)
    return losses


def imitation_errors(
    policy: ContactSetPolicy, obs: np.ndarray, expert_actions: np.ndarray, batch_size: int = 2048
) -> dict[str, float]:
    """How far the policy's head is from the expert's forces on ``obs`` (B, 14 + 7N) with the
    expert's actions (B, M): the angle (deg) between d_i and P*_i over the contacts the expert
    holds (median, p90), and the release gate's choice (:func:`release_set`) against the
    expert's released set over the real contacts: the share right, the releases missed and the
    false releases (counts)."""
    if len(expert_actions) != len(obs):
        raise ValueError(f"one expert action per observation: {len(expert_actions)} for {len(obs)}")
    head = policy.action_net
    angles, right, missed, false, total = [], 0, 0, 0, 0
    with torch.no_grad():
        for start in range(0, len(obs), batch_size):
            obs_t = torch.as_tensor(obs[start : start + batch_size], dtype=torch.float32)
            grasp = set_grasp(obs_t)
            actions = torch.as_tensor(expert_actions[start : start + batch_size])
            target, released = expert_forces(actions, grasp, head.k_max_ratio)
            features = policy.extract_features(obs_t, policy.pi_features_extractor)
            directions, _, logits, *_, mask = head.parts(
                policy.mlp_extractor.forward_actor(features)
            )
            real = grasp.mask > 0.5
            held = real & ~released
            chord = _direction_error(directions, target).clamp(max=2.0)  # 2 sin(angle / 2)
            angles.append(torch.rad2deg(2.0 * torch.asin(chord / 2.0))[held])
            chosen = release_set(logits, mask)
            right += int((chosen == released)[real].sum())
            missed += int((released & ~chosen)[real].sum())
            false += int((chosen & ~released)[real].sum())
            total += int(real.sum())
    angle = torch.cat(angles).numpy()
    return {
        "direction_median_deg": float(np.median(angle)),
        "direction_p90_deg": float(np.quantile(angle, 0.9)),
        "gate_right": right / max(total, 1),
        "releases_missed": float(missed),
        "false_releases": float(false),
    }


__all__ = ["expert_states", "fit_contact_set", "imitation_errors"]
