"""How far MuJoCo agrees with the analytic friction cone: force sets at poses, and trajectories.

**Poses.** Force sets are generated at chosen maximum friction angles: from the minimax optimum
k*, move k along a random direction and bisect on the distance travelled until max_i theta_i
equals the target exactly (any crossing will do, so the bisection needs only a bracket).
Targets cover 0 to 40 deg, plus sets 0.01 to 1 deg either side of the friction limit, for mu =
tan 10, 20 and 30 deg, several poses and several contact layouts (3 and 4 fingers, centred and
moved contacts, a moved centre of gravity); and four-finger optima that release a finger.

**Trajectories.** Grips carried through whole trajectories in one continuous rollout each
(:mod:`grasp_env.physics.rollout`): the expert's, grips perturbed mid-trajectory to cross the
limit (or stay just inside it) by 0.05 to 2 deg, the paper's equal-k grip at several mu, and a
grip on coarse steps that slips only between poses (:func:`trajectory_cases`); windows of the
certified finger-phasing gait, fingers lifted and placed, as planned and perturbed the same way
(:func:`gait_cases`); ``grasp-env verify --policy`` adds a learned policy's grips. Verdicts
are compared for the whole trajectory, the edge distance being the analytic margin over every
step of the run.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    START_ROTATION,
    Grasp,
    Scene,
    axis_angle_matrix,
    friction_angles,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)
from grasp_env.mechanics.checks import is_integer
from grasp_env.physics.motion import released
from grasp_env.physics.stability import SETTINGS, PhysicsReport, check_poses

#: Friction limits of the study, degrees (mu = tan of each).
LIMITS_DEG = (10.0, 20.0, 30.0)
#: Poses along the paper's trajectory, degrees.
ALPHAS_DEG = (-15.0, -7.0, 0.0, 8.0, 15.0)
#: Maximum friction angles swept, degrees, and the offsets from the limit near its edge.
SWEEP_DEG = tuple(np.linspace(0.0, 40.0, 17))
EDGE_OFFSETS_DEG = (0.01, 0.02, 0.05, 0.1, 0.3, 1.0)
#: Sets at least this far from the edge must all agree: MuJoCo's verdict the analytic one
#: (``grasp-env verify --agreement`` exits with 1 otherwise).
FAR_FROM_EDGE_DEG = 0.05


@dataclass(frozen=True)
class ForceSet:
    """One case of the study: contact forces on a scene at a pose, and the analytic verdict."""

    scene: Scene
    alpha_deg: float
    rotation: np.ndarray
    forces: np.ndarray
    max_angle_deg: float  #: the largest friction angle of a loaded finger (not released)

    @property
    def limit_deg(self) -> float:
        return float(np.degrees(self.scene.friction_limit))

    @property
    def predicted_holds(self) -> bool:
        """The analytic verdict: every loaded finger's friction angle within the limit."""
        return self.max_angle_deg <= self.limit_deg

    @property
    def edge_distance_deg(self) -> float:
        return abs(self.max_angle_deg - self.limit_deg)


def layouts(rng: np.random.Generator) -> list[dict]:
    """The contact layouts of the study, as :meth:`Scene.on_faces` keywords."""
    return [
        {"faces": PAPER_FACES},  # the paper's grip: the optimum is 0 deg at every pose
        {"faces": PAPER_FACES, "offsets": [[0.3, -0.2], [0.1, 0.25], [-0.2, 0.1]]},
        {
            "faces": PAPER_FACES,
            "offsets": rng.uniform(-0.35, 0.35, (3, 2)),
            "cg_offset": rng.uniform(-0.1, 0.1, 3),
            "weight": 12.0,
        },
        {"faces": FOUR_FINGER_FACES, "offsets": rng.uniform(-0.35, 0.35, (4, 2))},
    ]


def force_set_k(
    grasp: Grasp,
    start: np.ndarray,
    targets: np.ndarray,
    rng: np.random.Generator,
    k_bound: float,
    tries: int = 20,
) -> np.ndarray:
    """Interaction scalars k (T, m) with max_i theta_i(k) = ``targets`` (T,) radians, by
    bisection along random directions from ``start`` (m,). Rows are NaN where the target is not
    above the max angle at ``start`` or no direction reaches it within |k - start| <=
    ``k_bound``."""
    targets = np.asarray(targets, dtype=float)
    ks = np.full((len(targets), len(start)), np.nan)
    feasible = targets > grasp.angles(start).max()
    for _ in range(tries):
        todo = np.flatnonzero(np.isnan(ks[:, 0]) & feasible)
        if todo.size == 0:
            break
        direction = rng.normal(size=(todo.size, len(start)))
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        goal = targets[todo]
        reached = grasp.angles(start + k_bound * direction).max(-1) >= goal
        todo, direction, goal = todo[reached], direction[reached], goal[reached]
        low, high = np.zeros(todo.size), np.full(todo.size, k_bound)
        for _ in range(80):  # the bracket shrinks to 1e-24 of its size: exact in float64
            middle = (low + high) / 2
            below = grasp.angles(start + middle[:, None] * direction).max(-1) < goal
            low, high = np.where(below, middle, low), np.where(below, high, middle)
        ks[todo] = start + high[:, None] * direction
    return ks


def _integer(name: str, value: int, low: int) -> int:
    """``value`` as an int >= ``low`` (not a boolean, a float or a string), or a ValueError."""
    if not is_integer(value) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def agreement_sets(seed: int = 0, directions: int = 2) -> list[ForceSet]:
    """The study's force sets, ``directions`` per target and pose (deterministic for a seed)."""
    rng = np.random.default_rng(_integer("seed", seed, 0))
    directions = _integer("directions", directions, 1)
    sets = []
    for limit in LIMITS_DEG:
        edge = [limit + sign * offset for offset in EDGE_OFFSETS_DEG for sign in (-1, 1)]
        # Sweep targets on the edge itself are left out: there the verdict is a coin toss.
        sweep = [t for t in SWEEP_DEG if abs(t - limit) >= min(EDGE_OFFSETS_DEG)]
        targets = np.radians(np.repeat(sorted(sweep + edge), directions))
        for layout in layouts(np.random.default_rng(seed)):
            scene = Scene.on_faces(**layout, mu=float(np.tan(np.radians(limit))))
            rotations = pose_rotation(PAPER_AXIS, np.radians(ALPHAS_DEG))
            grasps = scene_grasp(scene, rotations)
            optima = solve_minimax(grasps, 2 * scene.weight)
            for a, alpha in enumerate(ALPHAS_DEG):
                grasp = scene_grasp(scene, rotations[a])
                best, k_best = optima.max_angle[a], optima.k[a]
                # Targets at the optimum (the paper's grip at 0 deg) are the optimum itself.
                at_best = targets[np.abs(targets - best) <= 1e-6][:1]
                above = targets[targets > best + 1e-6]
                ks = force_set_k(grasp, k_best, above, rng, 4 * scene.weight)
                ks = np.concatenate([np.tile(k_best, (at_best.size, 1)), ks])
                for k in ks[~np.isnan(ks[:, 0])]:
                    forces = grasp.forces(k)
                    angle = loaded_max_angle_deg(forces, grasp.normals, scene.weight)
                    sets.append(ForceSet(scene, alpha, rotations[a], forces, angle))
    return sets


def loaded_max_angle_deg(forces: np.ndarray, normals: np.ndarray, weight: float) -> float:
    """The analytic verdict's angle: the largest friction angle of a loaded finger (one
    released, at most ``released_force`` x w, is judged by neither verdict; its direction is
    arbitrary: an optimum that lets a finger go leaves it at about 1e-11 w), degrees."""
    loaded = ~released(forces, weight, SETTINGS["released_force"])
    angles = friction_angles(forces, normals)[loaded]
    return float(np.degrees(angles.max())) if angles.size else 0.0


def released_sets(seed: int = 0, scenes: int = 300) -> list[ForceSet]:
    """Four-finger optima that release a finger (its force vanishes, docs/design.md §1): random
    scenes and poses, each at its minimax optimum with the scene's mu a random 0.3 to 10 deg
    above it. They hold; a checker that counts the released finger as a lost hold says not."""
    rng = np.random.default_rng(_integer("seed", seed, 0))
    scenes = _integer("scenes", scenes, 0)
    sets = []
    for _ in range(scenes):
        offsets, cg = rng.uniform(-0.5, 0.5, (4, 2)), rng.uniform(-0.1, 0.1, 3)
        axis, alpha = rng.normal(size=3), np.radians(rng.uniform(-30, 30))
        rotation = axis_angle_matrix(axis, alpha) @ START_ROTATION
        scene = Scene.on_faces(FOUR_FINGER_FACES, offsets, cg_offset=cg)
        grasp = scene_grasp(scene, rotation)
        optimum = solve_minimax(grasp, 2 * scene.weight)
        forces = grasp.forces(optimum.k)
        if not released(forces, scene.weight, SETTINGS["released_force"]).any():
            continue
        if optimum.max_angle > np.radians(60):
            continue
        angle = loaded_max_angle_deg(forces, grasp.normals, scene.weight)
        limit = angle + rng.uniform(0.3, 10.0)
        scene = Scene.on_faces(
            FOUR_FINGER_FACES, offsets, cg_offset=cg, mu=float(np.tan(np.radians(limit)))
        )
        sets.append(ForceSet(scene, float(np.degrees(alpha)), rotation, forces, angle))
    return sets


#: Cases checked per parallel call of the studies (``progress`` advances by this many).
CHUNK = 64


def _checked_in_chunks(cases: Iterable, check: Callable[[list], list]) -> list:
    """``check`` applied to successive chunks of :data:`CHUNK` cases, the reports concatenated."""
    reports: list = []
    chunk: list = []
    for case in cases:
        chunk.append(case)
        if len(chunk) == CHUNK:
            reports += check(chunk)
            chunk = []
    return reports + (check(chunk) if chunk else [])


def check_sets(
    sets: list[ForceSet],
    progress: Callable[[Iterable[ForceSet]], Iterable[ForceSet]] = iter,
    threads: int | None = None,
    **settings: float,
) -> list[PhysicsReport]:
    """MuJoCo's report on each set, checked in parallel :data:`CHUNK` at a time; ``progress``
    wraps the iteration over the sets (e.g. with tqdm)."""

    def check(chunk: list[ForceSet]) -> list[PhysicsReport]:
        cases = [(s.scene, s.rotation, s.forces, None) for s in chunk]
        return check_poses(cases, threads, **settings)

    return _checked_in_chunks(progress(sets), check)


@dataclass(frozen=True)
class Agreement:
    """Confusion matrix (rows: analytic holds / slips; columns: MuJoCo holds / slips)."""

    confusion: np.ndarray
    overall: float
    far: float
    n_sets: int
    n_far: int

    def line(self, what: str = "sets") -> str:
        return (
            f"agreement: {100 * self.overall:.2f}% overall ({self.n_sets} {what}), "
            f"{100 * self.far:.2f}% at >= {FAR_FROM_EDGE_DEG} deg from the edge "
            f"({self.n_far} {what})"
        )


def agreement(predicted: np.ndarray, observed: np.ndarray, distance_deg: np.ndarray) -> Agreement:
    """The agreement of analytic (``predicted``) and MuJoCo (``observed``) verdicts, overall and
    where the analytic margin is at least :data:`FAR_FROM_EDGE_DEG` from the edge."""
    predicted = np.asarray(predicted, dtype=bool)
    observed = np.asarray(observed, dtype=bool)
    far = np.asarray(distance_deg) >= FAR_FROM_EDGE_DEG
    confusion = np.array(
        [
            [np.sum(predicted & observed), np.sum(predicted & ~observed)],
            [np.sum(~predicted & observed), np.sum(~predicted & ~observed)],
        ]
    )
    agree = predicted == observed
    return Agreement(
        confusion=confusion,
        overall=float(agree.mean()) if agree.size else 1.0,
        far=float(agree[far].mean()) if far.any() else 1.0,
        n_sets=int(agree.size),
        n_far=int(far.sum()),
    )


def summarise(sets: list[ForceSet], mujoco_holds: np.ndarray) -> Agreement:
    """The pose study's agreement."""
    return agreement(
        np.array([s.predicted_holds for s in sets], dtype=bool),
        mujoco_holds,
        np.array([s.edge_distance_deg for s in sets]),
    )
