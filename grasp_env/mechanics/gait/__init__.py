"""Finger gaits: when to phase a finger out or in along a trajectory (paper §II, docs/gait.md).

The object carries N contact **sites** (object-frame points on its faces); a
:class:`~grasp_env.mechanics.Hand` has F fingers, each of which can push on a site only while
the site's normal lies in its cone. At every pose each finger touches one site or none. A
**gait** says, pose by pose, which finger touches which site and which fingers carry load; it
obeys the hand's rules:

1. at every pose 3 or 4 fingers touch the object (three is the least that can grasp; the
   minimax solver takes at most four), each on a site it can reach at that pose;
2. at most one finger changes per pose (one **move**): a finger is **phased out** (lifted) at
   a pose where it still touches its site, reachable, but carries zero force; it is gone from
   the next pose on. A finger is **phased in** (placed) on a free site it can reach at a pose
   where it touches with zero force; it carries load from the next pose on. So a lift needs
   four fingers touching (three carry the load meanwhile) and a placement three (the placed
   finger makes four); every other touching finger carries load.

The margin of a pose is the certified minimax margin theta_lim - min_k max_i theta_i(k)
(eq. 2 and 4) of the site set that carries load there, over the action box |k_ij| <= k_max.
The optimal gait maximises the smallest margin over the whole trajectory; among those it takes
the fewest moves, then the largest sum of margins. It is found exactly by dynamic programming
over the hand's states (which finger touches which site), whose moves and values are known
pose by pose: :func:`optimal_gait`. Run on the certified upper bounds of the margins instead of
the attained ones, the same programme bounds what any gait could reach, so the gait is
certified optimal for the discretised trajectory within the gap (:func:`solve_gait`).

States and moves are encoded as integers: a state is an assignment (F,) of a site index to each
finger (-1: not touching); move 0 keeps the state, move 1 + f N + s toggles finger f on site s
(lifts it if it is there, places it if finger and site are both free).

Modules: ``sites`` (the object's sites, :class:`GaitScene`, and the per-pose values
:func:`set_values`, :func:`site_reach`), ``states`` (the hand's states and moves as tables,
:func:`gait_states`), ``programme`` (the dynamic programme :func:`optimal_gait` and the
baselines :func:`greedy_gait`, :func:`best_fixed`) and ``solution`` (:func:`solve_gait`).
"""

from .programme import (
    MARGIN_TOL,
    Gait,
    best_fixed,
    bottleneck_bound,
    first_best,
    greedy_gait,
    optimal_gait,
)

# the state tables' size limits, for callers that check a hand's size first
from .sites import _MAX_FINGERS as _MAX_FINGERS
from .sites import _MAX_SITES as _MAX_SITES
from .sites import (
    GAIT_CG_OFFSET,
    MAX_LOADED,
    MAX_TOUCHING,
    MIN_LOADED,
    PAPER_TURN,
    REACH_TOL,
    SITE_FACES,
    SITE_OFFSETS,
    VERTICAL_TURN,
    GaitScene,
    SetGroup,
    SetValues,
    cone_reach,
    set_values,
    site_reach,
    site_sets,
)
from .solution import GaitSolution, solve_gait
from .states import GaitStates, gait_states, move_name

__all__ = [
    "GAIT_CG_OFFSET",
    "MARGIN_TOL",
    "MAX_LOADED",
    "MAX_TOUCHING",
    "MIN_LOADED",
    "PAPER_TURN",
    "REACH_TOL",
    "SITE_FACES",
    "SITE_OFFSETS",
    "VERTICAL_TURN",
    "Gait",
    "GaitScene",
    "GaitSolution",
    "GaitStates",
    "SetGroup",
    "SetValues",
    "best_fixed",
    "bottleneck_bound",
    "cone_reach",
    "first_best",
    "gait_states",
    "greedy_gait",
    "move_name",
    "optimal_gait",
    "set_values",
    "site_reach",
    "site_sets",
    "solve_gait",
]
