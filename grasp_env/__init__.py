"""grasp-env: grip-force optimisation of multi-fingered grasps as Gymnasium environments.

``import grasp_env`` registers the environments (namespace ``grasp_env``)::

    import gymnasium as gym
    import grasp_env

    env = gym.make("grasp_env/CubeGrasp-v0")
    envs = gym.make_vec("grasp_env/CubeGraspRandom-v0", num_envs=64,
                        vectorization_mode="vector_entry_point")

The layers import one way (docs/design.md): ``grasp_env.mechanics`` (pure numpy and numba)
<- ``grasp_env.envs`` and ``grasp_env.physics``. So that ``import grasp_env.mechanics`` does
not load gymnasium, the environments are registered when gymnasium's registry is first
imported (at once if it already is): either import order works.
"""

from __future__ import annotations

import importlib.util
import sys
from importlib.abc import MetaPathFinder
from types import ModuleType
from typing import Any

__version__ = "0.2.0"

_FOUR_FINGERS = {"faces": ("-x", "-y", "-z", "+z")}
_ENVS = {
    # id: (single class, vector class or None, kwargs)
    "CubeGrasp-v0": ("CubeGraspEnv", "CubeGraspVectorEnv", {}),
    "CubeGraspRandom-v0": ("CubeGraspRandomEnv", "CubeGraspRandomVectorEnv", {}),
    "CubeGrasp4-v0": ("CubeGraspEnv", "CubeGraspVectorEnv", _FOUR_FINGERS),
    # MuJoCo checks every step and rolls out each ended episode; the vector envs check all
    # sub-environments' poses of a step in one parallel MuJoCo batch
    # (envs/cube_grasp/mujoco_vector.py).
    "CubeGraspMujoco-v0": (
        "CubeGraspEnv",
        "cube_grasp.mujoco_vector:CubeGraspMujocoVectorEnv",
        {"physics": "mujoco"},
    ),
    "CubeGraspRandomMujoco-v0": (
        "CubeGraspRandomEnv",
        "cube_grasp.mujoco_vector:CubeGraspRandomMujocoVectorEnv",
        {"physics": "mujoco"},
    ),
    "CubeGrasp4Mujoco-v0": (
        "CubeGraspEnv",
        "cube_grasp.mujoco_vector:CubeGraspMujocoVectorEnv",
        {**_FOUR_FINGERS, "physics": "mujoco"},
    ),
    # finger gaits (docs/gait.md): a hand with reach phases fingers out and in as it turns
    "CubeGait-v0": ("gait.env:CubeGaitEnv", "gait.vector:CubeGaitVectorEnv", {}),
    # the same with the certified grip: the agent chooses only the moves (when to phase out)
    "CubeGaitMoves-v0": (
        "gait.env:CubeGaitEnv",
        "gait.vector:CubeGaitVectorEnv",
        {"optimal_grip": True},
    ),
    # CubeGaitMoves-v0 with potential-based shaping from the certified programme
    # (envs/gait/shaping.py; rl-zoo3 keys its hyperparameters by id); no batched class
    "CubeGaitMovesShaped-v0": ("gait.shaping:shaped_gait_env", None, {}),
    # the coke can turned a full turn about its axis (docs/gait.md, "The can"): moves and
    # grip, and moves with the certified grip; no batched class (gym.make_vec: sync)
    "CanGait-v0": ("can_gait.env:CanGaitEnv", None, {}),
    "CanGaitMoves-v0": ("can_gait.env:CanGaitEnv", None, {"optimal_grip": True}),
    # CanGaitMoves-v0 with the certified programme's potential-based shaping
    # (envs/gait/shaping.py, which takes either gait); no batched class
    "CanGaitMovesShaped-v0": ("gait.shaping:shaped_can_gait_env", None, {}),
    # any object (box, cylinder, sphere, convex mesh) by 3 to 8 contacts, padded with a mask
    # (envs/object_grasp/): one scene from keywords, and random shapes, sizes and counts
    "ObjectGrasp-v0": (
        "object_grasp.env:ObjectGraspEnv",
        "object_grasp.vector:ObjectGraspVectorEnv",
        {},
    ),
    "ObjectGraspRandom-v0": (
        "object_grasp.env:ObjectGraspRandomEnv",
        "object_grasp.vector:ObjectGraspRandomVectorEnv",
        {},
    ),
}
ENV_IDS = tuple(f"grasp_env/{name}" for name in _ENVS)
#: The modules in grasp_env.envs of the bare class names above: the cube grasp family's.
_SINGLE, _VECTOR = "cube_grasp.env", "cube_grasp.vector"
_REGISTRATION = "gymnasium.envs.registration"


def _module(entry: str, default: str) -> str:
    """The entry point ``module:Class`` in grasp_env.envs (a bare class name: in ``default``)."""
    return entry if ":" in entry else f"{default}:{entry}"


def _register(registration: ModuleType) -> None:
    for name, (single, vector, kwargs) in _ENVS.items():
        if f"grasp_env/{name}" not in registration.registry:
            registration.register(
                id=f"grasp_env/{name}",
                entry_point=f"grasp_env.envs.{_module(single, _SINGLE)}",
                vector_entry_point=vector and f"grasp_env.envs.{_module(vector, _VECTOR)}",
                kwargs=kwargs,
            )


class _RegisterWithGymnasium(MetaPathFinder):
    """Finds gymnasium's registry module as usual, and registers the environments in it once
    it has run."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        if name != _REGISTRATION:
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        run = spec.loader.exec_module

        def exec_module(module: ModuleType) -> None:
            run(module)
            _register(module)

        spec.loader.exec_module = exec_module
        return spec


if _REGISTRATION in sys.modules:
    _register(sys.modules[_REGISTRATION])
elif not any(isinstance(finder, _RegisterWithGymnasium) for finder in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWithGymnasium())


def __getattr__(name: str) -> Any:
    if name == "MinimaxExpert":  # the expert lives with the environments (grasp_env.envs)
        from .envs.expert import MinimaxExpert

        return MinimaxExpert
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ENV_IDS", "MinimaxExpert", "__version__"]
