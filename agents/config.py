"""Training configurations: a YAML file checked against typed dataclasses.

A config names the environment (id and constructor keywords), the number of parallel
environments, the seed, the PPO hyperparameters (SB3's own keyword names, as in rl-zoo3), the
policy network, the evaluation and checkpoint frequencies and, optionally, an imitation phase in
which the minimax expert teaches the policy before PPO (behaviour cloning, then DAgger rounds).

Every key is checked: an unknown key, a wrong type, a value out of range or an unknown
environment id raises a :class:`ValueError` naming the key and what it accepts.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml

from grasp_env.envs.validation import DEFAULT_K_MAX_RATIO

#: The configs shipped with the package (``configs/`` in the repository), by name.
CONFIG_DIR = Path(str(resources.files("grasp_env_agents.configs")))
#: rl-zoo3's hyperparameter file for grasp_env's environments (``-conf`` of ``rl_zoo3.train``).
ZOO_HYPERPARAMS = CONFIG_DIR / "rl_zoo3" / "ppo.yml"
#: The config ``grasp-env train`` uses when given none.
DEFAULT_CONFIG = CONFIG_DIR / "default.yaml"


def shipped_configs() -> list[str]:
    """Names of the configs shipped with the package (``--config NAME``)."""
    return sorted(path.stem for path in CONFIG_DIR.glob("*.yaml"))


def config_path(name_or_path: str | Path) -> Path:
    """A config file: an existing path, or the name of a shipped config (``dagger``)."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    shipped = CONFIG_DIR / f"{path.name.removesuffix('.yaml')}.yaml"
    if path.parent == Path(".") and shipped.is_file():
        return shipped
    raise ValueError(
        f"config {str(name_or_path)!r}: no such file, nor a shipped config; the shipped"
        f" configs are {shipped_configs()} (or give the path of a YAML file)"
    )


@dataclass(frozen=True)
class PolicyConfig:
    """The actor-critic network (SB3 ``MlpPolicy``).

    Args:
        net_arch: hidden layer widths, shared by the separate actor and critic networks.
        activation: hidden activation function.
        log_std_init: initial log standard deviation of the Gaussian exploration noise, in
            action units (-1 gives std 0.37; a low value keeps a pretrained policy precise).
        features: the network's input: the raw ``observation``, or the ``grasp`` in the
            object's frame computed from it (:class:`grasp_env_agents.features.GraspFeatures`: the
            equilibrating forces, pair directions and normals, which is all k* depends on).
        output: what the actor network outputs: the actions ``k`` themselves (SB3's linear
            action layer), or each finger's ``force_directions``, from which the action is the
            least-squares grip that realises them (:mod:`grasp_env_agents.policy`; needs
            features: grasp).
    """

    net_arch: list[int] = field(default_factory=lambda: [256, 256])
    activation: Literal["tanh", "relu", "silu"] = "tanh"
    log_std_init: float = 0.0
    features: Literal["observation", "grasp"] = "observation"
    output: Literal["k", "force_directions"] = "k"

    def __post_init__(self) -> None:
        if not self.net_arch or any(width < 1 for width in self.net_arch):
            raise ValueError(f"policy.net_arch must be positive layer widths, got {self.net_arch}")
        if self.output == "force_directions" and self.features != "grasp":
            raise ValueError(
                "policy.output: force_directions needs policy.features: grasp (the head solves "
                f"for k in the grasp's object frame), got features: {self.features}"
            )
        _check_range("policy.log_std_init", self.log_std_init, -20.0, 2.0)


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters, named as SB3's :class:`~stable_baselines3.PPO` keywords.

    Args:
        learning_rate: Adam step size (the initial one under a linear schedule).
        lr_schedule: ``constant``, or ``linear`` decay to zero over ``total_timesteps``.
        n_steps: steps per environment per rollout; a rollout holds n_steps * n_envs samples.
        batch_size: minibatch size.
        n_epochs: passes over each rollout.
        gamma: discount. The states do not depend on the actions (the trajectory is fixed),
            so with termination off gamma = 0 is exact and removes the critic's bootstrap noise.
        gae_lambda: GAE lambda.
        clip_range: PPO ratio clip.
        ent_coef: entropy bonus.
        vf_coef: value loss weight.
        max_grad_norm: gradient clipping norm.
        target_kl: stop an update's epochs early past this KL divergence (None: never).
    """

    learning_rate: float = 3e-4
    lr_schedule: Literal["constant", "linear"] = "constant"
    n_steps: int = 64
    batch_size: int = 256
    n_epochs: int = 10
    gamma: float = 0.0
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = None

    def __post_init__(self) -> None:
        _check_range("ppo.learning_rate", self.learning_rate, 0.0, 1.0, low_open=True)
        _check_range("ppo.n_steps", self.n_steps, 1, 1 << 20)
        _check_range("ppo.batch_size", self.batch_size, 2, 1 << 24)
        _check_range("ppo.n_epochs", self.n_epochs, 1, 1000)
        _check_range("ppo.gamma", self.gamma, 0.0, 1.0)
        _check_range("ppo.gae_lambda", self.gae_lambda, 0.0, 1.0)
        _check_range("ppo.clip_range", self.clip_range, 0.0, 10.0, low_open=True)
        _check_range("ppo.ent_coef", self.ent_coef, 0.0, 10.0)
        _check_range("ppo.vf_coef", self.vf_coef, 0.0, 10.0)
        _check_range("ppo.max_grad_norm", self.max_grad_norm, 0.0, 1e6, low_open=True)
        if self.target_kl is not None:
            _check_range("ppo.target_kl", self.target_kl, 0.0, 10.0, low_open=True)


@dataclass(frozen=True)
class ImitationConfig:
    """The minimax expert as teacher, before PPO (:mod:`grasp_env_agents.imitation`).

    Round 0 is behaviour cloning: the expert drives the vector environment and every state it
    visits is stored with the expert's action. Each further round is a DAgger round: the
    learner drives, the expert labels the states the learner visits, the data set grows. After
    each round the policy's mean action is fitted to the labels (mean squared error) with Adam
    under a cosine learning-rate decay.

    Args:
        rounds: data-collection rounds: 1 is behaviour cloning alone, more add DAgger rounds.
        samples_per_round: expert-labelled states collected per round.
        epochs: passes over the aggregated data set after each round.
        batch_size: minibatch size.
        learning_rate: initial Adam step size of each round (cosine decay to 1% of it).
        n_envs: parallel environments of the data-collecting vector env.
        gap_weight: weight of the max friction angle (radians) the action gives, added to the
            squared error (0: pure imitation). That angle is computed from the observation
            alone, so this term trains on the environment's own reward, exactly.
    """

    rounds: int = 1
    samples_per_round: int = 100_000
    epochs: int = 10
    batch_size: int = 1024
    learning_rate: float = 1e-3
    n_envs: int = 256
    gap_weight: float = 0.0

    def __post_init__(self) -> None:
        _check_range("imitation.rounds", self.rounds, 1, 1000)
        _check_range("imitation.samples_per_round", self.samples_per_round, 1, 1 << 30)
        _check_range("imitation.epochs", self.epochs, 1, 100_000)
        _check_range("imitation.batch_size", self.batch_size, 1, 1 << 24)
        _check_range("imitation.learning_rate", self.learning_rate, 0.0, 1.0, low_open=True)
        _check_range("imitation.n_envs", self.n_envs, 1, 1 << 20)
        _check_range("imitation.gap_weight", self.gap_weight, 0.0, 1e6)


@dataclass(frozen=True)
class TrainConfig:
    """One training run.

    Args:
        env_id: a registered Gymnasium id, e.g. ``grasp_env/CubeGraspRandom-v0``.
        env_kwargs: keywords for the environment's constructor (training and evaluation).
        n_envs: parallel training environments.
        seed: seeds torch, numpy, Python's ``random`` and the environments.
        total_timesteps: PPO environment steps (0: the imitation phase alone).
        normalize: normalise observations with a running mean and variance (VecNormalize);
            the statistics are saved with every checkpoint.
        eval_freq: environment steps between evaluations (0: evaluate only at the end).
        eval_episodes: held-out episodes per evaluation, the same scenes every time.
        checkpoint_freq: environment steps between checkpoints (0: only at the end).
        torch_threads: CPU threads torch may use (fewer threads: less contention, the same
            numbers on every machine).
        policy: the network.
        ppo: PPO hyperparameters.
        imitation: the expert-teacher phase; None (absent) trains PPO from scratch.
    """

    env_id: str = "grasp_env/CubeGraspRandom-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 8
    seed: int = 0
    total_timesteps: int = 100_000
    normalize: bool = False
    eval_freq: int = 20_000
    eval_episodes: int = 64
    checkpoint_freq: int = 50_000
    torch_threads: int = 1
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    imitation: ImitationConfig | None = None

    def __post_init__(self) -> None:
        _check_range("n_envs", self.n_envs, 1, 1 << 20)
        _check_range("seed", self.seed, 0, 2**32 - 1)
        _check_range("total_timesteps", self.total_timesteps, 0, 1 << 40)
        _check_range("eval_freq", self.eval_freq, 0, 1 << 40)
        _check_range("eval_episodes", self.eval_episodes, 1, 1 << 20)
        _check_range("checkpoint_freq", self.checkpoint_freq, 0, 1 << 40)
        _check_range("torch_threads", self.torch_threads, 1, 1024)
        check_env_id(self.env_id)
        if self.policy.features == "grasp" and self.normalize:
            raise ValueError(
                "normalize must be false with policy.features: grasp (the grasp features are "
                "computed from the raw observation)"
            )

    @property
    def k_max_ratio(self) -> float:
        """k_max / w of the config's environment: the scale of its actions."""
        return self.env_kwargs.get("k_max_ratio", DEFAULT_K_MAX_RATIO)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (the YAML written into the run directory)."""
        return dataclasses.asdict(self)


def check_env_id(env_id: str) -> None:
    """Raise ValueError unless ``env_id`` is registered (importing grasp_env registers ours)."""
    import gymnasium as gym

    import grasp_env  # noqa: F401  (registers the grasp_env/ ids)

    if env_id not in gym.registry:
        ours = sorted(name for name in gym.registry if name.startswith("grasp_env/"))
        raise ValueError(f"env_id: unknown environment {env_id!r}; registered grasp ids: {ours}")


def load_config(path: str | Path, overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """Read and check a YAML config; ``overrides`` replace top-level keys (e.g. from the CLI)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"config file {str(path)!r} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ValueError(f"config {str(path)!r} is not valid YAML: {error}") from None
    data = {} if data is None else data
    if not isinstance(data, Mapping):
        raise ValueError(f"config {str(path)!r} must be a mapping of keys to values")
    return config_from_dict({**data, **(overrides or {})})


def config_from_dict(data: Mapping[str, Any]) -> TrainConfig:
    """Build a :class:`TrainConfig` from plain data, checking every key and type."""
    return _build(TrainConfig, data, "")


def save_config(config: TrainConfig, path: str | Path) -> None:
    """Write the config as YAML (what ``load_config`` reads back to the same config)."""
    Path(path).write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))


# --- checking ------------------------------------------------------------------------------


def _check_range(
    name: str, value: float, low: float, high: float, *, low_open: bool = False
) -> None:
    if not (low < value if low_open else low <= value) or not value <= high:
        bracket = "(" if low_open else "["
        raise ValueError(f"{name} must be in {bracket}{low}, {high}], got {value}")


def _build(cls: type, data: Any, where: str) -> Any:
    """Instantiate dataclass ``cls`` from a mapping, checking the keys and their types."""
    if not isinstance(data, Mapping):
        name = where.rstrip(".") or "config"
        raise ValueError(f"{name} must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for key in data:
        if key not in names:
            raise ValueError(f"unknown config key {where + str(key)!r}; accepted keys: {names}")
    values = {key: _convert(hints[key], value, where + key) for key, value in data.items()}
    return cls(**values)


def _convert(hint: Any, value: Any, name: str) -> Any:
    """Check ``value`` against the type hint ``hint``; return it converted (int to float...)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _convert(inner, value, name)
    if dataclasses.is_dataclass(hint):
        return _build(hint, value, name + ".")
    if origin is Literal:
        if value not in args:
            raise ValueError(f"{name} must be one of {list(args)}, got {value!r}")
        return value
    if origin is list:
        if not isinstance(value, list):
            raise ValueError(f"{name} must be a list, got {type(value).__name__} {value!r}")
        return [_convert(args[0], item, f"{name}[{i}]") for i, item in enumerate(value)]
    if origin is dict:
        if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
            raise ValueError(f"{name} must be a mapping with string keys, got {value!r}")
        return dict(value)
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return value
    if hint is int:
        # YAML reads 1e6 as a float (and 1.0e+6 too): accept floats with integer values.
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        return value
    if hint is float:
        # PyYAML reads 3e-4 (no dot) as a string: accept numeric strings for floats.
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise ValueError(f"{name} must be a number, got {value!r}") from None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{name} must be a number, got {value!r}")
        if value != value or value in (float("inf"), float("-inf")):
            raise ValueError(f"{name} must be finite, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{name} must be a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config type {hint!r} for {name}")  # a bug in this module
