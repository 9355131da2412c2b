"""Training configurations: a YAML file checked against typed pydantic models.

A config names the environment (id and constructor keywords), the number of parallel
environments, the seed, the PPO hyperparameters (SB3's own keyword names, as in rl-zoo3), the
policy network, the evaluation and checkpoint frequencies and, optionally, an imitation phase in
which the minimax expert teaches the policy before PPO (behaviour cloning, then DAgger rounds).

Every key is checked: an unknown or duplicate key, a missing ``env_id`` or ``total_timesteps``,
a wrong type, a value out of range, an environment that is not one of grasp_env's, or a config
that trains nothing raises a :class:`ValueError` naming the key and what it accepts (one line
per problem). The models are the documentation of every key (docs/agents.md).

The YAML reader (:func:`read_yaml`, for configs, sweep files and results specs) refuses a key
given twice, data nested deeper than :data:`~grasp_env_agents.safe_files.MAX_NESTING` levels
(while composing it, before Python's recursion fails) and reads an integer past the 4,300
digits Python converts as :class:`LongInteger`, which every key refuses by its own range.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictBool,
    StrictStr,
    ValidationError,
    model_validator,
)

from grasp_env import ENV_IDS
from grasp_env.envs.spec import check_keywords

from ..cli import MAX_SEED
from ..safe_files import MAX_NESTING

#: The finger-gait environments: sequential, scored by their own programme, not the held-out
#: grasp scenes this module's runs are evaluated on.
GAIT_IDS = ("grasp_env/CubeGait-v0", "grasp_env/CubeGaitMoves-v0")
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


# --- the value types YAML gives --------------------------------------------------------------


class LongInteger:
    """An integer of more digits than Python converts from text (4,300): no key of a config
    takes one, and its message names its size, not the digits."""

    def __init__(self, digits: int, line: int) -> None:
        self.digits, self.line = digits, line

    def __repr__(self) -> str:
        return f"an integer of {self.digits:,} digits (line {self.line})"


def _integer(value: Any) -> Any:
    """Integers as YAML writes them: 100000, or 1e6 and 1.0e+6 (floats)."""
    return int(value) if isinstance(value, float) and value.is_integer() else value


Int = Annotated[int, BeforeValidator(_integer)]
Float = Annotated[float, Field(allow_inf_nan=False)]


def _range(kind: type, low: float, high: float, *, low_open: bool = False) -> Any:
    """``kind`` in [low, high] (or (low, high] with ``low_open``), the range in the message."""
    interval = f"{'(' if low_open else '['}{low}, {high}]"

    def check(value: Any) -> Any:
        if isinstance(value, LongInteger) or (
            not (low < value if low_open else low <= value) or not value <= high
        ):
            raise ValueError(f"must be in {interval}, got {value!r}")
        return value

    def long_integer(value: Any) -> Any:
        # refused with the range, before the type check (which would not say it)
        return check(value) if isinstance(value, LongInteger) else value

    return Annotated[kind, BeforeValidator(long_integer), AfterValidator(check)]


class _Section(BaseModel):
    """Strict: unknown keys are errors, bools and strings are not numbers, frozen."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


# --- the sections ----------------------------------------------------------------------------


class PolicyConfig(_Section):
    """The actor-critic network (SB3 ``MlpPolicy``).

    Args:
        net_arch: hidden layer widths, shared by the separate actor and critic networks.
        activation: hidden activation function.
        log_std_init: initial log standard deviation of PPO's Gaussian exploration noise, in
            action units (-1 gives std 0.37; a low value keeps a pretrained policy precise);
            TD3's noise is ``offpolicy.action_noise``, SAC's std is learnt per state.
        features: the network's input: the raw ``observation``, or the ``grasp`` in the
            object's frame computed from it
            (:class:`grasp_env_agents.learning.features.GraspFeatures`: the equilibrating forces,
            pair directions and normals, which is all k* depends on).
        output: what the actor network outputs: the actions ``k`` themselves (SB3's linear
            action layer), or each finger's ``force_directions``, from which the action is the
            least-squares grip that realises them (:mod:`grasp_env_agents.learning.policy`; needs
            features: grasp).
        normalize_features: the hidden layers see the grasp features standardised by their
            mean and standard deviation over 4,096 poses of the config's scenes, fixed when the
            model is made (the head still reads the grasp itself; needs output:
            force_directions and algo: ppo). The grasp features vary by about 0.1 around
            means near 0.2-0.7, so unscaled they reach the network nearly constant.
    """

    net_arch: Annotated[list[_range(Int, 1, 1 << 16)], Field(min_length=1)] = [256, 256]
    activation: Literal["tanh", "relu", "silu"] = "tanh"
    log_std_init: _range(Float, -20.0, 2.0) = 0.0
    features: Literal["observation", "grasp"] = "observation"
    output: Literal["k", "force_directions"] = "k"
    normalize_features: StrictBool = False


class PPOConfig(_Section):
    """PPO hyperparameters, named as SB3's :class:`~stable_baselines3.PPO` keywords.

    Args:
        learning_rate: Adam step size (the initial one under a linear schedule).
        lr_schedule: ``constant``, or ``linear`` decay to zero over ``total_timesteps``.
        n_steps: steps per environment per rollout; a rollout holds n_steps * n_envs samples
            (at least 2).
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
        critic_warmup: rollouts during which only the critic learns (the actor, its head and
            log std fixed), so that the first actor updates follow the advantages of a fitted
            critic (:class:`grasp_env_agents.learning.algorithms.WarmCriticPPO`).
        baseline: what an action's advantage is measured against: ``critic``, PPO's learned
            value V(s), or ``mean_action``, the reward of the policy's own mean action at the
            same pose, computed exactly from the observation (a self-critical baseline; needs
            gamma = 0, where the advantage is r(s, a) - b(s), the grasp environments' reward,
            the min friction-angle margin, and the raw observation: normalize false; the
            critic is still fitted, and unused).
        use_sde: generalised state-dependent exploration (gSDE) instead of a fixed Gaussian.
        sde_sample_freq: with gSDE, steps between new noise matrices (-1: once per rollout).
    """

    learning_rate: _range(Float, 0.0, 1.0, low_open=True) = 3e-4
    lr_schedule: Literal["constant", "linear"] = "constant"
    n_steps: _range(Int, 1, 1 << 20) = 64
    batch_size: _range(Int, 2, 1 << 24) = 256
    n_epochs: _range(Int, 1, 1000) = 10
    gamma: _range(Float, 0.0, 1.0) = 0.0
    gae_lambda: _range(Float, 0.0, 1.0) = 0.95
    clip_range: _range(Float, 0.0, 10.0, low_open=True) = 0.2
    ent_coef: _range(Float, 0.0, 10.0) = 0.0
    vf_coef: _range(Float, 0.0, 10.0) = 0.5
    max_grad_norm: _range(Float, 0.0, 1e6, low_open=True) = 0.5
    target_kl: _range(Float, 0.0, 10.0, low_open=True) | None = None
    critic_warmup: _range(Int, 0, 1 << 20) = 0
    baseline: Literal["critic", "mean_action"] = "critic"
    use_sde: StrictBool = False
    sde_sample_freq: _range(Int, -1, 1 << 20) = -1


class OffPolicyConfig(_Section):
    """SAC and TD3 hyperparameters (``algo: sac`` or ``td3``), named as SB3's keywords.

    Args:
        learning_rate: Adam step size of the actor and the critics.
        buffer_size: transitions the replay buffer keeps. SB3 allocates it whole, and every
            checkpoint writes it whole (about 280 bytes a transition on the cube: 28 MB at the
            default, filled or not).
        learning_starts: environment steps of random actions before learning starts.
        batch_size: minibatch size of each gradient step.
        tau: soft update coefficient of the target networks.
        gamma: discount (0: every pose is a bandit, the critic regresses the reward).
        train_freq: environment steps (per environment) between updates.
        gradient_steps: gradient steps per update.
        action_noise: TD3's Gaussian exploration noise, in action units.
        ent_coef: SAC's entropy coefficient: ``auto`` (learned), or a number.
    """

    learning_rate: _range(Float, 0.0, 1.0, low_open=True) = 3e-4
    buffer_size: _range(Int, 1, 1 << 30) = 100_000
    learning_starts: _range(Int, 0, 1 << 40) = 10_000
    batch_size: _range(Int, 1, 1 << 24) = 256
    tau: _range(Float, 0.0, 1.0, low_open=True) = 0.005
    gamma: _range(Float, 0.0, 1.0) = 0.0
    train_freq: _range(Int, 1, 1 << 20) = 1
    gradient_steps: _range(Int, 1, 1 << 20) = 1
    action_noise: _range(Float, 0.0, 10.0) = 0.1
    ent_coef: Literal["auto"] | _range(Float, 0.0, 10.0) = "auto"


#: The offpolicy key of the other off-policy algorithm (refused if given, not written).
OTHER_ALGORITHMS_KEY = {"td3": "ent_coef", "sac": "action_noise"}


class ImitationConfig(_Section):
    """The policy's mean action fitted on collected states, before PPO
    (:mod:`grasp_env_agents.learning.imitation`): to the minimax expert's grip, to the reward's
    exact gradient, or both.

    Round 0 is behaviour cloning: the expert drives the vector environment and every state it
    visits is stored with the expert's action. Each further round is a DAgger round: the
    learner drives, the expert labels the states the learner visits, the data set grows. After
    each round the policy's mean action is fitted (``label_weight`` x the mean squared error to
    the labels + ``gap_weight`` x the max friction angle) with Adam under a cosine
    learning-rate decay. With ``label_weight`` 0 there is no expert: the learner drives every
    round and the fit follows the reward alone.

    Args:
        rounds: data-collection rounds: 1 is behaviour cloning alone, more add DAgger rounds.
        samples_per_round: states collected per round.
        epochs: passes over the aggregated data set after each round.
        batch_size: minibatch size.
        learning_rate: initial Adam step size of each round (cosine decay to 1% of it).
        n_envs: parallel environments of the data-collecting vector env.
        label_weight: weight of the squared error to the expert's actions (0: no expert is
            made or called).
        gap_weight: weight of the max friction angle (radians) the action gives (0: pure
            imitation). That angle is computed from the observation alone, so this term
            trains on the environment's own reward, exactly.
    """

    rounds: _range(Int, 1, 1000) = 1
    samples_per_round: _range(Int, 1, 1 << 30) = 100_000
    epochs: _range(Int, 1, 100_000) = 10
    batch_size: _range(Int, 1, 1 << 24) = 1024
    learning_rate: _range(Float, 0.0, 1.0, low_open=True) = 1e-3
    n_envs: _range(Int, 1, 1 << 20) = 256
    label_weight: _range(Float, 0.0, 1e6) = 1.0
    gap_weight: _range(Float, 0.0, 1e6) = 0.0

    @model_validator(mode="after")
    def _something_to_fit(self) -> ImitationConfig:
        if self.label_weight == 0 and self.gap_weight == 0:
            raise ValueError(
                "has nothing to fit: label_weight and gap_weight are both 0;"
                " give either a weight > 0 (label_weight: the expert's actions, gap_weight:"
                " the reward)"
            )
        return self


class TrainConfig(_Section):
    """One training run. ``env_id`` and ``total_timesteps`` are required: a config says what it
    trains on and for how long.

    Args:
        env_id: one of grasp_env's environment ids, e.g. ``grasp_env/CubeGraspRandom-v0``.
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
        algo: the learning algorithm: ``ppo``, or SB3's off-policy ``td3`` or ``sac``
            (:mod:`grasp_env_agents.learning.algorithms`).
        policy: the network.
        ppo: PPO hyperparameters (algo: ppo).
        offpolicy: TD3's and SAC's hyperparameters (algo: td3 or sac; absent or null: the
            defaults).
        imitation: the fit before the algorithm (algo: ppo): the expert as teacher, or with
            ``label_weight`` 0 the reward's exact gradient alone; None (absent or null) trains
            from scratch.
    """

    env_id: StrictStr
    env_kwargs: dict[StrictStr, Any] = {}
    n_envs: _range(Int, 1, 1 << 20) = 8
    seed: _range(Int, 0, MAX_SEED) = 0
    total_timesteps: _range(Int, 0, 1 << 40)
    normalize: StrictBool = False
    eval_freq: _range(Int, 0, 1 << 40) = 20_000
    eval_episodes: _range(Int, 1, 1 << 20) = 64
    checkpoint_freq: _range(Int, 0, 1 << 40) = 50_000
    torch_threads: _range(Int, 1, 1024) = 1
    algo: Literal["ppo", "td3", "sac"] = "ppo"
    policy: PolicyConfig = PolicyConfig()
    ppo: PPOConfig = PPOConfig()
    offpolicy: OffPolicyConfig | None = None
    imitation: ImitationConfig | None = None

    @model_validator(mode="before")
    @classmethod
    def _off_policy_defaults(cls, data: Any) -> Any:
        """An off-policy config without an offpolicy section has the section's defaults."""
        if isinstance(data, Mapping) and data.get("algo") in OTHER_ALGORITHMS_KEY:
            if data.get("offpolicy") is None:
                return {**data, "offpolicy": {}}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> TrainConfig:
        if self.env_id not in ENV_IDS:
            raise ValueError(
                f"env_id: {self.env_id!r} is not a grasp_env environment; one of {list(ENV_IDS)}"
            )
        if self.env_id in GAIT_IDS:  # their evaluation is the gait's (grasp-env gait --models)
            raise ValueError(
                f"env_id: {self.env_id} trains with rl-zoo3 (docs/gait.md) and is evaluated by"
                " grasp-env gait --models; grasp-env train trains the grasp environments"
            )
        check_keywords(self.env_kwargs)  # the keywords' ranges (spec.py), before any env is built
        if self.total_timesteps == 0 and self.imitation is None:
            raise ValueError(
                "nothing to train: total_timesteps is 0 and there is no imitation section;"
                " set total_timesteps > 0 (PPO steps) or add an imitation section"
            )
        if self.algo == "ppo" and self.offpolicy is not None:
            raise ValueError("offpolicy: the section is for algo: td3 or sac, got algo: ppo")
        if self.algo != "ppo" and "ppo" in self.model_fields_set:
            raise ValueError(
                f"ppo: the section is for algo: ppo, got algo: {self.algo} (its"
                " hyperparameters go in an offpolicy section)"
            )
        given = set() if self.offpolicy is None else self.offpolicy.model_fields_set
        other = OTHER_ALGORITHMS_KEY.get(self.algo)
        if other in given:
            owner = "SAC's entropy coefficient" if other == "ent_coef" else "TD3's noise"
            raise ValueError(f"offpolicy.{other} is {owner}, got algo: {self.algo}")
        if self.algo != "ppo" and self.imitation is not None:
            raise ValueError(
                f"imitation: the expert teaches PPO's actor-critic; algo: {self.algo} has none"
                " (use algo: ppo)"
            )
        if self.ppo.n_steps * self.n_envs < 2:
            raise ValueError(
                f"ppo.n_steps * n_envs must be >= 2 (a PPO rollout normalises its advantages"
                f" over its samples), got {self.ppo.n_steps} * {self.n_envs}"
            )
        if self.policy.output == "force_directions" and self.policy.features != "grasp":
            raise ValueError(
                "policy.output: force_directions needs policy.features: grasp (the head solves "
                f"for k in the grasp's object frame), got features: {self.policy.features}"
            )
        if self.ppo.baseline == "mean_action" and self.ppo.gamma != 0.0:
            raise ValueError(
                "ppo.baseline: mean_action is exact for gamma = 0 (each pose a bandit), got"
                f" ppo.gamma: {self.ppo.gamma}; use baseline: critic"
            )
        if self.policy.normalize_features and not (
            self.policy.output == "force_directions" and self.algo == "ppo"
        ):
            raise ValueError(
                "policy.normalize_features standardises the inputs of PPO's force-direction"
                f" policy: it needs policy.output: force_directions and algo: ppo, got output:"
                f" {self.policy.output} and algo: {self.algo}"
            )
        if self.ppo.baseline == "mean_action" and self.normalize:
            raise ValueError(
                "ppo.baseline: mean_action computes the reward from the raw observation, which"
                " normalize: true hides from the rollout; set normalize: false or use"
                " baseline: critic"
            )
        if self.policy.features == "grasp" and self.normalize:
            raise ValueError(
                "normalize must be false with policy.features: grasp (the grasp features are "
                "computed from the raw observation; policy.normalize_features standardises them)"
            )
        return self

    @property
    def expert_teaches(self) -> bool:
        """Whether an imitation phase learns from the expert (not the reward alone)."""
        return self.imitation is not None and self.imitation.label_weight > 0

    def to_dict(self) -> dict[str, Any]:
        """Plain data (the YAML written into the run directory): the sections of the config's
        algorithm only (an off-policy config has no ppo section, a PPO one no offpolicy)."""
        if self.algo == "ppo":
            return self.model_dump(exclude={"offpolicy"})
        other = OTHER_ALGORITHMS_KEY[self.algo]
        return self.model_dump(exclude={"ppo": True, "offpolicy": {other}})

    def replace(self, **changes: Any) -> TrainConfig:
        """A copy with keys changed, checked like a loaded config; nested keys by dotted path:
        ``config.replace(seed=1, **{"ppo.learning_rate": 1e-4})``."""
        return config_from_dict(_with_keys(self.to_dict(), changes))


# --- reading and writing ---------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, with fixes: a key given twice in one mapping is an error (not the
    last one silently), 1e6 and 3e-4 are numbers, as in YAML 1.2 (PyYAML follows YAML 1.1,
    which reads them as strings), data nested deeper than
    :data:`~grasp_env_agents.safe_files.MAX_NESTING` levels is refused as it is composed
    (PyYAML composes recursively: past about 300 levels, a RecursionError), and an integer too
    long for Python's int() is a :class:`LongInteger`."""

    _nesting = 0

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        self._nesting += 1
        try:
            if self._nesting > MAX_NESTING:
                line = self.peek_event().start_mark.line + 1
                raise ValueError(f"line {line}: nested deeper than {MAX_NESTING} levels; refused")
            return super().compose_node(parent, index)
        finally:
            self._nesting -= 1

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int | LongInteger:
        try:
            return super().construct_yaml_int(node)
        except ValueError:  # past the 4,300 digits Python converts
            digits = sum(c.isdigit() for c in str(node.value))
            return LongInteger(digits, node.start_mark.line + 1)

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            line = key_node.start_mark.line + 1
            if key in seen:
                first = seen[key]
                raise ValueError(
                    f"line {line}: duplicate key {key!r} (first given on line {first})"
                )
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def read_yaml(path: Path, what: str, keys: Sequence[str] | None = None) -> Any:
    """The YAML file ``path`` (a config, a sweep file, a results spec: ``what``) as data, with
    a key given twice refused and 1e-4 read as a number; a ValueError naming the file if it is
    missing, a directory or not valid YAML. With ``keys``: a mapping of those keys only (an
    empty file is an empty one)."""
    if path.is_dir():
        raise ValueError(f"{what} {str(path)!r} is a directory, not a file")
    if not path.is_file():
        raise ValueError(f"{what} {str(path)!r} does not exist")
    try:
        data = yaml.load(path.read_text(), Loader=_Loader)
    except yaml.YAMLError as error:
        raise ValueError(f"{what} {str(path)!r} is not valid YAML: {error}") from None
    except ValueError as error:  # a duplicate key, or nested too deep
        raise ValueError(f"{what} {str(path)!r}, {error}") from None
    except RecursionError:  # not past MAX_NESTING: never, but PyYAML recurses
        raise ValueError(
            f"{what} {str(path)!r} is nested deeper than {MAX_NESTING} levels; refused"
        ) from None
    if keys is None:
        return data
    data = {} if data is None else data
    if not isinstance(data, Mapping):
        raise ValueError(f"{what} {path} must be a mapping of the keys {list(keys)}")
    unknown = set(data) - set(keys)
    if unknown:
        raise ValueError(
            f"{what} {path}: unknown key(s) {sorted(unknown, key=str)}; accepted keys: {list(keys)}"
        )
    return dict(data)


def load_config(path: str | Path, overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """Read and check a YAML config.

    ``overrides`` replace keys after reading, by dotted path for nested ones
    (``{"total_timesteps": 0, "ppo.learning_rate": 1e-4}``: the CLI's, a sweep's).
    """
    path = Path(path)
    data = read_yaml(path, "config file")
    if data is None:
        raise ValueError(
            f"config {str(path)!r} is empty: a config sets at least env_id and total_timesteps"
            f" (see the shipped configs {shipped_configs()})"
        )
    if not isinstance(data, Mapping):
        raise ValueError(f"config {str(path)!r} must be a mapping of keys to values")
    try:
        return config_from_dict(_with_keys(data, overrides or {}))
    except ValueError as error:
        changed = ", ".join(f"{key}={value!r}" for key, value in (overrides or {}).items())
        where = f" with {changed}" if changed else ""  # the caller's overrides may be the cause
        raise ValueError(f"config {str(path)!r}{where}: {error}") from None


def config_from_dict(data: Mapping[str, Any]) -> TrainConfig:
    """Build a :class:`TrainConfig` from plain data, checking every key and type."""
    if not isinstance(data, Mapping):
        raise ValueError(f"a config must be a mapping of keys, got {type(data).__name__}")
    try:
        return TrainConfig.model_validate(data)
    except ValidationError as error:
        problems = [_explain(e) for e in error.errors()]
        head = "" if len(problems) == 1 else f"{len(problems)} problems:\n  "
        raise ValueError(head + "\n  ".join(problems)) from None


def save_config(config: TrainConfig, path: str | Path) -> None:
    """Write the config as YAML (what ``load_config`` reads back to the same config)."""
    Path(path).write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))


def _with_keys(data: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with each dotted key of ``changes`` set (missing sections created)."""

    def set_key(data: Mapping[str, Any], keys: list[str], value: Any) -> dict[str, Any]:
        head, *rest = keys
        if rest:
            inner = data.get(head)
            value = set_key(inner if isinstance(inner, Mapping) else {}, rest, value)
        return {**data, head: value}

    result = dict(data)
    for key, value in changes.items():
        result = set_key(result, key.split("."), value)
    return result


# --- error messages --------------------------------------------------------------------------


def _explain(error: Mapping[str, Any]) -> str:
    """One pydantic error as "key must be what it accepts, got what it got"."""
    loc = [part for part in error["loc"] if part != "[key]"]
    name = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc).lstrip(".")
    kind, message = error["type"], error["msg"]
    if kind == "value_error":  # a field's range, or TrainConfig's checks (naming their keys)
        return f"{name} {error['ctx']['error']}".strip()
    if kind == "extra_forbidden":
        section: Any = TrainConfig
        for part in loc[:-1]:  # the section that has no such key, for its accepted keys
            section = section.model_fields[part].annotation
            section = next(t for t in getattr(section, "__args__", [section]) if t is not None)
        return f"unknown config key {name!r}; accepted keys: {list(section.model_fields)}"
    if kind == "missing":
        return f"{name}: missing; a config must set it"
    if message.startswith("Input should be"):
        return f"{name} must be {message.removeprefix('Input should be ')}, got {error['input']!r}"
    return f"{name}: {message}"
