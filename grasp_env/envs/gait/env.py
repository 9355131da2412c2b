"""The single gait environment, `grasp_env/CubeGait-v0` (and `CubeGaitMoves-v0`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..validation import (
    DEFAULT_K_MAX_RATIO,
    action_array,
    check_bool,
    check_seed,
)
from .kernels import _buffers, _step_kernel, check_moves, optimal_actions
from .tasks import _task

#: Frames a second of rendered episodes (a pose a frame); grasp_env.envs.gait.render draws them.
GAIT_RENDER_FPS = 20

_SQRT3 = float(np.sqrt(3.0))


class CubeGaitEnv(gym.Env[np.ndarray, np.ndarray]):
    """Phase fingers out and in: hold the cube along a long rotation with a hand that reaches.

    ## Description
    The paper promises "an algorithm ... when to phase out a finger": a finger may reach a
    joint limit while the object turns, and must then hand its load to the others. A hand of
    five fingers (`grasp_env.mechanics.Hand`: four below the cube pushing up and inwards a
    quarter turn apart, a thumb above pushing down) can push on a face only while the face's
    inward normal lies within `cone_deg` (60 deg) of the finger's approach. The cube (unit
    edge, w = 5 N, centre of gravity 0.05 m off centre) carries one contact site per face,
    off-centre (`grasp_env.mechanics.gait.SITE_OFFSETS`); it turns about the paper's axis
    from -90 to +90 deg in 1 deg steps (181 poses). No fixed set of fingers stays within
    reach for the whole turn: at every pose the agent chooses the grip (the interaction
    forces of the fingers that carry load) and may lift one finger or place one. It is
    sequential: a finger must be lifted (with zero force, the others holding) before its
    site leaves its reach, and placed (within reach) before it is needed. The certified
    optimal gait (the dynamic programme of docs/gait.md) keeps a worst margin of 6.97 deg;
    the greedy one-pose lookahead (`GreedyGait`) loses a contact and drops the cube, at
    alpha = -44 deg from this environment's start (at -19 deg from its own best start).

    ## Action Space
    `Box(-1, 1, (P + M,), float32)` with P = F (F - 1) / 2 = 10 finger pairs and
    M = 1 + F N = 31 moves (F = 5 fingers, N = 6 sites):
    - `action[:P]`: the grip, k_fg = a_fg x k_max for the finger pairs (f, g), f < g, in the
      order of `grasp_env.mechanics.contact_pairs(5)` (k_max = `k_max_ratio` x w; k > 0
      squeezes the pair, eq. 4); pairs whose fingers do not both carry load are ignored.
    - `action[P:]`: scores of the moves; the move made is the argmax (ties: the lower index).
      Move 0 keeps the contacts; move 1 + f N + s toggles finger f on site s: it lifts f if f
      is on s (f carries no force at this pose and is gone from the next), and places f on s
      if both are free (f touches with zero force now and carries load from the next pose).
      Fingers are 0-3 (finger1-finger4) and 4 (the thumb); sites 0-5 on the faces
      -x, -y, -z, +x, +y, +z.

    With `optimal_grip=True` (the id `grasp_env/CubeGaitMoves-v0`) the action is the move
    alone, `Discrete(M)`, and the environment grips with the certified minimax optimum of the
    fingers that carry load after the move (a refused move: of those that carry it now), as
    the optimal and the greedy gait do: what is learnt is when to phase a finger out or in.

    ## Observation Space
    `Box(low, high, (110,), float32)`, world frame, forces in units of w, lengths of L:

    | index     | observation                                                | bounds  |
    |-----------|------------------------------------------------------------|---------|
    | 0-5       | first two columns of the orientation R                     | [-1, 1] |
    | 6-23      | site positions R (c_s - g) / L, site by site               | [-√3, √3] |
    | 24-41     | inward site normals R nu_s                                 | [-1, 1] |
    | 42-44     | load force (0, 0, -1) + f_d / w                            | [-2, 1] |
    | 45-47     | extra torque tau_d / (w L)                                 | [-1, 1] |
    | 48        | friction limit theta_lim = atan(mu), radians               | [0, pi/2] |
    | 49        | phase: steps taken / trajectory length                     | [0, 1]  |
    | 50-79     | contacts: 1 where finger f touches site s (index 50 + f N + s) | {0, 1} |
    | 80-109    | reach: 1 where finger f can push on site s at this pose    | {0, 1}  |

    ## Rewards
    min over the fingers that carry load of (theta_lim - theta_i), radians (eq. 2, 4), as in
    the other environments; a released finger (its force at most 1e-6 of the forces it is
    made of, `grasp_env.envs.kernels.RELEASE`) counts as inside its cone, angle 0 (the optimum
    often lets the fourth finger go, and float32 actions alone leave such a finger about
    1e-8 w in an arbitrary direction). A finger whose site has
    left its reach while it touches the object has lost its contact under load: the step's
    reward is theta_lim - pi/2 (its friction angle counts as 90 deg: it cannot push).

    ## The hand's rules
    - Refused (the move is ignored, `info["refused"]`, the grip still applies): lifting a
      finger when only three touch (fewer than three would carry load), placing a finger when
      four touch, on a site taken or out of its reach, or toggling a finger on a site it is
      not on while it touches another.
    - Lost contact (`info["lost"]`): a touching finger whose site is out of its reach at this
      pose leaves the hand; a slip (see Episode End). With fewer than three fingers left the
      cube drops.
    - A finger is never lifted under load: a lift takes its force to zero at that pose.

    ## Starting State
    The first pose (alpha = -90 deg), the hand in the optimal gait's first state (finger1 on
    -z, finger3 on +x, finger4 on +y); nothing is random. `start` sets another first state.

    ## Episode End
    - Termination: the cube drops (fewer than three fingers left), or, with
      `terminate_on_slip=True`, a loaded finger slips (theta_i > theta_lim) or a contact is
      lost.
    - Truncation: after the last pose.

    ## Info
    `alpha_deg`, `contacts` (F,) the site each finger touches after the step's move (-1: none),
    `move` (the move made, 0 if refused), `refused`, `lost` (F,) bool, `loaded` (F,) bool (the
    fingers that carried load), `theta` (F,) radians (0 for a finger carrying no load), `k`
    (P,) newtons (0 for pairs not both loaded),
    `contact_forces` (F, 3) newtons, `slip` (F,) bool, `expert_reward` (the optimal gait's
    margin at this pose, from the episode's start).

    ## Arguments
    ```python
    gym.make("grasp_env/CubeGait-v0", trajectory=None, mu=0.5, cone_deg=60.0,
             k_max_ratio=2.0, terminate_on_slip=True, start=None, optimal_grip=False,
             render_mode=None)
    ```
    - `trajectory`: a mapping with the keys `axis`, `alpha_start_deg`, `alpha_end_deg`,
      `alpha_step_deg` (missing keys: the paper's axis over [-90, 90] deg by 1 deg); e.g.
      `{"axis": (0, 0, 1), "alpha_start_deg": -180, "alpha_end_deg": 180}`, a full turn about
      the vertical (the cube turns about its own diagonal).
    - `mu`: the friction coefficient. `cone_deg`: the half-angle of every finger's cone.
    - `k_max_ratio`: k_max / w. `terminate_on_slip`: see Episode End.
    - `start`: the first state, an assignment of a site (0-5, or -1 for none) to each of the
      five fingers, 3 or 4 touching; default the optimal gait's.
    - `optimal_grip`: the action is the move only, the grip the certified optimum (see
      Action Space); `grasp_env/CubeGaitMoves-v0` sets it.
    - `render_mode`: None, "rgb_array" or "human" (see Rendering).
    The configuration is solved when the first environment with it is made (about 3 s: the
    certified minimax of 35 site sets at 181 poses and the dynamic programme), then shared.

    ## Rendering
    `render_mode="rgb_array"`: `render()` returns an RGB frame (480, 480, 3) uint8, drawn
    offscreen by MuJoCo (headless: `MUJOCO_GL=egl` or `osmesa`, which `grasp_env.physics`
    picks when no display is set); `"human"` opens a MuJoCo window (without a display it
    warns once and draws nothing). The frame shows the cube at the pose of the last step
    (after `reset`, the first pose with the certified minimax grip of the start's fingers)
    with the fingers on their sites after the step's move: each touching finger's push as an
    arrow ending at its site, inside its friction cone, both coloured green to red as theta_i
    nears theta_lim; free sites show a faint grey cone and a fingertip lifted off the face. With
    Pillow installed a caption gives alpha, the step's margin and which finger is on which
    face (`grasp_env.envs.gait.render`). `metadata["render_fps"]` is 20 (a pose a frame).
    The view is built on the first `render()`, and `close()` frees it.

    ## Version History
    - v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": GAIT_RENDER_FPS}  # noqa: RUF012

    def __init__(
        self,
        trajectory: Mapping[str, Any] | None = None,
        mu: float = 0.5,
        cone_deg: float = 60.0,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        terminate_on_slip: bool = True,
        start: Sequence[int] | None = None,
        optimal_grip: bool = False,
        render_mode: str | None = None,
    ) -> None:
        modes = self.metadata["render_modes"]
        if not (render_mode is None or (isinstance(render_mode, str) and render_mode in modes)):
            raise ValueError(f"render_mode must be None or one of {modes}, got {render_mode!r}")
        self.render_mode = render_mode
        self.task = _task(trajectory, mu, cone_deg, k_max_ratio, start)
        self.terminate_on_slip = check_bool("terminate_on_slip", terminate_on_slip)
        self.optimal_grip = check_bool("optimal_grip", optimal_grip)
        task = self.task
        P, M = task.n_pairs, task.n_moves
        F, N = task.n_fingers, task.n_sites
        self.action_space: spaces.Space = (
            spaces.Discrete(M)
            if self.optimal_grip
            else spaces.Box(-1.0, 1.0, (P + M,), dtype=np.float32)
        )
        low = np.concatenate(
            [-np.ones(6), np.full(3 * N, -_SQRT3), -np.ones(3 * N), [-2.0, -2.0, -2.0],
             -np.ones(3), [0.0, 0.0], np.zeros(2 * F * N)]
        )  # fmt: skip
        high = np.concatenate(
            [np.ones(6), np.full(3 * N, _SQRT3), np.ones(3 * N), np.ones(3), np.ones(3),
             [np.pi / 2, 1.0], np.ones(2 * F * N)]
        )  # fmt: skip
        self.observation_space = spaces.Box(
            low.astype(np.float32), high.astype(np.float32), dtype=np.float32
        )
        self._x = task.start
        self._t = 0
        self._done = True
        self._xs = np.zeros(1, np.int64)  # the kernel's inputs, reused
        self._ts = np.zeros(1, np.int64)
        self._view: Any = None  # GaitView, built on the first render()
        # what render() draws: None, the state and pose as they are (before the first step);
        # else the last step's pose, contacts after its move, forces (F, 3) and reward
        self._shown: tuple[int, np.ndarray, np.ndarray, float] | None = None

    def _observation(self, x: int, t: int) -> np.ndarray:
        task = self.task
        return np.concatenate([task.observations[t], task.contact_obs[x], task.reach_obs[t]])

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        # Checked before seeding: a refused reset changes nothing.
        seed = check_seed("seed", seed)
        if options:  # None and {} are the only options
            raise ValueError(f"the gait environment takes no reset options, got {options!r}")
        super().reset(seed=seed)
        self._x, self._t, self._done = self.task.start, 0, False
        self._shown = None
        if self.render_mode == "human":
            self.render()
        return self._observation(self._x, 0), {}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError("the episode has ended (or not started): call reset()")
        task = self.task
        t = self._t
        self._xs[0], self._ts[0] = self._x, t
        if self.optimal_grip:
            moves = check_moves(action, (), task.n_moves)[None]
            a = optimal_actions(task, self._xs, self._ts, moves)[0]
        else:
            a = action_array(action, self.action_space.shape)
        floats, ints, flags, obs = _buffers(task, 1)
        if not _step_kernel(
            self._xs, self._ts, a.reshape(1, -1), *task.kernel_arrays, self.terminate_on_slip,
            floats, ints, flags, obs,
        ):  # fmt: skip
            raise ValueError(f"actions must be finite numbers, got {a.tolist()}")
        f, i, g = floats[0], ints[0], flags[0]  # the layout of _step
        F, P = task.n_fingers, task.n_pairs
        terminated = bool(g[2])
        self._t = t + 1
        truncated = self._t == task.n_poses and not terminated
        self._done = terminated or truncated
        if not g[0]:
            self._x = int(i[0])
        info = {
            "refused": bool(g[1]),
            "lost": g[4 : 4 + F],
            "move": int(i[1]),
            "theta": f[1 : 1 + F],
            "loaded": g[4 + F : 4 + 2 * F],
            "k": f[1 + F : 1 + F + P],
            "contact_forces": f[1 + F + P :].reshape(F, 3),
            "slip": g[4 + 2 * F :],
            "contacts": i[2:],
            "alpha_deg": float(task.alphas[t]),
            "expert_reward": float(task.expert_margins[t]),
        }
        if self.render_mode is not None:  # copies: info's arrays are the user's to change
            self._shown = (t, i[2:].copy(), info["contact_forces"].copy(), float(f[0]))
            if self.render_mode == "human":
                self.render()
        return obs[0], float(f[0]), terminated, truncated, info

    # -- rendering (grasp_env.envs.gait.render, which loads MuJoCo, imported only when asked) --

    def render(self) -> np.ndarray | None:
        """An RGB frame (H, W, 3) uint8 for ``render_mode="rgb_array"``; a window for "human"
        (see Rendering in the class docstring)."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to make()")
            return None
        from .render import GaitView, resting_grips

        if self._view is None:
            self._view = GaitView(self.task, render_mode=self.render_mode)
        if self._shown is None:
            t = min(self._t, self.task.n_poses - 1)
            contacts, forces = resting_grips(self.task, [self._x], [t])
            return self._view.render(t, contacts[0], forces[0])
        return self._view.render(*self._shown)

    def close(self) -> None:
        if self._view is not None:
            self._view.close()
            self._view = None
        super().close()

    def __getstate__(self) -> dict[str, Any]:
        # The view holds MuJoCo's native resources: not pickled, rebuilt by the next render().
        state = self.__dict__.copy()
        state["_view"] = None
        return state


__all__ = ["CubeGaitEnv"]
