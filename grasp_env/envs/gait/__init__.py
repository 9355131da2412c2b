"""The gait family: hold the cube along a long rotation, choosing at every pose the grip and
which finger to phase out or in (docs/gait.md); `grasp_env/CubeGait-v0` and
`grasp_env/CubeGaitMoves-v0`.

Everything that does not depend on the agent is computed once per configuration (and shared by
every environment made with it): the certified minimax of every site set at every pose, the
hand's reach, the state tables of :mod:`grasp_env.mechanics.gait` and the dynamic programme's
policy, which is the expert. A step looks up the move in the tables and scores the grip with
the environments' step kernel :func:`~grasp_env.envs.kernels.evaluate_grips`; the single and
the vector environments share :func:`~grasp_env.envs.gait.kernels._step`, so they compute the
very same numbers.

Modules by concern: ``tasks`` (one configuration's tables, :func:`gait_task`), ``kernels``
(the compiled step and the certified grip of a move), ``experts`` (:class:`GaitExpert`,
:class:`GreedyGait`), ``env`` (:class:`CubeGaitEnv`), ``vector`` (:class:`CubeGaitVectorEnv`),
``render`` (``GaitView``: the frames of ``render_mode="rgb_array"``) and ``shaping``
(:class:`GaitShaping`: potential-based shaping from the certified programme;
:class:`GaitMoveMasks`: the legal moves as an action mask; :class:`GaitExpertStarts`:
episodes started partway along the optimal gait; each takes the can's gait envs too).
"""

from .env import CubeGaitEnv
from .experts import GaitExpert, GreedyGait
from .kernels import check_moves, optimal_actions
from .shaping import (
    POTENTIALS,
    STARTS,
    GaitExpertStarts,
    GaitMoveMasks,
    GaitShaping,
    expert_gait,
    legal_moves,
    poses_held,
    potential_table,
    shaped_can_gait_env,
    shaped_gait_env,
)
from .tasks import PAPER_TURN_SPEC, GaitTask, gait_task
from .vector import CubeGaitVectorEnv

__all__ = [
    "PAPER_TURN_SPEC",
    "POTENTIALS",
    "STARTS",
    "CubeGaitEnv",
    "CubeGaitVectorEnv",
    "GaitExpert",
    "GaitExpertStarts",
    "GaitMoveMasks",
    "GaitShaping",
    "GaitTask",
    "GreedyGait",
    "check_moves",
    "expert_gait",
    "gait_task",
    "legal_moves",
    "optimal_actions",
    "poses_held",
    "potential_table",
    "shaped_can_gait_env",
    "shaped_gait_env",
]
