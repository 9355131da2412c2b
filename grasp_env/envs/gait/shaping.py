"""Learning the gait (docs/gait.md, "Learning the whole turn"): potential-based shaping of
the reward from the certified programme (:class:`GaitShaping`), the moves the hand allows as
an action mask for sb3-contrib's ``MaskablePPO`` (:class:`GaitMoveMasks`), and episodes
started partway along the turn (:class:`GaitExpertStarts`); the ids
``grasp_env/CubeGaitMovesShaped-v0`` (:func:`shaped_gait_env`) and
``grasp_env/CanGaitMovesShaped-v0`` (:func:`shaped_can_gait_env`). Every wrapper takes the
cube's gait envs and the can's (docs/gait.md, "The can"): both programmes' tables have the
same form (states, moves in CSR form, each move's next state and loaded set), the can's
margins being those of its configurations, the same at every pose.

**Shaping** (Ng, Harada and Russell 1999). A shaping reward F(s, s') = gamma Phi(s') - Phi(s)
added to every step leaves the optimal policies of the discounted task unchanged, for any
potential Phi of the state (Phi = 0 at episode ends): an episode's shaped return is its
return plus gamma^n Phi(s_n) - Phi(s_0), so no choice changes its rank. Here the state is the
pose t and the hand's state x (which finger touches which site), and Phi comes from the
programme of docs/gait.md, "The algorithm", on the task's own tables (margins of every site
set at every pose, reach, moves):

- ``"held"``: Phi(t, x) = scale x H_t(x), H_t(x) the most poses a gait from state x at pose t
  still holds (no lost contact, no slip: every pose's margin theta_lim - max_i theta_i >= 0,
  eq. 2, 4) before the trajectory ends; a backward pass of the programme's form, H_T = 0 and
  H_t(x) = max over the moves k allowed at (t, x) with margin_t(k) >= 0 of
  1 + H_{t+1}(next(k)), 0 if there is none.
- ``"holds"``: Phi(t, x) = scale if a gait from x at t holds to the end (H_t(x) = T - t: the
  programme's pass 1 value V_t(x) >= 0), else 0.

The gait's missing choice (docs/gait.md, "Learning when to phase") pays off 18 poses after it
is made: with ``"held"`` the step that makes it earns the difference in H at once.

Phi is a table (T + 1, X), computed once per task (a compiled backward pass, 0.03 s of CPU
for 181 poses and 3,000 states) and cached; a step adds one look-up (0.93x the unwrapped
step rate; the masks' compiled rule 0.9x). The env's own reward stays in
``info["unshaped_reward"]``, and the episode statistics of a ``Monitor`` inside the wrapper
(``make_vec_env(..., wrapper_class=GaitShaping)`` puts it there) are unshaped; on the shaped
id, whose shaping is inside gymnasium's wrappers, a ``Monitor`` records the shaped reward.
``grasp-env gait --models`` plays agents on the unshaped environment.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import gymnasium as gym
import numba
import numpy as np

from ...mechanics.checks import real_number
from ...mechanics.gait.can_programme import _move_values
from ...mechanics.gait.programme import _pose_values, _state_ok
from ..can_gait.env import CanGaitEnv, CanGaitTask
from ..validation import check_bool
from .env import CubeGaitEnv
from .kernels import _allowed, optimal_actions
from .tasks import GaitTask

#: The tasks the wrappers take: the cube's gait (:class:`GaitTask`) and the can's
#: (:class:`~grasp_env.envs.can_gait.CanGaitTask`).
AnyGaitTask = GaitTask | CanGaitTask

#: The potentials :class:`GaitShaping` takes (see the module docstring).
POTENTIALS = ("held", "holds")
#: The starts :class:`GaitExpertStarts` draws from.
STARTS = ("expert", "holdable")


@numba.njit(cache=True)
def _poses_held(states, ptr, move, nxt, loaded, margin, reach):
    """(T + 1, X) int64: H_t(x), the most poses a gait from state x at pose t holds (each with
    an allowed move whose margin is >= 0, no contact lost), H_T = 0."""
    T = margin.shape[0]
    X = states.shape[0]
    ok = _state_ok(states, reach)
    vals = np.empty(move.shape[0])
    held = np.zeros((T + 1, X), np.int64)
    for t in range(T - 1, -1, -1):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)  # -inf: not allowed
        for x in range(X):
            best = 0
            for k in range(ptr[x], ptr[x + 1]):
                if vals[k] >= 0.0:
                    best = max(best, 1 + held[t + 1, nxt[k]])
            held[t, x] = best
    return held


@numba.njit(cache=True)
def _table_poses_held(ptr, nxt, vals, T):
    """(T + 1, X) int16: H_t(x) on move tables whose move k has the value vals[t, k] (vals of
    one row: the same at every pose; -inf: unusable), a state without moves (a lost contact)
    holding none: H_t(x) = max over k with vals[t, k] >= 0 of 1 + H_{t+1}(next[k]), H_T = 0."""
    X = ptr.shape[0] - 1
    one = vals.shape[0] == 1
    held = np.zeros((T + 1, X), np.int16)
    for t in range(T - 1, -1, -1):
        row = 0 if one else t
        for x in range(X):
            best = 0
            for k in range(ptr[x], ptr[x + 1]):
                if vals[row, k] >= 0.0:
                    best = max(best, 1 + held[t + 1, nxt[k]])
            held[t, x] = best
    return held


def _check_task(task: Any) -> AnyGaitTask:
    if not isinstance(task, (GaitTask, CanGaitTask)):
        raise ValueError(
            "task must be a GaitTask (gait_task) or a CanGaitTask (can_gait_task), got"
            f" {type(task).__name__}"
        )
    return task


def expert_gait(task: AnyGaitTask) -> Any:
    """The certified optimal gait the task's expert follows (its ``policy`` acts from every
    state, its ``margin`` is the bottleneck B, its ``states`` the states along it): the cube's
    ``task.solution.optimal``, the can's ``task.expert`` (from the episodes' start)."""
    return _check_task(task).expert if isinstance(task, CanGaitTask) else task.solution.optimal


def poses_held(task: AnyGaitTask) -> np.ndarray:
    """H (T + 1, X) of ``task`` (read-only, cached per task; int64 for the cube, int16 for the
    can's 536,068 states): H[t, x] is the most poses that a gait from state x at pose t holds
    before the trajectory ends (a pose is held when no touching finger has lost its site or
    contact and the loaded set's certified margin is >= 0, eq. 2, 4; the moves allowed as in
    the programme, docs/gait.md); H[T] = 0. The optimal gait's start has H[0, start] = T.
    On the can a state is each finger's age and the margins are those of the configurations
    (the same at every pose): H_t(x) = max over the table's moves k of x with margin >= 0 of
    1 + H_{t+1}(next(k)), a state with a lost contact (age H + 1) holding none."""
    return _held_table(_check_task(task))


@lru_cache(maxsize=8)
def _held_table(task: AnyGaitTask) -> np.ndarray:
    table = task.table
    if isinstance(task, CanGaitTask):
        vals = _move_values(table, task.solution.margin)
        held = _table_poses_held(table.ptr, table.next, vals, task.n_poses)
        held.flags.writeable = False
        return held
    solution = task.solution
    held = _poses_held(
        table.states, table.ptr, table.move, table.next, table.loaded,
        np.ascontiguousarray(solution.values.margin), np.ascontiguousarray(solution.reach),
    )  # fmt: skip
    held.flags.writeable = False
    return held


def potential_table(task: AnyGaitTask, potential: str = "held", scale: float = 1.0) -> np.ndarray:
    """Phi (T + 1, X) float64 of ``task`` (the cube's or the can's) for ``potential`` (one of
    :data:`POTENTIALS`) times ``scale``; Phi[T] = 0 (the trajectory's end is an episode end:
    Ng et al.'s potential of an absorbing state). Read-only, cached per (task, potential,
    scale): every wrapper of a task shares one table (163 MB on the can)."""
    if potential not in POTENTIALS:
        raise ValueError(f"potential must be one of {POTENTIALS}, got {potential!r}")
    scale = real_number("scale", scale, 0.0, open_low=True)
    return _potential_table(_check_task(task), potential, scale)


@lru_cache(maxsize=8)
def _potential_table(task: AnyGaitTask, potential: str, scale: float) -> np.ndarray:
    held = poses_held(task)
    if potential == "held":
        phi = held.astype(float)
    else:
        left = task.n_poses - np.arange(task.n_poses + 1)
        phi = (held == left[:, None]).astype(float)
    phi[task.n_poses] = 0.0
    phi *= scale
    phi.flags.writeable = False
    return phi


class _GaitState(gym.Wrapper):
    """Reads the gait environment's pose t and hand state x, whatever wrappers lie between
    (a ``Monitor``, gymnasium's checkers): one attribute read a step, no decoding."""

    def __init__(self, env: gym.Env) -> None:
        if not isinstance(env, gym.Env) or not isinstance(env.unwrapped, (CubeGaitEnv, CanGaitEnv)):
            raise ValueError(
                "env must be a gait environment (grasp_env/CubeGait-v0, CubeGaitMoves-v0,"
                f" CanGait-v0 or CanGaitMoves-v0, possibly wrapped), got {env!r}"
            )
        super().__init__(env)
        self._base: CubeGaitEnv | CanGaitEnv = env.unwrapped
        self.task: AnyGaitTask = self._base.task

    @property
    def pose_state(self) -> tuple[int, int]:
        """(t, x): the pose the next step is at (T after the end) and the hand's state index."""
        return self._base._t, self._base._x


class GaitShaping(_GaitState, gym.utils.RecordConstructorArgs):
    """The gait's reward plus a potential-based shaping term from the certified programme:
    r + gamma Phi(t + 1, x') - Phi(t, x) (Ng, Harada and Russell 1999; module docstring).

    Args:
        env: a gait environment (``grasp_env/CubeGait-v0``, ``CubeGaitMoves-v0``,
            ``CanGait-v0`` or ``CanGaitMoves-v0``), possibly wrapped.
        potential: ``"held"`` (scale x the poses a gait from here still holds) or ``"holds"``
            (scale if a gait from here holds to the end, else 0).
        scale: radians per unit of potential, a number > 0; default: the optimal gait's
            smallest margin B (6.97 deg on the cube's default task, 8.89 deg on the can's) for
            ``"held"`` (one pose held is
            worth a pose at the bottleneck), B / (1 - gamma) for ``"holds"`` (the discounted
            return of holding at B forever; 1e3 B at gamma = 1).
        gamma: the agent's discount factor, in (0, 1] (the shaping keeps the optimal policies
            only for the gamma the agent discounts with: rl-zoo3's entry uses 0.99).

    ``info`` gains ``unshaped_reward`` (the environment's reward), ``shaping`` (the term
    added) and ``potential`` (Phi of the state reached; 0 at an episode's end). The shaped
    return of an episode of n steps is its return plus gamma^n Phi(s_n) - Phi(s_0), Phi(s_n)
    = 0 if it ended.
    """

    def __init__(
        self,
        env: gym.Env,
        potential: str = "held",
        scale: float | None = None,
        gamma: float = 0.99,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, potential=potential, scale=scale, gamma=gamma
        )
        super().__init__(env)
        if potential not in POTENTIALS:
            raise ValueError(f"potential must be one of {POTENTIALS}, got {potential!r}")
        self.gamma = real_number("gamma", gamma, 0.0, 1.0, open_low=True)
        bottleneck = float(expert_gait(self.task).margin)
        if scale is None:
            scale = bottleneck if potential == "held" else bottleneck / max(1.0 - self.gamma, 1e-3)
        self.potential = potential
        self.scale = real_number("scale", scale, 0.0, open_low=True)
        self.phi = potential_table(self.task, potential, self.scale)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        t, x = self._base._t, self._base._x
        obs, reward, terminated, truncated, info = self.env.step(action)
        # Phi = 0 at an episode's end: a drop or slip (terminated), or the trajectory's end
        after = 0.0 if terminated else float(self.phi[self._base._t, self._base._x])
        shaping = self.gamma * after - float(self.phi[t, x])
        info["unshaped_reward"] = float(reward)
        info["shaping"] = shaping
        info["potential"] = after
        return obs, float(reward) + shaping, terminated, truncated, info


class GaitMoveMasks(_GaitState, gym.utils.RecordConstructorArgs):
    """The gait environment with :meth:`action_masks`, for sb3-contrib's ``MaskablePPO``
    (only with ``optimal_grip=True``: ``CubeGaitMoves-v0``, ``CanGaitMoves-v0``). Rewards and
    steps are the environment's.

    Args:
        env: ``grasp_env/CubeGaitMoves-v0`` or ``CanGaitMoves-v0`` (or the env class with
            ``optimal_grip=True``), possibly wrapped.
        hold: False (the default): the moves the rules allow (those the environment does not
            refuse). True: of those, the moves whose loaded set holds this pose (certified
            margin >= 0, eq. 2, 4; the others slip at once and end the episode), all the
            allowed ones where none holds. Which move keeps the turn going later is still the
            agent's to learn.
        lookahead: with ``hold``, also mask the moves into a state that loses a contact at the
            next pose (a finger kept on a site that leaves its reach; on the can, a contact past
            its age H), where another is left:
            the greedy gait's one-pose lookahead, given to the hand.
    """

    def __init__(self, env: gym.Env, hold: bool = False, lookahead: bool = False) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, hold=hold, lookahead=lookahead)
        super().__init__(env)
        if not self.env.unwrapped.optimal_grip:
            raise ValueError(
                "GaitMoveMasks masks Discrete moves: env must act with moves alone"
                " (grasp_env/CubeGaitMoves-v0 or CanGaitMoves-v0, optimal_grip=True)"
            )
        self.hold = check_bool("hold", hold)
        self.lookahead = check_bool("lookahead", lookahead)
        if self.lookahead and not self.hold:
            raise ValueError("lookahead=True masks among the moves that hold: set hold=True too")

    def action_masks(self) -> np.ndarray:
        """(M,) bool: True for the moves allowed now (see ``hold``); all True once the episode
        has ended."""
        t, x = self.pose_state
        if self._base._done:
            return np.ones(self.task.n_moves, bool)
        return legal_moves(self.task, t, x, self.hold, self.lookahead)


class GaitExpertStarts(_GaitState, gym.utils.RecordConstructorArgs):
    """Episodes that start partway along the optimal gait: a curriculum over the length of the
    trajectory left to the agent (after Salimans and Chen 2018, starts from a demonstration's
    states). At a reset, with probability ``fraction``, the certified expert (the programme's
    policy, docs/gait.md) makes the moves of the first k poses, k uniform in [1, T - 1], and
    the agent takes over at pose k; otherwise the episode starts at the first pose. The steps
    the expert makes are not the agent's (they are not returned); the agent's reward, its
    observation and the episode's end are the environment's.

    With ``among="holdable"`` the start at pose k is any state from which a gait still holds
    to the end (H_k(x) = T - k, :func:`poses_held`; 11 to 45 states a pose on the default
    task), drawn uniformly, the environment put there directly (Kakade and Langford's restart
    distribution): states off the optimal gait that the agent's own gaits pass through.

    Evaluation (``grasp-env gait --models``) starts at the first pose: a policy trained with
    these starts must hold the whole turn itself.

    Args:
        env: a gait environment (``CubeGait-v0``, ``CubeGaitMoves-v0``, ``CanGait-v0`` or
            ``CanGaitMoves-v0``), possibly wrapped (shaping may lie inside or outside: it
            reads the pose and state each step).
        fraction: the share of episodes started partway, in [0, 1].
        among: ``"expert"`` (the optimal gait's states) or ``"holdable"``.
    """

    def __init__(self, env: gym.Env, fraction: float = 0.5, among: str = "expert") -> None:
        gym.utils.RecordConstructorArgs.__init__(self, fraction=fraction, among=among)
        super().__init__(env)
        self.fraction = real_number("fraction", fraction, 0.0, 1.0)
        if among not in STARTS:
            raise ValueError(f"among must be one of {STARTS}, got {among!r}")
        self.among = among
        self._grip = self._base.optimal_grip
        self._policy = expert_gait(self.task).policy
        T = self.task.n_poses
        full = poses_held(self.task) == (T - np.arange(T + 1))[:, None]
        self._holdable = [np.flatnonzero(row) for row in full[:T]]

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        rng = self._base.np_random
        if self.fraction == 0.0 or rng.random() >= self.fraction:
            return obs, info
        task = self.task
        k = int(rng.integers(1, task.n_poses))
        if self.among == "holdable":
            base = self._base
            base._t, base._x = k, int(rng.choice(self._holdable[k]))
            if isinstance(base, CanGaitEnv):
                base._shown = None
                return task.observation(base._x, k), info
            return base._observation(base._x, k), info
        for _ in range(k):
            t, x = self.pose_state
            chosen = int(self._policy[t, x])
            move = int(task.table.move[chosen])
            if self._grip:
                action: Any = move
            elif isinstance(task, CanGaitTask):  # the certified grip of the move's config
                action = -np.ones(task.n_pairs + task.n_moves, np.float32)
                action[: task.n_pairs] = task.optimal_grip(int(task.table.config[chosen]))
                action[task.n_pairs + move] = 1.0
            else:
                action = optimal_actions(task, np.array([x]), np.array([t]), np.array([move]))[0]
            obs, _, terminated, truncated, info = self.env.step(action)
            if terminated or truncated:  # not along the optimal gait: start over
                return self.env.reset(options=options)
        return obs, info


def legal_moves(
    task: AnyGaitTask, t: int, x: int, hold: bool = False, lookahead: bool = False
) -> np.ndarray:
    """(M,) bool, the moves the rules allow from state ``x`` at pose ``t``: those the
    environment does not refuse (keep, always; lifts that leave three touching; placements on
    a free site within reach; the step kernel's rule). With ``hold``, of those the moves whose
    loaded set's certified margin at t is >= 0, if any (all allowed ones if none; a state with
    a contact out of reach loses it whatever the move). With ``lookahead`` too, of those the
    moves into a state whose every contact is within reach at t + 1, if any (the greedy gait's
    one-pose lookahead: a finger is not kept on a site it loses at the next pose).

    On the can (a :class:`~grasp_env.envs.can_gait.CanGaitTask`) the allowed moves are the
    state's moves in the can's tables (what ``CanGaitEnv`` does not refuse: 3 to
    ``max_loaded`` loaded, at most five touching); a state that has lost a contact (a finger
    past age H) has none, and every move is then the same void one: keep (0) alone is
    allowed. ``hold`` keeps the moves whose loaded configuration's margin is >= 0 and
    ``lookahead`` the moves into a state whose every contact is at most H poses old."""
    out = np.empty(task.n_moves, np.bool_)
    if isinstance(task, CanGaitTask):
        table = task.table
        _can_legal_moves(
            t, x, hold, lookahead, table.ptr, table.move, table.next, table.config,
            table.states, task.max_age, task.n_poses, task.solution.values.margin, out,
        )  # fmt: skip
        return out
    _legal_moves(
        t, x, hold, lookahead, task.csr, task.table.states, task.table.loaded, task.table.next,
        task.solution.reach, task.solution.values.margin, out,
    )  # fmt: skip
    return out


@numba.njit(cache=True, nogil=True)
def _legal_moves(t, x, hold, lookahead, csr, states, loaded, nxt, reach, margin, out):
    """:func:`legal_moves` into ``out`` (M,)."""
    M = csr.shape[1]
    F = states.shape[1]
    T = reach.shape[0]
    any_holds = False
    for m in range(M):
        out[m] = _allowed(x, t, m, csr, states, reach) >= 0
        if out[m] and margin[t, loaded[csr[x, m]]] >= 0.0:
            any_holds = True
    if not (hold and any_holds):
        return
    for m in range(M):
        if out[m] and margin[t, loaded[csr[x, m]]] < 0.0:
            out[m] = False
    if not lookahead or t + 1 >= T:
        return
    kept = np.zeros(M, np.bool_)
    any_kept = False
    for m in range(M):
        if out[m]:
            y = nxt[csr[x, m]]
            ok = True
            for f in range(F):
                site = states[y, f]
                if site >= 0 and not reach[t + 1, f, site]:
                    ok = False
            kept[m] = ok
            any_kept = any_kept or ok
    if any_kept:
        for m in range(M):
            out[m] = out[m] and kept[m]


@numba.njit(cache=True, nogil=True)
def _can_legal_moves(t, x, hold, lookahead, ptr, move, nxt, config, states, H, T, margin, out):
    """:func:`legal_moves` on the can's tables into ``out`` (M,)."""
    out[:] = False
    lo, hi = ptr[x], ptr[x + 1]
    if hi == lo:  # a lost contact: the move is void
        out[0] = True
        return
    any_holds = False
    for k in range(lo, hi):
        out[move[k]] = True
        any_holds = any_holds or margin[config[k]] >= 0.0
    if not (hold and any_holds):
        return
    for k in range(lo, hi):
        if margin[config[k]] < 0.0:
            out[move[k]] = False
    if not lookahead or t + 1 >= T:
        return
    any_kept = False
    for k in range(lo, hi):
        if out[move[k]] and states[nxt[k]].max() <= H:
            any_kept = True
    if any_kept:
        for k in range(lo, hi):
            if states[nxt[k]].max() > H:
                out[move[k]] = False


def _shaped(
    env: gym.Env,
    potential: str,
    scale: float | None,
    gamma: float,
    expert_starts: float,
    starts_among: str,
) -> GaitShaping:
    """``env`` with :class:`GaitExpertStarts` if ``expert_starts`` > 0, in :class:`GaitShaping`."""
    fraction = real_number("expert_starts", expert_starts, 0.0, 1.0)
    if fraction > 0.0:
        env = GaitExpertStarts(env, fraction, starts_among)
    return GaitShaping(env, potential, scale, gamma)


def shaped_gait_env(
    potential: str = "held",
    scale: float | None = None,
    gamma: float = 0.99,
    expert_starts: float = 0.0,
    starts_among: str = "expert",
    **kwargs: Any,
) -> GaitShaping:
    """``CubeGaitEnv(**kwargs)`` (``optimal_grip`` True unless given), with
    :class:`GaitExpertStarts` (``fraction=expert_starts``, ``among=starts_among``) if
    ``expert_starts`` > 0, in
    :class:`GaitShaping` with ``potential``, ``scale`` and ``gamma``: the id
    ``grasp_env/CubeGaitMovesShaped-v0``."""
    kwargs.setdefault("optimal_grip", True)
    return _shaped(CubeGaitEnv(**kwargs), potential, scale, gamma, expert_starts, starts_among)


def shaped_can_gait_env(
    potential: str = "held",
    scale: float | None = None,
    gamma: float = 0.99,
    expert_starts: float = 0.0,
    starts_among: str = "expert",
    **kwargs: Any,
) -> GaitShaping:
    """``CanGaitEnv(**kwargs)`` (``optimal_grip`` True unless given), with
    :class:`GaitExpertStarts` (``fraction=expert_starts``, ``among=starts_among``) if
    ``expert_starts`` > 0, in :class:`GaitShaping` with ``potential``, ``scale`` (default:
    the can's optimal gait's smallest margin, 8.893 deg, a pose) and ``gamma``: the id
    ``grasp_env/CanGaitMovesShaped-v0``."""
    kwargs.setdefault("optimal_grip", True)
    return _shaped(CanGaitEnv(**kwargs), potential, scale, gamma, expert_starts, starts_among)


__all__ = [
    "POTENTIALS",
    "STARTS",
    "AnyGaitTask",
    "GaitExpertStarts",
    "GaitMoveMasks",
    "GaitShaping",
    "expert_gait",
    "legal_moves",
    "poses_held",
    "potential_table",
    "shaped_can_gait_env",
    "shaped_gait_env",
]
