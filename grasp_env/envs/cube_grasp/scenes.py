"""Scenes and their trajectories as batched arrays: explicit scenes (parsed from a mapping)
and random ones (drawn by a :class:`SceneSampler`)."""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...mechanics import (
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
from .. import spec
from ..kernels import evaluate_grips, pose_geometry
from ..observation import ObservationLayout
from ..validation import (
    MU_RANGE,
    TRAJECTORY_KEYS,
    WEIGHT_RANGE,
    check_array,
    check_number,
    check_pose_count,
    check_trajectory,
)

#: Edge length L of the grasped cube, metres (the paper's unit cube; the observation's units).
EDGE = 1.0
SCENE_KEYS = (
    "contacts", "cg_offset", "weight", "mu", "extra_force", "extra_torque", "trajectory",
)  # fmt: skip

SCENE_ARRAYS = (
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
        return SceneBatch(*(getattr(self, name)[index] for name in SCENE_ARRAYS))

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


# ---------------------------------------------------------------------------- explicit scenes


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


def check_faces(faces: Any) -> tuple[str, ...]:
    """3 or 4 distinct face names ("-x", "+z", ...): the fingers' faces, in order."""
    if isinstance(faces, str) or not isinstance(faces, Sequence | np.ndarray):
        raise ValueError(f"faces must be a sequence of 3 or 4 face names such as"
                         f" ('-x', '-y', '-z'), got {faces!r}")  # fmt: skip
    faces = tuple(faces)
    for face in faces:
        if not isinstance(face, str) or face not in FACES:
            raise ValueError(f"unknown face {face!r}; the faces are {tuple(FACES)}")
    if len(faces) not in (3, 4) or len(set(faces)) != len(faces):
        raise ValueError(f"faces must name 3 or 4 distinct faces, got {faces}")
    return faces


def parse_scene(spec: Mapping[str, Any] | None, defaults: Mapping[str, Any]) -> SceneBatch:
    """A validated scene from a mapping with :data:`SCENE_KEYS` (missing keys from ``defaults``).

    ``contacts`` (n, 3) are object-frame points on the faces of the unit cube centred at the
    origin, n as in ``defaults``; ``cg_offset`` lies inside the cube; ``weight`` (N) and ``mu``
    lie in :data:`~grasp_env.envs.validation.WEIGHT_RANGE` and
    :data:`~grasp_env.envs.validation.MU_RANGE`; ``extra_force`` and ``extra_torque`` (world
    frame, N and N m about the cg) are at most w and w L per component; ``trajectory`` is a
    mapping with :data:`TRAJECTORY_KEYS` (see :func:`check_trajectory`).
    """
    spec = {} if spec is None else spec
    if not isinstance(spec, Mapping):
        raise ValueError(f"a scene must be a mapping with keys {SCENE_KEYS}, got {spec!r}")
    for key in spec:
        if key not in SCENE_KEYS:
            raise ValueError(f"unknown scene key {key!r}; the scene keys are {SCENE_KEYS}")
    merged = {**defaults, **spec}
    if not isinstance(merged["trajectory"], Mapping):
        raise ValueError(f"scene 'trajectory' must be a mapping with keys {TRAJECTORY_KEYS}")
    trajectory = check_trajectory({**defaults["trajectory"], **merged["trajectory"]})
    n = np.shape(defaults["contacts"])[0]
    weight = check_number("scene 'weight'", merged["weight"], *WEIGHT_RANGE)
    scene = Scene(
        contacts=check_array("scene 'contacts'", merged["contacts"], (n, 3)),
        size=EDGE,
        weight=weight,
        mu=check_number("scene 'mu'", merged["mu"], *MU_RANGE),
        cg_offset=check_array("scene 'cg_offset'", merged["cg_offset"], (3,)),
        extra_force=check_array("scene 'extra_force'", merged["extra_force"], (3,)),
        extra_torque=check_array("scene 'extra_torque'", merged["extra_torque"], (3,)),
    )
    if np.any(np.abs(scene.extra_force) > weight):
        raise ValueError(
            f"scene 'extra_force' {scene.extra_force.tolist()} must be at most the weight"
            f" ({weight}) per component"
        )
    if np.any(np.abs(scene.extra_torque) > weight * EDGE):
        raise ValueError(
            f"scene 'extra_torque' {scene.extra_torque.tolist()} must be at most weight x edge"
            f" ({weight * EDGE}) per component"
        )
    if not load_ok(np.array([weight]), scene.extra_force[None], scene.extra_torque[None])[0]:
        raise ValueError(
            f"scene 'extra_force' {scene.extra_force.tolist()} and 'extra_torque'"
            f" {scene.extra_torque.tolist()} nearly cancel the weight ({weight}): the net load"
            f" must be zero or at least {MIN_LOAD:g} w (w L for the torque) in some component"
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


#: The smallest net load accepted besides none at all, in units of w (and w L for the torque):
#: a load that nearly cancels the weight leaves equilibrating forces too small beside k_max
#: for the solver's certificate (it accepts k_max up to 1e12 times the largest of them).
MIN_LOAD = 1e-6


def load_ok(weight: np.ndarray, extra_force: np.ndarray, extra_torque: np.ndarray) -> np.ndarray:
    """(E,) bool: the net load f = (0, 0, -w) + f_d, tau_d is zero or at least
    :data:`MIN_LOAD` (largest component, in units of w and w L)."""
    force = np.array(extra_force, dtype=float) / weight[:, None]
    force[:, 2] -= 1.0
    size = np.maximum(np.abs(force).max(-1), np.abs(extra_torque).max(-1) / (weight * EDGE))
    return (size == 0.0) | (size >= MIN_LOAD)


def layout_ok(contacts: np.ndarray) -> np.ndarray:
    """(E,) bool: contact layouts (E, n, 3) on the unit cube that
    :class:`~grasp_env.mechanics.Scene` accepts: no two contacts within 1e-6 L, three not
    collinear (area 1e-6 L^2), four not coplanar (volume 1e-6 L^3)."""
    n = contacts.shape[1]
    i, j = np.triu_indices(n, 1)
    apart = np.all(np.linalg.norm(contacts[:, i] - contacts[:, j], axis=-1) > 1e-6 * EDGE, axis=1)
    d = contacts[:, 1:] - contacts[:, :1]
    if n == 3:
        spread = np.linalg.norm(np.cross(d[:, 0], d[:, 1]), axis=-1) > 1e-6 * EDGE**2
    else:
        spread = np.abs(np.linalg.det(d)) > 1e-6 * EDGE**3
    return apart & spread


# ----------------------------------------------------------- what the MuJoCo contact carries


def pose_arrays(scenes: SceneBatch, index: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The world-frame arrays of every pose of trajectories ``index`` (default: all) of
    ``scenes``, one trajectory after the other, by the kernel that builds the episodes (so bit
    for bit theirs): ``rotations`` (P, 3, 3), equilibrating ``forces`` F_i / w and ``normals``
    (P, n, 3), ``directions`` u_ij (P, m, 3), ``limit`` and ``weight`` (P,)."""
    index = np.arange(len(scenes)) if index is None else np.asarray(index)
    lengths = scenes.length[index]
    episode = np.repeat(index, lengths)
    step = np.arange(len(episode)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    count, n = len(episode), scenes.contacts.shape[1]
    pairs = contact_pairs(n)
    layout = ObservationLayout(n)
    out = {
        "rotations": np.empty((count, 3, 3)),
        "forces": np.empty((count, n, 3)),
        "directions": np.empty((count, len(pairs), 3)),
        "normals": np.empty((count, n, 3)),
        "limit": np.empty(count),
    }
    pose_geometry(
        scenes.contacts - scenes.cg_offset[:, None, :], scenes.normals, scenes.axis,
        scenes.alpha_start, scenes.alpha_step, scenes.length, scenes.weight, scenes.mu,
        scenes.extra_force, scenes.extra_torque, EDGE, episode, step, START_ROTATION, pairs,
        *layout.bounds(), np.empty(count), out["rotations"], np.empty((count, n, 3)),
        out["forces"], out["directions"], out["normals"],
        np.empty((count, layout.size), np.float32), out["limit"],
    )  # fmt: skip
    return {**out, "weight": scenes.weight[episode]}


def grip_forces(scenes: SceneBatch, k_max_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """At every pose of the batch's trajectories (one after the other, P poses): each finger's
    largest force over the action box, max |F_i + sum_j k_ij e_ij| / w over |k_ij| <= k_max,
    and its equilibrating force |F_i| / w, both (P, n).

    The force is convex in the grip, so its largest is at a corner of the box. The corners are
    stepped by the step's own kernel, so that these are the very numbers that a step's MuJoCo
    check (``grasp_env.physics.motion``) compares with what the contact carries.
    """
    poses = pose_arrays(scenes)
    forces, weight = poses["forces"], poses["weight"]
    count, n = forces.shape[:2]
    pairs = contact_pairs(n)
    rows = np.arange(count)
    largest = np.zeros((count, n))
    for corner in itertools.product((-1.0, 1.0), repeat=len(pairs)):
        _, _, net, *_ = evaluate_grips(
            forces, poses["directions"], poses["normals"], pairs, rows,
            np.tile(corner, (count, 1)), k_max_ratio, weight, poses["limit"],
        )  # fmt: skip
        # newtons over w, as the MuJoCo check divides them
        np.maximum(largest, np.linalg.norm(net, axis=-1) / weight[:, None], out=largest)
    return largest, np.linalg.norm(forces, axis=-1)


def _mujoco_max_force() -> float:
    from ...physics.model import MAX_FORCE  # imported only by the MuJoCo environments

    return MAX_FORCE


def mujoco_fits(scenes: SceneBatch, k_max_ratio: float) -> np.ndarray:
    """(E,) bool: every grip in the action box keeps every finger along the scene's whole
    trajectory within the force that the MuJoCo contact carries
    (``grasp_env.physics.model.MAX_FORCE``), so that MuJoCo can check any step of it."""
    largest, _ = grip_forces(scenes, k_max_ratio)
    starts = np.cumsum(scenes.length) - scenes.length
    return np.maximum.reduceat(largest.max(-1), starts) <= _mujoco_max_force()


def check_mujoco_scene(name: str, scenes: SceneBatch, k_max_ratio: float) -> None:
    """A ValueError naming ``name`` unless the scene (a batch of one) :func:`mujoco_fits`.

    Every grip in the box, not only the zero grip: an environment that accepts a scene then
    steps any action of its action space, so no step of it can fail MuJoCo's force check.
    """
    largest, equilibrating = grip_forces(scenes, k_max_ratio)
    limit = _mujoco_max_force()
    if largest.max() <= limit:
        return
    t, i = np.unravel_index(np.argmax(largest), largest.shape)
    n = largest.shape[1]
    raise ValueError(
        f"{name} with physics='mujoco': its equilibrating forces reach"
        f" {equilibrating.max():.4g} w along the trajectory, and with the action box (which"
        f" adds up to (n - 1) k_max = {(n - 1) * k_max_ratio:g} w a finger) a grip presses"
        f" finger {i} with {largest[t, i]:.4g} w at pose {t}, but the MuJoCo contact carries"
        f" at most {limit:g} w a finger: choose contacts around the centre of gravity that"
        " need smaller equilibrating forces, or a lower k_max_ratio"
    )


# --------------------------------------------------------------------------- random scenes


@dataclass(frozen=True)
class SceneSampler:
    """Ranges of the random scenes (see :class:`~grasp_env.envs.CubeGraspRandomEnv`)."""

    faces: tuple[str, ...] = PAPER_FACES
    contact_offset: float = spec.CONTACT_OFFSET.default
    cg_offset_max: float = spec.CG_OFFSET_MAX.default
    weight_range: tuple[float, float] = spec.WEIGHT_DRAWS.default
    mu_range: tuple[float, float] = spec.MU_DRAWS.default
    alpha_start_range_deg: tuple[float, float] = spec.ALPHA_START_DRAWS.default
    alpha_end_range_deg: tuple[float, float] = spec.ALPHA_END_DRAWS.default
    alpha_step_deg: float = spec.ALPHA_STEP.default
    extra_force_max: float = spec.EXTRA_FORCE_MAX.default
    extra_torque_max: float = spec.EXTRA_TORQUE_MAX.default

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "faces", check_faces(self.faces))
        for parameter in (
            spec.CONTACT_OFFSET,
            spec.CG_OFFSET_MAX,
            spec.WEIGHT_DRAWS,
            spec.MU_DRAWS,
            spec.ALPHA_START_DRAWS,
            spec.ALPHA_END_DRAWS,
            spec.ALPHA_STEP,
            spec.EXTRA_FORCE_MAX,
            spec.EXTRA_TORQUE_MAX,
        ):
            set_(self, parameter.name, parameter.check(getattr(self, parameter.name)))
        if self.alpha_start_range_deg[1] > self.alpha_end_range_deg[0]:
            raise ValueError(
                "alpha_start_range_deg must lie below alpha_end_range_deg, got"
                f" {self.alpha_start_range_deg} and {self.alpha_end_range_deg}"
            )
        span = self.alpha_end_range_deg[1] - self.alpha_start_range_deg[0]
        check_pose_count("alpha_step_deg", span, self.alpha_step_deg)

    @property
    def max_length(self) -> int:
        """The longest trajectory the ranges allow, in poses."""
        span = self.alpha_end_range_deg[1] - self.alpha_start_range_deg[0]
        return check_pose_count("alpha_step_deg", span, self.alpha_step_deg)

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
        cg = (2 * u[:, 0:3] - 1) * self.cg_offset_max * half
        (w0, w1), (m0, m1) = self.weight_range, self.mu_range
        weight = w0 + (w1 - w0) * u[:, 3]
        mu = m0 + (m1 - m0) * u[:, 4]
        (s0, s1), (e0, e1) = self.alpha_start_range_deg, self.alpha_end_range_deg
        start = s0 + (s1 - s0) * u[:, 5]
        end = e0 + (e1 - e0) * u[:, 6]
        extra_force = (2 * u[:, 7:10] - 1) * self.extra_force_max * weight[:, None]
        extra_torque = (2 * u[:, 10:13] - 1) * self.extra_torque_max * (weight * EDGE)[:, None]
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
