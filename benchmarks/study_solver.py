"""Study: is every result of the minimax solver certified, force limits included?

    python -m grasp_env_agents.benchmarks.study_solver [--scenes 20000] [--reference 600]

Scenes drawn from ranges far wider than the paper's neighbourhood, with force limits (the
solver must certify every result there), for three and four fingers (half each): contact
offsets up to 0.7 of the face half-width, centre-of-gravity offsets up to 0.2, weights 0.5 to
30 N, a random unit rotation axis, alpha in [-30, 30] deg, k_max 0.5 to 3 w and f_max 0.3 to 1
x the largest finger force |P_i| of the optimum without a limit. Beside them, smaller rows of
tiny boxes (k_max = 1e-9 w, with and without f_max). Every result is checked
(:func:`certificate_failures`): a certified gap 0 <= max_angle - lower_bound <= 1e-9 rad unless
NOT_PUSHING, which must carry lower_bound = pi/2; k in the box, the force limits met, the
angles those of k. A subsample is compared with the cvxpy + Clarabel bisection of
``reference_solver`` (:func:`reference_failures`): the same status, the optimum inside the
reference's bracket and each solver's bound consistent with the other's. Prints a table and
exits with status 1 on any failure. (Not named bench_*: ``grasp-env bench`` does not run it.)
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, fields

import numpy as np

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_FACES,
    Grasp,
    MinimaxResult,
    Scene,
    Status,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)

GAP = 1e-9  # radians: the certificate the solver promises
TOL = 1e-9  # radians: slack when comparing with the reference's bracket (its own tolerance 1e-10)


@dataclass(frozen=True)
class Scenes:
    """A batch of grasps (leading axis: scene) with their box and force limit."""

    grasp: Grasp
    k_max: np.ndarray
    f_max: np.ndarray | None

    def __len__(self) -> int:
        return len(self.k_max)

    def one(self, b: int) -> tuple[Grasp, float, float | None]:
        g = Grasp(*(getattr(self.grasp, f.name)[b] for f in fields(Grasp)))
        return g, float(self.k_max[b]), None if self.f_max is None else float(self.f_max[b])


def stacked(grasps: list[Grasp]) -> Grasp:
    return Grasp(*(np.stack([getattr(g, f.name) for g in grasps]) for f in fields(Grasp)))


def issue_scenes(
    n: int,
    count: int,
    seed: int,
    *,
    force_limit: bool = True,
    k_ratio: tuple[float, float] = (0.5, 3.0),
) -> Scenes:
    """``count`` scenes of the module doc's wide distribution with ``n`` fingers.

    k_max = U(k_ratio) x w; with ``force_limit``, f_max = U(0.3, 1) x the largest |P_i| of
    the optimum without a force limit (solved here).
    """
    rng = np.random.default_rng(seed)
    faces = PAPER_FACES if n == 3 else FOUR_FINGER_FACES
    grasps, k_max, fraction = [], [], []
    for _ in range(count):
        scene = Scene.on_faces(
            faces,
            offsets=rng.uniform(-0.7, 0.7, (n, 2)),
            weight=rng.uniform(0.5, 30.0),
            cg_offset=rng.uniform(-0.2, 0.2, 3),
        )
        axis = rng.normal(size=3)
        rotation = pose_rotation(axis / np.linalg.norm(axis), np.deg2rad(rng.uniform(-30, 30)))
        grasps.append(scene_grasp(scene, rotation))
        k_max.append(rng.uniform(*k_ratio) * scene.weight)
        fraction.append(rng.uniform(0.3, 1.0))
    grasp = stacked(grasps)
    k_max = np.array(k_max)
    f_max = None
    if force_limit:
        free = solve_minimax(grasp, k_max)
        f_max = np.array(fraction) * np.linalg.norm(grasp.forces(free.k), axis=-1).max(axis=-1)
    return Scenes(grasp, k_max, f_max)


def certificate_failures(scenes: Scenes, result: MinimaxResult) -> list[tuple[int, str]]:
    """(scene, what is wrong) for every result that is not a certified optimum."""
    g = scenes.grasp
    failures = []
    pushing = result.status != Status.NOT_PUSHING
    angles = g.angles(result.k)
    forces = np.linalg.norm(g.forces(result.k), axis=-1).max(axis=-1)
    checks = {
        "not finite": ~(
            np.isfinite(result.k).all(-1)
            & np.isfinite(result.angles).all(-1)
            & np.isfinite(result.lower_bound)
        ),
        "gap above 1e-9 rad": pushing & ~(result.gap <= GAP),
        "negative gap": pushing & (result.gap < 0),
        "NOT_PUSHING without lower_bound = pi/2": ~pushing & (result.lower_bound != np.pi / 2),
        "k outside the box": np.abs(result.k).max(-1) > scenes.k_max * (1 + 1e-12),
        # (1e-10: the direction of a finger force 1e-5 of the others' is rounded to ~1e-11)
        "max_angle is not k's": np.abs(angles.max(-1) - result.max_angle) > 1e-10,
    }
    if scenes.f_max is not None:
        checks["force limit exceeded"] = pushing & (forces > scenes.f_max * (1 + 1e-9))
    for what, bad in checks.items():
        failures += [(int(b), what) for b in np.flatnonzero(bad)]
    return failures


def reference_failures(
    scenes: Scenes, result: MinimaxResult, indices: np.ndarray, references: dict
) -> tuple[list[tuple[int, str]], float]:
    """Compare the scenes ``indices`` with the cone bisection; (failures, largest |difference|).

    ``references`` caches a ``ConeBisection`` per (n, force limit).
    """
    from grasp_env_agents.benchmarks.reference_solver import ConeBisection

    n = scenes.grasp.normals.shape[-2]
    limit = scenes.f_max is not None
    if (n, limit) not in references:
        references[n, limit] = ConeBisection(n, limit)
    reference = references[n, limit]
    failures, largest = [], 0.0
    for b in indices:
        g, k_max, f_max = scenes.one(int(b))
        ref = reference.solve(g.equilibrating, g.basis, g.normals, k_max, f_max)
        not_pushing = result.status[b] == Status.NOT_PUSHING
        if not_pushing != ref.not_pushing:
            failures.append((int(b), f"status {Status(result.status[b]).name}, reference "
                             f"{'not pushing' if ref.not_pushing else 'pushing'}"))  # fmt: skip
            continue
        if not_pushing:
            continue
        largest = max(largest, abs(result.max_angle[b] - ref.upper))
        if result.lower_bound[b] > ref.upper + TOL:
            failures.append((int(b), "lower_bound above a grip the reference attains"))
        if result.max_angle[b] < ref.lower - TOL:
            failures.append((int(b), "max_angle below the reference's certified bound"))
    return failures, largest


def study(name: str, scenes: Scenes, reference: int, references: dict, seed: int) -> dict:
    start = time.perf_counter()
    result = solve_minimax(scenes.grasp, scenes.k_max, scenes.f_max)
    elapsed = time.perf_counter() - start
    failures = certificate_failures(scenes, result)
    rng = np.random.default_rng(seed)
    indices = np.sort(rng.choice(len(scenes), min(reference, len(scenes)), replace=False))
    ref_failures, largest = reference_failures(scenes, result, indices, references)
    pushing = result.status != Status.NOT_PUSHING
    gaps = np.where(pushing, result.gap, 0.0)
    worst = int(np.argmax(gaps))
    return {
        "name": name,
        "scenes": len(scenes),
        "statuses": np.bincount(result.status, minlength=3),
        "certified": 1 - len({b for b, _ in failures}) / len(scenes),
        "gap": float(gaps.max()),
        "worst": worst,
        "reference": len(indices),
        "difference": largest,
        "failures": failures + ref_failures,
        "seconds": elapsed,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", type=int, default=20_000, help="force-limit scenes in all")
    parser.add_argument("--reference", type=int, default=600, help="of them against cvxpy")
    parser.add_argument("--tiny", type=int, default=1_000, help="tiny-box scenes per row")
    parser.add_argument("--seed", type=int, default=14)
    args = parser.parse_args(argv)
    rows = []
    for n in (3, 4):
        rows.append((f"{n} fingers, f_max", dict(n=n, count=args.scenes // 2)))
    for n in (3, 4):
        for limit in (False, True):
            tiny = dict(n=n, count=args.tiny, force_limit=limit, k_ratio=(1e-9, 1e-9))
            rows.append((f"{n} fingers, k_max 1e-9 w{', f_max' if limit else ''}", tiny))
    references: dict = {}
    figures = []
    for r, (name, spec) in enumerate(rows):
        print(f"{name}: {spec['count']:,} scenes ...", flush=True)
        scenes = issue_scenes(**spec, seed=args.seed * 100 + r)
        share = args.reference if "1e-9" not in name else max(1, args.reference // 10)
        figures.append(study(name, scenes, share // 2, references, seed=r))
    print()
    header = (
        f"{'':28s}{'scenes':>8s}{'interior':>9s}{'boundary':>9s}{'not push':>9s}"
        f"{'certified':>11s}{'largest gap':>13s}{'vs cvxpy':>9s}{'|opt - ref|':>13s}{'solve s':>9s}"
    )
    print(header)
    failed = False
    for f in figures:
        interior, boundary, not_pushing = f["statuses"]
        print(
            f"{f['name']:28s}{f['scenes']:8,d}{interior:9,d}{boundary:9,d}{not_pushing:9,d}"
            f"{f['certified']:11.4%}{f['gap']:11.1e} r{f['reference']:9d}"
            f"{np.rad2deg(f['difference']):11.1e} d{f['seconds']:9.2f}"
        )
        failed |= bool(f["failures"])
    print("(gaps in radians, differences in degrees; worst gap per row: scene "
          + ", ".join(str(f["worst"]) for f in figures) + ")")  # fmt: skip
    for f in figures:
        for b, what in f["failures"][:10]:
            print(f"FAILED {f['name']}, scene {b}: {what}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
