"""The arithmetic limit of one certified minimax solve on this machine, against which the
solver's speed targets (:data:`TARGETS`) are judged: a target above it cannot be reached.

**Counted from the kernel.** :class:`~.counting.Interpreter` runs the solver's kernels' own
Python source with :class:`~.counting.Counted` floats, which count every floating-point
operation (the rules are in :mod:`~.counting`), on the path the solve really takes, broken
down by kernel into the units of work: an SQP step, a Newton step on a KKT system, a
certificate, a friction-angle evaluation. The leaf kernels' counts have closed forms in n and
m (``*_flops`` below; tests/test_bench_limits.py checks them against the interpreter).

**The units a solve performs.** The benchmark's batch is solved once by the compiled
``solve_batch``, which reports for each grasp the attempt that certified it (its path). The
counts are measured on a few grasps of each path and weighted by how often each path occurs
in the whole batch (the rare paths, the fallback's barrier method and bisection, cost far
more than the common ones: an unweighted small sample would miss or overweight them).

**The machine's rate on that kind of code.** :func:`newton_steps` runs the solver's own leaf
kernels (``evaluate``, ``finger_derivatives`` with the exact Hessian, ``lu_solve`` with
partial pivoting on the KKT system of every finger at the maximum, size m + n + 1, and the
atan and square roots they contain) compiled, on data that stays in the cache, and its
operations per step are counted by the same interpreter. Its rate (counted operations per
second) is the most this machine sustains on the solver's kind of work: small dense systems,
short loops, branches, transcendental functions. Measured on one core (the one-grasp-per-call
path) and on as many threads as ``solve_minimax`` uses for a batch (it splits batches
between a thread pool of the CPUs this process may run on; the kernels release the GIL).
"""

from __future__ import annotations

import math
import threading
import time

import numba
import numpy as np

from grasp_env.mechanics import Grasp, MinimaxResult, solve_minimax
from grasp_env.mechanics.minimax import _THREADS
from grasp_env.mechanics.minimax.driver import solve_batch
from grasp_env.mechanics.minimax.fingers import evaluate, finger_derivatives, setup
from grasp_env.mechanics.minimax.linalg import lu_solve
from grasp_env_agents.benchmarks.counting import (  # noqa: F401 (importable from here too)
    ADD,
    DIV,
    KINDS,
    MATH,
    MODULES,
    MUL,
    SQRT,
    TRANS,
    Counted,
    Interpreter,
    _Tally,
    counted_array,
)

# ------------------------------------------------------- closed forms of the leaf kernels


def evaluate_flops(n: int, m: int) -> int:
    """``evaluate``: per finger the 3 m multiply-adds of a_i, tau_i (6 m), |tau_i| (2 mul,
    1 add, 1 sqrt) and the angle (a division and an atan where a_i > 0: 2)."""
    return n * (6 * m + 6)


def finger_derivatives_flops(m: int, exact: bool) -> int:
    """``finger_derivatives`` for one finger with rho_i > 0, a_i > 0 and a weight: the unit
    tangent (2 div), r2 (3), per component the gradient (7, the rotated gradient along u
    among them) and the rotated gradient across u (3), the Hessian's coefficients c1 (3)
    and, exact only, c2 (6) and c3 (5), per entry (p, q) the three terms added to H (13; with
    exact False the coefficients c2 = c3 = 0 are runtime values, multiplied all the same)."""
    return 8 + (11 if exact else 0) + 10 * m + 13 * m * m


def lu_solve_flops(size: int) -> int:
    """``lu_solve`` of a dense ``size`` system (no zero multipliers skipped): per column c the
    pivot threshold 1e-14 |A|max (1 mul) and, per row below it, the multiplier (1 div), the
    row update 2 (s - c - 1) and the right-hand side's (2); back substitution 2 (s - c - 1) + 1
    per row. Summed over c: (s - 1) s (2s - 1) / 3 + 5 s (s - 1) / 2 + 2 s."""
    s = size
    return (s - 1) * s * (2 * s - 1) // 3 + 5 * s * (s - 1) // 2 + 2 * s


# -------------------------------------------------------- the machine's rate on that code


@numba.njit(nogil=True, cache=True)
def newton_steps(k0, a0, al, tau0, T, repeats):
    """``repeats`` Newton steps on the KKT system of every finger at the maximum (the
    polish's work, with its kernels): evaluate, exact Hessians, the bordered system, LU.
    k stays at k0 plus a rounding-size drift, so every step does the same arithmetic."""
    n, m = al.shape
    size = m + n + 1
    a = np.empty(n)
    tau = np.empty((n, 2))
    rho = np.empty(n)
    theta = np.empty(n)
    grads = np.empty((n, m))
    H = np.empty((m, m))
    A = np.empty((size, size))
    rhs = np.empty(size)
    k = np.empty(m)
    total = 0.0
    for j in range(m):
        k[j] = k0[j]
    for _ in range(repeats):
        evaluate(k, a0, al, tau0, T, a, tau, rho, theta)
        for p in range(m):
            for q in range(m):
                H[p, q] = 0.0
        for i in range(n):
            finger_derivatives(True, i, 1.0 / n, a, tau, rho, al, T, grads[i], H)
        for p in range(size):
            for q in range(size):
                A[p, q] = 0.0
        for p in range(m):
            for q in range(m):
                A[p, q] = H[p, q]
            rhs[p] = 0.0
        for i in range(n):
            for p in range(m):
                A[p, m + i] = grads[i, p]
                A[m + i, p] = grads[i, p]
            A[m + i, size - 1] = -1.0
            A[size - 1, m + i] = 1.0
            rhs[m + i] = theta[i] - theta[0]
        rhs[size - 1] = 1.0
        lu_solve(A, rhs, size)
        for j in range(m):
            k[j] = k0[j] + 1e-12 * rhs[j]
        total += rhs[size - 1]
    return total


def newton_inputs(grasp: Grasp, k: np.ndarray) -> tuple[np.ndarray, ...]:
    """(k in units of the load, a0, al, tau0, T) of one grasp, from the solver's ``setup``."""
    F = np.ascontiguousarray(grasp.equilibrating, dtype=float)
    E = np.ascontiguousarray(grasp.basis, dtype=float)
    N = np.ascontiguousarray(grasp.normals, dtype=float)
    n, m = F.shape[0], E.shape[0]
    a0, al, tau0, T = np.empty(n), np.empty((n, m)), np.empty((n, 2)), np.empty((n, 2, m))
    scale, _ = _setup(F, E, N, a0, al, tau0, T)
    return np.asarray(k, dtype=float) / scale, a0, al, tau0, T


@numba.njit(cache=True)
def _setup(F, E, N, a0, al, tau0, T):
    return setup(F, E, N, a0, al, tau0, T)


def newton_step_flops(inputs: tuple[np.ndarray, ...]) -> int:
    """The operations of one :func:`newton_steps` step on ``inputs``, counted by the
    interpreter (the same rules as the solve's)."""
    import sys

    interpreter = Interpreter({"limits": sys.modules[__name__]})
    steps = interpreter.kernel("newton_steps")
    counted = [counted_array(x) for x in inputs]
    steps(*counted, 1)
    one = interpreter.total()
    interpreter.reset()
    steps(*counted, 3)
    three = interpreter.total()
    return (three - one) // 2


def machine_rate(
    inputs: tuple[np.ndarray, ...], threads: int, seconds: float
) -> tuple[float, float]:
    """Counted floating-point operations per second that :func:`newton_steps` sustains on
    ``threads`` threads at once (each on its own copy of the data): (the mean over about
    ``seconds``, as the solver's rates are taken: a shared machine slows both alike; the
    best of its bursts of a few milliseconds, the nearest to an idle machine)."""
    flops = newton_step_flops(inputs)
    copies = [tuple(x.copy() for x in inputs) for _ in range(threads)]
    newton_steps(*copies[0], 10)  # compiled (or loaded from the cache) before timing
    repeats, done, best = 1 << 11, 0, 0.0
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        workers = [threading.Thread(target=newton_steps, args=(*c, repeats)) for c in copies]
        t0 = time.perf_counter()
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join()
        best = max(best, threads * repeats / (time.perf_counter() - t0))
        done += threads * repeats
    return done * flops / elapsed, best * flops


# ------------------------------------------------------------------ the flops of a solve


def batch_paths(grasps: list[Grasp], k_max: np.ndarray) -> np.ndarray:
    """The path (the attempt that certified it) of each grasp, from the compiled solver."""
    F = np.stack([g.equilibrating for g in grasps]).astype(float)
    E = np.stack([g.basis for g in grasps]).astype(float)
    N = np.stack([g.normals for g in grasps]).astype(float)
    size, n, m = F.shape[0], F.shape[1], E.shape[1]
    path = np.empty(size, np.int8)
    solve_batch(
        F, E, N, np.asarray(k_max, float).copy(), np.full(size, np.inf),
        np.empty((size, m)), np.empty((size, n)), np.empty(size), np.empty(size, np.int8),
        path, np.zeros(size, bool), 0, size,
    )  # fmt: skip
    return path


#: The units of work reported: (name, kernel whose inclusive count is the unit's, the call
#: that marks one unit (caller, callee) or None for the kernel's own calls). Disjoint: none
#: of these kernels calls another of them.
UNITS = (
    ("SQP step", "sqp", ("sqp", "quadprog")),
    ("Newton step", "polish", ("polish", "lu_solve")),
    ("multiplier estimate", "multiplier_estimate", None),
    ("certificate", "certify", None),
    ("barrier solve", "barrier_solve", None),
    ("tangential-force start", "apex_start", None),
    ("common-normal-force start", "normal_start", None),
    ("released-finger start", "release_start", None),
)


class SolveCount:
    """The counted operations of one solve, averaged over the benchmark's grasps (weighted
    by the batch's paths): ``flops`` in all, ``kinds`` by kind, ``units[name]`` = (units per
    solve, flops per unit) for UNITS, ``evaluations`` of the friction angles per solve,
    ``paths[code]`` = (share of the batch, flops of a solve on that path)."""

    def __init__(self) -> None:
        self.flops = 0.0
        self.kinds: dict[str, float] = dict.fromkeys(KINDS, 0.0)
        self.units: dict[str, tuple[float, float]] = {}
        self.evaluations = 0.0
        self.paths: dict[int, tuple[float, float]] = {}
        self.counted = 0

    @property
    def rest(self) -> float:
        """Flops per solve outside the units (angle evaluations outside them, the attempts'
        bookkeeping, setup)."""
        return self.flops - sum(count * each for count, each in self.units.values())


def count_solves(grasps: list[Grasp], k_max: np.ndarray, per_path: int = 3) -> SolveCount:
    """Flops per solve: ``per_path`` grasps of each path counted, weighted by the paths'
    shares of the whole batch. Raises if an interpreted solve departs from the compiled one."""
    paths = batch_paths(grasps, k_max)
    interpreter = Interpreter()
    result = SolveCount()
    units = {name: [0.0, 0.0] for name, _, _ in UNITS}  # units, flops per solve
    codes, shares = np.unique(paths, return_counts=True)
    for code, share in zip(codes, shares / len(paths), strict=True):
        chosen = np.flatnonzero(paths == code)[:per_path]
        weight = share / len(chosen)
        flops = 0.0
        for b in chosen:
            g = grasps[b]
            interpreter.reset()
            _, _, _, path = interpreter.solve(
                g.equilibrating, g.basis, g.normals, float(k_max[b]), math.inf
            )
            if path != code:
                raise RuntimeError(f"interpreted solve took path {path}, compiled {code}")
            total = interpreter.total()
            flops += total / len(chosen)
            result.flops += weight * total
            for kind, value in interpreter.by_kind().items():
                result.kinds[kind] += weight * value
            for name, kernel, marker in UNITS:
                count = interpreter.edges[marker] if marker else interpreter.calls[kernel]
                units[name][0] += weight * count
                units[name][1] += weight * interpreter.inclusive[kernel]
            result.evaluations += weight * interpreter.calls["evaluate"]
            result.counted += 1
        result.paths[int(code)] = (float(share), flops)
    result.units = {
        name: (count, flops / count if count else 0.0) for name, (count, flops) in units.items()
    }
    return result


def count_along(
    along: Grasp, k_max: np.ndarray, optimum: MinimaxResult, every: int
) -> tuple[float, float]:
    """Mean flops of a solve on the poses of trajectories after their first two, (cold,
    warm): each pose solved on its own, and started from the two previous poses' ``optimum``
    as ``solve_batch`` does with ``follows`` (secant). ``along`` is (scenes, poses); every
    ``every``-th scene is counted. The ratio is what the arithmetic allows the warm start."""
    k, angles = optimum.k, optimum.angles
    interpreter = Interpreter()
    cold, warm = [], []
    for s in range(0, along.equilibrating.shape[0], every):
        F, E, N = along.equilibrating[s], along.basis[s], along.normals[s]
        for b in range(2, F.shape[0]):
            previous = (k[s, b - 1], k[s, b - 2], angles[s, b - 1], F[b - 1], E[b - 1], N[b - 1])
            for nearby, flops in ((None, cold), (previous, warm)):
                interpreter.reset()
                interpreter.solve(F[b], E[b], N[b], float(k_max[s, 0]), math.inf, nearby)
                flops.append(interpreter.total())
    return float(np.mean(cold)), float(np.mean(warm))


# ----------------------------------------------------------------------------- the report

#: The speeds the solver was asked to reach, solves per second: {fingers: {mode: target}}.
TARGETS = {3: {"single": 60_000, "batched": 300_000}, 4: {"batched": 80_000}}
PATH_NAMES = {0: "apex", 1: "direct", 2: "SQP", 3: "released", 4: "restarted", 5: "fallback",
              6: "uncertified", 7: "nearby", 8: "bisection"}  # fmt: skip


class Limit:
    """The arithmetic limit of one solve: the counted flops and the machine's rates.

    ``measure(mode, seconds)`` times the machine's rate for "single" (one core) or
    "batched" (the threads ``solve_minimax`` splits a batch between): call it next to the
    solver's own measurement of that mode. "single" also times what a solve costs besides
    its arithmetic: an array allocated in compiled code, and a call of ``solve_minimax`` on
    the same grasp without load (checked and answered at once: the call's own cost)."""

    def __init__(self, grasps: list[Grasp], k_max: np.ndarray, k: np.ndarray) -> None:
        self.n = grasps[0].equilibrating.shape[0]
        self.count = count_solves(grasps, k_max)
        self.inputs = newton_inputs(grasps[0], k)
        self.step_flops = newton_step_flops(self.inputs)
        self.threads = _THREADS
        g = grasps[0]
        self._unloaded = Grasp(g.positions, g.normals, np.zeros_like(g.equilibrating), g.basis,
                               g.friction_limit)  # fmt: skip
        self._k_max = float(k_max[0])
        self.rate: dict[str, float] = {}  # flops per second by mode (the mean)
        self.best: dict[str, float] = {}  # (the best burst)
        self.call = math.nan  # seconds per call of solve_minimax without load

    def measure(self, mode: str, seconds: float) -> None:
        if mode not in ("single", "batched"):
            raise ValueError(f"mode must be 'single' or 'batched', got {mode!r}")
        threads = 1 if mode == "single" else self.threads
        self.rate[mode], self.best[mode] = machine_rate(self.inputs, threads, seconds)
        if mode == "single":
            done, start = 0, time.perf_counter()
            while (elapsed := time.perf_counter() - start) < seconds / 4:
                for _ in range(64):
                    solve_minimax(self._unloaded, self._k_max)
                done += 64
            self.call = elapsed / done

    def solves(self, mode: str, best: bool = False) -> float:
        """The limit: solves per second the machine's rate allows for the counted flops."""
        return (self.best if best else self.rate)[mode] / self.count.flops

    def idle(self, mode: str) -> float:
        """The limit of an idle machine: the best one-core burst, on every core for a batch
        (the shared machine's other work cannot be switched off, nor its bursts on two
        threads at once trusted)."""
        cores = self.threads if mode == "batched" else 1
        return cores * self.best["single"] / self.count.flops

    def lines(self, speeds: dict[str, float]) -> list[str]:
        c = self.count
        kinds = ", ".join(f"{c.kinds[k] / c.flops:.0%} {k}" for k in KINDS)
        paths = ", ".join(
            f"{PATH_NAMES.get(code, code)} {share:.1%} at {flops:,.0f}"
            for code, (share, flops) in c.paths.items()
        )
        units = ", ".join(
            f"{count:.2f} {name}s at {each:,.0f}"
            for name, (count, each) in c.units.items()
            if count > 0
        )
        lines = [
            f"  limit: {c.flops:,.0f} flops a solve (counted from the kernels on {c.counted} "
            f"grasps, weighted by the batch's paths: {paths}); {kinds}",
            f"    per solve: {units}, the rest {c.rest:,.0f} ({c.evaluations:.1f} angle "
            f"evaluations at {evaluate_flops(self.n, n_pairs(self.n))})",
            f"    the machine sustains {self.rate['single'] / 1e9:.2f} Gflop/s on the solver's "
            f"Newton step ({self.step_flops:,} flops, compiled, cached data) on one core, "
            f"{self.rate['batched'] / 1e9:.2f} on {self.threads} threads (best bursts "
            f"{self.best['single'] / 1e9:.2f}, {self.best['batched'] / 1e9:.2f}): a limit of "
            f"{self.solves('single'):,.0f} solves/s single, {self.solves('batched'):,.0f} "
            f"batched (at the best bursts {self.solves('single', True):,.0f}, "
            f"{self.solves('batched', True):,.0f})",
        ]
        reach = ", ".join(
            f"{mode} {speeds[mode] / self.solves(mode):.3f}" for mode in ("single", "batched")
        )
        lines.append(f"    the solver reaches, of the limit measured beside it: {reach}")
        spent = 1 / speeds["single"]
        arithmetic = c.flops / self.rate["single"]
        lines.append(
            f"    a single solve takes {spent * 1e6:.1f} us: its arithmetic at the limit "
            f"{arithmetic * 1e6:.1f}, the call (solve_minimax without load) "
            f"{self.call * 1e6:.1f}, the rest {(spent - arithmetic - self.call) * 1e6:.1f} "
            "(branches, loads, the kernels' calls; they allocate nothing)"
        )
        for mode, target in TARGETS.get(self.n, {}).items():
            share = target / self.idle(mode)
            verdict = "below the limit" if share < 1 else "ABOVE the limit: unreachable"
            lines.append(
                f"    the target {mode} >= {target:,} solves/s: {share:.2f} x the limit of an "
                f"idle machine ({self.idle(mode):,.0f}: the best one-core burst"
                f"{f' x {self.threads} cores' if mode == 'batched' else ''}), {verdict}; "
                f"{target / speeds[mode]:.1f} x the solver's rate"
            )
        return lines


def n_pairs(n: int) -> int:
    return n * (n - 1) // 2
