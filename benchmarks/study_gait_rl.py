"""RL that finds the whole gait: MaskablePPO on ``grasp_env/CubeGaitMoves-v0`` (or, with
``--object can``, ``grasp_env/CanGaitMoves-v0``, the coke can's full turn) with the certified
programme's potential-based shaping, the hand's move masks and expert starts, over seeds,
scored on the unshaped environment.

    python -m grasp_env_agents.benchmarks.study_gait_rl [--object cube|can]
        [--seeds 0 1 2 3 4] [--steps 300000] [--no-starts] [--no-shaping] [--no-lookahead]
        [--no-hold] [--out DIR]

Training (sb3-contrib's MaskablePPO, rl-zoo3's ``CubeGaitMoves-v0`` hyperparameters: 8 envs x
256 steps, gamma 0.99, lr linear from 3e-4, entropy bonus 0.05, 2 x 256 network, one torch
thread): every training env is ``GaitMoveMasks(GaitShaping(GaitExpertStarts(env)))``
(``grasp_env.envs.gait.shaping``): half the episodes start at a random pose of the optimal
gait, the reward gains gamma Phi(s') - Phi(s) with Phi the poses a gait can still hold
(scaled by the optimal gait's smallest margin), and the moves that slip at this pose or lose
a contact at the next are masked. Scoring: one deterministic episode of the unshaped
environment from its first pose (reset seed 0) to the first slip or drop, with the same
masks (they are part of the policy), as ``grasp-env gait --models`` plays the cube's: poses
held of 181 (37 on the can) and the worst margin held, and their IQM with rliable's 95%
interval over seeds. Writes DIR/seed{S}/model.zip (the masks' settings in its data, its
``gait_masks`` entry: ``grasp-env gait --models`` plays the model with them) and
DIR/seed{S}/curve.csv (steps, held, worst margin, CPU s, every 25,000 steps; 10,000 on the
can); prints the baselines on the same environment (the certified expert, the greedy gait,
the best fixed set), one row per seed and the IQM. ``--no-shaping``, ``--no-starts``,
``--no-lookahead`` (hold masks only) and ``--no-hold`` (the refused moves masked alone) are
the ablations.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from sb3_contrib import MaskablePPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.can_gait import CanGreedyGait
from grasp_env.envs.gait import GaitExpertStarts, GaitMoveMasks, GaitShaping, expert_gait
from grasp_env_agents.studies.results import iqm_interval

ENV_ID = "grasp_env/CubeGaitMoves-v0"
#: The moves-only gait env of each object.
ENV_IDS = {"cube": ENV_ID, "can": "grasp_env/CanGaitMoves-v0"}
#: Steps between two points of the learning curve.
CURVE_EVERY = {"cube": 25_000, "can": 10_000}


def masked(env: gym.Env, lookahead: bool = True, hold: bool = True) -> GaitMoveMasks:
    """The masks the agents train and act with: refused moves, moves that slip at this pose
    (``hold``), moves into a state that loses a contact at the next (``lookahead``, with
    ``hold`` only)."""
    return GaitMoveMasks(env, hold=hold, lookahead=lookahead and hold)


def episode(env: gym.Env, act: Any) -> tuple[int, float]:
    """Poses held and the worst margin held (deg) of one episode of ``act(obs) -> move`` on
    ``env`` from reset seed 0, to its first slip or drop."""
    obs, _ = env.reset(seed=0)
    rewards, terminated, truncated = [], False, False
    while not (terminated or truncated):
        obs, reward, terminated, truncated, _ = env.step(int(act(obs)))
        rewards.append(reward)
    held = np.asarray(rewards[:-1] if terminated else rewards)  # the last pose slipped
    return len(held), float(np.rad2deg(held.min())) if len(held) else float("nan")


def score(
    model: MaskablePPO, env_id: str = ENV_ID, lookahead: bool = True, hold: bool = True
) -> tuple[int, float]:
    """Poses held (of 181 on the cube, 37 on the can) and the worst margin held (deg) of one
    deterministic episode of the unshaped environment ``env_id``, to its first slip or drop,
    with the masks the model trained with."""
    env = masked(gym.make(env_id), lookahead, hold)
    try:
        return episode(
            env,
            lambda obs: model.predict(obs, deterministic=True, action_masks=env.action_masks())[0],
        )
    finally:
        env.close()


def baselines(object_name: str = "cube") -> dict[str, tuple[int, float]]:
    """(poses held, worst margin held in deg) on the object's moves-only env from its first
    pose: the certified optimal gait (the expert), the greedy gait (one-pose lookahead) played
    from the same start, and the best fixed set (-1 and NaN: no fixed set stays within
    reach)."""
    from grasp_env.envs.gait import GreedyGait

    env = gym.make(ENV_IDS[object_name])
    task = env.unwrapped.task
    gait, fixed = expert_gait(task), task.solution.fixed
    greedy = (CanGreedyGait if object_name == "can" else GreedyGait)(optimal_grip=True)
    held = int(np.isfinite(fixed.margins).sum()) if fixed.margin > -np.inf else -1
    out = {
        "optimal gait (certified)": (
            int(np.isfinite(gait.margins).sum()),
            float(np.rad2deg(gait.margin)),
        ),
        "greedy gait": episode(env, lambda obs: greedy.predict(obs)[0]),
        "best fixed set": (held, float(np.rad2deg(fixed.margin)) if held > 0 else float("nan")),
    }
    env.close()
    return out


class _Curve(BaseCallback):
    """Scores the policy every ``every`` steps into a CSV (the learning curve)."""

    def __init__(
        self,
        path: Path,
        every: int,
        env_id: str = ENV_ID,
        lookahead: bool = True,
        hold: bool = True,
    ) -> None:
        super().__init__()
        self.env_id, self.lookahead, self.hold = env_id, lookahead, hold
        self.file = path.open("w", newline="")
        self.rows = csv.writer(self.file)
        self.rows.writerow(["steps", "held", "worst_margin_deg", "cpu_s"])
        self.every, self.next = every, every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next:
            self.next += self.every
            held, worst = score(self.model, self.env_id, self.lookahead, self.hold)
            self.rows.writerow(
                [self.num_timesteps, held, f"{worst:.3f}", f"{time.process_time():.0f}"]
            )
            self.file.flush()
        return True

    def _on_training_end(self) -> None:
        self.file.close()


def train(
    seed: int,
    steps: int,
    out: Path,
    starts: float = 0.5,
    *,
    object_name: str = "cube",
    shaping: bool = True,
    lookahead: bool = True,
    hold: bool = True,
) -> tuple[int, float, float]:
    """Train one seed on ``object_name``'s moves-only env (``"cube"`` or ``"can"``) with
    expert starts (share ``starts``), the shaping (unless ``shaping`` is False) and the hold
    masks (unless ``hold`` is False: the refused moves alone; with the lookahead unless
    False); returns (poses held, worst margin held in deg,
    CPU minutes)."""
    if object_name not in ENV_IDS:
        raise ValueError(f"object_name must be one of {sorted(ENV_IDS)}, got {object_name!r}")
    env_id = ENV_IDS[object_name]
    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)

    def wrap(env: gym.Env) -> gym.Env:
        if starts > 0:
            env = GaitExpertStarts(env, starts, "expert")
        if shaping:
            env = GaitShaping(env, "held", gamma=0.99)
        return masked(env, lookahead, hold)

    venv = make_vec_env(env_id, n_envs=8, seed=seed, wrapper_class=wrap)
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
    curve = _Curve(out / "curve.csv", CURVE_EVERY[object_name], env_id, lookahead, hold)
    model.learn(steps, callback=curve)
    # the masks are part of the policy: grasp-env gait --models plays the model with them
    model.gait_masks = {"hold": True, "lookahead": lookahead}  # saved in the data
    model.save(out / "model.zip")
    venv.close()
    held, worst = score(model, env_id, lookahead, hold)
    return held, worst, (time.process_time() - cpu) / 60


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--object", choices=sorted(ENV_IDS), default="cube")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--steps", type=int, default=300_000, help="training steps a seed")
    parser.add_argument("--no-starts", action="store_true", help="every episode from pose 0")
    parser.add_argument("--no-shaping", action="store_true", help="the env's reward alone")
    parser.add_argument("--no-lookahead", action="store_true", help="hold masks only")
    parser.add_argument("--no-hold", action="store_true", help="mask the refused moves only")
    parser.add_argument("--out", type=Path, default=None, help="default results/gait_rl[_can]")
    args = parser.parse_args()
    if args.steps < 1 or any(not 0 <= s < 2**32 for s in args.seeds):
        parser.error("--steps must be >= 1 and every seed in [0, 2^32 - 1]")
    out = args.out or Path("results/gait_rl" + ("" if args.object == "cube" else "_can"))
    T = gym.make(ENV_IDS[args.object]).unwrapped.task.n_poses
    for name, (held, worst) in baselines(args.object).items():
        where = "none stays within reach" if held < 0 else f"held {held} of {T}"
        print(f"{name}: {where}, worst margin {worst:.3f} deg", flush=True)
    rows = []
    for seed in args.seeds:
        held, worst, minutes = train(
            seed,
            args.steps,
            out / f"seed{seed}",
            0 if args.no_starts else 0.5,
            object_name=args.object,
            shaping=not args.no_shaping,
            lookahead=not args.no_lookahead,
            hold=not args.no_hold,
        )
        rows.append((held, worst))
        print(
            f"seed {seed}: held {held} of {T}, worst margin {worst:.3f} deg, {minutes:.2f} CPU min",
            flush=True,
        )
    if len(rows) > 1:
        held = iqm_interval([r[0] for r in rows]).format("{:.1f}")
        worst = iqm_interval([r[1] for r in rows]).format("{:.3f}")
        print(f"IQM [95% CI] over {len(rows)} seeds: held {held}, worst margin {worst} deg")


if __name__ == "__main__":
    main()
