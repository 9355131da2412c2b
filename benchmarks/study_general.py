"""Study: does the general minimax solver (3 to 8 contacts) agree with the cvxpy reference?

    python -m grasp_env_agents.benchmarks.study_general [--scenes 1000] [--out study_general]

For each n from 3 to 8, and without and with a force limit, ``--scenes`` random scenes of
:mod:`.general_scenes` (boxes, cylinders, spheres and convex meshes, a quarter each) are
solved by ``solve_minimax`` in one batched call, and one by one by the cvxpy + Clarabel
bisection of :mod:`.reference_solver` (``ConeBisection``; for n >= 5 its k is constrained
to the row space of k -> P, where it is its own minimum-norm representative, the k the
solver's box bounds). Per scene (:func:`compare`):

- **worse**: max(0, max_angle - the reference's last feasible level), how much worse the
  solver's grip is than one the reference found (apart for the uncertified scenes, whose
  grip may be worse by up to its gap);
- **reference inaccuracy**: max(0, the reference's claimed infeasible level - max_angle),
  where the reference calls a level impossible that the solver's grip attains; the grip is
  checked real (:func:`grip_failures`: k in the box and, for n >= 5, in the row space, the
  forces within f_max, the angles recomputed with numpy from k), so this is the reference's
  error;
- **false certificate**: lower_bound above the max angle that the reference's k attains
  (angles recomputed with numpy, + 1e-9 rad), where that k is a valid grip (in the box, its
  minimum-norm representative too for n >= 5, within f_max, no finger's force below 1e-9 of
  the load, whose direction would be rounding);
- certified (status != UNCERTIFIED), the gap max_angle - lower_bound of the uncertified,
  NOT_PUSHING against the reference's not_pushing.

Prints a table per n and f_max setting and one per shape, writes ``scenes.csv`` (a row a
scene), ``summary.csv`` and ``summary.md`` into ``--out`` after every block (so that a run
cut short leaves its figures so far), with a progress line as the reference runs (about
0.05 s a scene at n = 3 to 0.35 s at n = 8: the full study takes about an hour). Exits with
status 1 on any false certificate, invalid grip, NaN, NOT_PUSHING disagreement or a
certified grip worse beyond :data:`WORSE_TOL` than a feasible level that the reference's own
grip attains ("worse backed": elsewhere the level is not backed by a grip). (Not named bench_*:
``grasp-env bench`` does not run it.)
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg

from grasp_env.mechanics import Grasp, MinimaxResult, Status, solve_minimax
from grasp_env_agents.benchmarks.general_scenes import SHAPES, GeneralScenes, general_scenes

GAP = 1e-9  #: radians: the certificate the solver promises (codes.GAP_TOL)
CERTIFICATE_TOL = 1e-9  #: radians: slack for a lower bound above the reference's grip
#: degrees: how much worse than the reference's feasible level the solver's grip may be. The
#: reference decides each level by the sign of Clarabel's s* (absolute tolerances 1e-12 in
#: units of the load), so its last feasible level may lie below the optimum by what s*'s
#: tolerance moves t: about 1e-9 rad (6e-8 deg) where the cones are steep.
WORSE_TOL = 1e-7
#: relative slack of the box, the force limit and the row space (rounding of k = box y)
BOX_TOL = 1e-12
FORCE_TOL = 1e-9
ROW_SPACE_TOL = 1e-10
#: radians: the angles recomputed from k agree with the solver's (the largest; the others
#: to within more where a finger's force is small, see grip_failures)
ANGLE_TOL = 1e-10
#: a finger with |P_i| below this x the load is released (its angle is rounding)
RELEASED = 1e-9


def null_space(grasp: Grasp) -> np.ndarray:
    """(m, m - rank) basis of the null space of k -> P (the pair directions e_ij stacked per
    finger): empty for n = 3, 4, 3 or more columns for n >= 5."""
    E = np.asarray(grasp.basis, float)  # (m, n, 3)
    force_map = E.reshape(E.shape[0], -1).T  # (3n, m)
    return scipy.linalg.null_space(force_map, rcond=1e-10)


def minimum_norm(k: np.ndarray, null: np.ndarray) -> np.ndarray:
    """The minimum-norm pair scalars of the interaction force that k makes: k minus its
    null-space component."""
    return k - null @ (null.T @ k) if null.size else k


def grip_failures(scenes: GeneralScenes, result: MinimaxResult) -> list[list[str]]:
    """For each scene, what is wrong with the solver's result as a grip and as a certificate
    (empty if nothing): k within the box (for n >= 5: k the minimum-norm k, i.e. in the row
    space), the forces within f_max, the angles those of k (recomputed with numpy), never
    NaN, 0 <= gap, NOT_PUSHING with lower_bound pi/2, UNCERTIFIED iff gap > 1e-9 rad."""
    g = scenes.grasp
    pushing = result.status != Status.NOT_PUSHING
    angles = g.angles(result.k)
    # a finger's angle is rounding where its force is tiny (a released finger, |P_i| ~ 1e-14
    # of the load), and loses digits where it is small beside the largest (eps max|P| / |P_i|
    # rad): compared to within 1e-10 rad x (1e-5 max_j |P_j| / |P_i|), if larger
    load = np.linalg.norm(g.equilibrating, axis=-1).max(-1, keepdims=True)
    force = np.linalg.norm(g.forces(result.k), axis=-1)
    largest = force.max(-1, keepdims=True)
    tolerance = ANGLE_TOL * np.maximum(1.0, 1e-5 * largest / np.maximum(force, 1e-300))
    released = force < RELEASED * load

    def held(values: np.ndarray) -> np.ndarray:
        return np.where(released, -np.inf, values).max(-1)

    finite = (
        np.isfinite(result.k).all(-1)
        & np.isfinite(result.angles).all(-1)
        & np.isfinite(result.lower_bound)
        & np.isfinite(result.max_angle)
    )
    checks = {
        "NaN or inf": ~finite,
        "k outside the box": np.abs(result.k).max(-1) > scenes.k_max * (1 + BOX_TOL),
        # over the fingers that push (a released finger's angle is rounding, numpy's and the
        # kernel's alike: it may be the largest of numpy's, by up to 0.3 rad at n = 8)
        "max_angle is not k's": np.abs(held(angles) - held(result.angles)) > ANGLE_TOL,
        "max_angle below a pushing finger's": held(result.angles) > result.max_angle,
        "angles are not k's": (~released & (np.abs(angles - result.angles) > tolerance)).any(-1),
        "max_angle is not the largest angle": result.max_angle != result.angles.max(-1),
        "lower_bound above max_angle": pushing & (result.lower_bound > result.max_angle),
        "NOT_PUSHING without lower_bound = pi/2": ~pushing & (result.lower_bound != np.pi / 2),
        "UNCERTIFIED but gap <= 1e-9 rad": pushing
        & (result.status == Status.UNCERTIFIED)
        & ~(result.gap > GAP),
        "certified but gap > 1e-9 rad": pushing
        & (result.status != Status.UNCERTIFIED)
        & (result.gap > GAP),
    }
    if scenes.f_max is not None:
        forces = np.linalg.norm(g.forces(result.k), axis=-1).max(-1)
        checks["force limit exceeded"] = pushing & (forces > scenes.f_max * (1 + FORCE_TOL))
    failures: list[list[str]] = [[] for _ in range(len(scenes))]
    for what, bad in checks.items():
        for b in np.flatnonzero(bad):
            failures[b].append(what)
    if scenes.n >= 5:
        for b in range(len(scenes)):
            grasp, _, _ = scenes.one(b)
            null = null_space(grasp)
            k = result.k[b]
            if np.linalg.norm(null.T @ k) > ROW_SPACE_TOL * max(np.linalg.norm(k), 1e-300):
                failures[b].append("k not the minimum-norm k (off the row space)")
    return failures


def attained(grasp: Grasp, k: np.ndarray) -> float:
    """The largest friction angle that k attains, recomputed with numpy (radians)."""
    return float(grasp.angles(k).max())


def reference_grip_valid(
    grasp: Grasp,
    k: np.ndarray,
    k_max: float,
    f_max: float | None,
    null: np.ndarray,
    released: float = RELEASED,
) -> bool:
    """Whether the reference's k is a grip the solver's problem admits: k and its
    minimum-norm representative in the box, the forces within f_max, no finger released
    (|P_i| below ``released`` x the load, 1e-9: its direction, and angle, would be
    rounding; 0 admits them)."""
    scale = float(np.linalg.norm(grasp.equilibrating, axis=-1).max())
    forces = np.linalg.norm(grasp.forces(k), axis=-1)
    bound = k_max * (1 + FORCE_TOL)
    inside = np.abs(k).max() <= bound and np.abs(minimum_norm(k, null)).max() <= bound
    limited = f_max is None or forces.max() <= f_max * (1 + FORCE_TOL)
    return bool(inside and limited and forces.min() >= released * scale)


#: the columns of scenes.csv
COLUMNS = (
    "n", "f_max", "shape", "scene", "status", "max_angle", "lower_bound", "gap",
    "ref_not_pushing", "ref_lower", "ref_feasible", "ref_attained", "ref_valid", "worse",
    "ref_inaccuracy", "false_certificate", "grip_failures", "ref_error", "ref_seconds",
    "solver_seconds",
)  # fmt: skip


def compare(
    scenes: GeneralScenes, reference_seconds: float = math.inf, progress: str = ""
) -> list[dict]:
    """Solve ``scenes`` (one batched call) and each with the reference; a record per scene
    (the columns :data:`COLUMNS`; angles in radians). A progress line every
    ``reference_seconds`` of the reference's time, headed ``progress``."""
    from cvxpy.error import SolverError

    from grasp_env_agents.benchmarks.reference_solver import ConeBisection

    start = time.perf_counter()
    result = solve_minimax(scenes.grasp, scenes.k_max, scenes.f_max)
    solver_seconds = (time.perf_counter() - start) / len(scenes)
    failures = grip_failures(scenes, result)
    reference = ConeBisection(scenes.n, scenes.force_limit)
    records, began, shown = [], time.perf_counter(), time.perf_counter()
    for b in range(len(scenes)):
        grasp, k_max, f_max = scenes.one(b)
        record = {
            "n": scenes.n, "f_max": scenes.force_limit, "shape": scenes.shapes[b], "scene": b,
            "status": Status(result.status[b]).name, "max_angle": float(result.max_angle[b]),
            "lower_bound": float(result.lower_bound[b]), "gap": float(result.gap[b]),
            "grip_failures": "; ".join(failures[b]), "solver_seconds": solver_seconds,
            "ref_error": "",
        }  # fmt: skip
        t0 = time.perf_counter()
        try:
            ref = reference.solve(grasp.equilibrating, grasp.basis, grasp.normals, k_max, f_max)
        except (RuntimeError, ValueError, SolverError) as error:  # Clarabel failed; a layout
            record.update(ref_error=str(error)[:200], ref_seconds=time.perf_counter() - t0)
            records.append(record)
            continue
        record["ref_seconds"] = time.perf_counter() - t0
        null = null_space(grasp) if scenes.n >= 5 else np.zeros((len(ref.k), 0))
        valid = not ref.not_pushing and reference_grip_valid(grasp, ref.k, k_max, f_max, null)
        ref_attained = attained(grasp, ref.k)
        both = not ref.not_pushing and result.status[b] != Status.NOT_PUSHING
        record.update(
            ref_not_pushing=bool(ref.not_pushing),
            ref_lower=float(ref.lower),
            ref_feasible=float(ref.feasible),
            ref_attained=ref_attained,
            ref_valid=valid,
            worse=max(0.0, record["max_angle"] - ref.feasible) if both else math.nan,
            ref_inaccuracy=max(0.0, ref.lower - record["max_angle"]) if both else math.nan,
            false_certificate=bool(
                valid and record["lower_bound"] > ref_attained + CERTIFICATE_TOL
            ),
        )
        records.append(record)
        now = time.perf_counter()
        if progress and (now - shown >= reference_seconds or b + 1 == len(scenes)):
            shown = now
            each = (now - began) / (b + 1)
            print(
                f"  {progress}: {b + 1:,}/{len(scenes):,} scenes, reference {each:.2f} s a "
                f"scene, {each * (len(scenes) - b - 1) / 60:.1f} min left",
                flush=True,
            )
    return records


def _quantiles(values: np.ndarray) -> str:
    if not values.size:
        return "-"
    low, middle, high = np.quantile(values, [0.5, 0.9, 1.0])
    return f"{low:.1e} / {middle:.1e} / {high:.1e}"


def _decades(values: np.ndarray) -> str:
    """Counts of the gaps by decade, e.g. '1e-08: 3, 1e-07: 1' (each up to that bound)."""
    if not values.size:
        return "-"
    exponents = np.ceil(np.log10(values)).astype(int)
    found = np.unique(exponents, return_counts=True)
    return ", ".join(f"<=1e{e:+03d}: {c}" for e, c in zip(*found, strict=True))


def summarise(records: list[dict]) -> dict:
    """One row of figures for a group of scenes' records (angles in the row: degrees for
    the disagreements, radians for the gaps)."""

    def column(name: str, default: float = math.nan) -> np.ndarray:
        return np.array([r.get(name, default) for r in records], dtype=float)

    status = np.array([r["status"] for r in records])
    errors = np.array([bool(r["ref_error"]) for r in records])
    compared = ~errors
    mine_np = status == Status.NOT_PUSHING.name
    ref_np = np.array([bool(r.get("ref_not_pushing", False)) for r in records])
    uncertified = status == Status.UNCERTIFIED.name
    gaps = column("gap")[uncertified]
    worse, inaccuracy = column("worse"), column("ref_inaccuracy")
    # an uncertified grip may be worse by up to its gap: judged apart
    loose = np.where(uncertified, worse, np.nan)
    worse = np.where(uncertified, np.nan, worse)
    worst = int(np.nanargmax(worse)) if np.any(np.isfinite(worse)) else -1
    # where the reference's own valid grip attains its feasible level (elsewhere the level
    # is not backed by a grip: a finger nearly released, Clarabel's tolerance)
    backed = np.array([bool(r.get("ref_valid")) for r in records]) & (
        column("ref_attained") <= column("ref_feasible") + np.deg2rad(WORSE_TOL)
    )
    sure = np.where(backed, worse, np.nan)
    return {
        "scenes": len(records),
        "not pushing": int(mine_np.sum()),
        "NOT_PUSHING disagreements": int((mine_np != ref_np)[compared].sum()),
        "certified": float(1 - uncertified.mean()),
        "uncertified": int(uncertified.sum()),
        "uncertified gap median / 90% / max (rad)": _quantiles(gaps),
        "uncertified gaps by decade (rad)": _decades(gaps),
        "worse max (deg)": float(np.rad2deg(np.nanmax(worse))) if worst >= 0 else math.nan,
        "worse scene": records[worst]["scene"] if worst >= 0 else -1,
        "worse backed max (deg)": float(np.rad2deg(np.nanmax(sure)))
        if np.any(np.isfinite(sure))
        else math.nan,
        "worse uncertified max (deg)": float(np.rad2deg(np.nanmax(loose)))
        if np.any(np.isfinite(loose))
        else math.nan,
        "reference inaccuracy max (deg)": float(np.rad2deg(np.nanmax(inaccuracy)))
        if np.any(np.isfinite(inaccuracy))
        else math.nan,
        "false certificates": int(sum(bool(r.get("false_certificate")) for r in records)),
        "reference grips checked": int(sum(bool(r.get("ref_valid")) for r in records)),
        "invalid grips": int(sum(bool(r["grip_failures"]) for r in records)),
        "reference failures": int(errors.sum()),
        "solver s": float(column("solver_seconds").sum()),
        "reference s": float(np.nansum(column("ref_seconds"))),
    }


def failed(row: dict) -> bool:
    """Whether a summary row shows a failure of the solver (see the module doc)."""
    return bool(
        row["false certificates"]
        or row["invalid grips"]
        or row["NOT_PUSHING disagreements"]
        or row["worse backed max (deg)"] > WORSE_TOL
    )


#: the printed table's columns: (heading, summary key, format)
TABLE = (
    ("scenes", "scenes", "{:,d}"),
    ("not push", "not pushing", "{:,d}"),
    ("NP disagree", "NOT_PUSHING disagreements", "{:,d}"),
    ("certified", "certified", "{:.2%}"),
    ("uncert. gap med/90%/max rad", "uncertified gap median / 90% / max (rad)", "{}"),
    ("worse deg", "worse max (deg)", "{:.1e}"),
    ("worse backed deg", "worse backed max (deg)", "{:.1e}"),
    ("worse uncert deg", "worse uncertified max (deg)", "{:.1e}"),
    ("ref inacc deg", "reference inaccuracy max (deg)", "{:.1e}"),
    ("false cert", "false certificates", "{:,d}"),
    ("bad grips", "invalid grips", "{:,d}"),
    ("ref fail", "reference failures", "{:,d}"),
    ("solver s", "solver s", "{:.2f}"),
    ("ref s", "reference s", "{:.1f}"),
)


def groups(records: list[dict], by: tuple[str, ...]) -> list[tuple[tuple, dict]]:
    """(key, summary) for the records grouped by the columns ``by``, in sorted order."""
    keys = sorted({tuple(r[c] for c in by) for r in records}, key=str)
    return [(key, summarise([r for r in records if tuple(r[c] for c in by) == key]))
            for key in keys]  # fmt: skip


def _label(by: tuple[str, ...], key: tuple) -> str:
    parts = []
    for column, value in zip(by, key, strict=True):
        if column == "n":
            parts.append(f"n={value}")
        elif column == "f_max":
            parts.append("f_max" if value else "no f_max")
        else:
            parts.append(str(value))
    return ", ".join(parts)


def table(records: list[dict], by: tuple[str, ...]) -> list[str]:
    """The printed table's lines, a row per group."""
    width = 26
    lines = [f"{'':{width}s}" + "".join(f"{h:>{max(len(h), 9) + 2}s}" for h, _, _ in TABLE)]
    for key, row in groups(records, by):
        cells = "".join(f"{fmt.format(row[name]):>{max(len(h), 9) + 2}s}" for h, name, fmt in TABLE)
        lines.append(f"{_label(by, key):{width}s}{cells}")
    return lines


def write(records: list[dict], out: Path) -> None:
    """scenes.csv, summary.csv and summary.md in ``out`` (rewritten whole)."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "scenes.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, COLUMNS, restval="")
        writer.writeheader()
        writer.writerows(records)
    rows = [(("n", "f_max"), key, row) for key, row in groups(records, ("n", "f_max"))]
    rows += [(("n", "shape", "f_max"), key, row)
             for key, row in groups(records, ("n", "shape", "f_max"))]  # fmt: skip
    names = list(rows[0][2]) if rows else []
    with open(out / "summary.csv", "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["group", *names])
        for by, key, row in rows:
            writer.writerow([_label(by, key), *(row[name] for name in names)])
    lines = [
        "# The general minimax solver against the cvxpy + Clarabel reference",
        "",
        f"{len(records):,} scenes (benchmarks/general_scenes.py). Worse: max(0, max_angle -"
        " the reference's feasible level); reference inaccuracy: max(0, the reference's"
        " infeasible level - max_angle); false certificates: lower_bound above the max angle"
        " of the reference's valid grip + 1e-9 rad.",
        "",
        "| group | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    for by, key, row in rows:
        cells = [f"{v:.3g}" if isinstance(v, float) else str(v) for v in row.values()]
        lines.append(f"| {_label(by, key)} | " + " | ".join(cells) + " |")
    (out / "summary.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--scenes", type=int, default=1_000, help="scenes per n and f_max setting (>= 1)"
    )
    parser.add_argument("--contacts", type=int, nargs="+", default=list(range(3, 9)),
                        help="the numbers of contacts n to study (3 to 8)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("study_general"), help="output folder")
    parser.add_argument("--progress", type=float, default=30.0, help="seconds between lines")
    args = parser.parse_args(argv)
    if args.scenes < 1:
        parser.error(f"--scenes must be at least 1, got {args.scenes}")
    if not all(3 <= n <= 8 for n in args.contacts):
        parser.error(f"--contacts must be numbers from 3 to 8, got {args.contacts}")
    records: list[dict] = []
    for n in args.contacts:
        for limit in (False, True):
            name = f"n={n}, {'f_max' if limit else 'no f_max'}"
            print(f"{name}: {args.scenes:,} scenes ({', '.join(SHAPES)}) ...", flush=True)
            scenes = general_scenes(n, args.scenes, args.seed, force_limit=limit)
            records += compare(scenes, args.progress, name)
            write(records, args.out)
    print()
    print("\n".join(table(records, ("n", "f_max"))))
    print()
    print("\n".join(table(records, ("n", "shape", "f_max"))))
    print(f"(written to {args.out}/scenes.csv, summary.csv and summary.md)")
    bad = False
    for key, row in groups(records, ("n", "f_max")):
        if failed(row):
            bad = True
            print(f"FAILED {_label(('n', 'f_max'), key)}: {row}")
    for r in records:
        if r["grip_failures"] or r.get("false_certificate"):
            print(f"  scene n={r['n']} f_max={r['f_max']} {r['shape']} #{r['scene']}: "
                  f"{r['grip_failures'] or 'false certificate'}")  # fmt: skip
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
