"""One policy for every grasp, measured: the contact-set policy trained on some shapes and
finger counts, evaluated on held-out scenes of those, of a shape it never saw, and of finger
counts outside its training range, against the certified optimum.

    python -m grasp_env_agents.benchmarks.study_contact_set [--states 8000] [--epochs 30]
        [--reward-epochs 0] [--gate-weight 0.1] [--geometry-only] [--validation 2000]
        [--seeds 0] [--episodes 64] [--out FILE.md]

Training: states of ``grasp_env/ObjectGraspRandom-v0`` (boxes and cylinders, 3 to 6 contacts,
padded to 8), visited with the zero grip along whole trajectories (``terminate_on_slip``
off), each with the expert's action (the certified optimum the environment reports);
:func:`~grasp_env_agents.learning.contact_set_fit.fit_contact_set` fits the head's force
directions, magnitudes and release gate to the expert's forces for ``--epochs``, then
``--reward-epochs`` more with the reward's exact gradient added (released fingers at angle
0, as the environment counts them); ``--gate-weight`` weighs the release gate's
cross-entropy, ``--geometry-only`` leaves the mechanics tokens out of the network's inputs
(the ablation). ``--validation`` more expert-labelled states (another seed) measure the fit:
the head's directions against the expert's forces and its gate against the expert's
released set (:func:`~grasp_env_agents.learning.contact_set_fit.imitation_errors`).
Evaluation: ``--episodes`` held-out episodes (seeds
from 1,000,000) per condition, the policy's mean action at every pose: the mean and p90 of
the optimality gap (the expert's margin minus the policy's, degrees, every pose), the share
of episodes held (no finger slips at any pose), and the grip force against the expert's
(the mean over poses of sum_i |P_i| over the expert's sum_i |P*_i|). The zero grip
(equilibrating forces alone) and the paper's equal-k grip (eq. 8) are the floors beside
it. CPU seconds are the process's.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env_agents.learning.contact_set import (
    ENV_ID,
    ContactSetPolicy,
    net_forces,
    played_grip,
    set_grasp,
)
from grasp_env_agents.learning.contact_set_fit import (
    expert_states,
    fit_contact_set,
    imitation_errors,
)
from grasp_env_agents.learning.contact_set_tokens import EQUAL_K
from grasp_env_agents.learning.envs import HELD_OUT_SEED, action_scale
from grasp_env_agents.learning.imitation import mean_action

MAX_CONTACTS = 8
TRAIN = {"shapes": ("box", "cylinder"), "contact_counts": (3, 4, 5, 6)}
CONDITIONS = {
    "seen shapes, 3-6 contacts": TRAIN,
    "held-out shape (sphere), 3-6 contacts": {
        "shapes": ("sphere",),
        "contact_counts": (3, 4, 5, 6),
    },
    "seen shapes, 7-8 contacts (unseen counts)": {
        "shapes": ("box", "cylinder"),
        "contact_counts": (7, 8),
    },
}
ENVS = 64


def kwargs(condition: dict) -> dict:
    return {**condition, "max_contacts": MAX_CONTACTS, "terminate_on_slip": False}


def train(
    states: int,
    epochs: int,
    reward_epochs: int,
    seed: int,
    gate_weight: float = 0.1,
    mechanics: bool = True,
    validation: int = 0,
) -> ContactSetPolicy:
    """The contact-set policy fitted on ``states`` expert-labelled training states (and its
    imitation errors on ``validation`` others printed)."""
    start = time.process_time()
    obs, expert = expert_states(kwargs(TRAIN), states, ENVS, seed)
    print(f"seed {seed}: {states} states labelled in {time.process_time() - start:.0f} CPU s")
    envs = gym.make_vec(
        ENV_ID, num_envs=1, vectorization_mode="vector_entry_point", **kwargs(TRAIN)
    )
    spaces = envs.single_observation_space, envs.single_action_space
    scale = action_scale(envs)
    envs.close()
    torch.manual_seed(seed)
    policy = ContactSetPolicy(*spaces, lambda _: 1e-3, k_max_ratio=scale, mechanics=mechanics)
    generator = torch.Generator().manual_seed(seed)
    held_out = expert_states(kwargs(TRAIN), validation, ENVS, 10_000 + seed) if validation else None
    start = time.process_time()
    losses = fit_contact_set(
        policy, obs, expert, epochs, 256, 1e-3, generator, gate_weight=gate_weight
    )
    print(
        f"seed {seed}: imitation losses {losses[0]:.4g} -> {losses[-1]:.4g}"
        f" ({time.process_time() - start:.0f} CPU s)",
        flush=True,
    )
    if held_out is not None:
        print(f"seed {seed}: validation {imitation_errors(policy, *held_out)}", flush=True)
    if reward_epochs:
        losses = fit_contact_set(
            policy,
            obs,
            expert,
            reward_epochs,
            256,
            3e-4,
            generator,
            reward_weight=1.0,
            gate_weight=gate_weight,
        )
        print(f"seed {seed}: with the reward {losses[0]:.4g} -> {losses[-1]:.4g}", flush=True)
        if held_out is not None:
            print(f"seed {seed}: validation {imitation_errors(policy, *held_out)}", flush=True)
    return policy


def evaluate(policy: ContactSetPolicy | float, condition: dict, episodes: int) -> dict:
    """Gap (deg, every pose), episodes held and grip force ratio of ``policy`` (a number:
    every k_ij / w at that value, 0 the zero grip, EQUAL_K the paper's equal-k grip)."""
    envs = gym.make_vec(
        ENV_ID, num_envs=episodes, vectorization_mode="vector_entry_point", **kwargs(condition)
    )
    scale = action_scale(envs)
    obs, _ = envs.reset(seed=HELD_OUT_SEED)
    running, held = np.ones(episodes, bool), np.ones(episodes, bool)
    gaps, ratios = [], []
    while running.any():
        if not isinstance(policy, ContactSetPolicy):
            shape = (episodes, *envs.single_action_space.shape)
            action = np.full(shape, policy / scale, np.float32)
        else:
            with torch.no_grad():
                action = mean_action(policy, torch.as_tensor(obs)).clamp(-1, 1).numpy()
        following, _, terminated, truncated, info = envs.step(action)
        gaps.append(np.asarray(info["optimality_gap"])[running])
        held[running] &= ~np.asarray(info["slip"]).any(-1)[running]
        # the grip force, the policy's over the expert's (both in units of the weight)
        weight = np.linalg.norm(info["equilibrating_forces"].sum(1), axis=1)
        grasp = set_grasp(torch.as_tensor(obs))
        best = torch.as_tensor(info["expert_k"] / (weight[:, None] * scale))
        expert = net_forces(played_grip(best, grasp, scale), grasp).norm(dim=-1).sum(1).numpy()
        mine = np.linalg.norm(info["contact_forces"], axis=-1).sum(1) / weight
        ratios.append((mine / expert)[running])
        running &= ~(terminated | truncated)
        obs = following
    envs.close()
    gap = np.rad2deg(np.concatenate(gaps))
    return {
        "mean": gap.mean(),
        "p90": np.quantile(gap, 0.9),
        "held": held.mean(),
        "force": np.concatenate(ratios).mean(),
    }


def row(name: str, grip: str, seed: Any, result: dict) -> str:
    """One Markdown row of the table."""
    return (
        f"| {name} | {grip} | {seed} | {result['mean']:.3f} | {result['p90']:.3f} |"
        f" {result['held']:.1%} | {result['force']:.3f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--states", type=int, default=8_000, help="training states")
    parser.add_argument("--epochs", type=int, default=30, help="epochs of imitation")
    parser.add_argument(
        "--reward-epochs", type=int, default=0, help="epochs with the reward's gradient after"
    )
    parser.add_argument(
        "--gate-weight", type=float, default=0.1, help="the release gate's loss weight"
    )
    parser.add_argument(
        "--geometry-only", action="store_true", help="no mechanics tokens (the ablation)"
    )
    parser.add_argument(
        "--validation", type=int, default=0, help="held-out labelled states for the fit's errors"
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="training seeds")
    parser.add_argument("--episodes", type=int, default=64, help="episodes per condition")
    parser.add_argument("--no-floor", action="store_true", help="skip the zero grip's rows")
    parser.add_argument("--out", type=Path, help="write the table (Markdown) here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = [
        "| condition | grip | seed | mean gap (deg) | p90 gap (deg) | held | force ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    if not args.no_floor:
        for grip, value in (("zero interaction", 0.0), ("equal k (eq. 8)", EQUAL_K)):
            for name, condition in CONDITIONS.items():
                rows.append(row(name, grip, "-", evaluate(value, condition, args.episodes)))
                print(rows[-1], flush=True)
    for seed in args.seeds:
        start = time.process_time()
        policy = train(
            args.states,
            args.epochs,
            args.reward_epochs,
            seed,
            args.gate_weight,
            not args.geometry_only,
            args.validation,
        )
        print(f"seed {seed}: trained in {time.process_time() - start:.0f} CPU s", flush=True)
        for name, condition in CONDITIONS.items():
            rows.append(
                row(name, "contact-set policy", seed, evaluate(policy, condition, args.episodes))
            )
            print(rows[-1], flush=True)
    table = "\n".join(rows)
    print(table)
    print(f"CPU {time.process_time():.0f} s")
    if args.out:
        args.out.write_text(table + "\n")


if __name__ == "__main__":
    main()
