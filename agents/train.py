"""``grasp-env train``: PPO (optionally taught by the minimax expert first) from a YAML config.

One run, top to bottom (:func:`train`):

1. seed torch, numpy and Python, and cap torch's threads;
2. build the training environments and the held-out evaluation scenes;
3. build a fresh PPO model, or load the latest checkpoint with ``--resume``;
4. if the config has an ``imitation`` section: behaviour cloning and DAgger rounds from the
   minimax expert into the same policy network (:mod:`grasp_env_agents.imitation`);
5. PPO for ``total_timesteps`` environment steps with SB3's progress bar, checkpoint and
   evaluation callbacks; Ctrl-C saves a checkpoint before stopping;
6. save the model, the learning curve (CSV and PNG) and print the comparison with the expert
   and the baselines (:mod:`grasp_env_agents.evaluate`).

The run directory holds ``config.yaml`` (the exact config used), ``model.zip`` (and
``vecnormalize.pkl`` if observations are normalised), ``checkpoints/``, ``tb/`` (TensorBoard),
``eval/evaluations.npz`` (SB3's evaluation log), ``learning_curve.csv`` and ``.png``.
"""

from __future__ import annotations

import argparse
import csv
import re
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecNormalize, sync_envs_normalization
from tqdm import TqdmExperimentalWarning

from .config import TrainConfig, config_path, load_config, save_config, shipped_configs
from .envs import find_held_out, make_held_out_env, make_vec_env
from .features import GraspFeatures
from .policy import ForceDirectionPolicy

if TYPE_CHECKING:
    from .imitation import RoundResult

HELP = "train a PPO agent from a YAML config (default: a few minutes here)"

ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU, "silu": torch.nn.SiLU}
CHECKPOINT_PREFIX = "ppo"
CURVE_FIELDS = (
    "phase",
    "env_steps",
    "wall_seconds",
    "cpu_seconds",
    "mean_gap_deg",
    "p90_gap_deg",
    "worst_gap_deg",
    "success_rate",
    "mean_margin_deg",
    "mean_force",
)


# --- the command line ----------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        default="default",
        metavar="NAME|PATH",
        help=f"a shipped config by name ({', '.join(shipped_configs())}) or the path of a"
        " YAML config (default: default)",
    )
    parser.add_argument(
        "--run-dir",
        type=Path,
        help="directory for the run (default: runs/<config name>-<date>-<time>)",
    )
    parser.add_argument(
        "--resume",
        type=Path,
        metavar="RUN",
        help="continue the run in directory RUN from its latest checkpoint",
    )
    parser.add_argument(
        "--total-timesteps",
        type=int,
        metavar="N",
        help="PPO environment steps, overriding the config (e.g. to extend a resumed run)",
    )


def run(args: argparse.Namespace) -> int:
    overrides = {} if args.total_timesteps is None else {"total_timesteps": args.total_timesteps}
    if args.resume is not None:
        run_dir = args.resume
        if not (run_dir / "config.yaml").is_file():
            raise ValueError(f"--resume {str(run_dir)!r}: not a run directory (no config.yaml)")
        config = load_config(run_dir / "config.yaml", overrides)
    else:
        path = config_path(args.config)
        config = load_config(path, overrides)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        run_dir = args.run_dir or Path("runs") / f"{path.stem}-{stamp}"
    train(config, run_dir, resume=args.resume is not None)
    from .evaluate import evaluate_run

    print(evaluate_run(run_dir).markdown)
    return 0


# --- one training run ----------------------------------------------------------------------


def train(
    config: TrainConfig, run_dir: Path, *, resume: bool = False, progress_bar: bool = True
) -> PPO:
    """Train as ``config`` says, writing everything into ``run_dir``; return the model.

    With ``resume``, continue from the run's latest checkpoint: the weights, the optimiser
    state, PPO's step count, the learning-rate schedule and the learning curve carry on; the
    hyperparameters are ``config``'s (the run's ``config.yaml`` for ``--resume``). The random
    streams restart from the seed and the step count, so a resumed run is not bit-for-bit an
    uninterrupted one.
    """
    run_dir = Path(run_dir)
    checkpoint = latest_checkpoint(run_dir) if resume else None
    if not resume and (run_dir / "config.yaml").exists():
        raise ValueError(f"run directory {str(run_dir)!r} already holds a run; use --resume")
    run_dir.mkdir(parents=True, exist_ok=True)
    save_config(config, run_dir / "config.yaml")
    steps_done = 0 if checkpoint is None else checkpoint_steps(checkpoint)

    # SB3's progress bar uses tqdm's rich front end, which warns that it is experimental.
    warnings.filterwarnings("ignore", category=TqdmExperimentalWarning)

    # 1. Seeding: torch, numpy, random; few threads (the machine is shared, numbers repeatable).
    torch.set_num_threads(config.torch_threads)
    set_random_seed(config.seed + steps_done)

    # 2. Environments: training scenes from the seed, held-out scenes from a fixed far seed.
    env: VecEnv = make_vec_env(
        config.env_id, config.env_kwargs, config.n_envs, config.seed + steps_done
    )
    eval_env: VecEnv = make_held_out_env(config.env_id, config.env_kwargs, config.eval_episodes)
    held_out = find_held_out(eval_env)
    if config.normalize:
        if checkpoint is not None:
            env = VecNormalize.load(str(vecnormalize_path(checkpoint)), env)
        else:
            env = VecNormalize(env, norm_obs=True, norm_reward=False)
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False)

    # 3. The model, as the config says; on resume with the checkpoint's weights, optimiser
    # state and step count (so the run's config.yaml stays the one source of hyperparameters).
    model = new_model(config, env, run_dir)
    if checkpoint is not None:
        model.set_parameters(str(checkpoint), device="cpu")
        model.num_timesteps = steps_done
    curve = LearningCurve(run_dir / "learning_curve.csv", append=checkpoint is not None)
    clock = Clock(curve.last("wall_seconds"), curve.last("cpu_seconds"))
    imitation_steps = int(curve.last("env_steps", phase="imitation"))

    def evaluate_now(phase: str, env_steps: int) -> dict[str, float]:
        if config.normalize:
            sync_envs_normalization(env, eval_env)
        evaluate_policy(model, eval_env, n_eval_episodes=config.eval_episodes, warn=False)
        metrics = held_out.metrics()
        curve.append(phase, env_steps, clock(), metrics)
        return metrics

    # 4. The expert as teacher: behaviour cloning and DAgger rounds, then a checkpoint.
    try:
        if checkpoint is None:
            evaluate_now("initial", 0)
            if config.imitation is not None:
                imitation_steps = teach(model, config, env, evaluate_now)
                save_checkpoint(model, run_dir)

        # 5. PPO, with SB3's callbacks: checkpoints (and normalisation statistics), evaluations.
        remaining = config.total_timesteps - model.num_timesteps
        if remaining > 0:
            evaluation = EvalCallback(
                eval_env,
                callback_after_eval=RecordEvaluation(
                    lambda: curve.append(
                        "ppo", imitation_steps + model.num_timesteps, clock(), held_out.metrics()
                    )
                ),
                n_eval_episodes=config.eval_episodes,
                eval_freq=max(config.eval_freq // config.n_envs, 1) if config.eval_freq else 0,
                log_path=str(run_dir / "eval"),
                verbose=0,
                warn=False,
            )
            continue_evaluation_log(evaluation)
            callbacks: list[BaseCallback] = [evaluation]
            if config.checkpoint_freq:
                callbacks.append(
                    CheckpointCallback(
                        max(config.checkpoint_freq // config.n_envs, 1),
                        str(run_dir / "checkpoints"),
                        name_prefix=CHECKPOINT_PREFIX,
                        save_vecnormalize=True,
                    )
                )
            model.learn(
                remaining,
                callback=callbacks,
                tb_log_name="ppo",
                reset_num_timesteps=False,
                progress_bar=progress_bar,
            )
            if curve.last("env_steps") != imitation_steps + model.num_timesteps:
                evaluate_now("ppo", imitation_steps + model.num_timesteps)
            save_checkpoint(model, run_dir)
    except KeyboardInterrupt:
        # Save first. Mid-PPO, a checkpoint that --resume continues from; mid-imitation only
        # model.zip (a resumed run redoes the imitation rounds).
        if model.num_timesteps > 0 or latest_checkpoint(run_dir) is not None:
            save_checkpoint(model, run_dir)
        finish(model, run_dir, curve)
        print(f"\ninterrupted: saved the model in {run_dir} at {model.num_timesteps} PPO steps; "
              f"continue with: grasp-env train --resume {run_dir}")  # fmt: skip
        raise

    # 6. The final model and the learning curve.
    finish(model, run_dir, curve)
    return model


def teach(
    model: PPO,
    config: TrainConfig,
    env: VecEnv,
    evaluate_now: Callable[[str, int], dict[str, float]],
) -> int:
    """The imitation phase: the expert teaches ``model.policy``; returns the env steps used."""
    from .imitation import imitate

    assert config.imitation is not None
    steps = 0

    def after_round(result: RoundResult) -> None:
        nonlocal steps
        steps = result.env_steps
        metrics = evaluate_now("imitation", steps)
        print(
            f"imitation round {result.round}: {result.samples} labelled states, "
            f"loss {result.loss:.2e}, {result.seconds:.0f} s; held-out gap "
            f"{metrics['mean_gap_deg']:.2f} deg (p90 {metrics['p90_gap_deg']:.2f}), "
            f"success {metrics['success_rate']:.1%}"
        )

    imitate(
        model.policy,
        config.imitation,
        config.env_id,
        config.env_kwargs,
        config.seed,
        normalizer=env if isinstance(env, VecNormalize) else None,
        after_round=after_round,
    )
    return steps


def continue_evaluation_log(evaluation: EvalCallback) -> None:
    """Preload EvalCallback's lists from an earlier ``evaluations.npz`` (it rewrites the file)."""
    path = Path(f"{evaluation.log_path}.npz")
    if evaluation.log_path is None or not path.is_file():
        return
    with np.load(path) as log:
        evaluation.evaluations_timesteps = log["timesteps"].tolist()
        evaluation.evaluations_results = log["results"].tolist()
        evaluation.evaluations_length = log["ep_lengths"].tolist()
        if "successes" in log:
            evaluation.evaluations_successes = log["successes"].tolist()


def new_model(config: TrainConfig, env: VecEnv, run_dir: Path | None) -> PPO:
    """A fresh PPO model with the config's hyperparameters and network (TensorBoard logs in
    ``run_dir/tb`` unless ``run_dir`` is None)."""
    ppo = config.ppo
    rate = ppo.learning_rate
    policy = config.policy
    return PPO(
        ForceDirectionPolicy if policy.output == "force_directions" else "MlpPolicy",
        env,
        learning_rate=(lambda progress: progress * rate) if ppo.lr_schedule == "linear" else rate,
        n_steps=ppo.n_steps,
        batch_size=ppo.batch_size,
        n_epochs=ppo.n_epochs,
        gamma=ppo.gamma,
        gae_lambda=ppo.gae_lambda,
        clip_range=ppo.clip_range,
        ent_coef=ppo.ent_coef,
        vf_coef=ppo.vf_coef,
        max_grad_norm=ppo.max_grad_norm,
        target_kl=ppo.target_kl,
        policy_kwargs={
            "net_arch": {"pi": list(policy.net_arch), "vf": list(policy.net_arch)},
            "activation_fn": ACTIVATIONS[policy.activation],
            "log_std_init": policy.log_std_init,
            **({"features_extractor_class": GraspFeatures} if policy.features == "grasp" else {}),
            **({"k_max_ratio": config.k_max_ratio} if policy.output == "force_directions" else {}),
        },
        tensorboard_log=None if run_dir is None else str(run_dir / "tb"),
        seed=config.seed,
        device="cpu",
        verbose=0,
    )


# --- checkpoints ---------------------------------------------------------------------------


def checkpoint_steps(path: Path) -> int:
    """PPO steps of a checkpoint, from its SB3 CheckpointCallback name ``ppo_<N>_steps.zip``."""
    match = re.fullmatch(rf"{CHECKPOINT_PREFIX}_(\d+)_steps\.zip", path.name)
    if match is None:
        raise ValueError(f"{path} is not a checkpoint name")
    return int(match.group(1))


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint with the most PPO steps in ``run_dir/checkpoints`` (None: none yet)."""
    found = sorted((run_dir / "checkpoints").glob(f"{CHECKPOINT_PREFIX}_*_steps.zip"))
    return max(found, key=checkpoint_steps, default=None)


def vecnormalize_path(checkpoint: Path) -> Path:
    """The normalisation statistics saved beside a checkpoint (CheckpointCallback's naming)."""
    steps = checkpoint_steps(checkpoint)
    return checkpoint.with_name(f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.pkl")


def save_checkpoint(model: PPO, run_dir: Path) -> Path:
    """Save the model (and normalisation statistics) under CheckpointCallback's names."""
    path = run_dir / "checkpoints" / f"{CHECKPOINT_PREFIX}_{model.num_timesteps}_steps.zip"
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        normalizer.save(str(vecnormalize_path(path)))
    return path


def finish(model: PPO, run_dir: Path, curve: LearningCurve) -> None:
    """The run's final files: model.zip, vecnormalize.pkl (if used), learning_curve.png."""
    model.save(run_dir / "model.zip")
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        normalizer.save(str(run_dir / "vecnormalize.pkl"))
    curve.plot(run_dir / "learning_curve.png")


# --- the learning curve --------------------------------------------------------------------


class RecordEvaluation(BaseCallback):
    """Called by SB3's EvalCallback after each evaluation: records the held-out metrics."""

    def __init__(self, record: Callable[[], None]) -> None:
        super().__init__()
        self.record = record

    def _on_step(self) -> bool:
        self.record()
        return True


class Clock:
    """Wall and CPU seconds of training so far, continuing from a resumed run's times.

    The CPU time of this process tells how long the run would take on an idle machine when
    the wall time is stretched by other processes sharing the cores.
    """

    def __init__(self, wall: float = 0.0, cpu: float = 0.0) -> None:
        self.wall = time.perf_counter() - wall
        self.cpu = time.process_time() - cpu

    def __call__(self) -> tuple[float, float]:
        return time.perf_counter() - self.wall, time.process_time() - self.cpu


class LearningCurve:
    """Held-out evaluations over training, appended to a CSV as they happen.

    ``env_steps`` counts every environment step the run has consumed: states collected in
    imitation rounds, then PPO's steps.
    """

    def __init__(self, path: Path, append: bool = False) -> None:
        self.path = path
        self.rows: list[dict[str, str]] = []
        if append and path.is_file():
            with path.open() as file:
                self.rows = list(csv.DictReader(file))
        else:
            with path.open("w", newline="") as file:
                csv.writer(file).writerow(CURVE_FIELDS)

    def append(
        self, phase: str, env_steps: int, seconds: tuple[float, float], metrics: dict
    ) -> None:
        """One evaluation: ``seconds`` is (wall, cpu) since the run started."""
        row = {
            "phase": phase,
            "env_steps": env_steps,
            "wall_seconds": round(seconds[0], 2),
            "cpu_seconds": round(seconds[1], 2),
        }
        row |= {key: metrics[key] for key in CURVE_FIELDS[4:]}
        self.rows.append({key: str(value) for key, value in row.items()})
        with self.path.open("a", newline="") as file:
            csv.DictWriter(file, CURVE_FIELDS).writerow(row)

    def last(self, field: str, phase: str | None = None) -> float:
        """The latest value of a numeric field (of a phase), 0 if there is none."""
        rows = [row for row in self.rows if phase is None or row["phase"] == phase]
        return float(rows[-1][field]) if rows else 0.0

    def plot(self, path: Path) -> None:
        """Mean and p90 optimality gap and success rate against steps and wall time."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import EngFormatter

        if not self.rows:
            return
        data = {key: np.array([float(r[key]) for r in self.rows]) for key in CURVE_FIELDS[1:]}
        fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        for ax, x, label in (
            (axes[0], data["env_steps"], "environment steps"),
            (axes[1], data["wall_seconds"] / 60, "wall time (min)"),
        ):
            ax.plot(x, data["mean_gap_deg"], "o-", label="mean gap")
            ax.plot(x, data["p90_gap_deg"], "s--", label="90th percentile gap")
            ax.set_xlabel(label)
            ax.set_yscale("symlog", linthresh=0.1)
            ax.grid(True, which="both", alpha=0.3)
            twin = ax.twinx()
            twin.plot(x, 100 * data["success_rate"], "g:", label="success rate")
            twin.set_ylim(0, 101)
            twin.set_ylabel("held-out success (%)", color="g")
        axes[0].xaxis.set_major_formatter(EngFormatter())  # 100k, not 100000 (labels overlap)
        axes[0].set_ylabel("optimality gap (deg)")
        axes[0].legend(loc="upper right")
        fig.suptitle("Held-out scenes over training")
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
