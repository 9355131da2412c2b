"""Shared by the tests of sweeps and results (tests/test_sweep_*.py): a tiny run's config and a
writer of YAML files.
"""

from __future__ import annotations

from pathlib import Path

import yaml

TINY = {
    "env_id": "grasp_env/CubeGraspRandom-v0",
    "env_kwargs": {"terminate_on_slip": False},
    "n_envs": 4,
    "seed": 0,
    "total_timesteps": 256,
    "eval_freq": 128,
    "eval_episodes": 8,
    "checkpoint_freq": 128,
    "torch_threads": 1,
    "policy": {"net_arch": [16], "features": "grasp"},
    "ppo": {"n_steps": 32, "batch_size": 64, "n_epochs": 1},
}


def write(path: Path, data: dict | str) -> Path:
    """``data`` as YAML, or a string as the file's text (YAML no dict can give)."""
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path
