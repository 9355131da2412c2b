"""Speed of the certified minimax solver beside the cvxpy + Clarabel reference, in one run.

    grasp-env bench solver [--seconds 2] [--contacts 3,4,5,6,7,8]

Three and four fingers, scenes as in the solver's accuracy test: contact offsets up to 0.35
of the face half-width, centre-of-gravity offsets up to 0.12, weights 1 to 20 N, alpha
across the paper's trajectory, k_max = 2 w. "single" calls ``solve_minimax`` on one pose's
Grasp at a time; "batched" makes one call on a Grasp of 4,096 poses (one scene each);
"trajectories" one call on 128 scenes x 32 poses 1 degree apart with ``follows`` (each
pose's solve starts from the previous one's optimum, as the environments build their
episodes), beside the same batch solved without it (the two timed in turn, five rounds: the
median ratio), and the flops of a solve along them counted both ways (what the arithmetic
allows the warm start: the target is 2 x). The reference is ``benchmarks/reference_solver.py``,
bisection over second-order-cone feasibility solved by Clarabel, run on a few of the same
scenes; the largest difference between the two optima is printed too. The solver is warmed
up first (numba compiles once, then loads its cache).
The speed targets are for the paper's three fingers: single >= 5,000 solves/s and batched
>= 50,000 solves/s; four fingers are reported alongside. Exits with status 1 if a target is
missed.

**Five to eight contacts** (the conic solver): random scenes of
``benchmarks/general_scenes.py`` (boxes, cylinders, spheres and convex meshes, k_max 0.3 to
30 w, no force limit), "single" one grasp a call and "batched" 256 a call, each beside the
reference run on GENERAL_REFERENCE of the same scenes in the same run; the target is >= 1,000 x
the reference at n = 6 and n = 8, in both modes. ``benchmarks/limits_conic.py`` runs the conic
kernels' own Python source with counted arithmetic on GENERAL_COUNTED scenes: the Newton
steps a solve takes (barrier steps, each a Cholesky solve, and KKT steps, each an LU solve),
the levels t it tries, the flops of a solve, and the machine's rate on the barrier Newton
step beside each mode's measurement: the limit in solves/s and in x the reference, and the
share of it the solver reaches. (:func:`conic_steps` counts the kernels' calls alone, with
plain floats.)

**The limit** (``benchmarks/limits.py``, three and four fingers): the floating-point
operations of a solve, counted by running the kernels' own source with counted arithmetic on
grasps of each path the batch takes (weighted by the paths' shares), against the rate this
machine sustains on the solver's Newton step (its own kernels, compiled, cached data)
measured in the same run, on one core for "single" and on the batch's threads for
"batched"; the solver's rate as a share of that limit, and the limit's targets (three
fingers batched >= 300,000 and single >= 60,000 solves/s, four fingers batched >= 80,000)
against it (reported, not enforced).
"""

from __future__ import annotations

import argparse
import sys
import time
import types
from collections import Counter
from collections.abc import Callable

import numpy as np
from numba.core.dispatcher import Dispatcher

from grasp_env.mechanics import (
    FOUR_FINGER_FACES,
    PAPER_AXIS,
    PAPER_FACES,
    Grasp,
    Scene,
    Status,
    pose_rotation,
    scene_grasp,
    solve_minimax,
)
from grasp_env.mechanics.minimax import fingers, linalg, sqp
from grasp_env.mechanics.minimax.conic import active, barrier, driver, frames, polish, qp
from grasp_env_agents.benchmarks.general_scenes import general_scenes
from grasp_env_agents.benchmarks.limits import Limit, count_along
from grasp_env_agents.benchmarks.limits_conic import ConicLimit
from grasp_env_agents.benchmarks.reference_solver import ConeBisection
from grasp_env_agents.commands.bench import Targets

BATCH = 4096
TRAJECTORIES = 128  # x 32 poses = BATCH
#: the flops along trajectories are counted on every COUNTED_EVERY[n]-th (interpreted: slow)
COUNTED_EVERY = {3: 8, 4: 16}
REFERENCE_SCENES = 6
TARGETS = {"single": 5_000, "batched": 50_000}  # solves per second, three fingers
#: The conic solver's rows: contacts, grasps a batched call, scenes for the reference and for
#: the counted Newton steps, and the targets (x the reference's rate, both modes) by contacts.
GENERAL = (5, 6, 7, 8)
GENERAL_BATCH = 256
GENERAL_REFERENCE = 3
GENERAL_COUNTED = 6
RATIO_TARGETS = {6: 1_000, 8: 1_000}


def random_scene(rng: np.random.Generator, n: int) -> Scene:
    return Scene.on_faces(
        PAPER_FACES if n == 3 else FOUR_FINGER_FACES,
        offsets=rng.uniform(-0.35, 0.35, (n, 2)),
        weight=rng.uniform(1.0, 20.0),
        cg_offset=rng.uniform(-0.12, 0.12, 3),
    )


def random_grasps(n: int, count: int, seed: int) -> tuple[list[Grasp], np.ndarray]:
    """``count`` one-pose grasps of random scenes with ``n`` fingers, and their k_max."""
    rng = np.random.default_rng(seed)
    grasps, k_max = [], []
    for _ in range(count):
        scene = random_scene(rng, n)
        rotation = pose_rotation(PAPER_AXIS, np.deg2rad(rng.uniform(-15.0, 15.0)))
        grasps.append(scene_grasp(scene, rotation))
        k_max.append(2 * scene.weight)
    return grasps, np.array(k_max)


def trajectories(n: int, seed: int) -> tuple[Grasp, np.ndarray, np.ndarray]:
    """TRAJECTORIES random scenes along alpha = -15, -14, ..., 16 deg: (grasp, k_max, follows)."""
    rng = np.random.default_rng(seed)
    scenes = [random_scene(rng, n) for _ in range(TRAJECTORIES)]
    rotations = pose_rotation(PAPER_AXIS, np.deg2rad(np.arange(-15.0, 17.0)))
    grasp = stacked([scene_grasp(scene, rotations) for scene in scenes])
    k_max = np.array([[2 * scene.weight] for scene in scenes])
    return grasp, k_max, np.arange(len(rotations)) > 0


def stacked(grasps: list[Grasp]) -> Grasp:
    """One Grasp whose leading axis runs over ``grasps``."""
    fields = ("positions", "normals", "equilibrating", "basis", "friction_limit")
    return Grasp(*(np.stack([getattr(g, name) for g in grasps]) for name in fields))


def rate(call, seconds: float) -> float:
    """Calls per second of ``call(i) -> solves done``, for about ``seconds``."""
    done, i, start = 0, 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        done += call(i)
        i += 1
    return done / elapsed


def alternated(
    first: Callable[[int], int], second: Callable[[int], int], seconds: float, rounds: int = 5
) -> tuple[float, float, list[float]]:
    """The rates of two calls (see :func:`rate`) timed in turn ``rounds`` times for
    ``seconds`` in all: (the median rate of each, the rounds' ratios first / second, sorted).
    Two windows far apart in time would read the shared machine's swings as the ratio."""
    pairs = [
        (rate(first, seconds / 2 / rounds), rate(second, seconds / 2 / rounds))
        for _ in range(rounds)
    ]
    ratios = sorted(a / b for a, b in pairs)
    return (
        float(np.median([a for a, _ in pairs])),
        float(np.median([b for _, b in pairs])),
        ratios,
    )


def measure(n: int, seconds: float) -> dict[str, float]:
    grasps, k_max = random_grasps(n, BATCH, seed=n)
    batch = stacked(grasps)
    solve_minimax(grasps[0], k_max[0])  # warm-up: compile or load the kernels
    solve_minimax(batch, k_max)

    def single(i: int) -> int:
        solve_minimax(grasps[i % BATCH], k_max[i % BATCH])
        return 1

    def batched(_: int) -> int:
        solve_minimax(batch, k_max)
        return BATCH

    along, along_k_max, follows = trajectories(n, seed=n)

    def tracked(_: int) -> int:
        solve_minimax(along, along_k_max, follows=follows)
        return BATCH

    def untracked(_: int) -> int:
        solve_minimax(along, along_k_max)
        return BATCH

    # the limit's machine rate is timed right after the solver's in each mode
    limit = Limit(grasps, k_max, solve_minimax(grasps[0], k_max[0]).k)
    speeds = {}
    for mode, call in (("single", single), ("batched", batched)):
        speeds[mode] = rate(call, seconds)
        limit.measure(mode, seconds)
    result = solve_minimax(batch, k_max)
    reference = ConeBisection(n)
    start = time.perf_counter()
    errors = []
    for i in range(REFERENCE_SCENES):
        g = grasps[i]
        ref = reference.solve(g.equilibrating, g.basis, g.normals, k_max[i])
        errors.append(abs(result.max_angle[i] - ref.upper))
    reference_rate = REFERENCE_SCENES / (time.perf_counter() - start)
    optima = solve_minimax(along, along_k_max, follows=follows)
    # twice the time of one measurement, as the two windows it replaces
    tracked_rate, untracked_rate, ratios = alternated(tracked, untracked, 2 * seconds)
    return {
        "limit": limit,
        **speeds,
        "trajectories": tracked_rate,
        "untracked": untracked_rate,
        "along_ratios": ratios,
        "along_flops": count_along(along, along_k_max, optima, COUNTED_EVERY[n]),
        "reference": reference_rate,
        "error_deg": float(np.rad2deg(max(errors))),
        "gap": float(result.gap.max()),
        "status": np.bincount(result.status, minlength=3),
    }


def conic_steps(grasp: Grasp, k_max: float) -> tuple[Counter, float]:
    """The conic solver's kernel calls on one grasp, counted: the kernels' own Python source
    (``py_func``, what numba compiles) run with plain floats, each kernel's calls tallied by
    name (``cholesky_solve``: a barrier Newton step; ``lu_solve``: a KKT Newton step or a
    step of the QP's projections; ``dual_qp`` or ``quadprog``: an SQP step's QP; ``level``:
    a level t tried). Returns (the tallies, the largest angle found). Seconds a solve
    (about 2 s at n = 5, 15 s at n = 8)."""
    calls: Counter = Counter()
    names: dict = {}  # the conic modules' names in one namespace, so calls between them count
    # (fingers: setup, the angles; linalg and sqp: the active-set attempt's QP)
    for module in (linalg, fingers, sqp, frames, barrier, polish, qp, active, driver):
        names.update(vars(module))
    for name in ("stack_empty", "stack_zeros", "stack_large"):  # the stack arrays, on the heap
        names[name] = np.zeros
    names["stack_copy"] = np.copy
    for name, value in list(names.items()):
        if isinstance(value, Dispatcher):
            source = value.py_func
            body = types.FunctionType(
                source.__code__, names, name, source.__defaults__, source.__closure__
            )

            def counting(*args, _body=body, _name=name):  # type: ignore[no-untyped-def]
                calls[_name] += 1
                return _body(*args)

            names[name] = counting
    F, E, N = (np.array(x, dtype=float) for x in (grasp.equilibrating, grasp.basis, grasp.normals))
    k, theta = np.empty(E.shape[0]), np.empty(F.shape[0])
    names["solve_one"](F, E, N, float(k_max), np.inf, k, theta)
    return calls, float(theta.max())


def measure_general(n: int, seconds: float) -> dict[str, float]:
    """The conic solver's rates on GENERAL_BATCH random scenes with ``n`` contacts, the
    reference's on the first GENERAL_REFERENCE of them, and the Newton steps counted on the
    first GENERAL_COUNTED."""
    scenes = general_scenes(n, GENERAL_BATCH, seed=n)
    grasps = [scenes.one(b)[0] for b in range(len(scenes))]
    k_max = scenes.k_max
    solve_minimax(grasps[0], k_max[0])  # warm-up: compile or load the kernels
    solve_minimax(scenes.grasp, k_max)

    def single(i: int) -> int:
        solve_minimax(grasps[i % GENERAL_BATCH], k_max[i % GENERAL_BATCH])
        return 1

    def batched(_: int) -> int:
        solve_minimax(scenes.grasp, k_max)
        return GENERAL_BATCH

    # the limit's machine rate is timed right after the solver's in each mode
    limit = ConicLimit(grasps[:GENERAL_COUNTED], k_max[:GENERAL_COUNTED])
    speeds = {}
    for mode, call in (("single", single), ("batched", batched)):
        speeds[mode] = rate(call, seconds)
        limit.measure(mode, seconds)
    result = solve_minimax(scenes.grasp, k_max)
    reference = ConeBisection(n)
    errors = []  # the solver's optimum minus the reference's feasible level
    start = time.perf_counter()
    for i in range(GENERAL_REFERENCE):
        g = grasps[i]
        ref = reference.solve(g.equilibrating, g.basis, g.normals, k_max[i])
        errors.append(result.max_angle[i] - ref.feasible)
    reference_rate = GENERAL_REFERENCE / (time.perf_counter() - start)
    pushing = result.status != Status.NOT_PUSHING
    return {
        **speeds,
        "reference": reference_rate,
        "above_deg": float(np.rad2deg(max(0.0, *errors))),
        "below_deg": float(np.rad2deg(max(0.0, *(-e for e in errors)))),
        "certified": float(np.mean(result.status != Status.UNCERTIFIED)),
        "gap": float(np.where(pushing, result.gap, 0.0).max()),
        "status": np.bincount(result.status, minlength=4),
        "barrier_steps": limit.count.units["barrier Newton step"],
        "kkt_steps": limit.count.units["KKT Newton step"],
        "levels": limit.count.units["level"],
        "limit": limit,
    }


def general_lines(n: int, figures: dict, targets: Targets) -> list[str]:
    """The printed rows of the conic solver with ``n`` contacts, its targets judged."""
    interior, boundary, not_pushing, uncertified = figures["status"]
    lines = [
        f"{n} contacts (conic solver, {GENERAL_BATCH} random scenes on four shapes): reference "
        f"{figures['reference']:.2f} solves/s ({GENERAL_REFERENCE} of the scenes); the optima "
        f"at most {figures['above_deg']:.1e} deg above the reference's feasible levels, "
        f"{figures['below_deg']:.1e} deg below; statuses: "
        f"{interior} interior, {boundary} boundary, {not_pushing} not pushing, {uncertified} "
        f"uncertified ({figures['certified']:.1%} certified, largest gap {figures['gap']:.1e}"
        " rad)"
    ]
    for mode in ("single", "batched"):
        speed = figures[mode]
        ratio = speed / figures["reference"]
        line = f"  {mode:8s}{speed:12,.1f} solves/s   {ratio:8,.1f} x the reference"
        if n in RATIO_TARGETS:
            goal = RATIO_TARGETS[n]
            verdict = targets.check(f"{n} contacts {mode} >= {goal:,} x the reference",
                                    ratio >= goal)  # fmt: skip
            line += f"   target >= {goal:,} x: {verdict}"
        lines.append(line)
    steps = figures["barrier_steps"] + figures["kkt_steps"]
    lines.append(
        f"  a solve takes {figures['barrier_steps']:,.0f} barrier Newton steps (Cholesky) and "
        f"{figures['kkt_steps']:,.1f} KKT Newton steps (LU) over {figures['levels']:.1f} "
        f"levels t (its kernels' source run on {GENERAL_COUNTED} of the scenes, calls "
        f"counted): {1e6 / figures['single'] / steps:,.1f} us a step at the single rate"
    )
    lines += figures["limit"].lines(figures, figures["reference"])
    for mode in ("single", "batched"):
        if n in RATIO_TARGETS:
            most = figures["limit"].solves(mode) / figures["reference"]
            goal = RATIO_TARGETS[n]
            lines.append(
                f"    the target {mode} >= {goal:,} x the reference: the limit allows "
                f"{most:,.0f} x, {'below' if goal < most else 'ABOVE: unreachable with'} "
                "the method's counted arithmetic"
            )
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    parser.add_argument(
        "--contacts",
        default="3,4,5,6,7,8",
        help="the numbers of contacts to measure, comma-separated (3 to 8; default all)",
    )
    args = parser.parse_args()
    try:
        contacts = sorted({int(part) for part in args.contacts.split(",")})
    except ValueError:
        parser.error(f"--contacts takes numbers 3 to 8 separated by commas, not {args.contacts!r}")
    if not contacts or not all(3 <= n <= 8 for n in contacts):
        parser.error(f"--contacts takes numbers 3 to 8 separated by commas, not {args.contacts!r}")
    targets = Targets("solver")
    for n in (n for n in (3, 4) if n in contacts):
        figures = measure(n, args.seconds)
        interior, boundary, not_pushing = figures["status"]
        print(
            f"{n} fingers: reference (cvxpy + Clarabel bisection) {figures['reference']:.1f} "
            f"solves/s; largest |optimum - reference| {figures['error_deg']:.1e} deg, "
            f"largest certificate gap {figures['gap']:.1e} rad; statuses of the batch: "
            f"{interior} interior, {boundary} boundary, {not_pushing} not pushing"
        )
        for mode in ("single", "batched"):
            speed = figures[mode]
            line = (
                f"  {mode:8s}{speed:12,.0f} solves/s   "
                f"{speed / figures['reference']:8,.0f} x the reference"
            )
            if n == 3:
                target = f"3 fingers {mode} >= {TARGETS[mode]:,} solves/s"
                verdict = targets.check(target, speed >= TARGETS[mode])
                line += f"   target >= {TARGETS[mode]:,}: {verdict}"
            print(line, flush=True)
        ratios = figures["along_ratios"]
        print(
            f"  trajectories{figures['trajectories']:8,.0f} solves/s   "
            f"{np.median(ratios):8.2f} x the same batch without follows "
            f"({figures['untracked']:,.0f} solves/s; the median of {len(ratios)} rounds "
            f"timed in turn, {ratios[0]:.2f}-{ratios[-1]:.2f} x)",
            flush=True,
        )
        cold, warm = figures["along_flops"]
        print(
            f"    a solve along them: {warm:,.0f} flops from the previous optima, {cold:,.0f} "
            f"on its own (counted on the poses after the first two of every "
            f"{COUNTED_EVERY[n]}th scene): at one rate of arithmetic {cold / warm:.2f} x, "
            f"{'above' if cold / warm >= 2 else 'BELOW'} the target of 2 x (the costs "
            "a solve has besides its arithmetic lower it)",
            flush=True,
        )
        for line in figures["limit"].lines(figures):
            print(line, flush=True)
    for n in (n for n in GENERAL if n in contacts):
        for line in general_lines(n, measure_general(n, args.seconds), targets):
            print(line, flush=True)
    return targets.exit_code()


if __name__ == "__main__":
    sys.exit(main())
