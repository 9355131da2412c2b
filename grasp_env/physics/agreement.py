"""How far MuJoCo agrees with the analytic friction cone: a sweep of force sets.

Force sets are generated at chosen maximum friction angles: from the minimax optimum k*, move
k along a random direction and bisect on the distance travelled until max_i theta_i equals the
target exactly (any crossing will do, so the bisection needs only a bracket). Targets cover 0
to 40 deg, plus sets 0.01 to 1 deg either side of the friction limit, for mu = tan 10, 20 and
30 deg, several poses and several contact layouts (3 and 4 fingers, centred and moved
contacts, a moved centre of gravity).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    Grasp,
    Scene,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)

from .stability import PhysicsReport, StabilityChecker

#: Friction limits of the study, degrees (mu = tan of each).
LIMITS_DEG = (10.0, 20.0, 30.0)
#: Poses along the paper's trajectory, degrees.
ALPHAS_DEG = (-15.0, -7.0, 0.0, 8.0, 15.0)
#: Maximum friction angles swept, degrees, and the offsets from the limit near its edge.
SWEEP_DEG = tuple(np.linspace(0.0, 40.0, 17))
EDGE_OFFSETS_DEG = (0.01, 0.02, 0.05, 0.1, 0.3, 1.0)
#: Sets at least this far from the edge must agree exactly (the issue's target).
FAR_FROM_EDGE_DEG = 0.05


@dataclass(frozen=True)
class ForceSet:
    """One case of the study: contact forces on a scene at a pose, and the analytic verdict."""

    scene: Scene
    alpha_deg: float
    rotation: np.ndarray
    forces: np.ndarray
    max_angle_deg: float

    @property
    def limit_deg(self) -> float:
        return float(np.degrees(self.scene.friction_limit))

    @property
    def predicted_holds(self) -> bool:
        """The analytic verdict: every friction angle within the limit."""
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


def agreement_sets(seed: int = 0, directions: int = 2) -> list[ForceSet]:
    """The study's force sets, ``directions`` per target and pose (deterministic for a seed)."""
    rng = np.random.default_rng(seed)
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
                    sets.append(
                        ForceSet(
                            scene=scene,
                            alpha_deg=alpha,
                            rotation=rotations[a],
                            forces=grasp.forces(k),
                            max_angle_deg=float(np.degrees(grasp.angles(k).max())),
                        )
                    )
    return sets


def check_sets(
    sets: list[ForceSet],
    progress: Callable[[Iterable[ForceSet]], Iterable[ForceSet]] = iter,
    **settings: float,
) -> list[PhysicsReport]:
    """MuJoCo's report on each set; ``progress`` wraps the iteration (e.g. with tqdm)."""
    checkers: dict[int, StabilityChecker] = {}
    reports = []
    for case in progress(sets):
        key = id(case.scene)
        if key not in checkers:
            checkers[key] = StabilityChecker(case.scene, **settings)
        reports.append(checkers[key].check(case.rotation, case.forces))
    for checker in checkers.values():
        checker.close()
    return reports


@dataclass(frozen=True)
class Agreement:
    """Confusion matrix (rows: analytic holds / slips; columns: MuJoCo holds / slips)."""

    confusion: np.ndarray
    overall: float
    far: float
    n_sets: int
    n_far: int

    def line(self) -> str:
        return (
            f"agreement: {100 * self.overall:.2f}% overall ({self.n_sets} sets), "
            f"{100 * self.far:.2f}% at >= {FAR_FROM_EDGE_DEG} deg from the edge "
            f"({self.n_far} sets)"
        )


def summarise(sets: list[ForceSet], mujoco_holds: np.ndarray) -> Agreement:
    predicted = np.array([s.predicted_holds for s in sets], dtype=bool)
    observed = np.asarray(mujoco_holds, dtype=bool)
    far = np.array([s.edge_distance_deg >= FAR_FROM_EDGE_DEG for s in sets], dtype=bool)
    confusion = np.array(
        [
            [np.sum(predicted & observed), np.sum(predicted & ~observed)],
            [np.sum(~predicted & observed), np.sum(~predicted & ~observed)],
        ]
    )
    agree = predicted == observed
    return Agreement(
        confusion=confusion,
        overall=float(agree.mean()),
        far=float(agree[far].mean()),
        n_sets=len(sets),
        n_far=int(far.sum()),
    )
