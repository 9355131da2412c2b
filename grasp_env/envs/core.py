"""Per-episode work shared by the single and the vector environments.

An episode is a scene held along a trajectory. Everything that does not depend on the agent's
actions (the grasp geometry, the equilibrating forces, the observations and the expert's grip
at every pose) is computed once, batched over poses and episodes, when the episode starts;
a step then only forms P = F + sum k_ij e_ij (eq. 4) and the friction angles (eq. 2) with one
compiled kernel that the single and the vector environments share, so both compute the very
same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numba
import numpy as np

from ..expert import MinimaxExpert
from ..mechanics import (
    DEFAULT_MU,
    DEFAULT_WEIGHT,
    FACES,
    PAPER_FACES,
    START_ROTATION,
    Scene,
    Trajectory,
    contact_pairs,
    face_point,
)
from ._pose_kernels import pose_geometry
from .observation import ObservationLayout

#: Edge length L of the grasped cube, metres (the paper's unit cube; the observation's units).
EDGE = 1.0
_BOUNDS = {n: ObservationLayout(n).bounds() for n in (3, 4)}
SCENE_KEYS = (
    "contacts", "cg_offset", "weight", "mu", "extra_force", "extra_torque", "trajectory",
)  # fmt: skip
TRAJECTORY_KEYS = ("axis", "alpha_start_deg", "alpha_end_deg", "alpha_step_deg")


@numba.njit(cache=True)
def evaluate(forces, directions, normals, pairs, rows, actions, k_max, limit):
    """Net forces and friction angles of a batch of (pose, action) pairs.

    ``forces`` (R, n, 3) equilibrating forces, ``directions`` (R, m, 3) the unit vectors u_ij
    and ``normals`` (R, n, 3) of R stored poses; ``rows`` (B,) picks a pose per item, whose
    ``actions`` (B, m) are clipped to [-1, 1] and scaled by ``k_max`` (B,); ``limit`` (B,) is
    theta_lim. Returns (ok, k, P, theta, margin, reward); ok is False if an action is not
    finite (the outputs are then meaningless).
    """
    count = rows.shape[0]
    n = forces.shape[1]
    m = directions.shape[1]
    k = np.empty((count, m))
    net = np.empty((count, n, 3))
    theta = np.empty((count, n))
    margin = np.empty((count, n))
    reward = np.empty(count)
    ok = True
    for b in range(count):
        row = rows[b]
        for i in range(n):
            for c in range(3):
                net[b, i, c] = forces[row, i, c]
        for q in range(m):
            a = actions[b, q]
            if not math.isfinite(a):
                ok = False
            k[b, q] = min(max(a, -1.0), 1.0) * k_max[b]
            # P_i += k_ij u_ij and P_j -= k_ij u_ij: the basis e_ij of eq. 4
            i = pairs[q, 0]
            j = pairs[q, 1]
            for c in range(3):
                v = k[b, q] * directions[row, q, c]
                net[b, i, c] += v
                net[b, j, c] -= v
        worst = np.inf
        for i in range(n):
            px, py, pz = net[b, i, 0], net[b, i, 1], net[b, i, 2]
            nx, ny, nz = normals[row, i, 0], normals[row, i, 1], normals[row, i, 2]
            cx = py * nz - pz * ny
            cy = pz * nx - px * nz
            cz = px * ny - py * nx
            # eq. 2 as atan2(|P x n|, P . n), accurate near 0 where acos is not; written with
            # atan, which costs half as much as atan2 here (the step's largest cost)
            tangential = math.sqrt(cx * cx + cy * cy + cz * cz)
            normal = px * nx + py * ny + pz * nz
            if normal > 0.0:
                t = math.atan(tangential / normal)
            elif tangential > 0.0:
                t = 0.5 * math.pi + math.atan(-normal / tangential)
            else:
                t = math.pi if normal < 0.0 else 0.0
            theta[b, i] = t
            margin[b, i] = limit[b] - t
            worst = min(worst, limit[b] - t)
        reward[b] = worst
    return ok, k, net, theta, margin, reward


def _read_only(*arrays: np.ndarray) -> None:
    # Episodes are shared (between environments, through the cache): keep them unchangeable.
    for array in arrays:
        array.flags.writeable = False


_SCENE_ARRAYS = (
    "contacts", "cg_offset", "weight", "mu", "extra_force", "extra_torque",
    "axis", "alpha_start", "alpha_step", "length",
)  # fmt: skip


@dataclass(frozen=True)
class SceneBatch:
    """E scenes with their trajectories, as arrays (the unit cube, object frame).

    Trajectory e has poses alpha_start[e] + alpha_step[e] t, t < length[e] (degrees), about
    ``axis[e]`` (the same values as :attr:`grasp_env.mechanics.Trajectory.alphas_deg`).
    """

    contacts: np.ndarray  # (E, n, 3)
    cg_offset: np.ndarray  # (E, 3)
    weight: np.ndarray  # (E,)
    mu: np.ndarray  # (E,)
    extra_force: np.ndarray  # (E, 3)
    extra_torque: np.ndarray  # (E, 3)
    axis: np.ndarray  # (E, 3) unit vectors
    alpha_start: np.ndarray  # (E,) degrees
    alpha_step: np.ndarray  # (E,) degrees
    length: np.ndarray  # (E,) poses

    def __len__(self) -> int:
        return len(self.weight)

    @property
    def normals(self) -> np.ndarray:
        """Inward unit normals (E, n, 3) of the faces the contacts lie on."""
        axis = np.argmax(np.abs(self.contacts), axis=-1)[..., None]
        normals = np.zeros_like(self.contacts)
        np.put_along_axis(normals, axis, -np.sign(np.take_along_axis(self.contacts, axis, -1)), -1)
        return normals

    def alphas_deg(self, index: int) -> np.ndarray:
        """Trajectory ``index``'s alphas, degrees."""
        return self.alpha_start[index] + self.alpha_step[index] * np.arange(self.length[index])

    def take(self, index: Sequence[int] | np.ndarray) -> SceneBatch:
        index = np.asarray(index, dtype=np.intp)
        return SceneBatch(*(getattr(self, name)[index] for name in _SCENE_ARRAYS))

    @staticmethod
    def single(scene: Scene, trajectory: Trajectory) -> SceneBatch:
        return SceneBatch(
            scene.contacts[None].copy(),
            scene.cg_offset[None].copy(),
            np.array([scene.weight]),
            np.array([scene.mu]),
            scene.extra_force[None].copy(),
            scene.extra_torque[None].copy(),
            np.array([trajectory.axis]),
            np.array([float(trajectory.alpha_start_deg)]),
            np.array([float(trajectory.alpha_step_deg)]),
            np.array([len(trajectory)]),
        )

    def scene(self, index: int) -> Scene:
        """The mechanics :class:`Scene` of episode ``index``."""
        return Scene(
            contacts=self.contacts[index],
            size=EDGE,
            weight=float(self.weight[index]),
            mu=float(self.mu[index]),
            cg_offset=self.cg_offset[index],
            extra_force=self.extra_force[index],
            extra_torque=self.extra_torque[index],
        )


@dataclass(frozen=True)
class Poses:
    """World-frame data of P poses (flattened over episodes), ready for :func:`evaluate`."""

    rotations: np.ndarray  # (P, 3, 3)
    forces: np.ndarray  # (P, n, 3) equilibrating forces F_i, newtons
    directions: np.ndarray  # (P, m, 3) u_ij
    normals: np.ndarray  # (P, n, 3)
    observations: np.ndarray  # (P, size) float32
    alphas: np.ndarray  # (P,) degrees
    limit: np.ndarray  # (P,) theta_lim
    k_max: np.ndarray  # (P,)
    expert_action: np.ndarray  # (P, m) the expert's actions (float32 values)
    expert_k: np.ndarray  # (P, m)
    expert_reward: np.ndarray  # (P,)

    def take(self, rows: np.ndarray) -> Poses:
        return Poses(*(np.take(getattr(self, f.name), rows, axis=0) for f in fields(Poses)))


def build_poses(
    scenes: SceneBatch,
    episode: np.ndarray,
    step: np.ndarray,
    expert: MinimaxExpert,
    known: np.ndarray | None = None,
) -> Poses:
    """Grasp data, observations and the expert's grip at poses of the batch's trajectories.

    ``episode`` (P,) says which scene each pose belongs to and ``step`` (P,) which pose t of
    its trajectory it is; the observation's phase is t / length. ``known`` (P, m) holds the
    expert's actions where already solved (NaN elsewhere).
    """
    n = scenes.contacts.shape[1]
    pairs = contact_pairs(n)
    count = len(episode)
    alphas, limit = np.empty(count), np.empty(count)
    rotations = np.empty((count, 3, 3))
    forces, normals = np.empty((count, n, 3)), np.empty((count, n, 3))
    directions = np.empty((count, len(pairs), 3))
    observations = np.empty((count, ObservationLayout(n).size), np.float32)
    pose_geometry(
        scenes.contacts - scenes.cg_offset[:, None, :],
        scenes.normals,
        scenes.axis,
        scenes.alpha_start,
        scenes.alpha_step,
        scenes.length,
        scenes.weight,
        scenes.mu,
        scenes.extra_force,
        scenes.extra_torque,
        EDGE,
        episode,
        step,
        START_ROTATION,
        pairs,
        *_BOUNDS[n],
        alphas,
        rotations,
        forces,
        directions,
        normals,
        observations,
        limit,
    )
    weight = scenes.weight[episode]
    k_max = expert.k_max_ratio * weight
    todo = np.ones(count, bool) if known is None else np.isnan(known[:, 0])
    actions = np.zeros((count, len(pairs))) if known is None else known.copy()
    # a pose whose predecessor on the trajectory is solved just before it starts from its
    # optimum (the solver's warm start)
    follows = np.zeros(count, bool)
    follows[1:] = todo[1:] & todo[:-1] & (episode[1:] == episode[:-1]) & (step[1:] == step[:-1] + 1)
    actions[todo] = expert.actions(observations[todo], follows[todo])
    # The expert's grip scored exactly as an agent's action is (same kernel, same clipping).
    _, k, _, _, _, reward = evaluate(
        forces,
        directions,
        normals,
        pairs,
        np.arange(len(episode)),
        actions,
        k_max,
        limit,
    )
    return Poses(
        rotations,
        forces,
        directions,
        normals,
        observations,
        alphas,
        limit,
        k_max,
        actions,
        k,
        reward,
    )


@dataclass(frozen=True)
class EpisodeBatch:
    """E episodes: their scenes and the poses of all their trajectories, one after the other."""

    scenes: SceneBatch
    poses: Poses

    def __len__(self) -> int:
        return len(self.scenes)

    @property
    def starts(self) -> np.ndarray:
        """First pose row of every episode."""
        return np.cumsum(self.scenes.length) - self.scenes.length

    def worst_expert_reward(self) -> np.ndarray:
        """min over its trajectory of the expert's reward, per episode (E,)."""
        return np.minimum.reduceat(self.poses.expert_reward, self.starts)

    def take(self, index: Sequence[int] | np.ndarray) -> EpisodeBatch:
        index = np.asarray(index, dtype=np.intp)
        lengths = self.scenes.length[index]
        rows = np.repeat(self.starts[index] - np.cumsum(lengths) + lengths, lengths)
        return EpisodeBatch(self.scenes.take(index), self.poses.take(rows + np.arange(len(rows))))

    @staticmethod
    def concatenate(batches: Sequence[EpisodeBatch]) -> EpisodeBatch:
        return EpisodeBatch(
            SceneBatch(
                *(np.concatenate([getattr(b.scenes, f) for b in batches]) for f in _SCENE_ARRAYS)
            ),
            Poses(
                *(
                    np.concatenate([getattr(b.poses, f.name) for b in batches])
                    for f in fields(Poses)
                )
            ),
        )

    def final_observations(self) -> np.ndarray:
        """The observation after each episode's last step: its last pose with phase 1 (E, size)."""
        final = self.poses.observations[self.starts + self.scenes.length - 1]
        final[:, ObservationLayout(self.scenes.contacts.shape[1]).phase] = 1.0
        return final

    def episode(self, index: int) -> Episode:
        """Episode ``index`` as read-only arrays of its own."""
        start, length = int(self.starts[index]), int(self.scenes.length[index])
        part = self.poses.take(np.arange(start, start + length))
        scene = self.scenes.take([index])
        observations = np.vstack([part.observations, self.final_observations()[index : index + 1]])
        episode = Episode(
            scene,
            part.rotations,
            part.forces,
            part.directions,
            part.normals,
            observations,
            part.alphas,
            part.expert_k,
            part.expert_reward,
            limit=float(part.limit[0]),
            k_max=float(part.k_max[0]),
        )
        _read_only(*(getattr(scene, name) for name in _SCENE_ARRAYS))
        _read_only(*(getattr(episode, f.name) for f in fields(Episode)[1:-2]))
        return episode


@dataclass(frozen=True)
class Episode:
    """One episode's precomputed arrays (read-only), T poses.

    ``observations`` has T + 1 rows: row t is seen before step t, row T (the last pose with
    phase 1) after the last step.
    """

    scenes: SceneBatch  # a batch of one: the episode's scene and trajectory
    rotations: np.ndarray  # (T, 3, 3)
    forces: np.ndarray  # (T, n, 3)
    directions: np.ndarray  # (T, m, 3)
    normals: np.ndarray  # (T, n, 3)
    observations: np.ndarray  # (T + 1, size) float32
    alphas: np.ndarray  # (T,) degrees
    expert_k: np.ndarray  # (T, m)
    expert_reward: np.ndarray  # (T,)
    limit: float
    k_max: float

    def __len__(self) -> int:
        return self.rotations.shape[0]

    @property
    def scene(self) -> Scene:
        return self.scenes.scene(0)


def build_episodes(
    scenes: SceneBatch, expert: MinimaxExpert, known: np.ndarray | None = None
) -> EpisodeBatch:
    """The episodes of a batch of scenes, with every pose of every trajectory in one batch
    (``known``: the expert's actions at some of these poses, see :func:`build_poses`)."""
    lengths = scenes.length
    episode = np.repeat(np.arange(len(scenes)), lengths)
    step = np.arange(len(episode)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return EpisodeBatch(scenes, build_poses(scenes, episode, step, expert, known))


_EPISODE_CACHE: dict[tuple, Episode] = {}
_EPISODE_CACHE_SIZE = 32


def cached_episode(scenes: SceneBatch, expert: MinimaxExpert) -> Episode:
    """The episode of one scene, remembered: environments made with the same scene (every
    ``gym.make("grasp_env/CubeGrasp-v0")``) share one read-only episode."""
    key = (expert.k_max_ratio, *(getattr(scenes, name).tobytes() for name in _SCENE_ARRAYS))
    if key not in _EPISODE_CACHE:
        if len(_EPISODE_CACHE) >= _EPISODE_CACHE_SIZE:
            _EPISODE_CACHE.pop(next(iter(_EPISODE_CACHE)))
        _EPISODE_CACHE[key] = build_episodes(scenes, expert).episode(0)
    return _EPISODE_CACHE[key]


# ---------------------------------------------------------------------------- explicit scenes


def _vector(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"scene {name!r} must be numeric, got {value!r}") from error
    if array.shape != shape:
        raise ValueError(f"scene {name!r} must have shape {shape}, got {array.shape}")
    return array


def default_scene(faces: Sequence[str]) -> dict[str, Any]:
    """The paper's scene and trajectory with one face-centre contact per face in ``faces``."""
    trajectory = Trajectory()
    return {
        "contacts": np.array([face_point(f, size=EDGE) for f in faces]),
        "cg_offset": np.zeros(3),
        "weight": DEFAULT_WEIGHT,
        "mu": DEFAULT_MU,
        "extra_force": np.zeros(3),
        "extra_torque": np.zeros(3),
        "trajectory": {key: getattr(trajectory, key) for key in TRAJECTORY_KEYS},
    }


def parse_scene(spec: Mapping[str, Any] | None, defaults: Mapping[str, Any]) -> SceneBatch:
    """A validated scene from a mapping with :data:`SCENE_KEYS` (missing keys from ``defaults``).

    ``contacts`` (n, 3) are object-frame points on the faces of the unit cube centred at the
    origin, n as in ``defaults``; ``cg_offset`` lies inside the cube; ``weight`` (N) and ``mu``
    are > 0; ``extra_force`` and ``extra_torque`` (world frame, N and N m about the cg) are at
    most w and w L per component; ``trajectory`` is a mapping with :data:`TRAJECTORY_KEYS`.
    """
    spec = {} if spec is None else spec
    if not isinstance(spec, Mapping):
        raise ValueError(f"a scene must be a mapping with keys {SCENE_KEYS}, got {spec!r}")
    for key in spec:
        if key not in SCENE_KEYS:
            raise ValueError(f"unknown scene key {key!r}; the scene keys are {SCENE_KEYS}")
    merged = {**defaults, **spec}
    trajectory = merged["trajectory"]
    if not isinstance(trajectory, Mapping):
        raise ValueError(f"scene 'trajectory' must be a mapping with keys {TRAJECTORY_KEYS}")
    for key in trajectory:
        if key not in TRAJECTORY_KEYS:
            raise ValueError(
                f"unknown trajectory key {key!r}; the trajectory keys are {TRAJECTORY_KEYS}"
            )
    trajectory = Trajectory(**{**defaults["trajectory"], **trajectory})
    n = np.shape(defaults["contacts"])[0]
    weight = merged["weight"]
    if isinstance(weight, bool) or not isinstance(weight, int | float | np.number):
        raise ValueError(f"scene 'weight' must be a number, got {weight!r}")
    if isinstance(merged["mu"], bool) or not isinstance(merged["mu"], int | float | np.number):
        raise ValueError(f"scene 'mu' must be a number, got {merged['mu']!r}")
    scene = Scene(
        contacts=_vector("contacts", merged["contacts"], (n, 3)),
        size=EDGE,
        weight=float(weight),
        mu=float(merged["mu"]),
        cg_offset=_vector("cg_offset", merged["cg_offset"], (3,)),
        extra_force=_vector("extra_force", merged["extra_force"], (3,)),
        extra_torque=_vector("extra_torque", merged["extra_torque"], (3,)),
    )
    if np.any(np.abs(scene.extra_force) > scene.weight):
        raise ValueError(
            f"extra_force {scene.extra_force.tolist()} must be at most the weight"
            f" ({scene.weight}) per component"
        )
    if np.any(np.abs(scene.extra_torque) > scene.weight * EDGE):
        raise ValueError(
            f"extra_torque {scene.extra_torque.tolist()} must be at most weight x edge"
            f" ({scene.weight * EDGE}) per component"
        )
    return SceneBatch.single(scene, trajectory)


def parse_options(options: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
    """The scene mapping of ``reset(options=...)``; the only option is ``"scene"``."""
    if options is None:
        return None
    if not isinstance(options, Mapping):
        raise ValueError(f"options must be a mapping, got {options!r}")
    for key in options:
        if key != "scene":
            raise ValueError(f"unknown option {key!r}; the only option is 'scene'")
    return options.get("scene")


# --------------------------------------------------------------------------- random scenes


def _range(name: str, value: Any, low: float, high: float, *, open_low: bool = False) -> tuple:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a (low, high) pair, got {value!r}") from error
    below = lo <= low if open_low else lo < low
    if not (np.isfinite(lo) and np.isfinite(hi)) or below or hi > high or hi < lo:
        bracket = "(" if open_low else "["
        raise ValueError(
            f"{name} must satisfy low <= high within {bracket}{low}, {high}], got {value!r}"
        )
    return lo, hi


def _fraction(name: str, value: Any, high: float = 1.0, *, closed: bool = False) -> float:
    """A number in [0, high) (or [0, high] if ``closed``)."""
    interval = f"[0, {high:g}{']' if closed else ')'}"
    try:
        value = float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number in {interval}, got {value!r}") from error
    if not (0.0 <= value <= high if closed else 0.0 <= value < high):
        raise ValueError(f"{name} must be in {interval}, got {value}")
    return value


@dataclass(frozen=True)
class SceneSampler:
    """Ranges of the random scenes (see :class:`~grasp_env.envs.CubeGraspRandomEnv`)."""

    faces: tuple[str, ...] = PAPER_FACES
    contact_offset: float = 0.5
    cg_offset: float = 0.2
    weight_range: tuple[float, float] = (1.0, 10.0)
    mu_range: tuple[float, float] = (0.3, 1.0)
    alpha_start_range_deg: tuple[float, float] = (-30.0, -10.0)
    alpha_end_range_deg: tuple[float, float] = (10.0, 30.0)
    alpha_step_deg: float = 1.0
    extra_force: float = 0.0
    extra_torque: float = 0.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "faces", tuple(self.faces))
        set_(self, "contact_offset", _fraction("contact_offset", self.contact_offset))
        set_(self, "cg_offset", _fraction("cg_offset", self.cg_offset))
        set_(self, "weight_range", _range("weight_range", self.weight_range, 0, 1e6, open_low=True))
        set_(self, "mu_range", _range("mu_range", self.mu_range, 0, 1e6, open_low=True))
        set_(
            self,
            "alpha_start_range_deg",
            _range("alpha_start_range_deg", self.alpha_start_range_deg, -180, 180),
        )
        set_(
            self,
            "alpha_end_range_deg",
            _range("alpha_end_range_deg", self.alpha_end_range_deg, -180, 180),
        )
        if self.alpha_start_range_deg[1] > self.alpha_end_range_deg[0]:
            raise ValueError(
                "alpha_start_range_deg must lie below alpha_end_range_deg, got"
                f" {self.alpha_start_range_deg} and {self.alpha_end_range_deg}"
            )
        step = float(self.alpha_step_deg)
        if not (np.isfinite(step) and step > 0):
            raise ValueError(f"alpha_step_deg must be a finite number > 0, got {step}")
        set_(self, "alpha_step_deg", step)
        set_(self, "extra_force", _fraction("extra_force", self.extra_force, closed=True))
        set_(self, "extra_torque", _fraction("extra_torque", self.extra_torque, closed=True))
        if len(self.faces) not in (3, 4):
            raise ValueError(f"faces must name 3 or 4 faces, got {self.faces}")
        # Face names are validated by face_point; distinct faces keep the layout valid.
        if len(set(self.faces)) != len(self.faces):
            raise ValueError(f"faces must be distinct, got {self.faces}")
        for face in self.faces:
            face_point(face)

    @property
    def max_length(self) -> int:
        """The longest trajectory the ranges allow, in poses."""
        span = self.alpha_end_range_deg[1] - self.alpha_start_range_deg[0]
        return int(np.floor(span / self.alpha_step_deg + 1e-9)) + 1

    def raw(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """The random numbers of ``count`` scenes, (count, 2 n + 16): two calls to ``rng``,
        so that drawing for many generators is cheap; :meth:`scenes` maps them to scenes."""
        # 2 n contact offsets, then cg (3), weight, mu, alpha start and end, extra force (3)
        # and torque (3) uniform; then the axis (3) normal
        uniform = rng.random((count, 2 * len(self.faces) + 13))
        return np.concatenate([uniform, rng.standard_normal((count, 3))], axis=1)

    def scenes(self, raw: np.ndarray) -> SceneBatch:
        """The scenes of :meth:`raw` numbers (any number of rows, from any generators)."""
        count, n = raw.shape[0], len(self.faces)

        def uniform(columns: slice, low: Any, high: Any) -> np.ndarray:
            return low + (high - low) * raw[:, columns]

        offsets = uniform(slice(0, 2 * n), -self.contact_offset, self.contact_offset)
        u = raw[:, 2 * n :]
        half = EDGE / 2
        cg = (2 * u[:, 0:3] - 1) * self.cg_offset * half
        (w0, w1), (m0, m1) = self.weight_range, self.mu_range
        weight = w0 + (w1 - w0) * u[:, 3]
        mu = m0 + (m1 - m0) * u[:, 4]
        (s0, s1), (e0, e1) = self.alpha_start_range_deg, self.alpha_end_range_deg
        start = s0 + (s1 - s0) * u[:, 5]
        end = e0 + (e1 - e0) * u[:, 6]
        extra_force = (2 * u[:, 7:10] - 1) * self.extra_force * weight[:, None]
        extra_torque = (2 * u[:, 10:13] - 1) * self.extra_torque * (weight * EDGE)[:, None]
        axis = raw[:, -3:] / np.linalg.norm(raw[:, -3:], axis=1, keepdims=True)
        contacts = np.empty((count, n, 3))
        for i, face in enumerate(self.faces):
            index, sign = FACES[face]
            contacts[:, i, index] = sign * half
            contacts[:, i, [a for a in range(3) if a != index]] = (
                offsets[:, 2 * i : 2 * i + 2] * half
            )
        step = self.alpha_step_deg
        # The pose count of Trajectory.alphas_deg.
        length = np.floor((end - start) / step + 1e-9).astype(np.int64) + 1
        return SceneBatch(
            contacts,
            cg,
            weight,
            mu,
            extra_force,
            extra_torque,
            axis,
            start,
            np.full(count, step),
            length,
        )


#: Candidate scenes drawn per environment and round of :func:`sample_episodes`.
DRAWS_PER_ROUND = 2
#: Give up (the ranges admit almost no holdable scene) after this many candidates per episode.
MAX_DRAWS = 2000


def sample_episodes(
    rngs: Sequence[np.random.Generator],
    sampler: SceneSampler,
    expert: MinimaxExpert,
    min_margin: float,
) -> EpisodeBatch:
    """One random episode per generator whose expert keeps every margin >= ``min_margin``.

    Each generator draws :data:`DRAWS_PER_ROUND` candidates per round; a cheap screen solves
    the expert at the trajectory's two ends and middle, then candidates that pass are solved
    along the whole trajectory in order, the first that holds being the episode. Which scene a
    generator yields depends on that generator alone, so a vector of environments gets the
    same episodes as single environments with the same seeds; all solves are batched.
    """
    chosen: list[EpisodeBatch] = []
    owners: list[np.ndarray] = []
    pending = np.arange(len(rngs))
    rounds = 0
    while len(pending):
        rounds += 1
        if rounds * DRAWS_PER_ROUND > MAX_DRAWS:
            raise RuntimeError(
                f"no scene in {MAX_DRAWS} draws lets the expert hold the whole trajectory;"
                " widen mu_range or narrow the offset and trajectory ranges"
            )
        drafts = sampler.scenes(
            np.concatenate([sampler.raw(rngs[e], DRAWS_PER_ROUND) for e in pending])
        )
        # Screen: the two ends and the middle of every candidate's trajectory.
        last = drafts.length - 1
        picks = np.stack([np.zeros_like(last), last // 2 + last % 2, last], axis=1)
        screen = build_poses(drafts, np.repeat(np.arange(len(drafts)), 3), picks.ravel(), expert)
        screened = screen.expert_action.reshape(len(drafts), 3, -1)
        passed = (
            screen.expert_reward.reshape(len(pending), DRAWS_PER_ROUND, 3).min(-1) >= min_margin
        )
        open_ = np.ones(len(pending), bool)
        for d in range(DRAWS_PER_ROUND):  # candidates in their draw order
            slots = np.flatnonzero(open_ & passed[:, d])
            if len(slots) == 0:
                continue
            candidates = slots * DRAWS_PER_ROUND + d
            scenes = drafts.take(candidates)
            # The screened poses are solved already (the expert ignores the phase).
            m = screened.shape[2]
            known = np.full((scenes.length.sum(), m), np.nan)
            starts = np.cumsum(scenes.length) - scenes.length
            known[(starts[:, None] + picks[candidates]).ravel()] = screened[candidates].reshape(
                -1, m
            )
            full = build_episodes(scenes, expert, known)
            holds = full.worst_expert_reward() >= min_margin
            chosen.append(full.take(np.flatnonzero(holds)))
            owners.append(pending[slots[holds]])
            open_[slots[holds]] = False
        pending = pending[open_]
    batch = EpisodeBatch.concatenate(chosen)
    return batch.take(np.argsort(np.concatenate(owners)))


def check_margin(value: Any) -> float:
    """``min_expert_margin_deg`` in [0, 45) degrees, returned in radians."""
    return float(np.deg2rad(_fraction("min_expert_margin_deg", value, 45.0)))


def check_k_max_ratio(value: Any) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"k_max_ratio must be a finite number > 0, got {value!r}") from error
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"k_max_ratio must be a finite number > 0, got {value}")
    return value


__all__ = [
    "EDGE",
    "SCENE_KEYS",
    "TRAJECTORY_KEYS",
    "Episode",
    "EpisodeBatch",
    "SceneBatch",
    "SceneSampler",
    "build_episodes",
    "cached_episode",
    "default_scene",
    "evaluate",
    "parse_options",
    "parse_scene",
    "sample_episodes",
]
