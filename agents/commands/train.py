"""``grasp-env train``: PPO (optionally taught by the minimax expert first), TD3 or SAC from a
YAML config.

One run, top to bottom (:func:`train`):

1. seed torch, numpy and Python, and cap torch's threads;
2. build the training environments and the held-out evaluation scenes;
3. build a fresh model of the config's ``algo``
   (:func:`grasp_env_agents.learning.algorithms.new_model`),
   or, with ``--resume``, load the newest intact checkpoint
   (:mod:`grasp_env_agents.learning.checkpoints`: the algorithm's, else the last imitation round's);
4. if the config has an ``imitation`` section: behaviour cloning and DAgger rounds from the
   minimax expert into the same policy network (:mod:`grasp_env_agents.learning.imitation`),
   each round
   evaluated, logged and checkpointed;
5. the algorithm for ``total_timesteps`` environment steps with evaluation and checkpoint
   callbacks (each evaluation labelled with the steps its weights were trained on, the last
   one of the final model); Ctrl-C (or SIGTERM, from `grasp-env train`) saves a checkpoint
   before stopping;
6. save the model, the learning curve (CSV and PNG) and print the comparison with the expert
   and the baselines (:mod:`grasp_env_agents.studies.evaluation`).

The run directory holds ``config.yaml`` (the exact config used), ``model.zip`` (and
``vecnormalize.pkl`` if observations are normalised), ``checkpoints/``, ``tb/imitation`` and
``tb/<algo>`` (TensorBoard, at the run's environment steps), ``eval/evaluations.npz`` (SB3's
evaluation log), ``learning_curve.csv`` and ``.png`` (:mod:`grasp_env_agents.run.curve`).
"""

from __future__ import annotations

import argparse
import shutil
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecNormalize, sync_envs_normalization

from ..cli import folder_argument, integer_argument, path_argument
from ..learning.algorithms import new_model
from ..learning.checkpoints import (
    Start,
    find_start,
    imitation_checkpoint,
    load_round_data,
    model_checkpoint,
    restore,
    save_checkpoint,
    save_model,
    save_round_data,
    tensorboard_logger,
    trim_tensorboard,
)
from ..learning.envs import HeldOutScenes, find_held_out, make_held_out_env, make_vec_env
from ..learning.models import load_vecnormalize
from ..progress import say, status
from ..run.config import TrainConfig, config_path, load_config, save_config, shipped_configs
from ..run.curve import Clock, LearningCurve, last_steps
from ..run.folder import RunFolder

if TYPE_CHECKING:
    from ..learning.imitation import RoundResult


#: Held-out metrics logged to TensorBoard (``held_out/<name>``), from the learning curve's.
LOGGED = ("mean_gap_deg", "p90_gap_deg", "worst_gap_deg", "success_rate", "mean_margin_deg")


# --- the command line ----------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        metavar="NAME|PATH",
        help=f"a shipped config by name ({', '.join(shipped_configs())}) or the path of a"
        " YAML config (default: default)",
    )
    parser.add_argument(
        "--run-dir",
        type=folder_argument,
        help="directory for the run (default: runs/<config name>-<date>-<time>)",
    )
    parser.add_argument(
        "--resume",
        type=path_argument,
        metavar="RUN",
        help="continue the run in directory RUN from its newest intact checkpoint",
    )
    parser.add_argument(
        "--total-timesteps",
        type=integer_argument(0),
        metavar="N",
        help="the algorithm's environment steps, overriding the config (e.g. to extend a"
        " resumed run)",
    )


def run(args: argparse.Namespace) -> int:
    overrides = {} if args.total_timesteps is None else {"total_timesteps": args.total_timesteps}
    if args.resume is not None:
        if args.config is not None or args.run_dir is not None:
            raise ValueError(
                "--resume continues a run with its own config.yaml in its own directory:"
                " give it without --config and --run-dir"
            )
        run_dir = args.resume
        if not RunFolder(run_dir).is_run():
            raise ValueError(f"--resume {str(run_dir)!r}: not a run directory (no config.yaml)")
        config = load_config(RunFolder(run_dir).config, overrides)
    else:
        path = config_path(args.config or "default")
        config = load_config(path, overrides)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        run_dir = args.run_dir or Path("runs") / f"{path.stem}-{stamp}"
    # A batch scheduler, a container or `kill` stop a run by SIGTERM: save it as on Ctrl-C.
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        train(config, run_dir, resume=args.resume is not None)
    finally:
        signal.signal(signal.SIGTERM, previous)
    with status("loading the evaluation"):
        from ..studies.evaluation import evaluate_run

    print(evaluate_run(run_dir).markdown)
    return 0


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


# --- one training run ----------------------------------------------------------------------


def train(
    config: TrainConfig, run_dir: Path, *, resume: bool = False, progress_bar: bool = True
) -> BaseAlgorithm:
    """Train as ``config`` says, writing everything into ``run_dir``; return the model.

    With ``resume``, continue from the run's newest intact checkpoint: the weights, the
    optimiser state, the algorithm's step count (and an off-policy replay buffer), the
    learning-rate schedule, the imitation rounds done
    and their data, the learning curve and the TensorBoard logs (both cut back to the
    checkpoint) carry on; the hyperparameters are ``config``'s (the run's ``config.yaml`` for
    ``--resume``). The random streams restart from the seed and the step count, so a resumed
    run is not bit-for-bit an uninterrupted one.
    """
    run_dir = Path(run_dir)
    folder = RunFolder(run_dir)
    if not resume and folder.config.exists():
        raise ValueError(f"run directory {str(run_dir)!r} already holds a run; use --resume")
    start = Start()
    if resume:
        imitation_steps = last_steps(folder.curve, "imitation")
        start = find_start(run_dir, config.normalize, imitation_steps, config.algo)
        if config.total_timesteps < start.model_steps:
            raise ValueError(
                f"total_timesteps {config.total_timesteps:,} is below the {start.model_steps:,}"
                f" {config.algo.upper()} steps {run_dir} has done: give more to extend it"
            )
        say(f"resume: from {start.checkpoint or 'the beginning (no intact checkpoint)'}")
    created = not run_dir.exists()
    run_dir.mkdir(parents=True, exist_ok=True)

    # 1. Seeding: torch, numpy, random; few threads (the machine is shared, numbers repeatable).
    torch.set_num_threads(config.torch_threads)
    set_random_seed(config.seed + start.model_steps)

    try:
        with status("building the environments and the model"):
            env, eval_env, model = build(config, start, run_dir)
    except BaseException:
        if created:  # a config that fails to build leaves no empty run directory behind
            shutil.rmtree(run_dir, ignore_errors=True)
        raise
    # written once the run can start: a config that fails to build leaves no run to --resume
    save_config(config, folder.config)
    held_out = find_held_out(eval_env)
    # a resumed run drops what the killed one logged after its checkpoint
    kept = start.env_steps if start.checkpoint is not None else None
    curve = LearningCurve(folder.curve, keep_until=kept, expert=config.expert_teaches)
    trim_tensorboard(folder.tensorboard, -1 if kept is None else kept)
    clock = Clock(curve.last("wall_seconds"), curve.last("cpu_seconds"))
    imitation_steps = int(curve.last("env_steps", phase="imitation"))

    def evaluate_now(phase: str, env_steps: int, logger: Logger, step: int) -> dict[str, float]:
        """Evaluate on the held-out scenes, into the curve and TensorBoard (at ``step``)."""
        if config.normalize:
            sync_envs_normalization(env, eval_env)
        with status(f"evaluating on {config.eval_episodes} held-out scenes"):
            evaluate_policy(model, eval_env, n_eval_episodes=config.eval_episodes, warn=False)
        metrics = held_out.metrics()
        curve.append(phase, env_steps, clock(), metrics)
        log_held_out(logger, metrics, clock()[0], step)
        return metrics

    algo = config.algo
    trained = TrainedSteps()
    learning = start.model_steps > 0 or (start.checkpoint is not None and start.round < 0)
    try:
        # 4. The expert as teacher: behaviour cloning and DAgger rounds, then a checkpoint.
        if config.imitation is not None and not learning:
            imitation_steps = teach(model, config, env, evaluate_now, run_dir, start)
            save_model(model, model_checkpoint(run_dir, algo, 0))
            for data in folder.all_round_data():  # only an unfinished phase needs them
                data.unlink()
        learning = True

        # 5. The algorithm, with SB3's callbacks: evaluations, and checkpoints of our own.
        remaining = config.total_timesteps - model.num_timesteps
        if remaining > 0 or config.imitation is None:
            model.set_logger(
                tensorboard_logger(folder.tensorboard_of(algo), offset=imitation_steps)
            )
        if start.checkpoint is None and config.imitation is None:
            evaluate_now("initial", 0, model.logger, 0)
        if remaining > 0:
            # evaluated last (its final evaluation) and checkpointed after learn() returns
            record = held_out_recorder(model, algo, held_out, curve, clock, imitation_steps)
            learn(model, config, eval_env, run_dir, remaining, record, progress_bar, trained)
            save_checkpoint(model, model_checkpoint(run_dir, algo, model.num_timesteps))
    except KeyboardInterrupt:
        # Save first: while learning a checkpoint that --resume continues from; mid-imitation
        # the rounds done are checkpointed already (the round under way is lost).
        if learning:
            if trained.steps is not None:
                # The weights are those of the rollout's start: the checkpoint's count is
                # theirs. PPO drops the rollout under way; TD3 and SAC keep in their buffer
                # what it stored (an interrupt can land between a step's count and its store).
                model.num_timesteps = trained.steps
            save_checkpoint(model, model_checkpoint(run_dir, algo, model.num_timesteps))
        finish(model, run_dir, curve)
        print(f"\ninterrupted: saved the model in {run_dir} at {model.num_timesteps} "
              f"{algo.upper()} steps; continue with: grasp-env train --resume"
              f" {run_dir}")  # fmt: skip
        raise

    # 6. The final model and the learning curve.
    finish(model, run_dir, curve)
    return model


def build(config: TrainConfig, start: Start, run_dir: Path) -> tuple[VecEnv, VecEnv, BaseAlgorithm]:
    """The training and held-out environments and the model, fresh or from ``start``."""
    # 2. Environments: training scenes from the seed, held-out scenes from a fixed far seed.
    env: VecEnv = make_vec_env(
        config.env_id, config.env_kwargs, config.n_envs, config.seed + start.model_steps
    )
    eval_env: VecEnv = make_held_out_env(config.env_id, config.env_kwargs, config.eval_episodes)
    if config.normalize:
        if start.vecnormalize is not None:
            env = load_vecnormalize(start.vecnormalize, env)
        else:
            env = VecNormalize(env, norm_obs=True, norm_reward=False)
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False)

    # 3. The model, as the config says; on resume with the checkpoint's weights, optimiser
    # state, step count and replay buffer (so the run's config.yaml stays the one source of
    # hyperparameters).
    model = new_model(config, env)
    if start.checkpoint is not None:
        try:
            restore(model, start)
        except Exception as error:  # intact, but another network than the config's
            config_file = RunFolder(run_dir).config
            raise ValueError(
                f"{start.checkpoint} does not fit {config_file}'s network ({error})"
            ) from None
    return env, eval_env, model


def log_held_out(logger: Logger, metrics: dict[str, float], wall: float, step: int) -> None:
    """The held-out metrics into TensorBoard (``held_out/...``) at environment step ``step``."""
    for key in LOGGED:
        logger.record(f"held_out/{key}", metrics[key])
    logger.record("time/wall_seconds", wall)
    logger.dump(step)


def teach(
    model: BaseAlgorithm,
    config: TrainConfig,
    env: VecEnv,
    evaluate_now: Callable[[str, int, Logger, int], dict[str, float]],
    run_dir: Path,
    start: Start,
) -> int:
    """The imitation phase from ``start``: the expert teaches ``model.policy``, each round
    evaluated, logged to TensorBoard and checkpointed; returns the env steps it used."""
    from ..learning.imitation import imitate

    assert config.imitation is not None
    logger = tensorboard_logger(RunFolder(run_dir).tensorboard_of("imitation"))
    if start.checkpoint is None:
        evaluate_now("initial", 0, logger, 0)
    done = [load_round_data(path)[:2] for path in start.data]
    steps = start.env_steps

    def after_round(result: RoundResult) -> None:
        nonlocal steps
        steps = result.env_steps
        logger.record("imitation/loss", result.loss)
        logger.record("imitation/labelled_states", result.samples)
        logger.record("imitation/round", result.round)
        logger.record("imitation/round_seconds", result.seconds)
        logger.record("imitation/validation_angle_deg", result.validation_angle_deg)
        logger.record("imitation/kept", float(result.kept))
        metrics = evaluate_now("imitation", steps, logger, steps)
        save_round_data(run_dir, result.round, result.observations, result.labels, steps)
        save_model(model, imitation_checkpoint(run_dir, result.round))
        say(
            f"imitation round {result.round}: {result.samples} states, "
            f"loss {result.loss:.2e}, {result.seconds:.0f} s, validation "
            f"{result.validation_angle_deg:.2f} deg ({'kept' if result.kept else 'undone'}); "
            f"held-out gap "
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
        done=done,
        env_steps=steps,
    )
    logger.close()
    return steps


def held_out_recorder(
    model: BaseAlgorithm,
    phase: str,
    held_out: HeldOutScenes,
    curve: LearningCurve,
    clock: Clock,
    imitation_steps: int,
) -> Callable[[int], None]:
    """What to do after each of the algorithm's evaluations, of weights trained on ``steps``
    of the algorithm's steps: the curve's row (of ``phase``), the TensorBoard scalars."""

    def record(steps: int) -> None:
        metrics = held_out.metrics()
        curve.append(phase, imitation_steps + steps, clock(), metrics)
        log_held_out(model.logger, metrics, clock()[0], steps)

    return record


def learn(
    model: BaseAlgorithm,
    config: TrainConfig,
    eval_env: VecEnv,
    run_dir: Path,
    steps: int,
    record: Callable[[int], None],
    progress_bar: bool,
    trained: TrainedSteps | None = None,
) -> None:
    """``steps`` more steps of the algorithm, evaluating (then ``record``) and checkpointing as
    the config says (:class:`Evaluations`, :class:`Checkpoints`), the last evaluation of the
    final weights. ``trained`` follows the steps the weights were trained on."""
    trained = TrainedSteps() if trained is None else trained
    evaluation = Evaluations(
        eval_env,
        config.eval_freq,
        model.num_timesteps + steps,
        trained,
        callback_after_eval=RecordEvaluation(record),
        n_eval_episodes=config.eval_episodes,
        log_path=str(RunFolder(run_dir).eval_log),
        verbose=0,
        warn=False,
    )
    continue_evaluation_log(evaluation, model.num_timesteps)
    callbacks: list[BaseCallback] = [trained, evaluation]  # trained first: evaluation reads it
    if config.checkpoint_freq:
        callbacks.append(Checkpoints(config.checkpoint_freq, run_dir, config.algo))
    with status(config.algo.upper()) as detail:
        if progress_bar:
            callbacks.append(Progress(detail, model.num_timesteps + steps))
        model.learn(steps, callback=callbacks, reset_num_timesteps=False)


def continue_evaluation_log(evaluation: EvalCallback, until: int) -> None:
    """Preload EvalCallback's lists from an earlier ``evaluations.npz`` (it rewrites the file),
    up to step ``until`` (a resumed run evaluates the later steps again)."""
    path = Path(f"{evaluation.log_path}.npz")
    if evaluation.log_path is None or not path.is_file():
        return
    with np.load(path) as log:
        keep = log["timesteps"] <= until
        evaluation.evaluations_timesteps = log["timesteps"][keep].tolist()
        evaluation.evaluations_results = log["results"][keep].tolist()
        evaluation.evaluations_length = log["ep_lengths"][keep].tolist()
        if "successes" in log:
            evaluation.evaluations_successes = log["successes"][keep].tolist()


def finish(model: BaseAlgorithm, run_dir: Path, curve: LearningCurve) -> None:
    """The run's final files: model.zip, vecnormalize.pkl (if used), learning_curve.png."""
    with status("saving the model and drawing learning_curve.png"):
        save_model(model, RunFolder(run_dir).model)
        curve.plot(RunFolder(run_dir).curve_plot)


# --- callbacks -----------------------------------------------------------------------------
#
# The weights do not change while a rollout is collected: PPO updates them after each rollout
# (n_envs x n_steps steps), TD3 and SAC after each of theirs (train_freq steps). A callback's
# ``_on_step`` runs during the collection, where ``num_timesteps`` counts the rollout's steps
# already but the weights are those of its start. SB3's EvalCallback and CheckpointCallback act
# there and name what they see with ``num_timesteps``: PPO's evaluation "at N steps" was of the
# weights of the rollout's start (up to a rollout earlier), and the last one, in the last
# rollout, not of the final model. Here every evaluation is labelled with the steps its weights
# were trained on, the last one is of the final weights, and checkpoints are saved between
# rollouts.


class TrainedSteps(BaseCallback):
    """The steps the model's weights were trained on (collected before their last update):
    ``num_timesteps`` at the start of the rollout under way, and at the end of training."""

    def __init__(self) -> None:
        super().__init__()
        self.steps: int | None = None

    def _on_training_start(self) -> None:
        self.steps = self.model.num_timesteps

    def _on_rollout_start(self) -> None:
        self.steps = self.model.num_timesteps

    def _on_training_end(self) -> None:
        self.steps = self.model.num_timesteps

    def _on_step(self) -> bool:
        return True


class Evaluations(EvalCallback):
    """SB3's EvalCallback (``evaluations.npz``, the ``eval/`` scalars, then
    ``callback_after_eval``) once ``every`` steps (0: never) have passed, each evaluation
    labelled with the steps its weights were trained on (``trained``, which must come before
    this callback in the list), and once more at the end of training, of the final weights,
    unless they were the last evaluated.

    PPO evaluates at the start of the first rollout after each multiple of ``every``, after the
    previous rollout's update: its evaluations fall on the multiples when they are multiples of
    the rollout. TD3 and SAC, which update every ``train_freq`` steps, evaluate where SB3 does,
    in the step that passes the multiple (before its update: labelled with the steps before it),
    but not in the last step, whose update the final evaluation follows.
    """

    def __init__(
        self, eval_env: VecEnv, every: int, end: int, trained: TrainedSteps, **kwargs: Any
    ) -> None:
        super().__init__(eval_env, eval_freq=1, **kwargs)  # every _evaluate evaluates
        self.every = every
        self.end = end  # the steps learn() ends at
        self.trained = trained
        self.reached = 0  # num_timesteps when it last evaluated
        self.evaluated = 0  # the steps of the weights it last evaluated

    def _on_training_start(self) -> None:
        super()._on_training_start()
        # evaluated before learn(): the initial evaluation, the imitation's last round, or, when
        # resumed, the steps of the checkpoint (the curve keeps its evaluations up to them)
        self.reached = self.evaluated = self.model.num_timesteps

    def _due(self) -> bool:
        steps, every = self.model.num_timesteps, self.every
        return every > 0 and steps // every > self.reached // every

    def _on_rollout_start(self) -> None:
        if isinstance(self.model, OnPolicyAlgorithm) and self._due():
            self._evaluate()

    def _on_step(self) -> bool:
        if not isinstance(self.model, OnPolicyAlgorithm) and self._due():
            if self.model.num_timesteps < self.end:
                self._evaluate()
        return True

    def _on_training_end(self) -> None:
        if self.evaluated != self.model.num_timesteps:
            self._evaluate()

    def _evaluate(self) -> None:
        assert self.trained.steps is not None
        self.reached = self.model.num_timesteps
        if self.trained.steps == self.evaluated:
            return  # these weights were evaluated (a run resumed from the step that passed)
        self.num_timesteps = self.evaluated = self.trained.steps
        # Write the evaluation alone at its step: what the algorithm recorded (PPO's train/
        # values of the update just made) it dumps itself at the end of the rollout, as
        # without this evaluation (else a scalar could get two values at one step).
        logger = self.logger
        pending = (logger.name_to_value, logger.name_to_count, logger.name_to_excluded)
        kept = [dict(values) for values in pending]
        for values in pending:
            values.clear()
        try:
            super()._on_step()  # EvalCallback's evaluation (eval_freq 1: every call)
        finally:
            for values, saved in zip(pending, kept, strict=True):
                values.clear()
                values.update(saved)


class RecordEvaluation(BaseCallback):
    """Called by :class:`Evaluations` after each evaluation: records the held-out metrics at
    the steps of the evaluated weights (the evaluation's ``num_timesteps``)."""

    def __init__(self, record: Callable[[int], None]) -> None:
        super().__init__()
        self.record = record

    def _on_step(self) -> bool:
        assert self.parent is not None
        self.record(self.parent.num_timesteps)
        return True


class Progress(BaseCallback):
    """The algorithm's steps on the status line (:mod:`grasp_env_agents.progress`)."""

    def __init__(self, detail: Callable[[str], None], total: int) -> None:
        super().__init__()
        self.detail = detail
        self.total = total

    def _on_step(self) -> bool:
        if self.n_calls % 64 == 0:  # an off-policy rollout is one step: not at rollouts' ends
            self.detail(f"{self.model.num_timesteps:,} of {self.total:,} steps")
        return True


class Checkpoints(BaseCallback):
    """SB3's CheckpointCallback, written atomically (:func:`checkpoints.save_checkpoint`) and
    between rollouts: at the first rollout start after every ``every`` steps, so that
    ``<algo>_<N>_steps.zip`` holds the weights N steps trained."""

    def __init__(self, every: int, run_dir: Path, algo: str) -> None:
        super().__init__()
        self.every = every
        self.run_dir = run_dir
        self.algo = algo
        self.saved = 0

    def _on_training_start(self) -> None:
        self.saved = self.model.num_timesteps

    def _on_rollout_start(self) -> None:
        steps = self.model.num_timesteps
        if steps // self.every > self.saved // self.every:
            save_checkpoint(self.model, model_checkpoint(self.run_dir, self.algo, steps))
            self.saved = steps

    def _on_step(self) -> bool:
        return True
