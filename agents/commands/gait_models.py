"""``grasp-env gait --models``: trained agents played beside the certified and the greedy gait.

Each model file (SB3's PPO, TD3, SAC, rl-zoo3's, or sb3-contrib's MaskablePPO) is loaded
without running code from it (:func:`grasp_env_agents.learning.models.load_agent`) and checked
before any solving; each plays one deterministic episode of ``grasp_env/CubeGait-v0`` from the
first pose (``grasp_env/CubeGaitMoves-v0`` for an agent of the moves alone, a discrete
action) to the first slip or drop, the unshaped environment whatever it was trained on.

A MaskablePPO agent acts with the action masks it was trained with: they are part of its
policy (docs/gait.md, "Learning the whole turn": the study's networks hold 181 of 181 poses
with ``GaitMoveMasks(hold=True, lookahead=True)`` and 5 without masks). So it plays on
``CubeGaitMoves-v0`` in ``GaitMoveMasks`` with its settings, each step's ``action_masks()``
passed to ``predict(..., action_masks=...)``. The settings are ``GaitMoveMasks``'s keywords,
read from the model file itself (its data's :data:`MASKS_ENTRY` entry: SB3 saves a model's
attributes, and ``benchmarks/study_gait_rl.py`` sets ``model.gait_masks`` before it saves) or
from :data:`MASKS_FILE` beside it (JSON, for a model trained elsewhere); a MaskablePPO model
with neither, or with two that disagree, is refused, naming what is missing.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..progress import console
from .gait_options import add_arguments, resolve

#: The model's attribute (its file's ``data`` entry) holding its masks' settings.
MASKS_ENTRY = "gait_masks"
#: The JSON file beside a model file that holds its masks' settings, if its data does not.
MASKS_FILE = "gait_masks.json"
#: ``GaitMoveMasks``'s keywords, the settings a mask may have.
MASK_KEYWORDS = ("hold", "lookahead")
#: The most bytes a masks file may hold (its settings take 40).
MASKS_FILE_BYTES = 4096


def check_rliable(args: argparse.Namespace) -> None:
    """ValueError naming the extra if ``--models`` gives several agents (their IQM and its
    interval are rliable's) and rliable does not import: before any work, not after it."""
    if len(args.models) > 1:
        try:
            import rliable.library  # noqa: F401
        except ImportError as error:
            raise ValueError(
                f"--models with {len(args.models)} models reports their IQM with rliable, which"
                f' does not import ({error}): pip install "grasp-env[results]"'
            ) from None


def env_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """``grasp_env/CubeGait-v0``'s keywords for the options (ValueError for options that
    environment cannot take: it has the default hand, sites and weight)."""
    add_arguments(parser := argparse.ArgumentParser())
    defaults = resolve(parser.parse_args([]))
    resolve(args)
    fixed = ["weight", "offsets", "cg_offset", "finger_azimuths", "finger_elevation", "no_thumb"]
    changed = [name for name in fixed if getattr(args, name) != getattr(defaults, name)]
    if changed:
        options = ", ".join("--" + name.replace("_", "-") for name in changed)
        raise ValueError(
            f"--models plays on grasp_env/CubeGait-v0, whose hand, sites and weight are the"
            f" defaults: drop {options}"
        )
    trajectory = {
        "axis": tuple(args.axis),
        "alpha_start_deg": args.alpha_start,
        "alpha_end_deg": args.alpha_end,
        "alpha_step_deg": args.alpha_step,
    }
    kwargs: dict[str, Any] = {"trajectory": trajectory, "mu": args.mu, "cone_deg": args.cone}
    if args.k_max is not None:
        kwargs["k_max_ratio"] = args.k_max / args.weight
    return kwargs


@dataclass(frozen=True)
class Episode:
    """One deterministic episode of a gait policy: the poses it held (no slip, no drop), the
    alpha where it ended early (None if it held to the end) and its worst margin (radians)
    over the poses it held."""

    held: int
    ended_deg: float | None
    worst: float


class MaskedAgent:
    """A MaskablePPO agent (``agent``: a loaded :class:`TrainedAgent`) with the settings of the
    masks it acts with (``masks``: ``GaitMoveMasks``'s keywords); :func:`play` plays it on
    ``grasp_env/CubeGaitMoves-v0`` in ``GaitMoveMasks(**masks)``."""

    def __init__(self, agent: Any, masks: dict[str, bool]) -> None:
        self.agent = agent
        self.model = agent.model
        self.masks = dict(masks)

    def predict(
        self, observation: np.ndarray, deterministic: bool = True, action_masks: Any = None
    ) -> tuple[np.ndarray, Any]:
        """The agent's move for ``observation`` among those ``action_masks`` (M,) allows
        (the environment's ``action_masks()``); ValueError without them."""
        if action_masks is None:
            raise ValueError(
                "a MaskablePPO agent acts with the action masks it was trained with"
                f" (GaitMoveMasks({describe_masks(self.masks)})): pass action_masks"
            )
        normalizer = getattr(self.agent, "normalizer", None)
        if normalizer is not None:
            observation = normalizer.normalize_obs(observation)
        return self.model.predict(
            observation, deterministic=deterministic, action_masks=action_masks
        )


def describe_masks(masks: dict[str, bool]) -> str:
    """``hold=True, lookahead=True``: the masks' settings as ``GaitMoveMasks``'s keywords."""
    return ", ".join(f"{key}={masks[key]}" for key in MASK_KEYWORDS if key in masks)


def is_maskable(model: Any) -> bool:
    """Whether ``model`` is sb3-contrib's MaskablePPO (or a subclass of it)."""
    if type(model).__module__.split(".")[0] != "sb3_contrib":
        return False  # a model of SB3's own, or none: sb3-contrib is not imported for it
    from ..learning.models import algorithm

    return isinstance(model, algorithm("maskable_ppo"))


def check_masks(masks: Any, where: str) -> dict[str, bool]:
    """``masks`` as ``GaitMoveMasks``'s keywords (a mapping of ``hold`` and ``lookahead`` to
    booleans, ``lookahead`` only with ``hold``); a ValueError naming ``where`` otherwise."""
    if not isinstance(masks, dict):
        raise ValueError(
            f"{where} must be a mapping of GaitMoveMasks's keywords {list(MASK_KEYWORDS)} to"
            f' true or false (e.g. {{"hold": true, "lookahead": true}}), got {masks!r:.80}'
        )
    unknown = sorted(str(key) for key in masks if key not in MASK_KEYWORDS)
    if unknown:
        raise ValueError(
            f"{where} has {unknown}, which GaitMoveMasks does not take: its keywords are"
            f" {list(MASK_KEYWORDS)}"
        )
    for key, value in masks.items():
        if not isinstance(value, bool):
            raise ValueError(f"{where}: {key} must be true or false, got {value!r:.80}")
    if masks.get("lookahead", False) and not masks.get("hold", False):
        raise ValueError(f"{where}: lookahead masks among the moves that hold: it needs hold too")
    return dict(masks)


def read_masks_file(path: Path) -> dict[str, bool]:
    """The masks' settings in the JSON file ``path`` (:data:`MASKS_FILE`), checked."""
    size = path.stat().st_size
    if size > MASKS_FILE_BYTES:
        raise ValueError(
            f"{path}: {size} bytes, more than the {MASKS_FILE_BYTES} a masks file may hold"
        )
    try:
        masks = json.loads(path.read_bytes())
    except (ValueError, RecursionError) as error:  # JSONDecodeError, UnicodeDecodeError
        raise ValueError(f"{path}: not JSON ({type(error).__name__}: {error})") from None
    return check_masks(masks, str(path))


def mask_settings(model_file: Path, model: Any) -> dict[str, bool]:
    """The settings of the masks the MaskablePPO ``model`` (loaded from ``model_file``) was
    trained with: its data's :data:`MASKS_ENTRY` entry, or :data:`MASKS_FILE` beside the
    file; ValueError naming what is missing if neither holds them, or if the two disagree."""
    beside = Path(model_file).parent / MASKS_FILE
    found = []
    if hasattr(model, MASKS_ENTRY):
        where = f"{model_file}: its data's {MASKS_ENTRY!r} entry"
        found.append((where, check_masks(getattr(model, MASKS_ENTRY), where)))
    if beside.is_file():
        found.append((str(beside), read_masks_file(beside)))
    if not found:
        raise ValueError(
            f"{model_file}: a MaskablePPO model, which acts with the action masks it was trained"
            f" with (they are part of its policy), but its data has no {MASKS_ENTRY!r} entry and"
            f" there is no {beside}: write GaitMoveMasks's keywords there as JSON, e.g."
            ' {"hold": true, "lookahead": true} (the masks of benchmarks/study_gait_rl.py, which'
            f" saves them in its models as {MASKS_ENTRY})"
        )
    if len(found) == 2 and found[0][1] != found[1][1]:
        (first, a), (second, b) = found
        raise ValueError(
            f"{first} says GaitMoveMasks({describe_masks(a)}) and {second} says"
            f" GaitMoveMasks({describe_masks(b)}): which masks the model was trained with is"
            f" unclear; remove {second} or make it agree"
        )
    return found[0][1]


def check_observes(policy: Any, env: Any, name: str = "the model") -> None:
    """ValueError unless ``policy`` (a trained agent; the gaits observe anything) observes what
    ``env`` (a gait environment) observes and acts as ``grasp_env/CubeGait-v0`` or
    ``grasp_env/CubeGaitMoves-v0`` with its configuration act."""
    from gymnasium import spaces

    task = env.unwrapped.task
    grip_and_moves = (task.n_pairs + task.n_moves,)
    model = getattr(policy, "model", None)
    observes = getattr(model, "observation_space", env.observation_space)
    acts = getattr(model, "action_space", None)
    gait_actions = acts is None or (
        acts == spaces.Discrete(task.n_moves)
        or (isinstance(acts, spaces.Box) and acts.shape == grip_and_moves)
    )
    if observes.shape != env.observation_space.shape or not gait_actions:
        raise ValueError(
            f"{name} observes {observes.shape} and acts in {acts}; grasp_env/CubeGait-v0"
            f" observes {env.observation_space.shape} and acts in Box(-1, 1, {grip_and_moves}),"
            f" grasp_env/CubeGaitMoves-v0 in Discrete({task.n_moves}): not a gait agent"
        )


def load_models(args: argparse.Namespace) -> list[tuple[str, Any]]:
    """The agents of ``--models``, labelled (:func:`model_labels`) and checked before any work:
    each file is a model (:func:`grasp_env_agents.learning.models.load_agent`, which names
    the file and the problem) that observes what ``grasp_env/CubeGait-v0`` with the options
    observes; a MaskablePPO model comes with its masks (:func:`mask_settings`, a
    :class:`MaskedAgent`)."""
    import gymnasium as gym

    import grasp_env  # noqa: F401  (registers the environments)

    from ..learning.models import load_agent
    from ..run.folder import model_file

    env = gym.make("grasp_env/CubeGait-v0", **env_kwargs(args))
    agents = []
    try:
        for label, path in zip(model_labels(args.models), args.models, strict=True):
            agent = load_agent(path)
            check_observes(agent, env, f"{path}: the model")
            if is_maskable(agent.model):
                agent = MaskedAgent(agent, mask_settings(model_file(path), agent.model))
            agents.append((label, agent))
    finally:
        env.close()
    return agents


def play(policy: Any, kwargs: dict[str, Any]) -> Episode:
    """Plays ``policy.predict`` (deterministic) on ``grasp_env/CubeGait-v0`` with ``kwargs``
    (``grasp_env/CubeGaitMoves-v0`` for an agent that chooses only the moves: a discrete
    action; a :class:`MaskedAgent` there in ``GaitMoveMasks`` with its settings, each step's
    ``action_masks()`` passed to its ``predict``); the episode stops at the first slip or drop
    (the environment's default)."""
    import gymnasium as gym
    from gymnasium import spaces

    from grasp_env.envs.gait import GaitMoveMasks

    acts = getattr(getattr(policy, "model", None), "action_space", None)
    masks = policy.masks if isinstance(policy, MaskedAgent) else None
    moves = masks is not None or isinstance(acts, spaces.Discrete)
    env = gym.make(f"grasp_env/CubeGait{'Moves' if moves else ''}-v0", **kwargs)
    try:
        check_observes(policy, env)
        if masks is not None:
            env = GaitMoveMasks(env, **masks)
    except ValueError:
        env.close()
        raise
    obs, _ = env.reset(seed=0)
    rewards, terminated, truncated, info = [], False, False, {}
    while not (terminated or truncated):
        if masks is None:
            action = policy.predict(obs, deterministic=True)[0]
        else:
            action = policy.predict(obs, deterministic=True, action_masks=env.action_masks())[0]
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
    env.close()
    # a slip or a drop ends the episode: its last pose is not held
    held = np.asarray(rewards[:-1] if terminated else rewards)
    ended = float(info["alpha_deg"]) if terminated else None
    return Episode(len(held), ended, float(held.min()) if len(held) else -np.inf)


def model_labels(paths: list[Path]) -> list[str]:
    """The shortest endings of ``paths`` (at least folder/file) that tell them apart.

    rl-zoo3 saves every run as <env id>.zip in a folder <env id>_<n>, numbered within its log
    folder, so runs of several seeds differ only further up.
    """
    parts = [Path(p).parts for p in paths]
    for n in range(2, max(map(len, parts), default=2) + 1):
        labels = ["/".join(p[-n:]) for p in parts]
        if len(set(labels)) == len(labels):
            return labels
    return [str(p) for p in paths]


def compare_models(
    args: argparse.Namespace, loaded: list[tuple[str, Any]] | None = None
) -> list[tuple[str, Episode]]:
    """Prints the table of ``--models`` (``loaded``: their :func:`load_models`, loaded here if
    not given): the optimal and greedy gaits and each trained agent (a MaskablePPO agent's
    label followed by its masks), and across the agents the IQM with its 95% bootstrap
    interval (rliable); returns its rows."""
    from rich.table import Table

    from grasp_env.envs.gait import GaitExpert, GreedyGait

    kwargs = env_kwargs(args)
    if loaded is None:
        loaded = load_models(args)
    rows = [("optimal gait (certified)", play(GaitExpert(**kwargs), kwargs))]
    rows.append(("greedy gait", play(GreedyGait(**kwargs), kwargs)))
    agents = [
        (
            f"{label} (with its masks: {describe_masks(agent.masks) or 'refused moves'})"
            if isinstance(agent, MaskedAgent)
            else label,
            play(agent, kwargs),
        )
        for label, agent in loaded
    ]
    table = Table(
        title="On grasp_env/CubeGait-v0, agents of moves alone on CubeGaitMoves-v0, MaskablePPO"
        " ones in GaitMoveMasks (deterministic, to the first slip or drop)"
    )
    for name in ("policy", "poses held", "ended at alpha (deg)", "worst margin held (deg)"):
        left = name == "policy"
        table.add_column(
            name, justify="left" if left else "right", overflow="fold" if left else "ellipsis"
        )
    for name, episode in rows + agents:
        table.add_row(
            name,
            str(episode.held),
            "held to the end" if episode.ended_deg is None else f"{episode.ended_deg:g}",
            f"{np.rad2deg(episode.worst):.3f}" if episode.held else "none held",
        )
    if len(agents) > 1:
        from ..studies.results import iqm_interval

        held = iqm_interval([e.held for _, e in agents])
        worst = [np.rad2deg(e.worst) for _, e in agents if e.held]
        table.add_row(
            f"the {len(agents)} agents: IQM [95% CI]", held.format("{:.1f}"), "",
            iqm_interval(worst).format("{:.3f}") if worst else "none held",
        )  # fmt: skip
    console().print(table)
    return rows + agents
