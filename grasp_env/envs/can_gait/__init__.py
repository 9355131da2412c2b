"""The can's gait family: turn the coke can a full turn about its axis, choosing at every pose
which finger to lift or place (and the grip); `grasp_env/CanGait-v0` and
`grasp_env/CanGaitMoves-v0` (docs/gait.md, "The can"; docs/environments.md)."""

from .env import CanGaitEnv, CanGaitExpert, CanGaitTask, CanGreedyGait, can_gait_task

__all__ = ["CanGaitEnv", "CanGaitExpert", "CanGaitTask", "CanGreedyGait", "can_gait_task"]
