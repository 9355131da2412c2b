"""The can gait environment `grasp_env/CanGait-v0` (and `CanGaitMoves-v0`), its task tables
and its expert and greedy policies (docs/gait.md, "The can")."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from itertools import combinations
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ...mechanics import contact_pairs
from ...mechanics.forces import grasp, load_wrench
from ...mechanics.gait.can import (
    CAN_DEFAULT_LOADED,
    CAN_MAX_LOADED,
    CAN_MIN_LOADED,
    CAN_WEIGHT,
    CanHand,
    CanTurn,
    contact_points,
)
from ...mechanics.gait.can_programme import (
    CanGait,
    CanGaitSolution,
    CanStates,
    optimal_can_gait,
    solve_can_gait,
)
from ..kernels import evaluate_grips
from ..spec import K_MAX_RATIO, MU, TERMINATE_ON_SLIP
from ..validation import action_array, check_bool, check_integer, check_number, check_seed

#: Frames a second of rendered episodes (a pose a frame).
CAN_RENDER_FPS = 10


@dataclass(frozen=True, eq=False)
class CanGaitTask:
    """One configuration's tables, shared by every environment and policy made with it.

    Attributes:
        solution: the can's gait problem solved (:func:`solve_can_gait`).
        expert: the certified optimal gait from ``start`` (its policy over every state).
        start: the state index episodes start from.
        code: ((H + 3)^F,) the state index of each ages code (-1: no state).
        points, normals: (F, H + 2, 3) each finger's contact point (relative to the centre of
            gravity, metres) and inward normal at every age 0..H + 1, world frame (the same
            at every pose: the turn is about the can's axis).
        k_max_ratio: k_max / w.
        scores: each configuration's :meth:`score` at its certified grip, filled as steps
            meet them (a step of ``optimal_grip=True`` looks its score up: the same numbers,
            about a quarter of the step's CPU).
    """

    solution: CanGaitSolution
    expert: CanGait
    start: int
    code: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    k_max_ratio: float
    scores: dict[int, tuple] = field(default_factory=dict, repr=False)

    @property
    def table(self) -> CanStates:
        return self.expert.table

    @property
    def n_fingers(self) -> int:
        return self.table.n_fingers

    @property
    def max_age(self) -> int:
        return self.table.max_age

    @property
    def n_poses(self) -> int:
        return len(self.solution.turn)

    @property
    def n_pairs(self) -> int:
        return self.n_fingers * (self.n_fingers - 1) // 2

    @property
    def n_moves(self) -> int:
        return 1 + self.n_fingers

    @property
    def limit(self) -> float:
        return self.solution.friction_limit

    @property
    def observation_size(self) -> int:
        return 4 + 8 * self.n_fingers

    def state_of(self, ages: np.ndarray) -> int:
        """The state index of ages (F,) (-1 for none, e.g. fewer than three touching)."""
        base = self.max_age + 3
        key = int(((np.asarray(ages) + 1) * base ** np.arange(self.n_fingers)).sum())
        return int(self.code[key])

    def observation(self, x: int, t: int) -> np.ndarray:
        """Phase t / T, cos and sin alpha, theta_lim, touching (F), age / (H + 1) (F), contact
        points / half-height (3F) and inward normals (3F) of the touching fingers."""
        T, F, H = self.n_poses, self.n_fingers, self.max_age
        ages = self.table.states[x] if x >= 0 else np.full(F, -1)
        touching = ages >= 0
        alpha = np.deg2rad(self.solution.turn.alphas_deg[min(t, T - 1)])
        rows = np.arange(F)
        a = np.clip(ages, 0, H + 1)
        points = np.where(touching[:, None], self.points[rows, a], 0.0)
        normals = np.where(touching[:, None], self.normals[rows, a], 0.0)
        half = 0.5 * self.solution.can.height
        return np.concatenate(
            [[min(t, T) / T, np.cos(alpha), np.sin(alpha), self.limit], touching,
             np.where(touching, ages / (H + 1), 0.0), (points / half).ravel(), normals.ravel()]
        ).astype(np.float32)  # fmt: skip

    def score(self, fingers: list[int], ages: np.ndarray, grip: np.ndarray) -> tuple:
        """The grip ``grip`` (P,) in [-1, 1] (pairs of all F fingers) on the loaded ``fingers``:
        (reward, theta (n,), k (P,) newtons, net forces (n, 3) newtons), eq. 4 and eq. 2."""
        n = len(fingers)
        w = self.solution.weight
        p = self.points[fingers, ages[fingers]][None]
        nu = self.normals[fingers, ages[fingers]][None]
        g = grasp(p, nu, np.eye(3), load_wrench(w), self.limit)
        pairs = contact_pairs(n)
        u = g.basis[:, np.arange(len(pairs)), pairs[:, 0], :]
        columns = {q: i for i, q in enumerate(combinations(range(self.n_fingers), 2))}
        cols = [columns[(fingers[i], fingers[j])] for i, j in pairs]
        _, k, net, theta, _, reward = evaluate_grips(
            g.equilibrating / w, u, g.normals, pairs, np.zeros(1, np.int64),
            np.asarray(grip, float)[cols][None], self.k_max_ratio, np.full(1, w),
            np.full(1, self.limit),
        )  # fmt: skip
        out = np.zeros(self.n_pairs)
        out[cols] = k[0]
        return float(reward[0]), theta[0], out, net[0]

    def optimal_score(self, config: int) -> tuple:
        """:meth:`score` of configuration ``config`` at its certified grip
        (:meth:`optimal_grip`), computed once per configuration; fresh arrays each call."""
        hit = self.scores.get(config)
        if hit is None:
            fingers = [f for f, _ in self.solution.values.configs[config]]
            ages = np.full(self.n_fingers, -1, np.int64)
            for f, a in self.solution.values.configs[config]:
                ages[f] = a
            hit = self.score(fingers, ages, self.optimal_grip(config))
            self.scores[config] = hit
        reward, theta, k, net = hit
        return reward, theta.copy(), k.copy(), net.copy()

    def optimal_grip(self, config: int) -> np.ndarray:
        """The certified minimax grip k* / k_max (P,) of a configuration, clipped to [-1, 1]."""
        k, _ = self.solution.values.grip(config)
        fingers = [f for f, _ in self.solution.values.configs[config]]
        columns = {q: i for i, q in enumerate(combinations(range(self.n_fingers), 2))}
        out = np.zeros(self.n_pairs)
        for q, (i, j) in enumerate(contact_pairs(len(fingers))):
            out[columns[(fingers[i], fingers[j])]] = k[q] / (self.k_max_ratio * CAN_WEIGHT)
        return np.clip(out, -1.0, 1.0)


@lru_cache(maxsize=8)
def can_gait_task(
    reach_deg: float, alpha_step_deg: float, alpha_end_deg: float, max_loaded: int, mu: float,
    k_max_ratio: float, start: tuple[int, ...] | None,
) -> CanGaitTask:  # fmt: skip
    """The task of one configuration (cached: every environment made with it shares it)."""
    hand = CanHand(reach_deg=reach_deg)
    turn = CanTurn(0.0, alpha_end_deg, alpha_step_deg)
    H = hand.max_age(alpha_step_deg)
    if not 1 <= H <= 12:
        raise ValueError(
            f"2 reach_deg / alpha_step_deg must give a contact 1 to 12 poses, got {H}"
            f" (reach_deg={reach_deg:g}, alpha_step_deg={alpha_step_deg:g})"
        )
    solution = solve_can_gait(
        hand, turn, CAN_WEIGHT, mu, k_max_ratio * CAN_WEIGHT, max_loaded=max_loaded
    )
    F = hand.n_fingers
    expert = solution.optimal
    if start is not None:
        expert = optimal_can_gait(solution.margin, F, H, start, max_loaded)
    if not expert.margin > -np.inf:
        raise ValueError(
            f"no gait{'' if start is None else f' from start {list(start)}'} keeps three fingers"
            f" within reach along the turn (reach_deg={reach_deg:g}): widen the reach"
        )
    table = expert.table
    base = H + 3
    code = np.full(base**F, -1, np.int64)
    code[((table.states + 1) * base ** np.arange(F)).sum(axis=1)] = np.arange(len(table.states))
    points, normals = _finger_points(solution, H)
    return CanGaitTask(solution, expert, int(expert.states[0]), code, points, normals, k_max_ratio)


def _finger_points(solution: CanGaitSolution, H: int) -> tuple[np.ndarray, np.ndarray]:
    """(F, H + 2, 3) points and normals of every finger at every age (:func:`contact_points`)."""
    F = solution.hand.n_fingers
    points = np.empty((F, H + 2, 3))
    normals = np.empty((F, H + 2, 3))
    for a in range(H + 2):
        p, nu = contact_points(
            solution.can, solution.hand, solution.turn.step_deg, np.arange(F), np.full(F, a)
        )
        points[:, a], normals[:, a] = p, nu
    return points, normals


def _task(
    reach_deg: Any, alpha_step_deg: Any, alpha_end_deg: Any, max_loaded: Any, mu: Any,
    k_max_ratio: Any, start: Any,
) -> CanGaitTask:  # fmt: skip
    reach_deg = check_number("reach_deg", reach_deg, 0.0, 90.0, open_low=True)
    alpha_step_deg = check_number("alpha_step_deg", alpha_step_deg, 0.0, 90.0, open_low=True)
    alpha_end_deg = check_number("alpha_end_deg", alpha_end_deg, 0.0, 720.0, open_low=True)
    max_loaded = check_integer("max_loaded", max_loaded, CAN_MIN_LOADED, CAN_MAX_LOADED)
    mu = MU.check(mu)
    k_max_ratio = K_MAX_RATIO.check(k_max_ratio)
    if start is not None:
        try:
            start = tuple(int(a) for a in start) if not isinstance(start, str) else None
        except (TypeError, ValueError):
            start = None
        if start is None:
            raise ValueError("start must give each finger an age (1 to H) or -1 (not touching)")
    return can_gait_task(
        reach_deg, alpha_step_deg, alpha_end_deg, max_loaded, mu, k_max_ratio, start
    )


class CanGaitEnv(gym.Env[np.ndarray, Any]):
    """Turn the coke can about its axis, phasing fingers out and in.

    ## Description
    The paper's stretch: "turning a coke can about its axis requires phasing in and out of the
    fingers". The can (radius 33 mm, height 115 mm, w = 3.4 N, mu = 0.5) stands upright and
    turns a full turn about its axis, alpha from 0 to 360 deg in 10 deg steps (37 poses). Five
    fingertips (`grasp_env.mechanics.gait.CanHand`) push on its side from fixed azimuths, each
    reaching points whose azimuth lies within `reach_deg` (60 deg) of its own. A finger is
    placed at the upstream edge of its patch, and its contact turns with the can: it lasts
    H = floor(2 reach / step) = 12 poses, then the finger must be lifted and placed again.
    At every pose 3 to 5 fingers touch, 3 to `max_loaded` (4) carry load, and at most one
    finger is lifted or placed. The certified optimal gait (docs/gait.md) keeps a worst
    margin of 8.893 deg with 25 phase changes; the greedy one-pose lookahead drops the can.

    ## Action Space
    `Box(-1, 1, (P + M,), float32)`, P = 10 finger pairs, M = 1 + F = 6 moves:
    - `action[:P]`: the grip, k_fg = a_fg k_max for the pairs (f, g), f < g
      (`grasp_env.mechanics.contact_pairs(5)` order; k_max = `k_max_ratio` w, eq. 4); pairs
      not both carrying load are ignored.
    - `action[P:]`: scores of the moves; the argmax is made (ties: the lower). Move 0 keeps;
      move 1 + f toggles finger f: lifts it if it touches (zero force now, gone next pose),
      places it at the upstream edge of its patch if not (zero force now, loaded from the next).
    With `optimal_grip=True` (`grasp_env/CanGaitMoves-v0`) the action is the move alone,
    `Discrete(M)`, and the grip is the certified minimax optimum of the loaded fingers.

    ## Observation Space
    `Box(low, high, (44,), float32)`: phase t / T, cos alpha, sin alpha, theta_lim, then per
    finger: touching (5, {0, 1}), age / (H + 1) (5, [0, 1]), contact point / half-height
    (15, [-1, 1]) and inward normal (15, [-1, 1]), world frame, zero where it does not touch.

    ## Rewards
    min over the loaded fingers of (theta_lim - theta_i), radians (eq. 2, 4), as in the cube
    gait env; a contact lost (a finger past its reach) scores theta_lim - pi/2.

    ## The hand's rules
    - Refused (`info["refused"]`): a move the can's tables do not allow (fewer than three
      loaded, more than `max_loaded` loaded, more than five touching, a lost contact). The step
      then makes the state's first allowed move: keep where it is allowed (with five touching
      and four loaded at most, keep is not: the lowest-numbered finger is lifted).
    - Lost contact (`info["lost"]`): a finger past its reach (age H + 1) leaves the hand.
      With fewer than three left, the can drops.

    ## Starting State
    The optimal gait's first state (or `start`); nothing is random.

    ## Episode End
    Termination: the can drops, or with `terminate_on_slip=True` a loaded finger slips or a
    contact is lost. Truncation: after the last pose.

    ## Info
    `alpha_deg`, `ages` (F,) each finger's age after the move (0: just placed, -1: none),
    `move`, `refused`, `lost`, `loaded`, `theta` (F,), `k` (P,) newtons, `contact_forces`
    (F, 3) newtons, `slip` (F,), `expert_reward` (the certified optimal gait's margin at this
    pose from the episode's start) and `certified_reward` (the certified optimum of the
    fingers loaded at this step, NaN after a lost contact).

    ## Arguments
    ```python
    gym.make("grasp_env/CanGait-v0", reach_deg=60.0, alpha_step_deg=10.0,
             alpha_end_deg=360.0, max_loaded=4, mu=0.5, k_max_ratio=2.0,
             terminate_on_slip=True, start=None, optimal_grip=False, render_mode=None)
    ```
    - `reach_deg` in (0, 90], `alpha_step_deg` in (0, 90] (2 reach / step must give 1 to 12
      poses a contact), `alpha_end_deg` in (0, 720] (the turn from 0).
    - `max_loaded`: 3 to 5 fingers carrying load (5 solves every five-finger configuration
      with the conic solver: minutes).
    - `mu` in [0.001, 1000], `k_max_ratio` in [0.001, 1000] (k_max / w).
    - `start`: each finger's age (1 to H) or -1, 3 to 5 touching.
    The configuration is solved when the first environment with it is made (about 24 s of
    CPU at the defaults), then shared.

    ## Rendering
    `render_mode="rgb_array"` (headless: MUJOCO_GL=egl): the can at the pose with the
    touching fingertips, their pushes and friction cones (green to red), lifted fingers grey
    off the side, and a caption with alpha, the margin and the fingers' ages.

    ## Version History
    - v0: initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": CAN_RENDER_FPS}  # noqa: RUF012

    def __init__(
        self,
        reach_deg: float = 60.0,
        alpha_step_deg: float = 10.0,
        alpha_end_deg: float = 360.0,
        max_loaded: int = CAN_DEFAULT_LOADED,
        mu: float = 0.5,
        k_max_ratio: float = K_MAX_RATIO.default,
        terminate_on_slip: bool = TERMINATE_ON_SLIP.default,
        start: Any = None,
        optimal_grip: bool = False,
        render_mode: str | None = None,
    ) -> None:
        modes = self.metadata["render_modes"]
        if not (render_mode is None or (isinstance(render_mode, str) and render_mode in modes)):
            raise ValueError(f"render_mode must be None or one of {modes}, got {render_mode!r}")
        self.render_mode = render_mode
        self.task = _task(
            reach_deg, alpha_step_deg, alpha_end_deg, max_loaded, mu, k_max_ratio, start
        )
        self.k_max_ratio = self.task.k_max_ratio
        self.terminate_on_slip = check_bool("terminate_on_slip", terminate_on_slip)
        self.optimal_grip = check_bool("optimal_grip", optimal_grip)
        task = self.task
        P, M, F = task.n_pairs, task.n_moves, task.n_fingers
        self.action_space: spaces.Space = (
            spaces.Discrete(M)
            if self.optimal_grip
            else spaces.Box(-1.0, 1.0, (P + M,), dtype=np.float32)
        )
        low = np.concatenate([[0.0, -1.0, -1.0, 0.0], np.zeros(2 * F), -np.ones(6 * F)])
        high = np.concatenate([[1.0, 1.0, 1.0, np.pi / 2], np.ones(8 * F)])
        self.observation_space = spaces.Box(
            low.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )
        self._x, self._t, self._done = task.start, 0, True
        self._view: Any = None
        self._shown: tuple[int, np.ndarray, np.ndarray, float | None] | None = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        seed = check_seed("seed", seed)
        if options:
            raise ValueError(f"the can gait environment takes no reset options, got {options!r}")
        super().reset(seed=seed)
        self._x, self._t, self._done = self.task.start, 0, False
        self._shown = None
        return self.task.observation(self._x, 0), {}

    def _move(self, action: Any) -> tuple[int, np.ndarray | None]:
        M = self.task.n_moves
        if self.optimal_grip:
            array = np.asarray(action)
            if array.shape != () or array.dtype.kind not in "iu" or not 0 <= int(array) < M:
                raise ValueError(f"a move is an integer in [0, {M - 1}], got {action!r}")
            return int(array), None
        a = action_array(action, self.action_space.shape)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"actions must be finite numbers, got {a.tolist()}")
        P = self.task.n_pairs
        return int(np.argmax(a[P:])), np.asarray(a[:P], float)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError("the episode has ended (or not started): call reset()")
        task, table = self.task, self.task.table
        move, grip = self._move(action)
        t, x = self._t, self._x
        F, H = task.n_fingers, task.max_age
        ages = table.states[x].copy()
        lost = ages > H
        theta, forces, k = np.zeros(F), np.zeros((F, 3)), np.zeros(task.n_pairs)
        loaded = np.zeros(F, bool)
        refused, made, certified = False, 0, float("nan")
        if lost.any():  # the move is void: the contacts past reach leave the hand
            reward = task.limit - 0.5 * np.pi
            after = np.where(lost, -1, ages)
            older = np.where(after >= 0, after + 1, -1)
            y = task.state_of(older) if (after >= 0).sum() >= 3 else -1
        else:
            lo, hi = int(table.ptr[x]), int(table.ptr[x + 1])
            hits = np.flatnonzero(table.move[lo:hi] == move)
            refused = hits.size == 0
            kk = lo if refused else lo + int(hits[0])
            made = int(table.move[kk])
            config = int(table.config[kk])
            fingers = [f for f, _ in task.solution.values.configs[config]]
            loaded[fingers] = True
            if grip is None:
                reward, angles, k, net = task.optimal_score(config)
            else:
                reward, angles, k, net = task.score(fingers, ages, grip)
            theta[fingers], forces[fingers] = angles, net
            certified = float(task.solution.values.margin[config])
            after = ages.copy()
            if made:
                f = made - 1
                after[f] = -1 if ages[f] >= 0 else 0
            y = int(table.next[kk])
        slip = lost | (theta > task.limit)
        dropped = y < 0
        terminated = bool(dropped or (self.terminate_on_slip and slip.any()))
        self._t = t + 1
        truncated = self._t == task.n_poses and not terminated
        self._done = terminated or truncated
        if not dropped:
            self._x = y
        info = {
            "alpha_deg": float(task.solution.turn.alphas_deg[t]),
            "ages": after,
            "move": made,
            "refused": refused,
            "lost": lost,
            "loaded": loaded,
            "theta": theta,
            "k": k,
            "contact_forces": forces,
            "slip": slip,
            "expert_reward": float(task.expert.margins[t]),
            "certified_reward": certified,
        }
        self._shown = (t, after, forces, reward)
        obs = task.observation(-1 if dropped else y, self._t)
        return obs, float(reward), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """An RGB frame (480, 480, 3) uint8 (see Rendering in the class docstring)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to make()")
            return None
        from .render import CanView, resting_frame

        if self._view is None:
            self._view = CanView(self.task)
        if self._shown is None:
            return self._view.render(*resting_frame(self.task, self._x, self._t))
        return self._view.render(*self._shown)

    def close(self) -> None:
        if self._view is not None:
            self._view.close()
            self._view = None
        super().close()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_view"] = None
        return state


class _CanPolicy:
    """Acts from observations with a move table over (pose, state) and the certified grip."""

    def __init__(self, optimal_grip: bool = False, **kwargs: Any) -> None:
        env = CanGaitEnv(**kwargs)
        self.task = env.task
        self.optimal_grip = check_bool("optimal_grip", optimal_grip)

    def _policy(self) -> np.ndarray:
        raise NotImplementedError

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[Any, None]:  # fmt: skip
        """The action for one observation (the signature of an SB3 model's ``predict``)."""
        task = self.task
        obs = np.asarray(observation, float)
        if obs.shape != (task.observation_size,) or not np.all(np.isfinite(obs)):
            raise ValueError(f"observation must be ({task.observation_size},) finite numbers")
        F, H, T = task.n_fingers, task.max_age, task.n_poses
        t = min(int(np.rint(obs[0] * T)), T - 1)
        touching = obs[4 : 4 + F] > 0.5
        ages = np.where(touching, np.rint(obs[4 + F : 4 + 2 * F] * (H + 1)), -1).astype(int)
        x = task.state_of(ages)
        if x < 0:
            raise ValueError("the observation's ages are no state of the hand")
        k = int(self._policy()[t, x])
        move = int(task.table.move[k]) if k >= 0 else 0
        if self.optimal_grip:
            return np.int64(move), None
        config = int(task.table.config[k]) if k >= 0 else -1
        action = -np.ones(task.n_pairs + task.n_moves, np.float32)
        action[: task.n_pairs] = task.optimal_grip(config) if config >= 0 else 0.0
        action[task.n_pairs + move] = 1.0
        return action, None


class CanGaitExpert(_CanPolicy):
    """The certified optimal can gait as a policy (the dynamic programme's move from any
    state, and the certified minimax grip); the environment's keywords."""

    def _policy(self) -> np.ndarray:
        return self.task.expert.policy


class CanGreedyGait(_CanPolicy):
    """The greedy baseline (one-pose lookahead) as a policy, with the certified grip."""

    def _policy(self) -> np.ndarray:
        return self.task.solution.greedy.policy
