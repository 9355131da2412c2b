"""The single object environments: one explicit scene of any shape, and randomised ones."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ...mechanics import DEFAULT_MU, DEFAULT_WEIGHT, MAX_SCENE_CONTACTS, contact_pairs
from .. import spec
from ..validation import (
    DEFAULT_K_MAX_RATIO,
    action_array,
    check_bool,
    check_integer,
    check_k_max_ratio,
    check_margin,
    check_seed,
)
from .episodes import EpisodeStream, ObjectEpisode, ObjectLayout, build_episodes, solve_pending
from .kernels import object_row
from .scenes import (
    SHAPE_KINDS,
    ObjectSampler,
    ObjectScene,
    default_contacts,
    default_trajectory,
    make_scene,
    object_shape,
    parse_options,
    parse_scene,
)

_EPISODE_CACHE: dict[tuple, ObjectEpisode] = {}
_EPISODE_CACHE_SIZE = 32


def cached_episode(scene: ObjectScene, k_max_ratio: float, max_contacts: int) -> ObjectEpisode:
    """The episode of one explicit scene, remembered (scenes compare by value): environments
    made with the same keywords share one read-only episode."""
    key = (scene.scene, scene.trajectory, k_max_ratio, max_contacts)
    if key not in _EPISODE_CACHE:
        if len(_EPISODE_CACHE) >= _EPISODE_CACHE_SIZE:
            _EPISODE_CACHE.pop(next(iter(_EPISODE_CACHE)))
        episode = build_episodes([scene], k_max_ratio, max_contacts)[0]
        assert episode is not None
        _EPISODE_CACHE[key] = episode
    return _EPISODE_CACHE[key]


def check_max_contacts(value: Any, n: int) -> int:
    """``max_contacts`` (None: ``n``): an integer in [n, 8], the padded contact count."""
    if value is None:
        return n
    return check_integer("max_contacts", value, n, MAX_SCENE_CONTACTS)


class _ObjectGraspEnv(gym.Env[np.ndarray, np.ndarray]):
    """What the explicit and the random environments share: spaces, step, rendering."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(
        self, max_contacts: int, k_max_ratio: float, terminate_on_slip: bool, render_mode: Any
    ) -> None:
        modes = self.metadata["render_modes"]
        if not (render_mode is None or (isinstance(render_mode, str) and render_mode in modes)):
            raise ValueError(f"render_mode must be None or one of {modes}, got {render_mode!r}")
        self.k_max_ratio = check_k_max_ratio(k_max_ratio)
        self.terminate_on_slip = check_bool("terminate_on_slip", terminate_on_slip)
        self.render_mode = render_mode
        self.max_contacts = max_contacts
        self.layout = ObjectLayout(max_contacts)
        low, high = self.layout.bounds()
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._pairs = contact_pairs(max_contacts)
        self.action_space = spaces.Box(-1.0, 1.0, (len(self._pairs),), dtype=np.float32)
        self._unit = np.empty((max_contacts, 3))
        self._grip = np.empty(len(self._pairs))
        self._episode: ObjectEpisode | None = None
        self._step = 0
        self._done = True
        self._last_forces: np.ndarray | None = None
        self._view: Any = None
        self._view_scene: Any = None

    def _next_episode(self, scene: ObjectScene | None) -> ObjectEpisode:
        raise NotImplementedError

    def scene_option(self, options: Mapping[str, Any] | None) -> ObjectScene | None:
        """The validated scene of ``reset(options={"scene": {...}})`` (None without one)."""
        values = parse_options(options)
        if values is None:
            return None
        scene = parse_scene(values, self._defaults, self.shape)
        if scene.n_contacts > self.max_contacts:
            raise ValueError(
                f"reset option 'scene' has {scene.n_contacts} contacts, more than the"
                f" environment's max_contacts ({self.max_contacts})"
            )
        return scene

    @property
    def episode(self) -> ObjectEpisode:
        """The current episode's precomputed arrays (after :meth:`reset`)."""
        if self._episode is None:
            raise RuntimeError("call reset() first")
        return self._episode

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        seed = check_seed("seed", seed)  # checked before seeding: a refused reset changes nothing
        scene = self.scene_option(options)
        super().reset(seed=seed)
        self._episode = self._next_episode(scene)
        self._step = 0
        self._done = False
        self._last_forces = None
        if self.render_mode == "human":
            self.render()
        return self._episode.observations[0].copy(), {"n_contacts": self._episode.n_contacts}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply the grip of ``action`` (see :mod:`.kernels`) at the current pose."""
        if self._done:
            raise RuntimeError("the episode has ended (or not started): call reset()")
        episode = self.episode
        a = action_array(action, self.action_space.shape)
        t = self._step
        if not episode.solved[t]:  # a random episode's pose the expert has not solved yet
            solve_pending([(episode, t)], self.k_max_ratio)
        big, m = self.max_contacts, len(self._pairs)
        k, forces = np.empty((1, m)), np.empty((1, big, 3))
        theta, margin = np.empty((1, big)), np.empty((1, big))
        finite, reward = object_row(
            episode.forces_w, episode.directions, episode.normals, self._pairs, t,
            a.reshape(1, m), 0, episode.n_contacts, episode.projection, self.k_max_ratio,
            episode.weight, episode.limit, k, forces, theta, margin, self._unit, self._grip,
        )  # fmt: skip
        if not finite:
            raise ValueError(f"action must be finite, got {a.tolist()}")
        expert_reward = float(episode.expert_reward[t])
        info = {
            "alpha_deg": float(episode.alphas[t]),
            "theta": theta[0],
            "margin": margin[0],
            "k": k[0],
            "contact_forces": forces[0],
            "equilibrating_forces": episode.forces_w[t] * episode.weight,
            "expert_k": episode.expert_k_w[t] * episode.weight,
            "expert_reward": expert_reward,
            "expert_gap": float(episode.expert_gap[t]),
            "optimality_gap": expert_reward - reward,
            "slip": margin[0] < 0.0,
            "n_contacts": episode.n_contacts,
        }
        terminated = self.terminate_on_slip and reward < 0.0
        self._step = t + 1
        truncated = self._step == len(episode)
        self._done = terminated or truncated
        self._last_forces = forces[0]
        if self.render_mode == "human":
            self.render()
        return episode.observations[t + 1].copy(), reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """An RGB frame (480, 480, 3) uint8 for "rgb_array" (the shape's bounding box, its
        fingers' pushes and friction cones, :class:`grasp_env.physics.GraspView`); a window
        for "human"."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to make()")
            return None
        episode = self.episode
        scene = episode.scene.scene
        if self._view is None or self._view_scene is not scene:
            from ...physics import GraspView  # loads MuJoCo: only when rendering

            if self._view is not None:
                self._view.close()
            self._view = GraspView(scene, render_mode=self.render_mode)
            self._view_scene = scene
        n = episode.n_contacts
        if self._last_forces is None:
            pose, forces = 0, episode.forces_w[0, :n] * episode.weight
        else:
            pose, forces = min(self._step, len(episode)) - 1, self._last_forces[:n]
        return self._view.render(episode.rotations[pose], forces)

    def close(self) -> None:
        if self._view is not None:
            self._view.close()
            self._view = None
            self._view_scene = None
        super().close()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()  # the view holds an OpenGL context: rebuilt on demand
        state.update(_view=None, _view_scene=None)
        return state


_DOC_SPACES = """
    ## Action Space
    `Box(-1, 1, (M,), float32)`, M = N (N - 1) / 2 interaction scalars, one per pair of the
    N = `max_contacts` padded contacts in `grasp_env.mechanics.contact_pairs(N)` order
    ((0, 1), (0, 2), ..., (N - 2, N - 1)). Of a scene of n contacts (the first n), the pairs
    (i, j) with j < n are used and the others ignored; k_ij = a_ij k_max, k_max =
    `k_max_ratio` w, k_ij > 0 squeezes the pair (eq. 4). With five or more contacts the pairs
    are redundant: the grip is the minimum-norm k of the force E k, scaled back into
    |k_ij| <= k_max where it leaves the box (the box the expert's optimum is taken over,
    docs/solver.md "Any number of contacts"); for n <= 4 it is k itself.

    ## Observation Space
    `Box(low, high, (14 + 7N,), float32)`, world frame, lengths in units of L (the largest
    edge of the shape's bounding box), forces in units of the weight w:

    | index            | observation                                     | bounds          |
    |------------------|-------------------------------------------------|-----------------|
    | 0-5              | first two columns of the orientation R          | [-1, 1]         |
    | 6 to 5+3N        | contact positions R (c_i - g) / L, 0 if padding | [-√3, √3]       |
    | 6+3N to 5+6N     | inward contact normals R nu_i, 0 if padding     | [-1, 1]         |
    | 6+6N to 5+7N     | contact mask: 1 real, 0 padding                 | [0, 1]          |
    | 6+7N to 8+7N     | load force (0, 0, -1) + f_d / w                 | x, y [-1, 1]; z [-2, 0] |
    | 9+7N to 11+7N    | extra load torque tau_d / (w L)                 | [-1, 1]         |
    | 12+7N            | friction limit theta_lim = atan(mu), radians    | [0, pi/2]       |
    | 13+7N            | phase: steps taken / trajectory length          | [0, 1]          |

    ## Rewards
    min_i (theta_lim - theta_i) over the real contacts, radians: theta_i is finger i's friction
    angle (eq. 2) under P = F + sum k_ij e_ij (eq. 4); positive while every finger holds.

    ## Episode End
    - Termination: a finger slips (theta_i > theta_lim), with `terminate_on_slip=True`.
    - Truncation: after the trajectory's last pose.

    ## Info
    As the cube ids', padded: `alpha_deg`, `theta` (N,) and `margin` (N,) radians (padding:
    0 and theta_lim), `k` (M,) the grip applied, `contact_forces` and `equilibrating_forces`
    (N, 3) newtons, `expert_k` (M,) newtons and `expert_reward`, the minimax optimum of the
    exact pose (`solve_minimax`, solved when the episode starts), `expert_gap` its
    certificate's gap (radians; 0 where certified to 1e-9 rad; where the solver returns
    UNCERTIFIED, mostly with five or more contacts, 1e-9 to 1e-5 rad: the optimum lies
    within it), `optimality_gap` = expert_reward -
    reward (>= -expert_gap), `slip` (N,) bool and `n_contacts`. `reset` returns
    `{"n_contacts": n}`.
"""

_DOC_COMMON_ARGS = """\
    - `max_contacts`: N, the padded contact count (at least the scene's, at most 8).
    - `k_max_ratio` (default 2, in [1e-3, 1e3]): k_max / w.
    - `terminate_on_slip` (default True): end the episode when a finger slips.
    - `render_mode`: None, "rgb_array" or "human" (MuJoCo, headless with MUJOCO_GL=egl).
"""


class ObjectGraspEnv(_ObjectGraspEnv):
    __doc__ = (
        """Hold any object by 3 to 8 point contacts along a quasi-static turn.

    ## Description
    An object (a box, cylinder, sphere or convex mesh, `grasp_env.mechanics.objects`) of
    weight w is held by point contacts with Coulomb friction given by surface coordinates
    (`grasp_env.envs.object_grasp.scenes`: `("-x", u, v)` on a box, `("side", angle,
    height)` or `("-z", x, y)` on a cylinder, `("sphere", azimuth, elevation)`, `(face,
    *weights)` on a mesh, or `(x, y, z)` metres). It turns as the cube does: R(alpha) =
    Rot(axis, alpha) R0 (eq. 5), by default the paper's -15 to 15 deg by 1 deg about
    (1, -1, 0) / √2. At every pose the agent chooses the interaction forces; the best grip
    minimises the largest friction angle. The default contacts' normals meet at the shape's
    centre, so with the centre of gravity there the optimum is 0 deg.
"""
        + _DOC_SPACES
        + """
    ## Starting State
    The trajectory's first pose; nothing is random. `reset(options={"scene": {...}})` sets
    another scene of the same shape for that episode: any of `contacts`, `cg_offset`, `weight`,
    `mu`, `extra_force`, `extra_torque`, `trajectory` (missing keys keep the environment's).

    ## Arguments
    ```python
    gym.make("grasp_env/ObjectGrasp-v0", object="cube", contacts=None, weight=5.0, mu=0.5,
             cg_offset=(0, 0, 0), extra_force=(0, 0, 0), extra_torque=(0, 0, 0), trajectory=None,
             max_contacts=None, k_max_ratio=2.0, terminate_on_slip=True, render_mode=None)
    ```
    - `object`: an object spec (`grasp_env.mechanics.parse_object`: "cube", "can",
      "box:x=0.1,y=0.2,z=0.3", "cylinder:r=0.033,h=0.115", "sphere:r=0.05") or a shape.
    - `contacts`: 3 to 8 surface coordinates (default: three whose normals meet at the
      centre; a convex mesh needs them).
    - `weight` (N, [1e-6, 1e6]), `mu` ([1e-3, 1e3]), `cg_offset` (the centre of gravity,
      object frame, metres, inside the shape), `extra_force`, `extra_torque` (world frame,
      at most w and w L per component).
    - `trajectory`: a mapping of `axis`, `alpha_start_deg`, `alpha_end_deg`,
      `alpha_step_deg` (missing keys: the paper's).
"""
        + _DOC_COMMON_ARGS
        + """
    ## Version History
    - v0: initial version.
    """
    )

    def __init__(
        self,
        object: Any = "cube",
        contacts: Sequence[Any] | None = None,
        weight: float = DEFAULT_WEIGHT,
        mu: float = DEFAULT_MU,
        cg_offset: Sequence[float] = (0.0, 0.0, 0.0),
        extra_force: Sequence[float] = (0.0, 0.0, 0.0),
        extra_torque: Sequence[float] = (0.0, 0.0, 0.0),
        trajectory: Mapping[str, Any] | None = None,
        max_contacts: int | None = None,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        terminate_on_slip: bool = True,
        render_mode: str | None = None,
    ) -> None:
        self.shape = object_shape(object)
        contacts = default_contacts(self.shape) if contacts is None else contacts
        trajectory = {**default_trajectory(), **(trajectory or {})}
        scene = make_scene(
            self.shape, contacts, weight, mu, cg_offset, extra_force, extra_torque, trajectory
        )
        big = check_max_contacts(max_contacts, scene.n_contacts)
        super().__init__(big, k_max_ratio, terminate_on_slip, render_mode)
        self.object_scene = scene
        self._defaults = {
            "contacts": contacts, "weight": weight, "mu": mu, "cg_offset": cg_offset,
            "extra_force": extra_force, "extra_torque": extra_torque, "trajectory": trajectory,
        }  # fmt: skip
        self._default_episode = cached_episode(scene, self.k_max_ratio, big)

    def _next_episode(self, scene: ObjectScene | None) -> ObjectEpisode:
        if scene is None:
            return self._default_episode
        episode = build_episodes([scene], self.k_max_ratio, self.max_contacts)[0]
        assert episode is not None
        return episode


class ObjectGraspRandomEnv(_ObjectGraspEnv):
    __doc__ = (
        """Randomised objects: a new shape, size, contacts, load and turn every episode.

    ## Description
    As `grasp_env/ObjectGrasp-v0`, but every reset draws a scene: the shape uniformly from
    `shapes` ("box", "cylinder", "sphere", "mesh"), its sizes uniform in `size_range` metres
    (box edges; a cylinder's diameter and height; a sphere's diameter; a convex mesh's
    three axes: the hull of 12 random directions scaled by them), the contact count
    uniformly from `contact_counts`, each contact on a random face of a box, on a
    cylinder's side (70%) or a cap, anywhere on a sphere, or on a random face of a mesh
    (on a box moved from the face centre by up to `contact_offset` of the half-widths; on
    a mesh's face each corner weighs at least (1 - `contact_offset`) / its corners); the
    centre of gravity by up to `cg_offset_max` of the half-widths per axis (inside the
    shape); weight and mu uniform in their ranges; the
    trajectory as the cube's random one (a uniform axis, alpha_start and alpha_end uniform
    in their ranges, by `alpha_step_deg`). Only draws that the minimax expert holds along the
    whole trajectory (every margin >= `min_expert_margin_deg`, every certificate gap <= 1e-5
    rad) are kept, so a perfect policy completes every episode. Observations and actions are
    padded to `max_contacts` with a mask.
"""
        + _DOC_SPACES
        + """
    ## Starting State
    The first pose of a fresh draw from the environment's `np_random` (the same seed gives
    the same episodes). Draws are made ahead, a growing batch of candidates at a time (up to
    32), their expert solves batched, so most resets pop a ready episode.

    ## Arguments
    ```python
    gym.make("grasp_env/ObjectGraspRandom-v0", shapes=("box", "cylinder", "sphere", "mesh"),
             size_range=(0.05, 0.3), contact_counts=(3, 4, 5, 6), contact_offset=0.6,
             cg_offset_max=0.2, weight_range=(1.0, 10.0), mu_range=(0.4, 1.0),
             alpha_start_range_deg=(-20.0, -5.0), alpha_end_range_deg=(5.0, 20.0),
             alpha_step_deg=2.5, extra_force_max=0.0, extra_torque_max=0.0,
             min_expert_margin_deg=1.0, max_contacts=None, k_max_ratio=2.0,
             terminate_on_slip=True, render_mode=None)
    ```
    - `contact_counts`: the counts drawn from, each in [3, 8]; `max_contacts` defaults to the
      largest. Five or more contacts cost the expert's conic solver 2 to 5 ms a pose.
    - The other ranges as `grasp_env/CubeGraspRandom-v0`'s. Its defaults, except
      `contact_offset`, `mu_range` and the turn's (`grasp_env.envs.spec.OBJECT_DEFAULTS`:
      the conic solver's poses cost more, so the turns are shorter and coarser). Ranges
      that let fewer than 1 draw in 2,000 hold raise `ValueError` at reset.
"""
        + _DOC_COMMON_ARGS
        + """
    ## Version History
    - v0: initial version.
    """
    )

    def __init__(
        self,
        shapes: Sequence[str] = SHAPE_KINDS,
        size_range: tuple[float, float] = (0.05, 0.3),
        contact_counts: Sequence[int] = (3, 4, 5, 6),
        contact_offset: float = spec.OBJECT_DEFAULTS["contact_offset"],
        cg_offset_max: float = spec.CG_OFFSET_MAX.default,
        weight_range: tuple[float, float] = spec.WEIGHT_DRAWS.default,
        mu_range: tuple[float, float] = spec.OBJECT_DEFAULTS["mu_range"],
        alpha_start_range_deg: tuple[float, float] = spec.OBJECT_DEFAULTS["alpha_start_range_deg"],
        alpha_end_range_deg: tuple[float, float] = spec.OBJECT_DEFAULTS["alpha_end_range_deg"],
        alpha_step_deg: float = spec.OBJECT_DEFAULTS["alpha_step_deg"],
        extra_force_max: float = spec.EXTRA_FORCE_MAX.default,
        extra_torque_max: float = spec.EXTRA_TORQUE_MAX.default,
        min_expert_margin_deg: float = spec.MIN_EXPERT_MARGIN.default,
        max_contacts: int | None = None,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        terminate_on_slip: bool = True,
        render_mode: str | None = None,
    ) -> None:
        self.sampler = ObjectSampler(
            tuple(shapes) if isinstance(shapes, list) else shapes,
            size_range,
            tuple(contact_counts) if isinstance(contact_counts, list) else contact_counts,
            contact_offset,
            cg_offset_max,
            weight_range,
            mu_range,
            alpha_start_range_deg,
            alpha_end_range_deg,
            alpha_step_deg,
            extra_force_max,
            extra_torque_max,
        )
        self.min_expert_margin = check_margin(min_expert_margin_deg)
        largest = np.arctan(self.sampler.mu_range[1])
        if self.min_expert_margin >= largest:
            raise ValueError(
                f"min_expert_margin_deg ({min_expert_margin_deg}) must lie below the largest"
                f" friction limit atan(mu_range[1]) = {np.rad2deg(largest):.4g} deg"
            )
        big = check_max_contacts(max_contacts, self.sampler.max_contacts)
        super().__init__(big, k_max_ratio, terminate_on_slip, render_mode)
        self.shape = None  # drawn per episode; a scene option is a box's (the paper's cube)
        self._stream = EpisodeStream(self.sampler, self.k_max_ratio, self.min_expert_margin, big)
        self._defaults = {}

    def scene_option(self, options: Mapping[str, Any] | None) -> ObjectScene | None:
        """A scene option of the random env is on the current episode's shape (the unit cube
        before the first reset), missing keys from the paper's scene."""
        values = parse_options(options)
        if values is None:
            return None
        shape = self._episode.scene.shape if self._episode else object_shape("cube")
        self.shape = shape
        self._defaults = {
            "contacts": default_contacts(shape),
            "weight": DEFAULT_WEIGHT, "mu": DEFAULT_MU, "cg_offset": (0.0, 0.0, 0.0),
            "extra_force": (0.0, 0.0, 0.0), "extra_torque": (0.0, 0.0, 0.0),
            "trajectory": default_trajectory(),
        }  # fmt: skip
        return super().scene_option(options)

    def _next_episode(self, scene: ObjectScene | None) -> ObjectEpisode:
        if scene is not None:
            episode = build_episodes([scene], self.k_max_ratio, self.max_contacts)[0]
            assert episode is not None
            return episode
        return self._stream.next(self.np_random)


__all__ = ["ObjectGraspEnv", "ObjectGraspRandomEnv", "cached_episode"]
