"""RL that finds the whole cube gait: MaskablePPO on ``grasp_env/CubeGaitMoves-v0`` with the
certified programme's potential-based shaping, the hand's move masks and expert starts, over
seeds, scored on the unshaped environment.

    python -m grasp_env_agents.benchmarks.study_gait_rl [--seeds 0 1 2 3 4] [--steps 300000]
        [--no-starts] [--out DIR]

Training (sb3-contrib's MaskablePPO, rl-zoo3's ``CubeGaitMoves-v0`` hyperparameters: 8 envs x
256 steps, gamma 0.99, lr linear from 3e-4, entropy bonus 0.05, 2 x 256 network, one torch
thread): every training env is ``GaitMoveMasks(GaitShaping(GaitExpertStarts(env)))``
(``grasp_env.envs.gait.shaping``): half the episodes start at a random pose of the optimal
gait, the reward gains gamma Phi(s') - Phi(s) with Phi the poses a gait can still hold
(scaled by the optimal gait's smallest margin), and the moves that slip at this pose or lose
a contact at the next are masked. Scoring: one deterministic episode of the unshaped
environment from its first pose (reset seed 0) to the first slip or drop, with the same
masks (they are part of the policy), as ``grasp-env gait --models`` plays the others: poses
held of 181 and the worst margin held, and their IQM with rliable's 95% interval over seeds.
Writes DIR/seed{S}/model.zip and DIR/seed{S}/curve.csv (steps, held, worst margin, CPU s,
every 25,000 steps); prints one row per seed and the IQM.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import MaskablePPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.gait import GaitExpertStarts, GaitMoveMasks, GaitShaping
from grasp_env_agents.studies.results import iqm_interval

ENV_ID = "grasp_env/CubeGaitMoves-v0"


def masked(env: gym.Env) -> GaitMoveMasks:
    """The masks the agents train and act with: refused moves, moves that slip at this pose,
    moves into a state that loses a contact at the next."""
    return GaitMoveMasks(env, hold=True, lookahead=True)


def score(model: MaskablePPO) -> tuple[int, float]:
    """Poses held (of 181) and the worst margin held (deg) of one deterministic episode of
    the unshaped environment, to its first slip or drop."""
    env = masked(gym.make(ENV_ID))
    obs, _ = env.reset(seed=0)
    rewards, terminated, truncated = [], False, False
    while not (terminated or truncated):
        action = model.predict(obs, deterministic=True, action_masks=env.action_masks())[0]
        obs, reward, terminated, truncated, _ = env.step(int(action))
        rewards.append(reward)
    env.close()
    held = np.asarray(rewards[:-1] if terminated else rewards)  # the last pose slipped
    return len(held), float(np.rad2deg(held.min())) if len(held) else float("nan")


class _Curve(BaseCallback):
    """Scores the policy every ``every`` steps into a CSV (the learning curve)."""

    def __init__(self, path: Path, every: int) -> None:
        super().__init__()
        self.file = path.open("w", newline="")
        self.rows = csv.writer(self.file)
        self.rows.writerow(["steps", "held", "worst_margin_deg", "cpu_s"])
        self.every, self.next = every, every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next:
            self.next += self.every
            held, worst = score(self.model)
            self.rows.writerow(
                [self.num_timesteps, held, f"{worst:.3f}", f"{time.process_time():.0f}"]
            )
            self.file.flush()
        return True

    def _on_training_end(self) -> None:
        self.file.close()


def train(seed: int, steps: int, out: Path, starts: float = 0.5) -> tuple[int, float, float]:
    """Train one seed; returns (poses held, worst margin held in deg, CPU minutes)."""
    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)

    def wrap(env: gym.Env) -> gym.Env:
        if starts > 0:
            env = GaitExpertStarts(env, starts, "expert")
        return masked(GaitShaping(env, "held", gamma=0.99))

    venv = make_vec_env(ENV_ID, n_envs=8, seed=seed, wrapper_class=wrap)
    model = MaskablePPO(
        "MlpPolicy",
        venv,
        n_steps=256,
        batch_size=256,
        n_epochs=10,
        gamma=0.99,
        gae_lambda=0.95,
        learning_rate=lambda left: 3e-4 * left,
        clip_range=0.2,
        ent_coef=0.05,
        policy_kwargs={"net_arch": [256, 256]},
        seed=seed,
        device="cpu",
    )
    cpu = time.process_time()
    model.learn(steps, callback=_Curve(out / "curve.csv", 25_000))
    model.save(out / "model.zip")
    venv.close()
    held, worst = score(model)
    return held, worst, (time.process_time() - cpu) / 60


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--steps", type=int, default=300_000, help="training steps a seed")
    parser.add_argument("--no-starts", action="store_true", help="every episode from pose 0")
    parser.add_argument("--out", type=Path, default=Path("results/gait_rl"))
    args = parser.parse_args()
    if args.steps < 1 or any(not 0 <= s < 2**32 for s in args.seeds):
        parser.error("--steps must be >= 1 and every seed in [0, 2^32 - 1]")
    rows = []
    for seed in args.seeds:
        held, worst, minutes = train(
            seed, args.steps, args.out / f"seed{seed}", 0 if args.no_starts else 0.5
        )
        rows.append((held, worst))
        print(
            f"seed {seed}: held {held} of 181, worst margin {worst:.3f} deg, {minutes:.2f} CPU min",
            flush=True,
        )
    if len(rows) > 1:
        held = iqm_interval([r[0] for r in rows]).format("{:.1f}")
        worst = iqm_interval([r[1] for r in rows]).format("{:.3f}")
        print(f"IQM [95% CI] over {len(rows)} seeds: held {held}, worst margin {worst} deg")


if __name__ == "__main__":
    main()
