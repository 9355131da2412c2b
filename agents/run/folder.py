"""A training run's folder: the one place that names its files and sub-folders.

``grasp-env train`` writes, and every reader (``evaluate``, ``results``, ``sweep``,
``verify --policy``, ``train --resume``) reads, this layout::

    RUN/
    ├── config.yaml                  the exact config used (its presence makes RUN a run)
    ├── model.zip                    the final model (a finished run)
    ├── vecnormalize.pkl             its observation statistics (normalize: true)
    ├── learning_curve.csv           one row per held-out evaluation
    ├── learning_curve.png
    ├── report.md                    the run's own evaluation (written by train)
    ├── comparison.csv
    ├── grip_along_alpha.png
    ├── evaluation-<N>-scenes/       grasp-env evaluate RUN --episodes N
    │   ├── report.md
    │   ├── comparison.csv
    │   └── grip_along_alpha.png
    ├── checkpoints/
    │   ├── imitation_round_<r>.zip  (.npz: the round's labelled states, until imitation ends)
    │   └── <algo>_<N>_steps.zip     (with SB3's CheckpointCallback's .pkl beside it)
    ├── eval/evaluations.npz         SB3's evaluation log
    └── tb/imitation, tb/<algo>      TensorBoard

A run record (``docs/records``) keeps only ``config.yaml``, ``learning_curve.csv`` and an
``evaluation-<N>-scenes/``: all a results table needs. The names are those runs written by
earlier versions hold, so they keep loading.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

CONFIG = "config.yaml"
MODEL = "model.zip"
STATISTICS = "vecnormalize.pkl"
CURVE = "learning_curve.csv"
CURVE_PLOT = "learning_curve.png"
REPORT = "report.md"
COMPARISON = "comparison.csv"
GRIP_PLOT = "grip_along_alpha.png"
CHECKPOINTS = "checkpoints"
EVAL_LOG = "eval"
TENSORBOARD = "tb"
#: An imitation round's checkpoint: ``imitation_round_<r>.zip``.
IMITATION_PREFIX = "imitation_round"


@dataclass(frozen=True)
class EvaluationFolder:
    """Where an evaluation of a run writes its report (:func:`evaluate_run`): the run folder
    itself (``grasp-env train``'s), an ``evaluation-<N>-scenes/`` in it, or any ``--out``."""

    path: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    @property
    def report(self) -> Path:
        """``report.md``, written last: its presence means the evaluation finished."""
        return self.path / REPORT

    @property
    def comparison(self) -> Path:
        """``comparison.csv``: the metrics per policy."""
        return self.path / COMPARISON

    @property
    def grip_plot(self) -> Path:
        return self.path / GRIP_PLOT


@dataclass(frozen=True)
class RunFolder:
    """A training run's folder (the layout in this module's docstring); ``path`` need not
    exist yet."""

    path: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    @classmethod
    def of_model(cls, path: Path) -> RunFolder | None:
        """The run folder whose final model ``path`` is (a file named ``model.zip``), or None
        (a checkpoint, a model file of any other name)."""
        path = Path(path)
        return cls(path.parent) if path.name == MODEL else None

    # --- files -----------------------------------------------------------------------------

    @property
    def config(self) -> Path:
        return self.path / CONFIG

    @property
    def model(self) -> Path:
        return self.path / MODEL

    @property
    def vecnormalize(self) -> Path:
        """The observation statistics beside ``model.zip`` (a run with ``normalize: true``)."""
        return self.path / STATISTICS

    @property
    def curve(self) -> Path:
        """``learning_curve.csv`` (:mod:`grasp_env_agents.run.curve`)."""
        return self.path / CURVE

    @property
    def curve_plot(self) -> Path:
        return self.path / CURVE_PLOT

    @property
    def own_evaluation(self) -> EvaluationFolder:
        """The run's own report, ``grasp-env train``'s, in the run folder itself."""
        return EvaluationFolder(self.path)

    def evaluation(self, episodes: int) -> EvaluationFolder:
        """``evaluation-<N>-scenes/``: where ``grasp-env evaluate RUN --episodes N`` writes."""
        return EvaluationFolder(self.path / f"evaluation-{episodes}-scenes")

    # --- checkpoints and logs --------------------------------------------------------------

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS

    def checkpoint(self, algo: str, steps: int) -> Path:
        """``checkpoints/<algo>_<N>_steps.zip``: the algorithm's model after ``steps`` steps."""
        return self.checkpoints / f"{algo}_{steps}_steps.zip"

    def checkpoints_of(self, algo: str) -> list[Path]:
        """The algorithm's checkpoints present, unordered."""
        return list(self.checkpoints.glob(f"{algo}_*_steps.zip"))

    def imitation_checkpoint(self, round_: int) -> Path:
        """``checkpoints/imitation_round_<r>.zip``: the policy after imitation round r."""
        return self.checkpoints / f"{IMITATION_PREFIX}_{round_}.zip"

    def imitation_checkpoints(self) -> list[Path]:
        """The imitation rounds' checkpoints present, unordered."""
        return list(self.checkpoints.glob(f"{IMITATION_PREFIX}_*.zip"))

    def round_data(self, round_: int) -> Path:
        """``checkpoints/imitation_round_<r>.npz``: the states round r labelled."""
        return self.imitation_checkpoint(round_).with_suffix(".npz")

    def all_round_data(self) -> list[Path]:
        """Every imitation round's labelled states present (deleted when imitation ends)."""
        return list(self.checkpoints.glob("*.npz"))

    @property
    def eval_log(self) -> Path:
        """SB3's EvalCallback ``log_path``: it writes ``eval/evaluations.npz``."""
        return self.path / EVAL_LOG

    @property
    def tensorboard(self) -> Path:
        """``tb/``: every phase's TensorBoard events."""
        return self.path / TENSORBOARD

    def tensorboard_of(self, phase: str) -> Path:
        """``tb/<phase>``: ``imitation`` or the algorithm (``ppo``, ``td3``, ``sac``)."""
        return self.tensorboard / phase

    # --- what the folder holds -------------------------------------------------------------

    def is_run(self) -> bool:
        """Whether the folder holds a run (a ``config.yaml``; it is written once the run's
        environments and model are built)."""
        return self.config.is_file()

    def is_finished(self) -> bool:
        """Whether the run saved its final model (``model.zip``)."""
        return self.model.is_file()

    def is_record(self, episodes: int) -> bool:
        """Whether the folder holds a run record for ``episodes`` held-out scenes: the
        learning curve and an evaluation on them, without the model (``docs/records``)."""
        return self.evaluation(episodes).comparison.is_file() and self.curve.is_file()


def model_file(path: Path) -> Path:
    """The model a path names: a run folder's ``model.zip``, or the file itself."""
    path = Path(path)
    return RunFolder(path).model if path.is_dir() else path
