"""Gymnasium environments of the grasp (DESIGN.md §3): single, vector and an SB3 adapter.

The classes load lazily, so that ``grasp_env.expert`` can use the observation layout here
without importing the environments.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "CubeGraspEnv": "cube_grasp",
    "CubeGraspRandomEnv": "cube_grasp",
    "CubeGraspVectorEnv": "vector",
    "CubeGraspRandomVectorEnv": "vector",
    "ObservationLayout": "observation",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
