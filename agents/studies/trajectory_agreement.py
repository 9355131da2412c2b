"""The trajectory agreement study: the analytic verdict along whole trajectories against one
continuous MuJoCo rollout each, on random scenes with the expert's grip and grips perturbed to
cross the limit mid-trajectory or stay inside it, the equal-k grip, a grip that slips only
between coarse steps, and windows of the certified finger-phasing gait."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import numpy as np

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_FACES,
    PAPER_TURN,
    PHI,
    VERTICAL_TURN,
    GaitSolution,
    Scene,
    Trajectory,
    friction_angles,
    grasp_matrix,
    scene_grasp,
    solve_gait,
    solve_minimax,
)
from grasp_env.physics.motion import path_settings, plan_motion, released
from grasp_env.physics.rollout import RolloutReport, check_trajectories
from grasp_env.physics.stability import SETTINGS

from .agreement import Agreement, _checked_in_chunks, _integer, agreement

#: How far the perturbed grips' largest friction angle lies from the edge, degrees: above the
#: limit (they cross it mid-trajectory) or below it (they stay just inside).
CROSSINGS_DEG = (0.05, 0.1, 0.2, 0.5, 1.0, 2.0)


@dataclass(frozen=True)
class TrajectoryCase:
    """One trajectory of the study: per-pose contact forces (world frame) along a trajectory.

    ``kind`` says where the grip comes from: "expert" (the minimax optimum at every pose),
    "crossing" and "inside" (the expert's grip perturbed by a bump mid-trajectory until its
    largest friction angle lies a chosen distance above or below the limit), "equal-k" (the
    paper's eq. 8 grip), "coarse steps" (an expert grip that holds at every pose and slips
    between two), "gait", "gait crossing" and "gait inside" (a window of the certified optimal
    finger-phasing gait, with its ``in_contact`` (T, n), as planned and perturbed) or "learned"
    (a trained policy's, added by ``grasp-env verify --policy``)."""

    kind: str
    scene: Scene
    alphas_deg: np.ndarray
    rotations: np.ndarray
    forces: np.ndarray
    in_contact: np.ndarray | None = None
    trajectory: Trajectory | None = None  #: the trajectory, where it is one (for a policy)


#: The perturbations are bisected on the force path sampled densely and uniformly (the
#: run's steps are timed by the forces, so they are not affine in a force change), then
#: polished on the run's own steps (:func:`_polished`).
PATH_SETTINGS = path_settings(SETTINGS)


def _polished(
    scale: float, largest: Callable[[float], float], target: float, tries: int = 8
) -> float | None:
    """``scale`` refined by secant steps until the run's own largest friction angle,
    ``largest(c)``, equals ``target`` radians (within 1e-10); None if they do not converge.
    The run's steps differ from the path's samples by little, so a step of more than 1% of
    ``scale`` is a secant gone astray, not convergence: the run's largest angle jumps there
    (the timing moved a step onto a finger's force passing near zero, where its direction
    swings), and the grip's margin on the steps run is not the target."""
    a, fa = scale, largest(scale) - target
    b = scale * (1 + 1e-6) + 1e-9
    fb = largest(b) - target
    for _ in range(tries):
        if abs(fa) <= 1e-10:
            return a
        if fb == fa:
            break
        step = fa * (a - b) / (fa - fb)
        if not abs(a - step - scale) <= 0.01 * scale:
            break
        a, fa, b, fb = a - step, 0.0, a, fa
        fa = largest(a) - target
    return a if abs(fa) <= 1e-10 else None


def _step_angles(scene: Scene, forces: np.ndarray, settle: int) -> float:
    """The largest friction angle of a loaded finger (not released) over a run's steps
    (``forces`` in units of w) after the settle."""
    loaded = ~released(forces, 1.0, SETTINGS["released_force"])
    angles = np.where(loaded, friction_angles(forces, scene.normals), 0.0)
    return float(angles[settle:].max())


def _run_angle(
    scene: Scene, rotations: np.ndarray, forces: np.ndarray, in_contact: np.ndarray | None
) -> float:
    """The largest friction angle of a loaded finger over the steps of the run of
    ``forces`` (newtons), radians."""
    motion = plan_motion(scene, rotations, forces, in_contact, SETTINGS)
    return _step_angles(scene, motion.forces, motion.settle_steps)


def perturbed_k(
    scene: Scene,
    rotations: np.ndarray,
    alphas_deg: np.ndarray,
    k: np.ndarray,
    target: float,
    rng: np.random.Generator,
    tries: int = 10,
) -> np.ndarray | None:
    """A grip k + c b(alpha) d (T, m): the pose grips ``k`` plus a random direction d (|d| = w)
    times a bump b centred in the middle third of the trajectory, with c in [0, 4] bisected
    so that the
    largest friction angle over the continuous run's steps (the ones MuJoCo applies) equals
    ``target`` radians. None if no direction reaches it."""
    grasps = scene_grasp(scene, rotations)
    if _run_angle(scene, rotations, grasps.forces(k), None) >= target:
        return None
    base = plan_motion(scene, rotations, grasps.forces(k), None, PATH_SETTINGS)
    if _step_angles(scene, base.forces, base.settle_steps) >= target:
        return None
    lo, hi = np.percentile(alphas_deg, [100 / 3, 200 / 3])
    for _ in range(tries):
        direction = rng.normal(size=k.shape[-1])
        direction *= scene.weight / np.linalg.norm(direction)
        centre, width = rng.uniform(lo, hi), rng.uniform(2.0, 6.0)
        bump = np.exp(-(((alphas_deg - centre) / width) ** 2))[:, None] * direction
        # The steps' forces are affine in c (the interpolation is linear in the pose forces).
        moved = plan_motion(scene, rotations, grasps.forces(k + bump), None, PATH_SETTINGS)
        change = moved.forces - base.forces

        def largest(c: float, base=base, change=change) -> float:
            forces = base.forces + c * change
            return _step_angles(scene, forces, base.settle_steps)

        high = 4.0  # at most 4 w added to a grip: far beyond it, the grip means nothing
        if largest(high) < target:
            continue
        low = 0.0
        for _ in range(60):
            middle = (low + high) / 2
            low, high = (middle, high) if largest(middle) < target else (low, middle)
        if abs(largest(high) - target) <= 1e-9:  # not a jump (a finger becoming loaded)
            pose_forces = grasps.forces(k)
            pose_change = grasps.forces(k + bump) - pose_forces

            def run(c: float, forces=pose_forces, change=pose_change) -> float:
                return _run_angle(scene, rotations, forces + c * change, None)

            scale = _polished(high, run, target)
            if scale is not None:
                return k + scale * bump
    return None


def _bisected_bump(
    scene: Scene,
    rotations: np.ndarray,
    forces: np.ndarray,
    in_contact: np.ndarray | None,
    bump: np.ndarray,
    target: float,
) -> float | None:
    """The scale c in [0, 4] of the force change ``bump`` (T, n, 3) at which the largest
    friction angle over the run's steps of ``forces`` + c ``bump`` equals ``target`` radians;
    None if c = 4 does not reach it or the angle jumps past it (a finger becoming loaded, or
    on the run's steps, :func:`_polished`)."""
    base = plan_motion(scene, rotations, forces, in_contact, PATH_SETTINGS)
    moved = plan_motion(scene, rotations, forces + bump, in_contact, PATH_SETTINGS)
    change = moved.forces - base.forces  # the steps' forces are affine in c

    def largest(c: float) -> float:
        return _step_angles(scene, base.forces + c * change, base.settle_steps)

    low, high = 0.0, 4.0  # at most 4 w added to a grip: far beyond it, the grip means nothing
    if largest(low) >= target or largest(high) < target:
        return None
    for _ in range(60):
        middle = (low + high) / 2
        low, high = (middle, high) if largest(middle) < target else (low, middle)
    if abs(largest(high) - target) > 1e-9:
        return None
    return _polished(
        high, lambda c: _run_angle(scene, rotations, forces + c * bump, in_contact), target
    )


def _random_trajectory(index: int, rng: np.random.Generator) -> Trajectory:
    if index % 3 == 0:
        return Trajectory()  # the paper's: about a, -15 to 15 deg by 1 deg
    axis = tuple(rng.normal(size=3))
    start, end = rng.uniform(-30.0, -10.0), rng.uniform(10.0, 30.0)
    return Trajectory(axis, float(start), float(end), 2.0)


def trajectory_cases(
    seed: int = 0, scenes: int = 200, progress: Callable[[Iterable[int]], Iterable[int]] = iter
) -> list[TrajectoryCase]:
    """The trajectory study's cases (deterministic for a seed): for each of ``scenes`` random
    scenes (three and four fingers, face centres or moved contacts and centre of gravity, the
    paper's trajectory or a random axis and range) with mu a random 0.2 to 8 deg above the
    expert's largest friction angle, the expert's grip, a perturbed grip crossing the limit and
    one staying just inside (:data:`CROSSINGS_DEG`); the paper's equal-k grip at several mu;
    and an expert grip on coarse steps that holds at every pose but slips between two.
    ``progress`` wraps the scenes' indices (a progress bar)."""
    rng = np.random.default_rng(_integer("seed", seed, 0))
    scenes = _integer("scenes", scenes, 0)
    cases = []
    for index in progress(range(scenes)):
        faces = PAPER_FACES if index % 2 == 0 else FOUR_FINGER_FACES
        layout: dict = {"faces": faces}
        if index % 5:
            layout.update(
                offsets=rng.uniform(-0.4, 0.4, (len(faces), 2)),
                cg_offset=rng.uniform(-0.1, 0.1, 3),
                weight=float(rng.uniform(1.0, 10.0)),
            )
        trajectory = _random_trajectory(index, rng)
        rotations, alphas = trajectory.rotations(), trajectory.alphas_deg
        scene = Scene.on_faces(**layout)
        grasps = scene_grasp(scene, rotations)
        k = solve_minimax(grasps, 2 * scene.weight).k
        motion = plan_motion(scene, rotations, grasps.forces(k), None, SETTINGS)
        expert = _step_angles(scene, motion.forces, motion.settle_steps)
        if expert > np.radians(45.0):
            continue
        limit = expert + np.radians(rng.uniform(0.2, 8.0))
        scene = Scene.on_faces(**layout, mu=float(np.tan(limit)))
        cases.append(
            TrajectoryCase("expert", scene, alphas, rotations, grasps.forces(k), None, trajectory)
        )
        offset = np.radians(CROSSINGS_DEG[index % len(CROSSINGS_DEG)])
        for kind, target in (("crossing", limit + offset), ("inside", limit - offset)):
            perturbed = perturbed_k(scene, rotations, alphas, k, target, rng)
            if perturbed is not None:
                cases.append(
                    TrajectoryCase(kind, scene, alphas, rotations, grasps.forces(perturbed))
                )
    trajectory = Trajectory()
    rotations = trajectory.rotations()
    for limit in (3.0, 4.0, 4.5, 5.0, 6.0, 8.0, 12.0, 18.0):
        scene = Scene(mu=float(np.tan(np.radians(limit))))
        k = scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(3)
        forces = scene_grasp(scene, rotations).forces(k)
        cases.append(TrajectoryCase("equal-k", scene, trajectory.alphas_deg, rotations, forces))
    cases.append(coarse_steps_case())
    return cases


def coarse_steps_case() -> TrajectoryCase:
    """Four fingers turned 30 deg per step: the expert's grip holds at each of the three poses
    (margins 8.2, 11.6 and 0.7 deg) but, interpolated between them, passes the limit by 2.1 deg
    between the second and third (found by a search over random scenes)."""
    trajectory = Trajectory((-0.47, 0.59, -0.66), -30.0, 30.0, 30.0)
    scene = Scene.on_faces(
        FOUR_FINGER_FACES,
        [[0.08, -0.31], [0.03, 0.02], [-0.41, 0.48], [0.07, -0.49]],
        cg_offset=(0.08, 0.14, 0.03),
        mu=float(np.tan(np.radians(19.0))),
    )
    rotations = trajectory.rotations()
    grasps = scene_grasp(scene, rotations)
    forces = grasps.forces(solve_minimax(grasps, 2 * scene.weight).k)
    return TrajectoryCase("coarse steps", scene, trajectory.alphas_deg, rotations, forces)


#: The finger-phasing gaits of the study: the certified optimal gait of the default
#: :class:`GaitScene` and :class:`Hand` along these trajectories (docs/gait.md).
GAIT_TRAJECTORIES = (PAPER_TURN, VERTICAL_TURN)


#: A gait case is a window of at most this many poses (4.7 s at the default timing), as long
#: as the paper's trajectory: holding grips creep in MuJoCo at up to about 1e-6 L/s, so a run
#: of 9 s reaches the 1e-5 L slip threshold at a margin of 7 deg (docs/physics.md).
GAIT_WINDOW = 31


def gait_windows(contacts: np.ndarray, longest: int = GAIT_WINDOW) -> list[slice]:
    """Consecutive windows of a gait's poses, each touching at most four sites (a
    :class:`Scene`, hence one MuJoCo model, has at most four contacts) and at most ``longest``
    poses long; ``contacts`` (T, F) is the gait's site per finger (-1: none)."""
    windows, start, used = [], 0, set()
    for t, row in enumerate(contacts):
        sites = {int(s) for s in row if s >= 0}
        if len(used | sites) > 4 or t - start >= longest:
            windows.append(slice(start, t))
            start, used = t, set()
        used |= sites
    windows.append(slice(start, len(contacts)))
    return windows


def gait_window_case(solution: GaitSolution, window: slice) -> TrajectoryCase:
    """A window of the solution's optimal gait as a case: one contact per site the window's
    fingers touch (which finger holds a site is immaterial to the physics), touched where some
    finger touches it, with that finger's certified grip (zero for one being placed or lifted)."""
    gait = solution.optimal
    contacts = gait.contacts[window]
    sites = sorted({int(s) for s in contacts.ravel() if s >= 0})
    finger_forces = solution.forces(gait)[window]
    forces = np.zeros((len(contacts), len(sites), 3))
    touching = np.zeros((len(contacts), len(sites)), dtype=bool)
    for t, row in enumerate(contacts):
        for f, s in enumerate(row):
            if s >= 0:
                forces[t, sites.index(s)] = finger_forces[t, f]
                touching[t, sites.index(s)] = True
    trajectory = solution.trajectory
    return TrajectoryCase(
        "gait",
        solution.scene.scene(sites),
        np.asarray(trajectory.alphas_deg)[window],
        trajectory.rotations()[window],
        forces,
        touching,
    )


def perturbed_gait(
    case: TrajectoryCase, target: float, rng: np.random.Generator, tries: int = 10
) -> np.ndarray | None:
    """A gait case's forces plus a bump centred in the middle third of its poses: at each pose
    a random force change in the null space of the loaded fingers' grasp matrix (it balances
    nothing, like a change of the k_ij; fingers placed, lifted or away keep zero force), of
    size w times the bump, scaled so that the largest friction angle over the run's steps
    equals ``target`` radians. None if no direction reaches it."""
    scene, rotations, forces = case.scene, case.rotations, case.forces
    loaded = ~released(forces, scene.weight, SETTINGS["released_force"])
    arms = np.einsum("tij,nj->tni", rotations, scene.contacts - scene.cg_offset)
    alphas = np.asarray(case.alphas_deg)
    lo, hi = np.percentile(alphas, [100 / 3, 200 / 3])
    for _ in range(tries):
        u = rng.normal(size=forces.shape[1:])
        centre, width = rng.uniform(lo, hi), rng.uniform(2.0, 6.0)
        bump = np.zeros_like(forces)
        for t, height in enumerate(np.exp(-(((alphas - centre) / width) ** 2))):
            on = np.flatnonzero(loaded[t])
            _, values, vt = np.linalg.svd(grasp_matrix(arms[t, on]))
            null = vt[np.sum(values > 1e-9 * values[0]) :]  # (3 |on| - rank, 3 |on|)
            change = null.T @ (null @ u[on].ravel())
            bump[t, on] = height * scene.weight * (change / np.linalg.norm(change)).reshape(-1, 3)
        scale = _bisected_bump(scene, rotations, forces, case.in_contact, bump, target)
        if scale is not None:
            return forces + scale * bump
    return None


def gait_cases(seed: int = 0) -> list[TrajectoryCase]:
    """The study's finger-phasing gaits: each window (:func:`gait_windows`) of the certified
    optimal gait along each of :data:`GAIT_TRAJECTORIES`, as planned ("gait") and perturbed
    to cross the limit ("gait crossing") or stay just inside it ("gait inside") by
    :data:`CROSSINGS_DEG` in turn (deterministic for a seed)."""
    rng = np.random.default_rng(_integer("seed", seed, 0))
    cases = []
    for trajectory in GAIT_TRAJECTORIES:
        solution = solve_gait(trajectory=trajectory)
        limit = solution.scene.friction_limit
        for index, window in enumerate(gait_windows(solution.optimal.contacts)):
            case = gait_window_case(solution, window)
            cases.append(case)
            offset = np.radians(CROSSINGS_DEG[index % len(CROSSINGS_DEG)])
            targets = {"gait crossing": limit + offset, "gait inside": limit - offset}
            for kind, target in targets.items():
                forces = perturbed_gait(case, target, rng)
                if forces is not None:
                    cases.append(replace(case, kind=kind, forces=forces))
    return cases


def check_cases(
    cases: list[TrajectoryCase],
    progress: Callable[[Iterable[TrajectoryCase]], Iterable[TrajectoryCase]] = iter,
    threads: int | None = None,
    **settings: float,
) -> list[RolloutReport]:
    """The continuous rollout of every case, in parallel :data:`CHUNK` at a time; ``progress``
    wraps the iteration over the cases (e.g. with tqdm)."""

    def check(chunk: list[TrajectoryCase]) -> list[RolloutReport]:
        grips = [(c.scene, c.rotations, c.forces, c.in_contact) for c in chunk]
        return check_trajectories(grips, threads, **settings)

    return _checked_in_chunks(progress(cases), check)


def summarise_trajectories(reports: list[RolloutReport]) -> Agreement:
    """The trajectory study's agreement (the edge distance is the analytic margin's size)."""
    return agreement(
        np.array([r.predicted_holds for r in reports], dtype=bool),
        np.array([r.holds for r in reports], dtype=bool),
        np.abs([r.margin_deg for r in reports]),
    )
