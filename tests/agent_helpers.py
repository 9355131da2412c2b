"""Shared by the tests of the agents (tests/test_agent_*.py): the tiny run's config (a few hundred
PPO steps of a 16 x 16 network on the paper's scene, ``grasp_env/CubeGrasp-v0``, so that each
run takes seconds), and readers of a run's learning curve and TensorBoard events.
"""

from __future__ import annotations

import csv
from pathlib import Path

from grasp_env_agents.run.config import config_from_dict

TINY = {
    "env_id": "grasp_env/CubeGrasp-v0",
    "env_kwargs": {"terminate_on_slip": False},
    "n_envs": 2,
    "seed": 3,
    "total_timesteps": 256,
    "eval_freq": 128,
    "eval_episodes": 2,
    "checkpoint_freq": 128,
    "policy": {"net_arch": [16, 16]},
    "ppo": {"n_steps": 32, "batch_size": 32, "n_epochs": 2},
}


def tiny(**changes):
    return config_from_dict({**TINY, **changes})


def curve(run: Path) -> list[dict[str, str]]:
    with (run / "learning_curve.csv").open() as file:
        return list(csv.DictReader(file))


def tensorboard_events(folder: Path) -> dict[str, list[tuple[int, float]]]:
    """Every scalar's (step, value) pairs, read from the raw event files (as any reader sees
    them)."""
    from tensorboard.backend.event_processing.event_file_loader import EventFileLoader
    from tensorboard.util.tensor_util import make_ndarray

    events: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(folder.glob("events.out.tfevents.*")):
        for event in EventFileLoader(str(path)).Load():
            for value in event.summary.value:
                number = value.simple_value if value.HasField("simple_value") else None
                if number is None:
                    number = float(make_ndarray(value.tensor))
                events.setdefault(value.tag, []).append((event.step, number))
    return events


def tensorboard_steps(folder: Path) -> dict[str, list[int]]:
    return {tag: [s for s, _ in pairs] for tag, pairs in tensorboard_events(folder).items()}


def tensorboard_scalars(folder: Path, tag: str) -> list[float]:
    return [v for _, v in tensorboard_events(folder)[tag]]
