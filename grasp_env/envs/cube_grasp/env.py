"""The single grasp environments: the paper's trajectory and randomised grasps."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ...mechanics import FOUR_FINGER_FACES, PAPER_FACES, Scene, contact_pairs, n_pairs
from .. import spec
from ..kernels import step_grip
from ..observation import ObservationLayout
from ..validation import (
    DEFAULT_K_MAX_RATIO,
    action_array,
    check_bool,
    check_k_max_ratio,
    check_margin,
    check_mujoco_k_max_ratio,
    check_seed,
)
from .episodes import Episode, EpisodeStream, build_episodes, cached_episode
from .scenes import (
    SceneBatch,
    SceneSampler,
    check_faces,
    check_mujoco_scene,
    default_scene,
    mujoco_fits,
    parse_options,
    parse_scene,
)

PHYSICS_ENGINES = (None, "mujoco")
#: A random environment checked in MuJoCo draws at most this many holdable scenes for an
#: episode, keeping the first whose every grip in the action box the MuJoCo contact carries
#: (the others, rare and only with wide ranges, would fail MuJoCo's force check at a step).
MUJOCO_DRAWS = 100


def mujoco_draws_error(k_max_ratio: float) -> ValueError:
    """The error of a random MuJoCo environment whose :data:`MUJOCO_DRAWS` draws all failed."""
    return ValueError(
        f"fewer than 1 in {MUJOCO_DRAWS} holdable random scenes keeps every finger's force,"
        " under every grip in the action box, within what the MuJoCo contact carries"
        f" (k_max_ratio {k_max_ratio:g}): narrow contact_offset, cg_offset_max and the extra"
        " load, or lower k_max_ratio"
    )


def check_physics(physics: str | None, render_mode: str | None, modes: Sequence[str]) -> None:
    if not (physics is None or (isinstance(physics, str) and physics in PHYSICS_ENGINES)):
        raise ValueError(f"physics must be one of {PHYSICS_ENGINES}, got {physics!r}")
    if not (render_mode is None or (isinstance(render_mode, str) and render_mode in modes)):
        raise ValueError(f"render_mode must be None or one of {list(modes)}, got {render_mode!r}")


def physics_info(report: dict[str, Any]) -> dict[str, Any]:
    """A pose check's report as ``info["physics"]``: its per-finger lists as arrays, so that
    Gymnasium's SyncVectorEnv batches them to (N, n) arrays, as the MuJoCo vector env does."""
    return {key: np.asarray(v) if isinstance(v, list) else v for key, v in report.items()}


class _CubeGraspEnv(gym.Env[np.ndarray, np.ndarray]):
    """What the fixed and the random environments share: spaces, step, physics and rendering."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(
        self,
        faces: Sequence[str],
        k_max_ratio: float,
        terminate_on_slip: bool,
        physics: str | None,
        render_mode: str | None,
    ) -> None:
        check_physics(physics, render_mode, self.metadata["render_modes"])
        self.faces = check_faces(faces)
        self.k_max_ratio = check_k_max_ratio(k_max_ratio)
        if physics is not None:
            check_mujoco_k_max_ratio(k_max_ratio)
        self.terminate_on_slip = check_bool("terminate_on_slip", terminate_on_slip)
        self.physics = physics
        self.render_mode = render_mode
        n = len(self.faces)
        self.layout = ObservationLayout(n)
        low, high = self.layout.bounds()
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (n_pairs(n),), dtype=np.float32)
        self._pairs = contact_pairs(n)
        self._unit = np.empty((n, 3))  # the step kernel's scratch
        self._episode: Episode | None = None
        self._step = 0
        self._done = True
        self._last_forces: np.ndarray | None = None
        self._checker: Any = None
        self._grips: list[np.ndarray] = []  # the forces of this episode's steps (physics)
        self._view: Any = None
        self._world_episode: Episode | None = None  # what the checker and view show

    # -- the episode ---------------------------------------------------------------------------

    def _next_episode(self, scene: SceneBatch | None) -> Episode:
        raise NotImplementedError

    def scene_option(self, options: Mapping[str, Any] | None) -> SceneBatch | None:
        """The validated scene of ``reset(options=...)`` (None without one): a ValueError for
        options that the reset refuses."""
        scene = parse_options(options)
        return None if scene is None else self.scene_batch(scene)

    def scene_batch(self, scene: Mapping[str, Any]) -> SceneBatch:
        """The validated scene of a ``reset(options={"scene": scene})`` (with physics, one
        whose every grip in the action box the MuJoCo contact carries)."""
        batch = parse_scene(scene, self._defaults)
        if self.physics is not None:
            check_mujoco_scene("reset option 'scene'", batch, self.k_max_ratio)
        return batch

    @property
    def episode(self) -> Episode:
        """The current episode's precomputed arrays (after :meth:`reset`)."""
        if self._episode is None:
            raise RuntimeError("call reset() first")
        return self._episode

    @property
    def scene(self) -> Scene:
        """The current episode's :class:`~grasp_env.mechanics.Scene`."""
        return self.episode.scene

    @property
    def alphas_deg(self) -> np.ndarray:
        """The current trajectory's alpha values, degrees."""
        return self.episode.alphas

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        # Everything that can refuse the call is checked before seeding: a refused reset
        # changes nothing (neither the generator nor the running episode).
        seed = check_seed("seed", seed)
        scene = self.scene_option(options)
        super().reset(seed=seed)
        episode = self._next_episode(scene)
        self._episode = episode
        self._step = 0
        self._done = False
        self._last_forces = None
        self._grips = []
        if self.physics is not None or self.render_mode is not None:
            self._update_world()
        if self.render_mode == "human":
            self.render()
        return episode.observations[0].copy(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply the grip k = clip(action, -1, 1) x k_max at the current pose, then move on."""
        if self._done:
            raise RuntimeError("the episode has ended (or not started): call reset()")
        episode = self._episode
        assert episode is not None
        a = action_array(action, self.action_space.shape)
        t = self._step
        n, m = len(self.faces), len(self._pairs)
        k, forces, theta, margin = np.empty(m), np.empty((n, 3)), np.empty(n), np.empty(n)
        finite, reward = step_grip(
            episode.forces_w, episode.directions, episode.normals, self._pairs, t, a,
            self.k_max_ratio, episode.weight, episode.limit, k, forces, theta, margin, self._unit,
        )  # fmt: skip
        if not finite:
            raise ValueError(f"action must be finite, got {a.tolist()}")
        expert_reward = float(episode.expert_reward[t])
        info = {
            "alpha_deg": float(episode.alphas[t]),
            "theta": theta,
            "margin": margin,
            "k": k,
            "contact_forces": forces,
            "equilibrating_forces": episode.forces[t].copy(),  # users keep infos: new arrays
            "expert_k": episode.expert_k[t].copy(),
            "expert_reward": expert_reward,
            "optimality_gap": expert_reward - reward,
            "slip": margin < 0.0,  # theta_i > theta_lim, as the vector env computes it
        }
        terminated = self.terminate_on_slip and reward < 0.0
        if self._checker is not None:
            report = self._checker.check(episode.rotations[t], forces)
            info["physics"] = physics_info(report.as_dict())
            terminated = self.terminate_on_slip and not report.holds
            self._grips.append(forces.copy())  # info's forces are the user's to change
        self._step = t + 1
        truncated = self._step == len(episode)
        self._done = terminated or truncated
        if self._done and self._checker is not None:
            info["physics_trajectory"] = self._trajectory_report()
        self._last_forces = forces
        if self.render_mode == "human":
            self.render()
        return episode.observations[t + 1].copy(), reward, terminated, truncated, info

    # -- physics and rendering (grasp_env.physics, imported only when asked for) ----------------

    def _trajectory_report(self) -> dict[str, Any]:
        """The episode's grips carried through its poses in one continuous MuJoCo rollout
        (:class:`grasp_env.physics.TrajectoryChecker`), as plain values: a grip that holds at
        every pose checked on its own may still slip on the way between poses."""
        from ...physics import check_trajectories

        episode = self.episode
        grips = np.stack(self._grips)
        case = (self._checker.scene, episode.rotations[: len(grips)], grips, None)
        return check_trajectories([case], threads=1)[0].as_dict()

    def _update_world(self) -> None:
        """Build the MuJoCo checker for a new scene (the view waits for a render()); reset the
        checker every episode."""
        episode = self.episode
        if self._world_episode is None or self._world_episode.scenes is not episode.scenes:
            if self._checker is not None:
                self._checker.close()
            if self.physics == "mujoco":
                from ...physics import StabilityChecker

                self._checker = StabilityChecker(episode.scene)
            if self._view is not None:  # the next render() draws the new scene
                self._view.close()
                self._view = None
            self._world_episode = episode
        if self._checker is not None:
            self._checker.reset()

    def render(self) -> np.ndarray | None:
        """An RGB frame (H, W, 3) uint8 for ``render_mode="rgb_array"``; a window for "human"."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to make()")
            return None
        episode = self.episode
        if self._view is None:  # built on the first render() of a scene, not at its reset
            from ...physics import GraspView

            self._view = GraspView(episode.scene, render_mode=self.render_mode)
        pose = min(self._step, len(episode)) - 1 if self._last_forces is not None else 0
        forces = episode.forces[0] if self._last_forces is None else self._last_forces
        return self._view.render(episode.rotations[pose], forces)

    def close(self) -> None:
        if self._view is not None:
            self._view.close()
            self._view = None
        if self._checker is not None:
            self._checker.close()
            self._checker = None
        self._world_episode = None
        super().close()

    def __getstate__(self) -> dict[str, Any]:
        # The MuJoCo checker and view hold native resources: not pickled, rebuilt on loading.
        state = self.__dict__.copy()
        state.update(_checker=None, _view=None, _world_episode=None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if self._episode is not None and (self.physics is not None or self.render_mode):
            self._update_world()


_DOC_SPACES = """
    ## Action Space
    `Box(-1, 1, (m,), float32)`, m = n (n - 1) / 2 interaction scalars, one per finger pair in
    the order (1, 2), (1, 3), (2, 3) for three fingers and (1, 2), (1, 3), (1, 4), (2, 3),
    (2, 4), (3, 4) for four (`grasp_env.mechanics.contact_pairs`). The grip is
    k_ij = a_ij x k_max with k_max = `k_max_ratio` x w; k_ij > 0 squeezes the pair together
    (paper eq. 4). Actions outside [-1, 1] are clipped; a wrong shape or a non-finite entry
    raises `ValueError`.

    ## Observation Space
    `Box(low, high, (14 + 6n,), float32)` in the world frame, scale-free (forces in units of
    the weight w, lengths in units of the edge L = 1 m):

    | index          | observation                                      | bounds          |
    |----------------|--------------------------------------------------|-----------------|
    | 0-5            | first two columns of the orientation R           | [-1, 1]         |
    | 6 to 5+3n      | contact positions R (c_i - g) / L                | [-√3, √3]       |
    | 6+3n to 5+6n   | inward contact normals R nu_i                    | [-1, 1]         |
    | 6+6n to 8+6n   | load force (0, 0, -1) + f_d / w                  | x, y [-1, 1]; z [-2, 0] |
    | 9+6n to 11+6n  | extra load torque tau_d / (w L)                  | [-1, 1]         |
    | 12+6n          | friction limit theta_lim = atan(mu), radians     | [0, pi/2]       |
    | 13+6n          | phase: steps taken / trajectory length           | [0, 1]          |

    This is everything the minimax expert needs (`grasp_env.MinimaxExpert` acts from it alone).

    ## Rewards
    min_i (theta_lim - theta_i), radians, where theta_i is finger i's friction angle (eq. 2)
    under the net force P = F + sum k_ij e_ij (eq. 4): positive while every finger is inside
    its friction cone, and at most theta_lim (all forces along the normals).

    ## Episode End
    - Termination: a finger slips, theta_i > theta_lim (with `terminate_on_slip=True`; with
      `physics="mujoco"`, when the MuJoCo check reports that the grasp does not hold).
    - Truncation: after the last pose of the trajectory.

    ## Info
    `alpha_deg` (the pose), `theta` (n,) and `margin` (n,) radians, `k` (m,) newtons,
    `contact_forces` (n, 3) and `equilibrating_forces` (n, 3) world-frame forces on the object,
    newtons (everything is computed in units of w, then multiplied by w), `expert_k` (m,)
    newtons and `expert_reward`: the minimax optimum of this exact pose, certified (the
    solver's gap is at most 1e-9 rad), solved in float64 when the episode starts, so that no
    action earns more than `expert_reward` beyond rounding (where no grip in the box keeps
    every finger pushing, `expert_reward` is the certified bound theta_lim - 90 deg);
    `optimality_gap` = expert_reward - reward >= 0; `slip` (n,) bool; with
    `physics="mujoco"` also `physics`, the MuJoCo check of this step's forces at its pose
    (`PhysicsReport.as_dict()`, per-finger lists as arrays: `holds`, `slip`, `contact_lost`,
    `released`, `drift`, `rotation_deg`, `time`), and at the episode's last step (terminated,
    or truncated at the trajectory's end; a `TimeLimit` wrapper cuts from outside, unseen)
    `physics_trajectory`, the grips of all its steps carried through its poses in one
    continuous MuJoCo rollout (`RolloutReport.as_dict()`: `holds`, `predicted_holds`,
    `pose_holds`, `pose_predicted`, `max_angle_deg`, `margin_deg`, `slip`, `drift`,
    `rotation_deg`, `first_failure`, `predicted_first_failure`, `time`, `diverged`; plain
    Python values).
    `MinimaxExpert.predict`
    solves the same problem from the float32 observation: its reward is up to about 1e-6 rad
    below `expert_reward`.

    ## Accepted inputs
    Numbers are real numbers (booleans, complex numbers, strings are refused, not converted),
    flags are booleans; anything else raises `ValueError` naming the input and its range:
    weight in [1e-6, 1e6] N, mu in [1e-3, 1e3], `k_max_ratio` in [1e-3, 1e3], alphas in
    [-180, 180] deg, at most 10,000 poses per trajectory (docs/environments.md has them all).
"""

_DOC_COMMON_ARGS = """\
    - `k_max_ratio` (default 2, in [1e-3, 1e3]): k_max / w, the largest grip an action can
      command.
    - `terminate_on_slip` (default True): end the episode when a finger slips.
    - `physics` (default None): "mujoco" checks every step's forces in MuJoCo
      (`grasp_env.physics.StabilityChecker`, a few ms a step) and terminates on its verdict;
      at the episode's end it carries the episode's grips through one continuous rollout
      (`grasp_env.physics.TrajectoryChecker`, `info["physics_trajectory"]`); `k_max_ratio`
      is then at most 40 (MuJoCo's contact carries at most 150 w a finger faithfully), and
      a scene in which some grip of the action box would press a finger harder is refused
      (`ValueError`) or, if drawn at random, drawn again.
    - `render_mode`: None, "rgb_array" or "human" (MuJoCo view of the grasp).
"""


class CubeGraspEnv(_CubeGraspEnv):
    __doc__ = (
        """The paper's grasp: hold a cube along a quasi-static turn with the least friction angles.

    ## Description
    A unit cube (L = 1 m, weight w = 5 N) is held by point contacts with Coulomb friction at
    the centres of the faces meeting at its corner (-1/2, -1/2, -1/2) (Suhaib, Khan and
    Mukherjee, "Contact Force Optimization for Stable Grasp of Multifingered Robotic
    Grippers"). The cube turns from alpha = -15 deg to +15 deg in 1 deg steps (31 poses) about
    a = (1, -1, 0)/√2 from the pose with its body diagonal vertical (eq. 5). At every pose the
    agent chooses the interaction forces k_ij that the fingers add to the equilibrating forces;
    the best grip minimises the largest friction angle. In this scene the normals meet at the
    centre of gravity, so the optimum is 0 deg at every pose: the minimax expert earns
    theta_lim at each step. The default friction coefficient is mu = 0.5
    (theta_lim = 26.57 deg).

    `grasp_env/CubeGrasp4-v0` adds a fourth finger at the centre of the top face (+z), pressing
    down opposite the bottom finger: n = 4 contacts and m = 6 interaction scalars.
"""
        + _DOC_SPACES
        + """
    ## Starting State
    The first pose of the trajectory (alpha = -15 deg); nothing is random. `reset(options=
    {"scene": {...}})` sets another scene for that episode: `contacts` ((n, 3) object-frame
    points on the faces of the cube centred at the origin), `cg_offset` (3,), `weight` (N),
    `mu`, `extra_force` and `extra_torque` (world frame, at most w and w L per component) and
    `trajectory` (`axis`, `alpha_start_deg`, `alpha_end_deg`, `alpha_step_deg`); missing keys
    keep the environment's values, unknown keys raise `ValueError`.

    ## Arguments
    ```python
    gym.make("grasp_env/CubeGrasp-v0", scene=None, faces=("-x", "-y", "-z"), k_max_ratio=2.0,
             terminate_on_slip=True, physics=None, render_mode=None)
    ```
    - `scene` (default None, the paper's): the environment's scene, a mapping with the keys of
      the `scene` reset option.
    - `faces` (default ("-x", "-y", "-z")): one face-centre contact per named face;
      `grasp_env/CubeGrasp4-v0` uses ("-x", "-y", "-z", "+z").
"""
        + _DOC_COMMON_ARGS
        + """
    ## Version History
    - v0 (0.2.0): rewards computed in units of w (the same for any weight); `expert_reward`
      the certified optimum of the exact pose; inputs outside the documented ranges refused.
    - v0: initial version.
    """
    )

    def __init__(
        self,
        scene: Mapping[str, Any] | None = None,
        faces: Sequence[str] = PAPER_FACES,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        terminate_on_slip: bool = True,
        physics: str | None = None,
        render_mode: str | None = None,
    ) -> None:
        super().__init__(faces, k_max_ratio, terminate_on_slip, physics, render_mode)
        base = default_scene(self.faces)
        scenes = parse_scene(scene, base)
        if self.physics is not None:
            check_mujoco_scene("scene", scenes, self.k_max_ratio)
        self._default_episode = cached_episode(scenes, self.k_max_ratio)
        # Reset options fill missing keys from the environment's own scene.
        scene = dict(scene or {})
        self._defaults = {
            **base,
            **scene,
            "trajectory": {**base["trajectory"], **scene.get("trajectory", {})},
        }

    def _next_episode(self, scene: SceneBatch | None) -> Episode:
        if scene is None:
            return self._default_episode
        return build_episodes(scene, self.k_max_ratio).episode(0)


class CubeGraspRandomEnv(_CubeGraspEnv):
    __doc__ = (
        """Randomised grasps: a new scene and trajectory every episode, always holdable.

    ## Description
    As `grasp_env/CubeGrasp-v0`, but every reset draws a scene: each contact moves from its
    face centre by up to `contact_offset` of the half-width along both in-plane axes, the
    centre of gravity moves by up to `cg_offset_max` of the half-width along each axis, the weight
    and mu are uniform in their ranges, the trajectory turns about a uniformly random axis from
    the start pose (body diagonal vertical), from alpha_start to alpha_end (uniform in their
    ranges) by `alpha_step_deg`; optionally an extra load force and torque are drawn. Only
    draws in which the minimax expert keeps every finger at least `min_expert_margin_deg`
    inside its friction cone along the whole trajectory are kept, so a perfect policy always
    completes the episode. Away from the paper's symmetric layout the optimum is typically
    5 to 40 deg.
"""
        + _DOC_SPACES
        + """
    ## Starting State
    The first pose of a freshly drawn scene and trajectory (from the environment's
    `np_random`: the same seed gives the same episode). `reset(options={"scene": {...}})`
    sets the scene for that episode instead, as in `grasp_env/CubeGrasp-v0` (missing keys take
    the paper's values); such a scene is not checked for holdability.

    ## Arguments
    ```python
    gym.make("grasp_env/CubeGraspRandom-v0", faces=("-x", "-y", "-z"), contact_offset=0.5,
             cg_offset_max=0.2, weight_range=(1.0, 10.0), mu_range=(0.3, 1.0),
             alpha_start_range_deg=(-30.0, -10.0), alpha_end_range_deg=(10.0, 30.0),
             alpha_step_deg=1.0, extra_force_max=0.0, extra_torque_max=0.0,
             min_expert_margin_deg=1.0,
             k_max_ratio=2.0, terminate_on_slip=True, physics=None, render_mode=None)
    ```
    - `faces`: one contact per named face, 3 or 4 faces.
    - `contact_offset`, `cg_offset_max` in [0, 1): largest offsets as fractions of the half-width.
    - `weight_range` (N, within [1e-6, 1e6]), `mu_range` (within [1e-3, 1e3]): uniform ranges.
    - `alpha_start_range_deg`, `alpha_end_range_deg`: uniform ranges of the trajectory's
      first and last alpha within [-180, 180] (the first lying below the second),
      `alpha_step_deg` its step (at most 10,000 poses).
    - `extra_force_max`, `extra_torque_max` in [0, 1]: each component of an extra load force
      (torque) is uniform within this fraction of w (of w L); 0 draws none.
    - `min_expert_margin_deg` in [0, 45), below atan(mu_range[1]): the margin the expert must
      keep at every pose. Ranges that let fewer than 1 draw in 2,000 hold raise `ValueError`
      at reset.
"""
        + _DOC_COMMON_ARGS
        + """
    ## Version History
    - v0 (0.2.0): rewards computed in units of w (the same for any weight); `expert_reward`
      the certified optimum of the exact pose; inputs outside the documented ranges refused.
    - v0: initial version.
    """
    )

    def __init__(
        self,
        faces: Sequence[str] = PAPER_FACES,
        contact_offset: float = spec.CONTACT_OFFSET.default,
        cg_offset_max: float = spec.CG_OFFSET_MAX.default,
        weight_range: tuple[float, float] = spec.WEIGHT_DRAWS.default,
        mu_range: tuple[float, float] = spec.MU_DRAWS.default,
        alpha_start_range_deg: tuple[float, float] = spec.ALPHA_START_DRAWS.default,
        alpha_end_range_deg: tuple[float, float] = spec.ALPHA_END_DRAWS.default,
        alpha_step_deg: float = spec.ALPHA_STEP.default,
        extra_force_max: float = spec.EXTRA_FORCE_MAX.default,
        extra_torque_max: float = spec.EXTRA_TORQUE_MAX.default,
        min_expert_margin_deg: float = spec.MIN_EXPERT_MARGIN.default,
        k_max_ratio: float = DEFAULT_K_MAX_RATIO,
        terminate_on_slip: bool = True,
        physics: str | None = None,
        render_mode: str | None = None,
    ) -> None:
        self.sampler = SceneSampler(
            faces,
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
                f" friction limit atan(mu_range[1]) = {np.rad2deg(largest):.4g} deg: no grip"
                " keeps a larger margin"
            )
        super().__init__(self.sampler.faces, k_max_ratio, terminate_on_slip, physics, render_mode)
        self._defaults = default_scene(self.faces)
        # the episodes of np_random, drawn ahead (a new np_random, as a reseed makes, restarts it)
        self._stream = EpisodeStream(self.sampler, self.k_max_ratio, self.min_expert_margin)

    def _next_episode(self, scene: SceneBatch | None) -> Episode:
        if scene is not None:
            return build_episodes(scene, self.k_max_ratio).episode(0)
        # With physics a drawn scene must fit the MuJoCo contact as an explicit one must; the
        # vector env draws again from the same generator, so it gets the same episodes.
        for _ in range(MUJOCO_DRAWS):
            episode = self._stream.next(self.np_random)
            if self.physics is None or mujoco_fits(episode.scenes, self.k_max_ratio)[0]:
                return episode
        raise mujoco_draws_error(self.k_max_ratio)


__all__ = ["FOUR_FINGER_FACES", "CubeGraspEnv", "CubeGraspRandomEnv"]
