"""One policy for every grasp, measured: the contact-set policy trained on some shapes and
finger counts, evaluated on held-out scenes of those, of a shape it never saw, and of finger
counts outside its training range, against the certified optimum.

    python -m grasp_env_agents.benchmarks.study_contact_set [--states 20000] [--epochs 30]
        [--seeds 0] [--episodes 64] [--out FILE.md]

Training: states of ``grasp_env/ObjectGraspRandom-v0`` (boxes and cylinders, 3 to 6 contacts,
padded to 8), visited with the zero grip along whole trajectories (``terminate_on_slip``
off); the fit is the reward's exact gradient (:func:`~grasp_env_agents.learning.imitation.fit`
with the mean largest friction angle as its loss, no expert labels), so the expert is only
the judge. Evaluation: ``--episodes`` held-out episodes (seeds from 1,000,000) per condition,
the policy's mean action at every pose: the mean and p90 of the optimality gap (the expert's
margin minus the policy's, degrees, every pose), and the share of episodes held (no finger
slips at any pose). The zero grip (equilibrating forces alone) is the floor beside it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env_agents.learning.contact_set import ContactSetPolicy, set_grasp
from grasp_env_agents.learning.envs import HELD_OUT_SEED, action_scale
from grasp_env_agents.learning.imitation import StateCollector, fit, mean_action

ENV_ID = "grasp_env/ObjectGraspRandom-v0"
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


def train(states: int, epochs: int, seed: int) -> ContactSetPolicy:
    collector = StateCollector(ENV_ID, kwargs(TRAIN), ENVS, seed)
    try:
        shape = collector.envs.single_action_space.shape
        obs, _ = collector.collect(lambda o: np.zeros((len(o), *shape), np.float32), states)
        scale = action_scale(collector.envs)
        spaces = collector.envs.single_observation_space, collector.envs.single_action_space
    finally:
        collector.close()
    torch.manual_seed(seed)
    policy = ContactSetPolicy(*spaces, lambda _: 1e-3, k_max_ratio=scale)
    generator = torch.Generator().manual_seed(seed)
    empty = np.zeros((len(obs), 0), np.float32)
    grasp = set_grasp(torch.as_tensor(obs))
    fit(policy, obs, empty, epochs, 512, 1e-3, generator, grasp, 1.0, scale, label_weight=0.0)
    return policy


def evaluate(policy: ContactSetPolicy | None, condition: dict, episodes: int) -> dict:
    """Gap (deg, every pose) and episodes held of ``policy`` (None: the zero grip)."""
    envs = gym.make_vec(
        ENV_ID, num_envs=episodes, vectorization_mode="vector_entry_point", **kwargs(condition)
    )
    obs, _ = envs.reset(seed=HELD_OUT_SEED)
    running, held = np.ones(episodes, bool), np.ones(episodes, bool)
    gaps, counts = [], np.zeros(episodes, int)
    while running.any():
        if policy is None:
            action = np.zeros((episodes, *envs.single_action_space.shape), np.float32)
        else:
            with torch.no_grad():
                action = mean_action(policy, torch.as_tensor(obs)).clamp(-1, 1).numpy()
        obs, _, terminated, truncated, info = envs.step(action)
        gaps.append(np.asarray(info["optimality_gap"])[running])
        held[running] &= ~np.asarray(info["slip"]).any(-1)[running]
        counts[running] = np.asarray(info["n_contacts"])[running]
        running &= ~(terminated | truncated)
    envs.close()
    gap = np.rad2deg(np.concatenate(gaps))
    return {"mean": gap.mean(), "p90": np.quantile(gap, 0.9), "held": held.mean(), "n": counts}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--states", type=int, default=20_000, help="training states")
    parser.add_argument("--epochs", type=int, default=30, help="epochs of the fit")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="training seeds")
    parser.add_argument("--episodes", type=int, default=64, help="episodes per condition")
    parser.add_argument("--out", type=Path, help="write the table (Markdown) here")
    args = parser.parse_args()
    rows = [
        "| condition | grip | seed | mean gap (deg) | p90 gap (deg) | held |",
        "|---|---|---|---|---|---|",
    ]
    floor = {name: evaluate(None, c, args.episodes) for name, c in CONDITIONS.items()}
    for name, result in floor.items():
        rows.append(
            f"| {name} | zero interaction | - | {result['mean']:.3f} | {result['p90']:.3f} |"
            f" {result['held']:.1%} |"
        )
    for seed in args.seeds:
        start = time.perf_counter()
        policy = train(args.states, args.epochs, seed)
        print(f"seed {seed}: trained in {time.perf_counter() - start:.0f} s", flush=True)
        for name, condition in CONDITIONS.items():
            result = evaluate(policy, condition, args.episodes)
            rows.append(
                f"| {name} | contact-set policy | {seed} | {result['mean']:.3f} |"
                f" {result['p90']:.3f} | {result['held']:.1%} |"
            )
            print(rows[-1], flush=True)
    table = "\n".join(rows)
    print(table)
    if args.out:
        args.out.write_text(table + "\n")


if __name__ == "__main__":
    main()
