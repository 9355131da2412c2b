"""Study: does MuJoCo's verdict agree with the analytic one on every shape?

    python -m grasp_env_agents.benchmarks.study_physics_shapes [--per-cell 40] [--seed 0]
        [--out study_physics_shapes] [--condim6 cylinder,sphere] [--rolling-share 0.02]

For each shape kind of :data:`KINDS` (a random box, cylinder, sphere or convex mesh of
:mod:`.general_scenes`, and the paper's coke can with contacts up to 1 mm from its rims) and
each number of contacts n of :data:`CONTACTS`, ``--per-cell`` random scenes, each carried
along a random trajectory (:func:`random_turn`: a random start pose turned about a random
axis by +-6 to +-14 deg in 2 deg steps, 7 to 15 poses) in one continuous MuJoCo rollout
(:func:`grasp_env.physics.check_trajectories`). The grip is the expert's: the certified
minimax optimum ``solve_minimax`` at every pose (k_max = :data:`K_MAX` w; the optimum does not
depend on mu), and mu is set so that the analytic margin, atan(mu) minus the largest friction
angle of a loaded finger over every step of the run, is a chosen distance from the edge,
inside or outside (:data:`MARGINS_DEG`, alternately): so about half the grips hold and half
slip, at known distances from the cone's edge. Each can scene also gives a grip with a
deliberately wrong torque ("torque error"): the can's grip, checked on the same scene with an
extra torque it does not balance, :data:`TORQUE_ERROR` N m beyond what the grip's rolling and
torsional friction can hold (:func:`torque_error`; its margin 2 deg inside), which both
verdicts must call a failure.

Prints a table per shape kind (agreement overall and at >= 0.05 deg from the edge, the
confusion matrix, per n) and writes ``cases.csv`` (a row a trajectory) and ``summary.md`` into
``--out``. Exits with status 1 if the targets are missed: >= 99% agreement overall and 100% at
>= 0.05 deg from the edge. ``--condim6`` names the shape kinds whose contacts get torsional and
rolling friction (:data:`grasp_env.physics.model.CURVED`; ``none`` for the cube's condim 3 on
every shape, to see why the curved ones need it); ``--rolling-share`` the share of the grip's
largest normal force below which a curved object's contact does not roll
(:data:`grasp_env.physics.model.ROLLING_SHARE`; 0: every touching contact rolls).
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from grasp_env.mechanics import (
    MAX_SCENE_CONTACTS,
    Cylinder,
    Scene,
    axis_angle_matrix,
    friction_angles,
    scene_grasp,
    solve_minimax,
)
from grasp_env.mechanics.objects import CAN_HEIGHT, CAN_RADIUS, CAPS
from grasp_env.physics import model as physics_model
from grasp_env.physics.model import MAX_FORCE, check_aspect
from grasp_env.physics.motion import plan_motion, released
from grasp_env.physics.rollout import RolloutReport, check_trajectories
from grasp_env.physics.stability import SETTINGS
from grasp_env_agents.benchmarks.general_scenes import random_rotation, random_scene

#: The shape kinds of the study: :mod:`.general_scenes`' random shapes and the coke can.
KINDS: tuple[str, ...] = ("box", "cylinder", "can", "sphere", "mesh")
#: The numbers of contacts of the study.
CONTACTS: tuple[int, ...] = (3, 4, 5, 6)
#: The analytic margins the grips are set to, degrees: alternately inside (+) and outside (-).
MARGINS_DEG: tuple[float, ...] = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
#: The expert's box, in units of the weight w.
K_MAX = 3.0
#: A grip whose friction angles exceed this is left out (degrees): mu would be above 1 (and one
#: whose margin outside would put atan(mu) below 0.1 deg).
MAX_EXPERT_DEG = 45.0
#: The wrong torque of the "torque error" grips on the can *beyond what the model's rolling and
#: torsional friction can hold*, N m (0.076 w L: the can's weight 3.43 N, its largest edge
#: 0.115 m). A contact's elliptic cone lets it resist a torque of at most its spin length
#: (``SPIN_FRICTION`` tip radii, 0.40 mm on the can) times its normal force, so a grip resists
#: at most that length times the sum of its normal forces: the error is this plus that
#: capacity (:func:`torque_error`), or a squeezing grip (100 N: 0.04 N m) would legitimately
#: hold it.
TORQUE_ERROR = 0.03
#: The can's weight, newtons (a full 330 ml can, 0.35 kg).
CAN_WEIGHT = 0.35 * 9.81
#: How near the can's contacts come to its rims: side heights up to this fraction of the
#: half-height (1.7 mm from a rim), cap offsets up to this fraction of the radius (1 mm).
CAN_REACH = 0.97
#: Sets at least this far from the edge must all agree (agents.studies.agreement's).
FAR_FROM_EDGE_DEG = 0.05


@dataclass(frozen=True)
class ShapeCase:
    """One trajectory of the study: the scene, its poses and the expert's forces (world
    frame, newtons), and the margin it was set to (degrees; None for a torque error)."""

    kind: str
    shape: str
    n: int
    scene: Scene
    rotations: np.ndarray
    forces: np.ndarray
    target_deg: float | None


def can_scene(rng: np.random.Generator, n: int) -> Scene:
    """A random grasp of the coke can (``parse_object("can")``) by ``n`` contacts: on the side
    (two in three) at a random angle and a height up to :data:`CAN_REACH` of the half-height,
    else on a random cap up to :data:`CAN_REACH` of the radius; its centre of gravity within
    0.3 of its half-extents, its weight :data:`CAN_WEIGHT`. Drawn again until the scene is
    accepted."""
    can = Cylinder(radius=CAN_RADIUS, height=CAN_HEIGHT)
    caps = sorted(CAPS)
    for _ in range(1000):
        contacts = []
        for _ in range(n):
            if rng.uniform() < 2 / 3:
                height = rng.uniform(-CAN_REACH, CAN_REACH)
                contacts.append(can.side_point(rng.uniform(0, 2 * np.pi), height))
            else:
                radius, angle = CAN_REACH * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
                offset = radius * np.array([np.cos(angle), np.sin(angle)])
                contacts.append(can.cap_point(caps[rng.integers(2)], offset))
        cg = rng.uniform(-0.3, 0.3, 3) * np.array([CAN_RADIUS, CAN_RADIUS, CAN_HEIGHT / 2])
        cg[:2] *= 0.7  # inside the circle
        try:
            return Scene(shape=can, contacts=np.array(contacts), weight=CAN_WEIGHT, cg_offset=cg)
        except ValueError:
            continue
    raise RuntimeError(f"no can scene with {n} contacts in 1000 draws")


def study_scene(rng: np.random.Generator, n: int, kind: str) -> Scene:
    """A random scene of ``kind`` (:data:`KINDS`) with ``n`` contacts that the MuJoCo model
    accepts (not thinner than its ``MIN_ASPECT``)."""
    for _ in range(1000):
        scene = can_scene(rng, n) if kind == "can" else random_scene(rng, n, kind)
        try:
            check_aspect(scene)
        except ValueError:
            continue
        return scene
    raise RuntimeError(f"no {kind} scene with {n} contacts thick enough in 1000 draws")


def random_turn(rng: np.random.Generator) -> np.ndarray:
    """A random trajectory (T, 3, 3): a random start pose R0 turned about a random world axis
    b, R(alpha) = Rot(b, alpha) R0, alpha from -a to +a by 2 deg, a in {6, 8, ..., 14}."""
    start = random_rotation(rng)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    half = 2.0 * rng.integers(3, 8)
    alphas = np.radians(np.arange(-half, half + 1e-9, 2.0))
    return axis_angle_matrix(np.broadcast_to(axis, (len(alphas), 3)), alphas) @ start


def rolling_capacity(scene: Scene, rotations: np.ndarray, forces: np.ndarray) -> float:
    """The largest torque the model's torsional and rolling friction can hold against the
    grip ``forces`` (T, n, 3; world frame, newtons) along ``rotations``, N m: the contacts'
    spin length (:func:`grasp_env.physics.model.contact_friction`, metres) times the largest
    sum of the normal forces over the poses (MuJoCo's elliptic cone bounds each contact's
    torque by its length times its normal force); 0 on a shape without it (condim 3)."""
    condim, friction = physics_model.contact_friction(scene)
    if condim == 3:
        return 0.0
    spin = float(friction.split()[2]) * physics_model.length_unit(scene)
    local = np.einsum("tji,tnj->tni", rotations, forces)  # R^T P: the object's frame
    normal = np.einsum("tni,ni->tn", local, scene.normals)
    return spin * float(np.clip(normal, 0.0, None).sum(axis=-1).max())


def torque_error(scene: Scene, rotations: np.ndarray, forces: np.ndarray) -> float:
    """The size of a torque error's wrong torque, N m: :data:`TORQUE_ERROR` beyond what the
    grip's rolling and torsional friction can hold (:func:`rolling_capacity`), so that no
    modelled friction can legitimately balance it."""
    return TORQUE_ERROR + rolling_capacity(scene, rotations, forces)


def run_largest_angle(scene: Scene, rotations: np.ndarray, forces: np.ndarray) -> float:
    """The largest friction angle of a loaded finger over the steps of the run of ``forces``
    (radians): what the analytic verdict judges."""
    motion = plan_motion(scene, rotations, forces, None, SETTINGS)
    loaded = ~released(motion.forces, 1.0, SETTINGS["released_force"])
    angles = np.where(loaded, friction_angles(motion.forces, scene.normals), 0.0)
    return float(angles[motion.settle_steps :].max())


def shape_cases(
    seed: int = 0,
    per_cell: int = 40,
    kinds: tuple[str, ...] = KINDS,
    contacts: tuple[int, ...] = CONTACTS,
    margins: tuple[float, ...] = MARGINS_DEG,
) -> list[ShapeCase]:
    """The study's cases (deterministic for a seed): ``per_cell`` expert grips per shape kind
    and number of contacts, their mu set to a margin of ``margins`` (degrees, > 0) in turn
    (inside, then outside), and a torque error per can scene. Scenes whose expert needs more than
    :data:`grasp_env.physics.model.MAX_FORCE` w a finger or angles beyond
    :data:`MAX_EXPERT_DEG` are drawn again."""
    if not (isinstance(per_cell, int) and per_cell >= 1):
        raise ValueError(f"per_cell must be an integer >= 1, got {per_cell!r}")
    unknown = sorted(set(kinds) - set(KINDS))
    if not kinds or unknown:
        raise ValueError(f"kinds must be names from {KINDS}, got {kinds!r}")
    if not contacts or any(not 3 <= n <= MAX_SCENE_CONTACTS for n in contacts):
        raise ValueError(f"contacts must be numbers from 3 to {MAX_SCENE_CONTACTS}, got {contacts}")
    if not margins or not all(m > 0 for m in margins):
        raise ValueError(f"margins must be distances from the edge > 0 deg, got {margins!r}")
    cases = []
    for kind in kinds:
        for n in contacts:
            rng = np.random.default_rng([seed, KINDS.index(kind), n])
            made = 0
            while made < per_cell:
                scene = study_scene(rng, n, kind)
                rotations = random_turn(rng)
                grasps = scene_grasp(scene, rotations)
                k = solve_minimax(grasps, K_MAX * scene.weight).k
                forces = grasps.forces(k)
                if np.linalg.norm(forces, axis=-1).max() > MAX_FORCE * scene.weight:
                    continue
                largest = run_largest_angle(scene, rotations, forces)
                if largest > np.radians(MAX_EXPERT_DEG):
                    continue
                size = margins[(made // 2) % len(margins)]
                target = size if made % 2 == 0 else -size
                if largest + np.radians(target) <= np.radians(0.1):
                    continue  # an expert this near 0 deg has no such margin outside
                mu = float(np.tan(largest + np.radians(target)))
                cases.append(
                    ShapeCase("expert", kind, n, replace(scene, mu=mu), rotations, forces, target)
                )
                if kind == "can":
                    axis = rng.normal(size=3)
                    error = torque_error(scene, rotations, forces)
                    torque = error * axis / np.linalg.norm(axis)
                    wrong = replace(
                        scene, mu=float(np.tan(largest + np.radians(2.0))), extra_torque=torque
                    )
                    cases.append(ShapeCase("torque error", kind, n, wrong, rotations, forces, None))
                made += 1
    return cases


def check_cases(cases: list[ShapeCase], threads: int | None = None) -> list[RolloutReport]:
    """Each case's continuous rollout, 64 at a time."""
    reports: list[RolloutReport] = []
    for start in range(0, len(cases), 64):
        chunk = cases[start : start + 64]
        reports += check_trajectories(
            [(c.scene, c.rotations, c.forces, None) for c in chunk], threads
        )
    return reports


def agreement_row(
    name: str, cases: list[ShapeCase], reports: list[RolloutReport]
) -> dict[str, float | int | str]:
    """One row of a table: agreement overall and far from the edge, and the confusion
    matrix (analytic holds / slips against MuJoCo holds / slips)."""
    predicted = np.array([r.predicted_holds for r in reports], dtype=bool)
    observed = np.array([r.holds for r in reports], dtype=bool)
    far = np.array(
        [
            c.target_deg is None or abs(r.margin_deg) >= FAR_FROM_EDGE_DEG
            for c, r in zip(cases, reports, strict=True)
        ]
    )
    agree = predicted == observed
    return {
        "group": name,
        "trajectories": int(agree.size),
        "agree %": 100.0 * float(agree.mean()) if agree.size else 100.0,
        "far": int(far.sum()),
        "far agree %": 100.0 * float(agree[far].mean()) if far.any() else 100.0,
        "hold/hold": int(np.sum(predicted & observed)),
        "hold/slip": int(np.sum(predicted & ~observed)),
        "slip/hold": int(np.sum(~predicted & observed)),
        "slip/slip": int(np.sum(~predicted & ~observed)),
    }


def markdown(rows: list[dict]) -> str:
    """The rows as a markdown table."""
    keys = list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for row in rows:
        cells = [f"{v:.2f}" if isinstance(v, float) else str(v) for v in row.values()]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def tables(cases: list[ShapeCase], reports: list[RolloutReport]) -> str:
    """The study's tables: all shapes, then one per shape kind by number of contacts."""

    def rows(select) -> tuple[list[ShapeCase], list[RolloutReport]]:
        chosen = [i for i, c in enumerate(cases) if select(c)]
        return [cases[i] for i in chosen], [reports[i] for i in chosen]

    kinds = sorted({c.shape for c in cases}, key=KINDS.index)
    out = ["All shapes", ""]
    out.append(markdown([agreement_row(k, *rows(lambda c, k=k: c.shape == k)) for k in kinds]
                        + [agreement_row("all", cases, reports)]))  # fmt: skip
    for kind in kinds:
        body = [
            agreement_row(f"n = {n}", *rows(lambda c, k=kind, n=n: c.shape == k and c.n == n))
            for n in sorted({c.n for c in cases if c.shape == kind})
        ]
        for grip in sorted({c.kind for c in cases if c.shape == kind}):
            picked = rows(lambda c, k=kind, g=grip: c.shape == k and c.kind == g)
            body.append(agreement_row(grip, *picked))
        out += ["", f"{kind}", "", markdown(body)]
    return "\n".join(out)


def write_cases(path: Path, cases: list[ShapeCase], reports: list[RolloutReport]) -> None:
    """``cases.csv``: a row a trajectory."""
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["shape", "n", "grip", "target_deg", "margin_deg", "analytic_holds",
                         "mujoco_holds", "largest_slip_m", "drift_m", "poses", "spec"])  # fmt: skip
        for c, r in zip(cases, reports, strict=True):
            spec = c.scene.shape.spec() if c.shape != "mesh" else "mesh"
            writer.writerow([c.shape, c.n, c.kind, c.target_deg, f"{r.margin_deg:.6f}",
                             r.predicted_holds, r.holds, f"{r.slip.max():.3e}",
                             f"{r.drift.max():.3e}", len(c.rotations), spec])  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--per-cell", type=int, default=40, help="scenes per shape and n")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("study_physics_shapes"))
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--kinds", default=",".join(KINDS), help="shape kinds, comma-separated")
    parser.add_argument(
        "--condim6",
        default=None,
        help="shape kinds (box, cylinder, sphere, convex mesh) whose contacts get condim 6,"
        " comma-separated, or 'none' (default: the model's CURVED)",
    )
    parser.add_argument(
        "--spin",
        type=float,
        default=None,
        help="torsional and rolling friction on curved shapes, in tip radii (default: the"
        " model's SPIN_FRICTION)",
    )
    parser.add_argument(
        "--rolling-share",
        type=float,
        default=None,
        help="on curved shapes a contact rolls only where its normal force is at least this"
        " share of the grip's largest (default: the model's ROLLING_SHARE; 0: every touching"
        " contact rolls)",
    )
    args = parser.parse_args(argv)
    if args.rolling_share is not None:
        if not 0.0 <= args.rolling_share <= 1.0:
            parser.error(f"--rolling-share must be in [0, 1], got {args.rolling_share}")
        physics_model.ROLLING_SHARE = args.rolling_share  # a study knob, read per run
    if args.spin is not None:
        physics_model.SPIN_FRICTION = args.spin  # a study knob: the model reads it per scene
    if args.condim6 is not None:
        chosen = () if args.condim6 == "none" else tuple(args.condim6.split(","))
        physics_model.CURVED = chosen  # a study knob: the model reads it per scene
    kinds = tuple(args.kinds.split(","))
    args.out.mkdir(parents=True, exist_ok=True)
    clock, cpu = time.perf_counter(), time.process_time()
    cases = shape_cases(args.seed, args.per_cell, kinds)
    made, made_cpu = time.perf_counter() - clock, time.process_time() - cpu
    print(f"{len(cases)} trajectories made in {made:.1f} s ({made_cpu:.1f} s CPU)", flush=True)
    clock, cpu = time.perf_counter(), time.process_time()
    reports = check_cases(cases, args.threads)
    ran, ran_cpu = time.perf_counter() - clock, time.process_time() - cpu
    steps = sum(len(r.motion) for r in reports)
    summary = (
        f"seed {args.seed}, {args.per_cell} scenes per shape and n, condim 6 on"
        f" {physics_model.CURVED or 'nothing'} ({physics_model.SPIN_FRICTION:g} tip radii,"
        f" rolling where a contact's normal force is at least {physics_model.ROLLING_SHARE:g}"
        " of the grip's largest):"
        f" {len(cases)} trajectories, {steps} MuJoCo"
        f" steps; cases {made:.1f} s ({made_cpu:.1f} s CPU), MuJoCo {ran:.1f} s wall"
        f" ({ran_cpu:.1f} s CPU, {1000 * ran_cpu / len(cases):.1f} ms CPU a trajectory)"
    )
    text = summary + "\n\n" + tables(cases, reports)
    print(text)
    (args.out / "summary.md").write_text(text + "\n")
    write_cases(args.out / "cases.csv", cases, reports)
    everything = agreement_row("all", cases, reports)
    met = everything["agree %"] >= 99.0 and everything["far agree %"] == 100.0
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
