"""Loading model files, shared or damaged, without running code from them.

A Stable-Baselines3 model is a zip: ``data`` (JSON; the values JSON cannot hold, such as the
policy class, the spaces and the schedules, as base64 cloudpickle), ``policy.pth`` and
``policy.optimizer.pth`` (torch tensors) and ``pytorch_variables.pth``. ``PPO.load`` unpickles
the ``data`` entries with cloudpickle, and a pickle may call any importable function: a model
file whose ``policy_class`` holds ``os.system`` runs a shell command when loaded. The
``vecnormalize.pkl`` beside it (SB3's ``VecNormalize.save``) and an off-policy checkpoint's
replay buffer (``save_replay_buffer``) are plain pickles, likewise.

So every file is read here, never by SB3's unpickling:

- the pickled entries are decoded by :class:`SafeUnpickler`, which resolves only the names in
  :data:`ALLOWED` (classes, and the functions numpy and torch use to rebuild arrays and random
  generators); any other name is refused before anything is called, with an error naming the
  file, the entry and the name;
- SB3 then builds the model from those decoded objects (``custom_objects``: it unpickles
  nothing itself), and torch loads the tensors with ``weights_only=True`` (no code either);
- a schedule that is code (a ``lambda`` pickled by value, as this package wrote for
  ``lr_schedule: linear`` before it used SB3's ``LinearSchedule``) is not decoded: the model
  predicts as saved, and continuing its training goes through ``grasp-env train --resume``,
  which takes the schedules from the run's config and only the tensors from the checkpoint.

Models pickled while the package was importable as ``agents`` (``agents.policy``,
``agents.features``) load through :data:`RENAMED`. A truncated or garbage zip, a missing member,
damaged tensors, weights that are NaN or infinite or that do not fit the network raise a
ValueError naming the file and what is wrong.

A hostile file is refused before it costs much (:mod:`grasp_env_agents.safe_files`): a zip
whose directory declares members past :data:`~grasp_env_agents.safe_files.MODEL_ZIP`'s bounds
(a zip bomb: gigabytes from a few megabytes) before any member is inflated, the torch zips
inside it likewise, and ``data`` JSON or a pickle nested deeper than
:data:`~grasp_env_agents.safe_files.MAX_NESTING` levels before Python's recursion fails on it.

:func:`load_agent` is the entry point (a model file or a run directory, with its observation
normalisation): ``grasp-env evaluate``, ``verify --policy`` and ``gait --models`` load models
through it. sb3-contrib's MaskablePPO files load too (:data:`CONTRIB_ALGORITHMS`: its policy
and rollout buffer classes are allowed names), sb3-contrib imported only for them; without it
the error names the ``agents`` extra.
"""

from __future__ import annotations

import base64
import importlib
import io
import json
import pickle
import reprlib
import warnings
import zipfile
from collections import deque
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from ..run.folder import RunFolder
from ..run.folder import model_file as named_model
from ..safe_files import (
    MODEL_ZIP,
    NestedTooDeep,
    check_json_depth,
    check_object_depth,
    check_zip_directory,
    nested_too_deep,
    read_member,
    size_text,
)
from .baselines import TrainedAgent

#: The algorithms a model file may be loaded as; its policy class says which wrote it.
ALGORITHMS: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "td3": TD3, "sac": SAC}
#: sb3-contrib's algorithms a model file may be loaded as too, by name: (module, class). The
#: package is in the ``agents`` extra and imported only for a file that needs it. MaskablePPO's
#: agents act with the action masks they were trained with (``predict(..., action_masks=...)``):
#: ``grasp-env gait --models`` plays them with theirs
#: (:mod:`grasp_env_agents.commands.gait_models`).
CONTRIB_ALGORITHMS = {"maskable_ppo": ("sb3_contrib", "MaskablePPO")}
#: The modules of sb3-contrib a model file's pickles may name (:data:`ALLOWED`).
CONTRIB_MODULES = ("sb3_contrib.common.maskable.policies", "sb3_contrib.common.maskable.buffers")

#: Everything a model file's pickles may name, by module. Classes are only referenced or
#: rebuilt (their __init__ is not what unpickling calls); the functions rebuild arrays, numpy
#: random generators and containers from data. None of them runs code given as data.
ALLOWED: dict[str, set[str]] = {
    "collections": {"deque", "OrderedDict"},
    "numpy": {"dtype", "ndarray", "float32", "float64"},
    "numpy._core.multiarray": {"_reconstruct", "scalar"},
    "numpy._core.numeric": {"_frombuffer"},
    "numpy.core.multiarray": {"_reconstruct", "scalar"},  # numpy 1.x's names
    "numpy.core.numeric": {"_frombuffer"},
    "numpy.random._pickle": {"__generator_ctor", "__bit_generator_ctor", "__randomstate_ctor"},
    "numpy.random._pcg64": {"PCG64", "PCG64DXSM"},
    "numpy.random._mt19937": {"MT19937"},
    "numpy.random.bit_generator": {"SeedSequence", "__pyx_unpickle_SeedSequence"},
    "gymnasium.spaces.box": {"Box"},
    "gymnasium.spaces.discrete": {"Discrete"},  # the moves of grasp_env/CubeGaitMoves-v0
    "torch": {"device"},  # a replay buffer's (torch.device("cpu") is all unpickling calls)
    "torch.nn.modules.activation": {"Tanh", "ReLU", "SiLU"},  # config: policy.activation
    "stable_baselines3.common.policies": {"ActorCriticPolicy"},
    "sb3_contrib.common.maskable.policies": {"MaskableActorCriticPolicy"},
    "sb3_contrib.common.maskable.buffers": {"MaskableRolloutBuffer"},
    "stable_baselines3.td3.policies": {"TD3Policy"},
    "stable_baselines3.sac.policies": {"SACPolicy"},
    "stable_baselines3.common.buffers": {"RolloutBuffer", "ReplayBuffer"},
    "stable_baselines3.common.noise": {"NormalActionNoise", "VectorizedActionNoise"},
    "stable_baselines3.common.type_aliases": {"TrainFreq", "TrainFrequencyUnit"},
    "stable_baselines3.common.utils": {"FloatSchedule", "ConstantSchedule", "LinearSchedule"},
    "stable_baselines3.common.running_mean_std": {"RunningMeanStd"},
    "stable_baselines3.common.vec_env.vec_normalize": {"VecNormalize"},
    "grasp_env_agents.learning.policy": {"ForceDirectionPolicy"},
    "grasp_env_agents.learning.algorithms": {
        "ForceDirectionTD3Policy",
        "ForceDirectionSACPolicy",
    },
    "grasp_env_agents.learning.features": {"GraspFeatures"},
}
#: Modules under their earlier names, which models saved by earlier versions name: the package
#: was importable as ``agents``, and its modules were flat (``grasp_env_agents.policy``; those
#: paths stay importable as aliases for SB3's own loader too).
RENAMED = {
    "agents.policy": "grasp_env_agents.learning.policy",
    "agents.features": "grasp_env_agents.learning.features",
    "grasp_env_agents.policy": "grasp_env_agents.learning.policy",
    "grasp_env_agents.algorithms": "grasp_env_agents.learning.algorithms",
    "grasp_env_agents.features": "grasp_env_agents.learning.features",
}
#: The entries a model needs to predict: decoded, or the file is refused.
NEEDED = ("policy_class", "policy_kwargs", "observation_space", "action_space")
#: Entries that may legitimately be code (SB3 accepts functions as schedules), and what replaces
#: them when they are: prediction does not use them.
SCHEDULES: dict[str, Any] = {
    "learning_rate": 0.0,
    "lr_schedule": None,
    "clip_range": 0.2,
    "clip_range_vf": None,
}


class ForbiddenName(pickle.UnpicklingError):
    """A pickle names something outside :data:`ALLOWED`."""


class MissingExtra(pickle.UnpicklingError):
    """A pickle names an allowed class of sb3-contrib, which does not import."""


def contrib_error(what: str, error: BaseException) -> ValueError:
    """The error for ``what`` (a file and its entry, or an algorithm) needing sb3-contrib,
    which does not import: it names the extra that installs it."""
    return ValueError(
        f"{what} needs sb3-contrib (a MaskablePPO model), which does not import ({error}):"
        ' pip install "grasp-env[agents]"'
    )


class SafeUnpickler(pickle.Unpickler):
    """An unpickler that resolves only the names in :data:`ALLOWED` (and :data:`RENAMED`)."""

    def find_class(self, module: str, name: str) -> Any:
        module = RENAMED.get(module, module)
        if name not in ALLOWED.get(module, ()):
            raise ForbiddenName(f"{module}.{name}")
        if module in CONTRIB_MODULES:
            try:
                return super().find_class(module, name)
            except ImportError as error:  # the agents extra without sb3-contrib
                raise MissingExtra(f"{module}.{name}: {error}") from None
        return super().find_class(module, name)


def safe_loads(data: bytes, where: str = "the pickle") -> Any:
    """Unpickle ``data`` resolving only allowed names (:class:`ForbiddenName` otherwise);
    :class:`~grasp_env_agents.safe_files.NestedTooDeep` (naming ``where``) if what it holds
    nests deeper than :data:`~grasp_env_agents.safe_files.MAX_NESTING` levels."""
    try:
        item = SafeUnpickler(io.BytesIO(data)).load()
    except RecursionError:  # objects rebuilt inside objects, past Python's limit
        raise nested_too_deep(where, "a pickle") from None
    check_object_depth(item, where)
    return item


def _refusal(path: Path, what: str, name: str) -> ValueError:
    return ValueError(
        f"{path}: {what} names {name}, which a model file may not use (loading it could run"
        " code from the file); refused, nothing from it was run"
    )


def _damaged(path: Path, what: str, error: BaseException) -> ValueError:
    reason = f"{type(error).__name__}: {error}"
    return ValueError(f"{path}: {what} is damaged or not a model file ({reason})")


# --- model.zip -----------------------------------------------------------------------------


def read_archive(path: Path) -> tuple[bytes, zipfile.ZipFile]:
    """The bytes of a model file and the zip they hold, checked member by member (CRC)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such model file")
    size = path.stat().st_size
    if size > MODEL_ZIP.total:  # SB3 stores its members: the file is as large as they are
        raise ValueError(
            f"{path}: {size_text(size)}, more than the {size_text(MODEL_ZIP.total)} a model file"
            " may hold; refused unread"
        )
    raw = path.read_bytes()
    unreadable = f"{path}: not a readable zip archive (truncated, or not a model file)"
    try:
        archive = zipfile.ZipFile(io.BytesIO(raw))
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, NotImplementedError) as error:
        raise ValueError(f"{unreadable}: {error}") from None
    # the sizes its directory declares, before testzip inflates every member
    check_zip_directory(archive, str(path), MODEL_ZIP)
    try:
        bad = archive.testzip()
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, NotImplementedError) as error:
        raise ValueError(f"{unreadable}: {error}") from None
    if bad is not None:
        raise ValueError(f"{path}: member {bad!r} of the zip is damaged (CRC mismatch)")
    missing = {"data", "policy.pth"} - set(archive.namelist())
    if missing:  # a cut model file can read as the zip of its last member (policy.pth is one)
        raise ValueError(
            f"{path}: not a complete SB3 model file (truncated, or another zip): it has no"
            f" {sorted(missing)} member"
        )
    return raw, archive


def load_tensors(path: Path, archive: zipfile.ZipFile, name: str) -> Any:
    """Member ``name`` (a ``.pth``) of a model file as plain tensors (torch's
    ``weights_only``), read within :data:`~grasp_env_agents.safe_files.MODEL_ZIP`'s bounds:
    the zip torch wrote is checked from its own directory before torch inflates anything."""
    content = read_member(archive, name, str(path), MODEL_ZIP)
    if zipfile.is_zipfile(io.BytesIO(content)):  # torch's format (older ones are plain pickles)
        try:
            inner = zipfile.ZipFile(io.BytesIO(content))
        except (zipfile.BadZipFile, OSError, ValueError, NotImplementedError) as error:
            raise _damaged(path, name, error) from None
        check_zip_directory(inner, f"{path}: {name}", MODEL_ZIP)
    try:
        return torch.load(io.BytesIO(content), map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises RuntimeError, UnpicklingError, EOFError...
        raise _damaged(path, name, error) from None


def check_tensors(path: Path, archive: zipfile.ZipFile) -> None:
    """Every ``.pth`` member loads as plain tensors (torch's ``weights_only``), all finite:
    a NaN or an infinity in the weights (or the optimiser's state) is refused, naming it."""
    for name in archive.namelist():
        if name.endswith(".pth"):
            check_finite(path, name, load_tensors(path, archive, name))


def check_finite(path: Path, member: str, saved: Any) -> None:
    """ValueError naming the first floating tensor in ``saved`` (a state dict, an optimiser's
    state, nested dicts and lists of tensors) that holds a NaN or an infinity."""
    todo: deque[tuple[str, Any]] = deque([("", saved)])
    while todo:
        name, item = todo.popleft()
        if isinstance(item, torch.Tensor):
            if item.is_floating_point() or item.is_complex():
                if not bool(torch.isfinite(item).all()):
                    raise ValueError(
                        f"{path}: model weights contain NaN or inf in {name or 'the tensor'}"
                        f" ({member}); refused"
                    )
        elif isinstance(item, dict):
            todo.extend((f"{name}.{key}".lstrip("."), value) for key, value in item.items())
        elif isinstance(item, list | tuple):
            todo.extend((f"{name}.{i}".lstrip("."), value) for i, value in enumerate(item))


def decode_entries(path: Path, archive: zipfile.ZipFile) -> dict[str, Any]:
    """The pickled entries of the model's ``data``, decoded safely (module docstring)."""
    text = read_member(archive, "data", str(path), MODEL_ZIP)
    check_json_depth(text, f"{path}: its 'data' member")
    try:
        data = json.loads(text)
    except RecursionError:  # not past the scan's depth: never, but json recurses
        raise nested_too_deep(f"{path}: its 'data' member", "JSON") from None
    except ValueError as error:  # JSONDecodeError, UnicodeDecodeError, a 5,000-digit number
        raise _damaged(path, "its 'data' member", error) from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: its 'data' member is not a mapping: not an SB3 model file")
    missing = [key for key in NEEDED if key not in data]
    if missing:
        raise ValueError(f"{path}: not an SB3 model file, its data has no {missing}")
    decoded: dict[str, Any] = {}
    code: list[str] = []
    for key, item in data.items():
        if not (isinstance(item, dict) and ":serialized:" in item):
            continue
        try:
            serialized = base64.b64decode(str(item[":serialized:"]), validate=True)
            decoded[key] = safe_loads(serialized, f"{path}: entry {key!r}")
        except NestedTooDeep:
            raise
        except MissingExtra as error:
            raise contrib_error(f"{path}: entry {key!r}", error) from None
        except ForbiddenName as error:
            if key not in SCHEDULES:
                raise _refusal(path, f"entry {key!r}", str(error)) from None
            decoded[key] = SCHEDULES[key]
            code.append(key)
        except Exception as error:  # damaged data fails in many ways, none of them runs code
            raise _damaged(path, f"entry {key!r}", error) from None
    _check_needed(path, {**data, **decoded})
    if code:
        warnings.warn(
            f"{path}: {code} are code in the file and were not loaded; the model predicts as"
            " saved (continue its training with grasp-env train --resume, which takes them from"
            " the run's config)",
            stacklevel=3,
        )
    return decoded


def _check_needed(path: Path, entries: dict[str, Any]) -> None:
    shown = reprlib.repr  # what a file holds may be long: a line, not the file
    policy = entries["policy_class"]
    if not (isinstance(policy, type) and issubclass(policy, BasePolicy)):
        raise ValueError(f"{path}: its policy_class is {shown(policy)}, not an SB3 policy class")
    if not isinstance(entries["policy_kwargs"], dict):
        raise ValueError(f"{path}: its policy_kwargs are not a mapping")
    if not isinstance(entries["observation_space"], gym.spaces.Box):
        raise ValueError(
            f"{path}: its observation_space is {shown(entries['observation_space'])}, not a Box"
            " space"
        )
    if not isinstance(entries["action_space"], gym.spaces.Box | gym.spaces.Discrete):
        raise ValueError(
            f"{path}: its action_space is {shown(entries['action_space'])}, not a Box or"
            " Discrete space"
        )


def algorithm(algo: str) -> type[BaseAlgorithm]:
    """The class of ``algo``, a name of :data:`ALGORITHMS` or :data:`CONTRIB_ALGORITHMS`
    (sb3-contrib's, imported here: a ValueError naming the extra if it does not import)."""
    if algo in ALGORITHMS:
        return ALGORITHMS[algo]
    if algo not in CONTRIB_ALGORITHMS:
        names = sorted([*ALGORITHMS, *CONTRIB_ALGORITHMS])
        raise ValueError(f"algo must be one of {names}, got {algo!r}")
    module, name = CONTRIB_ALGORITHMS[algo]
    try:
        return getattr(importlib.import_module(module), name)
    except ImportError as error:
        raise contrib_error(f"algo {algo!r}", error) from None


def algorithm_name(algo: str) -> str:
    """How messages name ``algo``: ``PPO``, ``TD3``, ``SAC``, ``MaskablePPO``."""
    return CONTRIB_ALGORITHMS[algo][1] if algo in CONTRIB_ALGORITHMS else algo.upper()


def written_by(policy: type[BasePolicy]) -> str | None:
    """The algorithm of :data:`ALGORITHMS` or :data:`CONTRIB_ALGORITHMS` whose policies
    ``policy`` is one of (None if none). sb3-contrib's come first: MaskablePPO's policy is a
    subclass of PPO's, and is not PPO's (it predicts with masks)."""
    if policy.__module__.split(".")[0] == "sb3_contrib":  # decoded, so sb3-contrib imports
        for algo in CONTRIB_ALGORITHMS:
            if issubclass(policy, algorithm(algo).policy_aliases["MlpPolicy"]):
                return algo
    for algo, known in ALGORITHMS.items():
        if issubclass(policy, known.policy_aliases["MlpPolicy"]):
            return algo
    return None


def load_model(
    path: str | Path, algo: str | None = None, env: VecEnv | None = None
) -> BaseAlgorithm:
    """The SB3 model saved at ``path`` (a ``.zip``), on the CPU, without running code from it.

    The file's policy class says which algorithm of :data:`ALGORITHMS` (or sb3-contrib's
    MaskablePPO, :data:`CONTRIB_ALGORITHMS`) wrote it; ``algo``, if given, must be that one.
    ``env`` (optional) is checked against the model's spaces. Raises ValueError naming the file
    and the problem (and the ``agents`` extra for a MaskablePPO file without sb3-contrib).
    """
    if algo is not None and algo not in ALGORITHMS and algo not in CONTRIB_ALGORITHMS:
        names = sorted([*ALGORITHMS, *CONTRIB_ALGORITHMS])
        raise ValueError(f"algo must be one of {names}, got {algo!r}")
    path = Path(path)
    raw, archive = read_archive(path)
    check_tensors(path, archive)
    decoded = decode_entries(path, archive)
    policy = decoded["policy_class"]
    wrote = written_by(policy)
    if wrote is None:
        names = ", ".join([*ALGORITHMS, *CONTRIB_ALGORITHMS])
        raise ValueError(f"{path}: its policy class {policy.__name__} is none of {names}'s")
    if algo is not None and algo != wrote:
        raise ValueError(
            f"{path}: a {algorithm_name(wrote)} model (its policy class is {policy.__name__}),"
            f" not {algorithm_name(algo)}"
        )
    loader = algorithm(wrote)
    try:
        return loader.load(io.BytesIO(raw), env=env, device="cpu", custom_objects=decoded)
    except Exception as error:  # the tensors do not fit the network, or the network cannot be built
        lines = str(error).strip().splitlines() or [type(error).__name__]
        raise ValueError(f"{path}: cannot rebuild the model it describes ({lines[0]})") from None


# --- vecnormalize.pkl ----------------------------------------------------------------------


def _read_pickle(path: Path) -> Any:
    """The pickle file at ``path``, read without running code from it; a one-line error for a
    forbidden name or damaged data."""
    try:
        return safe_loads(path.read_bytes(), str(path))
    except NestedTooDeep:
        raise
    except ForbiddenName as error:
        raise _refusal(path, "the pickle", str(error)) from None
    except Exception as error:  # damaged data fails in many ways, none of them runs code
        raise _damaged(path, "the file", error) from None


def load_vecnormalize(path: str | Path, venv: VecEnv | None = None) -> VecNormalize:
    """SB3's ``VecNormalize.load(path, venv)``, without running code from the file.

    Without ``venv`` the statistics only normalise (``normalize_obs``), as an agent needs.
    """
    path = Path(path)
    normalizer = _read_pickle(path)
    if not isinstance(normalizer, VecNormalize) or not all(
        isinstance(getattr(normalizer, name, None), RunningMeanStd)
        for name in ("obs_rms", "ret_rms")
    ):
        raise ValueError(f"{path}: not VecNormalize statistics (SB3's VecNormalize.save)")
    if venv is not None:
        try:
            normalizer.set_venv(venv)
        except (AssertionError, ValueError) as error:
            raise ValueError(
                f"{path}: the statistics do not fit the environment ({error})"
            ) from None
    return normalizer


# --- replay buffers --------------------------------------------------------------------------


def load_replay_buffer(path: str | Path) -> ReplayBuffer:
    """SB3's ``model.load_replay_buffer(path)``'s buffer, without running code from the file."""
    path = Path(path)
    buffer = _read_pickle(path)
    if not isinstance(buffer, ReplayBuffer):
        raise ValueError(f"{path}: not a replay buffer (SB3's save_replay_buffer)")
    return buffer


# --- agents --------------------------------------------------------------------------------


def load_agent(path: str | Path, algo: str | None = None) -> TrainedAgent:
    """A trained agent from a model file or a ``grasp-env train`` run directory.

    A run directory's ``model.zip`` is loaded (as :func:`load_model`, ``algo`` likewise; a
    MaskablePPO model too, whose agent predicts without masks unless given them: ``grasp-env
    gait --models`` plays it with those it was trained with,
    :class:`grasp_env_agents.commands.gait_models.MaskedAgent`);
    ``vecnormalize.pkl`` beside the model file, if there is one, normalises the observations
    (not updated while playing). A run whose ``config.yaml`` says ``normalize: true`` without
    that file is refused: its model would see observations it was never trained on.
    """
    path = Path(path)
    model_file = named_model(path)
    with warnings.catch_warnings():
        # an agent only predicts: schedules skipped as code (rl-zoo3's lin_3e-4, say) do not matter
        warnings.filterwarnings("ignore", "(?s).*are code in the file and were not loaded")
        model = load_model(model_file, algo)
    normalizer = None
    statistics = RunFolder(model_file.parent).vecnormalize  # beside any model file
    if not statistics.is_file() and _normalized_run(model_file.parent):
        raise ValueError(
            f"{model_file}: its run's config.yaml says normalize: true, but the observation"
            f" statistics it was trained with ({statistics}) are missing; copy the run's"
            " vecnormalize.pkl beside the model"
        )
    if statistics.is_file():
        normalizer = load_vecnormalize(statistics)
        normalizer.training = False
    return TrainedAgent(model, normalizer)


def misfit(model: BaseAlgorithm, env: gym.Env | VecEnv, env_id: str) -> str | None:
    """What differs between ``model``'s spaces and those of ``env`` (named ``env_id``), or
    None if the model fits it."""
    trained = (model.observation_space.shape, model.action_space.shape)
    given = (env.observation_space.shape, env.action_space.shape)
    if trained == given:
        return None
    return (
        f"the model observes {trained[0]} and acts in {trained[1]}, {env_id} observes"
        f" {given[0]} and acts in {given[1]}"
    )


def _normalized_run(folder: Path) -> bool:
    """Whether ``folder`` holds a run config (``config.yaml``) that says ``normalize: true``
    (a config.yaml of something else says nothing about the model)."""
    from ..run.config import load_config

    try:
        return load_config(RunFolder(folder).config).normalize
    except ValueError:  # none, or not a run's
        return False
