"""A run's checkpoints, where ``--resume`` continues from, and its TensorBoard logs.

A run directory's ``checkpoints/`` holds, as the run goes:

- ``imitation_round_<r>.zip`` after each imitation round r (the policy after its fit), with
  ``imitation_round_<r>.npz`` (the states the round labelled: a resumed run refits on all
  rounds' data) until the imitation phase ends;
- ``<algo>_<N>_steps.zip`` (``ppo``, ``td3``, ``sac``) every ``checkpoint_freq`` steps of the
  algorithm, after the imitation phase (``ppo_0_steps.zip``), on Ctrl-C and at the end, with
  ``<algo>_vecnormalize_<N>_steps.pkl`` when observations are normalised and, for TD3 and SAC,
  ``<algo>_replay_buffer_<N>_steps.pkl`` (SB3's CheckpointCallback names). The replay buffer
  is large (every transition it keeps), so only the newest checkpoint's is kept: an off-policy
  run resumes from its newest checkpoint, whose buffer holds what the run had learnt from.

Every file is written to a temporary name and renamed, so a killed run leaves no half-written
file under a checkpoint's name. A damaged one (from an older run, a full disk, a copy) is
skipped on resume with a message naming it: :func:`find_start` continues from the newest intact
checkpoint, the algorithm's first, then the imitation rounds'.

TensorBoard (``tb/imitation`` and ``tb/ppo``) logs at the run's environment steps, the learning
curve's x (imitation's labelled states, then PPO's steps after them). A resumed run first drops
what the killed run logged after its checkpoint (:func:`trim_tensorboard`), so no step shows
twice.
"""

from __future__ import annotations

import io
import os
import re
import zipfile
from dataclasses import dataclass
from operator import attrgetter
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger, TensorBoardOutputFormat
from torch.utils.tensorboard import SummaryWriter

from ..progress import say
from ..run.folder import IMITATION_PREFIX, RunFolder
from ..safe_files import ROUND_DATA, check_zip_directory
from .models import (
    ALGORITHMS,
    check_tensors,
    load_replay_buffer,
    load_tensors,
    load_vecnormalize,
    read_archive,
)

#: A checkpoint of an algorithm's model: ``<algo>_<N>_steps.zip``.
CHECKPOINT_NAME = re.compile(rf"({'|'.join(ALGORITHMS)})_(\d+)_steps\.zip")


@dataclass(frozen=True)
class Start:
    """Where a run (re)starts: ``checkpoint`` None is the beginning.

    ``round`` is the last imitation round the checkpoint completed (-1: none),
    ``model_steps`` the algorithm's steps (the model's ``num_timesteps``), ``env_steps`` the
    run's environment steps at that point, ``data`` the files of the imitation rounds' states
    (empty once the imitation phase is over).
    """

    checkpoint: Path | None = None
    round: int = -1
    model_steps: int = 0
    env_steps: int = 0
    data: tuple[Path, ...] = ()

    @property
    def vecnormalize(self) -> Path | None:
        return None if self.checkpoint is None else statistics_path(self.checkpoint)

    @property
    def replay_buffer(self) -> Path | None:
        """The checkpoint's replay buffer (TD3's and SAC's), None for PPO and imitation."""
        if self.checkpoint is None or not has_replay_buffer(self.checkpoint):
            return None
        return replay_buffer_path(self.checkpoint)


# --- names and writing -----------------------------------------------------------------------


def model_checkpoint(run_dir: Path, algo: str, steps: int) -> Path:
    return RunFolder(run_dir).checkpoint(algo, steps)


def imitation_checkpoint(run_dir: Path, round_: int) -> Path:
    return RunFolder(run_dir).imitation_checkpoint(round_)


def _name(path: Path) -> tuple[str, int]:
    match = CHECKPOINT_NAME.fullmatch(path.name)
    if match is None:
        raise ValueError(f"{path} is not a checkpoint name (<algo>_<N>_steps.zip)")
    return match.group(1), int(match.group(2))


def checkpoint_steps(path: Path) -> int:
    """The algorithm's steps of a checkpoint named ``<algo>_<N>_steps.zip``."""
    return _name(path)[1]


def statistics_path(checkpoint: Path) -> Path:
    """The normalisation statistics saved beside a checkpoint (CheckpointCallback's naming)."""
    if checkpoint.name.startswith(IMITATION_PREFIX):
        return checkpoint.with_suffix(".vecnormalize.pkl")
    algo, steps = _name(checkpoint)
    return checkpoint.with_name(f"{algo}_vecnormalize_{steps}_steps.pkl")


def has_replay_buffer(checkpoint: Path) -> bool:
    """Whether the checkpoint is an off-policy algorithm's (TD3, SAC): saved with its buffer."""
    return not checkpoint.name.startswith(IMITATION_PREFIX) and _name(checkpoint)[0] != "ppo"


def replay_buffer_path(checkpoint: Path) -> Path:
    """The replay buffer saved beside an off-policy checkpoint (CheckpointCallback's naming)."""
    algo, steps = _name(checkpoint)
    return checkpoint.with_name(f"{algo}_replay_buffer_{steps}_steps.pkl")


def write_atomically(path: Path, content: bytes) -> None:
    """``path`` holds ``content`` or what it held before, never a part (a kill mid-write)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    partial.write_bytes(content)
    os.replace(partial, path)


def save_model(model: BaseAlgorithm, path: Path) -> None:
    """The model at ``path`` (and its VecNormalize statistics beside it), atomically."""
    buffer = io.BytesIO()
    model.save(buffer)
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:  # the statistics first: a model never lacks its own
        run = RunFolder.of_model(path)  # the final model's, else a checkpoint's
        statistics = statistics_path(path) if run is None else run.vecnormalize
        write_atomically(statistics, _pickled(normalizer))
    write_atomically(path, buffer.getvalue())


def save_checkpoint(model: BaseAlgorithm, path: Path) -> None:
    """A checkpoint of the model (:func:`save_model`) and, for TD3 and SAC, its replay buffer
    (written first; the earlier checkpoints' buffers are deleted after)."""
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None:
        kept = replay_buffer_path(path)
        write_atomically(kept, _pickled(buffer))
        for older in path.parent.glob("*_replay_buffer_*_steps.pkl"):
            if older != kept:
                older.unlink()
    save_model(model, path)


def _pickled(item: Any) -> bytes:
    import pickle

    return pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL)  # as VecNormalize.save writes


def save_round_data(
    run_dir: Path, round_: int, obs: np.ndarray, labels: np.ndarray, env_steps: int
) -> None:
    """The states an imitation round labelled, for a resumed run to refit on."""
    buffer = io.BytesIO()
    np.savez(buffer, observations=obs, labels=labels, env_steps=env_steps)
    write_atomically(RunFolder(run_dir).round_data(round_), buffer.getvalue())


def load_round_data(path: Path) -> tuple[np.ndarray, np.ndarray, int]:
    """The states, labels and environment steps of an imitation round (:func:`save_round_data`);
    ValueError if the file is damaged, or its zip directory declares a zip bomb."""
    try:
        archive = zipfile.ZipFile(path)
    except Exception as error:  # missing, not a zip, a damaged directory
        raise ValueError(f"{path} is damaged ({type(error).__name__}: {error})") from None
    with archive:
        check_zip_directory(archive, str(path), ROUND_DATA)  # before np.load inflates
    try:
        with np.load(path, allow_pickle=False) as data:
            return data["observations"], data["labels"], int(data["env_steps"])
    except Exception as error:  # a damaged npz fails in several ways
        raise ValueError(f"{path} is damaged ({type(error).__name__}: {error})") from None


# --- resuming --------------------------------------------------------------------------------


def check_checkpoint(path: Path, normalize: bool) -> None:
    """Raise ValueError (naming what is wrong) unless ``path`` and its statistics (and, for
    TD3 and SAC, its replay buffer) are intact."""
    _, archive = read_archive(path)
    check_tensors(path, archive)
    if normalize:
        statistics = statistics_path(path)
        if not statistics.is_file():
            raise ValueError(f"{statistics} is missing (the normalisation statistics)")
        load_vecnormalize(statistics)
    if has_replay_buffer(path):
        buffer = replay_buffer_path(path)
        if not buffer.is_file():
            raise ValueError(f"{buffer.name} is missing (only the newest checkpoint keeps one)")
        load_replay_buffer(buffer)


def find_start(run_dir: Path, normalize: bool, imitation_steps: int, algo: str = "ppo") -> Start:
    """The newest intact checkpoint of the run, printing each damaged one it skips.

    ``imitation_steps`` is the environment steps of the run's imitation phase (from its
    learning curve), which the algorithm's steps follow; ``algo`` the run's algorithm.
    """
    folder = RunFolder(run_dir)

    def intact(path: Path, data: list[Path] = ()) -> bool:
        try:
            check_checkpoint(path, normalize)
            for file in data:
                load_round_data(file)
        except ValueError as error:
            say(f"resume: skipping {path.relative_to(run_dir)}: {error}")
            return False
        return True

    models = sorted(folder.checkpoints_of(algo), key=checkpoint_steps, reverse=True)
    for path in models:
        if intact(path):
            steps = checkpoint_steps(path)
            return Start(path, round=-1, model_steps=steps, env_steps=imitation_steps + steps)
    rounds = sorted(
        (int(p.stem.rsplit("_", 1)[1]) for p in folder.imitation_checkpoints()),
        reverse=True,
    )
    for round_ in rounds:
        path = folder.imitation_checkpoint(round_)
        data = [folder.round_data(r) for r in range(round_ + 1)]
        if intact(path, data):
            steps = load_round_data(data[-1])[2]
            return Start(path, round=round_, env_steps=steps, data=tuple(data))
    return Start()


def restore(model: BaseAlgorithm, start: Start) -> None:
    """Put ``start``'s checkpoint into a fresh ``model``: weights and optimiser states, the
    tensors beside them (SAC's entropy coefficient), the step count and the replay buffer."""
    assert start.checkpoint is not None
    model.set_parameters(str(start.checkpoint), device="cpu")
    names = model._get_torch_save_params()[1]
    if names:
        _, archive = read_archive(start.checkpoint)
        saved = load_tensors(start.checkpoint, archive, "pytorch_variables.pth")
        with torch.no_grad():  # in place, as SB3's load: the optimisers hold these tensors
            for name in names:
                attrgetter(name)(model).copy_(saved[name])
    model.num_timesteps = start.model_steps
    if start.replay_buffer is not None:
        buffer = load_replay_buffer(start.replay_buffer)
        buffer.device = model.device
        model.replay_buffer = buffer


# --- TensorBoard -----------------------------------------------------------------------------


class _TensorBoard(TensorBoardOutputFormat):
    """SB3's TensorBoard output at the run's environment steps (``offset`` + SB3's step)."""

    def __init__(self, folder: Path, offset: int) -> None:
        self.writer = SummaryWriter(log_dir=str(folder))
        self._is_closed = False
        self.offset = offset

    def write(self, key_values: dict, key_excluded: dict, step: int = 0) -> None:
        super().write(key_values, key_excluded, step + self.offset)


def tensorboard_logger(folder: Path, offset: int = 0) -> Logger:
    """An SB3 logger writing TensorBoard events into ``folder`` at ``offset`` + step."""
    return Logger(str(folder), [_TensorBoard(folder, offset)])


def trim_tensorboard(folder: Path, last_step: int) -> int:
    """Drop the summaries logged after ``last_step`` from every event file under ``folder``
    (a killed run's steps past its checkpoint, which the resumed run logs again); returns how
    many were dropped."""
    from tensorboard.backend.event_processing.event_file_loader import RawEventFileLoader
    from tensorboard.compat.proto.event_pb2 import Event
    from tensorboard.summary.writer.record_writer import RecordWriter

    dropped = 0
    for path in sorted(folder.glob("**/events.out.tfevents.*")):
        records = list(RawEventFileLoader(str(path)).Load())
        keep = [r for r in records if not _logged_after(Event.FromString(r), last_step)]
        if len(keep) < len(records):
            buffer = io.BytesIO()
            writer = RecordWriter(buffer)
            for record in keep:
                writer.write(record)
            write_atomically(path, buffer.getvalue())
            dropped += len(records) - len(keep)
    return dropped


def _logged_after(event: Any, step: int) -> bool:
    return event.HasField("summary") and event.step > step
