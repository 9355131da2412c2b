"""The arithmetic limit of the conic solver (five to eight contacts, docs/solver.md "Any
number of contacts"), as :mod:`.limits` states it for three and four: the floating-point
operations of a solve, counted on the path the solve really takes, against the rate this
machine sustains on the solver's own Newton step; a target above that limit cannot be reached.

**Counted from the kernels.** :class:`ConicInterpreter` is :class:`~.counting.Interpreter`
with the conic package's modules added: it runs the conic kernels' own Python source with
:class:`~.counting.Counted` floats (the same rules: one operation per addition,
multiplication, division, square root or transcendental function, none for constants alone),
``np.cos`` / ``np.sin`` counted as the ``math`` ones are. Four numpy calls it cannot count run
on plain floats instead: the SVD of the force coordinates (once a solve, its operations added
as :func:`svd_flops`, the Golub-Van Loan count of a thin SVD), the least-squares step of a
singular KKT system (rare; not counted), the active-set attempt's start (one solve of its
d + 1 normal equations, not counted) and its least-norm correction that holds the released
fingers (a least squares of 3 rows a released finger, not counted). The leaf kernels' counts
have closed forms (:func:`barrier_flops`, :func:`cholesky_flops`; tests/test_bench_limits.py
checks them against the interpreter).

**The units of a solve.** A barrier Newton step (``centre``: the barrier's gradient and
Hessian, the Jacobi scaling, a Cholesky solve, a backtracking line search of barrier values),
a KKT Newton step (``polish``: the active rows, an LU solve, residuals of the damped step),
a certificate (the barrier duals' weak-duality bound), an SQP step of the active-set attempt
(``sqp``: the angles' and limits' derivatives, the convexified Hessian's inverse, a
Goldfarb-Idnani QP (``qp.dual_qp``, warm-started from the last step's active rows), the line
search on the largest angle).

**The machine's rate.** :func:`barrier_steps` repeats the barrier Newton step (the barrier
with derivatives, the scaling and the Cholesky solve: the work that dominates a solve)
compiled, on data that stays in the cache; its operations per step are counted by the same
interpreter. Measured on one core and on the threads ``solve_minimax`` splits a batch
between.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from math import sqrt

import numba
import numpy as np

from grasp_env.mechanics import Grasp
from grasp_env.mechanics.minimax import _THREADS
from grasp_env.mechanics.minimax.conic import active as conic_active
from grasp_env.mechanics.minimax.conic import barrier as conic_barrier
from grasp_env.mechanics.minimax.conic import codes as conic_codes
from grasp_env.mechanics.minimax.conic import driver as conic_driver
from grasp_env.mechanics.minimax.conic import frames as conic_frames
from grasp_env.mechanics.minimax.conic import polish as conic_polish
from grasp_env.mechanics.minimax.conic import qp as conic_qp
from grasp_env.mechanics.minimax.conic.barrier import barrier
from grasp_env.mechanics.minimax.conic.frames import cholesky_solve, force_coordinates, reduced
from grasp_env.mechanics.minimax.fingers import setup
from grasp_env_agents.benchmarks.counting import (
    MATH,
    Interpreter,
    _CountingNumpy,
    counted_array,
)

#: The conic package's kernel modules, callees before callers.
CONIC_MODULES = {
    module.__name__: module
    for module in (
        conic_codes,
        conic_frames,
        conic_barrier,
        conic_polish,
        conic_qp,
        conic_active,
        conic_driver,
    )
}

# ------------------------------------------------------- closed forms of the leaf kernels


def cholesky_flops(d: int) -> int:
    """``cholesky_solve`` of a positive definite ``d`` system: column j's pivot (2 j and a
    square root) and, per row below it, its entry (j multiply-adds and a division), in all
    sum_j (2 j + 1) (d - j) = d (d + 1) (2 d + 1) / 6; the two triangular solves 2 i + 1 a
    row each, 2 d^2."""
    return d * (d + 1) * (2 * d + 1) // 6 + 2 * d * d


def barrier_flops(n: int, m: int, pairs: int, limited: bool, derivatives: bool) -> int:
    """``barrier`` at a point inside its domain, y of dimension m (d = m + 1 with r),
    ``pairs`` box rows, n fingers, the force limits' cones too where ``limited``.

    Value: tb r (1); per box row b_j . y (2 m), its two sides (2), their logs and sum (4);
    per finger a_i, tau_i (6 m); the angle's cone u (5), |u| (2 x 2 + 1), D (3), -log D (2);
    the limit's cone u0 (2), |u| (3 x 2 + 1), D (3), -log D (2): 14. With derivatives, per box row
    the slopes (3 + 5) and g, H (2 m + 3 m (m + 1) / 2); per cone its Jacobian rows (3 m for
    the angle's, whose entries scale the frames by ct, st; none for the limit's, which copies
    them), J u / D (rows divisions), the gradient (d (2 rows + 2)) and the Hessian's upper
    triangle (2 rows + 5 an entry). The entries that a constant zero of the Jacobian
    multiplies by a constant zero are not counted (see :mod:`.counting`): in the limit's
    cone row 0 is (0, ..., 0, f), in the angle's rows 1 and 2 end in 0."""
    d = m + 1
    value = 1 + pairs * (2 * m + 6) + n * (6 * m + 15)
    if limited:
        value += n * 14
    if not derivatives:
        return value
    upper = d * (d + 1) // 2
    total = value + pairs * (8 + 2 * m + 3 * m * (m + 1) // 2)
    # the angle's cone: rows = 3; at (m, m) rows 1 and 2 multiply constant zeros (2 products
    # not counted)
    total += n * (3 * m + 3 + d * 8 + upper * 11 - 2)
    if limited:
        # the limit's cone: rows = 4; row 0's product is counted only where it meets f (the
        # last column: d entries), so upper - d entries lose one multiplication, and at
        # (m, m) rows 1 to 3 multiply constant zeros (3 products)
        total += n * (4 + d * 10 + upper * 13 - (upper - d) - 3)
    return total


def svd_flops(rows: int, columns: int) -> int:
    """A thin SVD of a rows x columns matrix with its right singular vectors (Golub and Van
    Loan, Matrix Computations, 4th ed., Fig. 8.6.1: R-SVD, 4 r c^2 + 22 c^3 for r >= c; the
    transpose's count otherwise). An estimate, once a solve: numpy's LAPACK is not counted."""
    r, c = max(rows, columns), min(rows, columns)
    return 4 * r * c * c + 22 * c**3


# ---------------------------------------------------------------- the interpreted solve


class _ConicNumpy(_CountingNumpy):
    """The counting numpy, with cos and sin counted and the two uncountable linalg calls
    run on plain floats."""

    cos = staticmethod(MATH["cos"])
    sin = staticmethod(MATH["sin"])

    class linalg:  # (numpy's name)
        @staticmethod
        def svd(a, full_matrices=True):  # type: ignore[no-untyped-def]
            u, s, vt = np.linalg.svd(np.array(a, float), full_matrices=full_matrices)
            return counted_array(u), counted_array(s), counted_array(vt)

        @staticmethod
        def lstsq(a, b, rcond=None):  # type: ignore[no-untyped-def]
            solution = np.linalg.lstsq(np.array(a, float), np.array(b, float), rcond=rcond)
            return (counted_array(solution[0]), *solution[1:])

        @staticmethod
        def solve(a, b):  # type: ignore[no-untyped-def]
            return counted_array(np.linalg.solve(np.array(a, float), np.array(b, float)))


class ConicInterpreter(Interpreter):
    """:class:`~.counting.Interpreter` over the parent package's kernels and the conic
    package's (``kernel("solve_one")`` is the conic ``solve_one``: the extra modules' names
    come last)."""

    def __init__(self) -> None:
        super().__init__(dict(CONIC_MODULES) | {"limits_conic": sys.modules[__name__]})
        for name in CONIC_MODULES:
            self._globals[name]["np"] = _ConicNumpy()

    def conic_solve(
        self, F: np.ndarray, E: np.ndarray, N: np.ndarray, k_max: float, f_max: float
    ) -> tuple[np.ndarray, float, int]:
        """The conic ``solve_one`` on one grasp, counted: (k, lower, status)."""
        n, m = F.shape[0], E.shape[0]
        k, theta = counted_array(np.zeros(m)), counted_array(np.zeros(n))
        grasp = counted_array(F), counted_array(E), counted_array(N)
        lower, status = self.kernel("solve_one")(
            *grasp, *(counted_array(np.array(v, float))[()] for v in (k_max, f_max)), k, theta
        )
        return np.array(k, dtype=float), float(lower), int(status)


#: The SQP's QP calls: warm-started by qp.dual_qp, or (the cold retry where the warm attempt
#: leaves a gap) by minimax.sqp.quadprog.
SQP_QPS = (("sqp", "dual_qp"), ("sqp", "quadprog"))
#: The units of a conic solve: (name, the call that marks one unit: (caller, callee), a
#: tuple of such calls, or a kernel's name for its calls from anywhere).
UNITS = (
    ("barrier Newton step", ("centre", "cholesky_solve")),
    ("KKT Newton step", ("polish", "lu_solve")),
    ("level", "level"),
    ("SQP step", SQP_QPS),
)


class ConicCount:
    """The counted operations of conic solves, averaged over the grasps counted: ``flops``
    a solve (the SVD's estimate included), ``svd`` its share, ``units[name]`` per solve,
    ``barrier_step``, ``kkt_step`` and ``sqp_step`` the flops of one such step (inclusive
    of its line search); ``counted`` scenes counted, ``departed`` left out (their
    interpreted path was not the compiled one's)."""

    def __init__(self) -> None:
        self.flops = 0.0
        self.svd = 0.0
        self.units: dict[str, float] = {}
        self.barrier_step = 0.0
        self.kkt_step = 0.0
        self.sqp_step = 0.0
        self.counted = 0
        self.departed = 0


def count_conic(grasps: list[Grasp], k_max: np.ndarray, f_max: float = math.inf) -> ConicCount:
    """Flops per conic solve, counted on ``grasps`` (each solved by the interpreter) whose
    interpreted solve is the compiled one (the same status, the largest angle within 1e-12
    rad). The interpreter's SVD is numpy's and its products are summed in order where the
    compiled kernels call BLAS, so a scene on a knife edge (a certificate within rounding of
    1e-9 rad) may take another path: such scenes are left out and counted in ``departed``.
    Raises if every scene departs."""
    from grasp_env.mechanics import solve_minimax

    result = ConicCount()
    units = dict.fromkeys((name for name, _ in UNITS), 0.0)
    centre_flops = polish_flops = centre_steps = polish_steps = sqp_flops = sqp_steps = 0.0
    totals: list[float] = []
    svds: list[float] = []
    for g, K in zip(grasps, k_max, strict=True):
        interpreter = ConicInterpreter()
        F, E, N = (np.asarray(x, float) for x in (g.equilibrating, g.basis, g.normals))
        k, _, status = interpreter.conic_solve(F, E, N, float(K), float(f_max))
        compiled = solve_minimax(g, float(K), None if f_max == math.inf else float(f_max))
        if status != int(compiled.status) or not math.isclose(
            float(g.angles(k).max()), float(compiled.max_angle), abs_tol=1e-12
        ):
            result.departed += 1
            continue
        n, m = F.shape[0], E.shape[0]
        svds.append(svd_flops(3 * n, m))
        totals.append(interpreter.total() + svds[-1])
        for name, edge in UNITS:
            if isinstance(edge, str):
                calls = interpreter.calls[edge]
            elif isinstance(edge[0], tuple):
                calls = sum(interpreter.edges[e] for e in edge)
            else:
                calls = interpreter.edges[edge]
            units[name] += calls
        centre_flops += interpreter.inclusive["centre"]
        centre_steps += interpreter.edges[("centre", "cholesky_solve")]
        polish_flops += interpreter.inclusive["polish"]
        polish_steps += interpreter.edges[("polish", "lu_solve")]
        sqp_flops += interpreter.inclusive["sqp"]
        sqp_steps += sum(interpreter.edges[e] for e in SQP_QPS)
        result.counted += 1
    if not result.counted:
        raise RuntimeError(f"every interpreted conic solve departed from the compiled one "
                           f"({result.departed} scenes)")  # fmt: skip
    result.flops = float(np.mean(totals))
    result.svd = float(np.mean(svds))
    result.units = {name: calls / result.counted for name, calls in units.items()}
    result.barrier_step = centre_flops / max(centre_steps, 1)
    result.kkt_step = polish_flops / max(polish_steps, 1)
    result.sqp_step = sqp_flops / max(sqp_steps, 1)
    return result


# -------------------------------------------------------- the machine's rate on that code


@numba.njit(nogil=True, cache=True)
def barrier_steps(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, repeats):
    """``repeats`` barrier Newton steps at x (``centre``'s work without its line search):
    the barrier's gradient and Hessian, the Jacobi scaling, the Cholesky solve. x moves by
    a rounding-size step, so every step does the same arithmetic."""
    d = x.shape[0]
    g = np.empty(d)
    H = np.empty((d, d))
    dx = np.empty(d)
    diag = np.empty(d)
    total = 0.0
    for _ in range(repeats):
        barrier(x, a0, al, tau0, T, box, K, f, ct, st, w, tb, g, H, True)
        for p in range(d):
            diag[p] = 1.0 / sqrt(H[p, p])
        for p in range(d):
            for q in range(d):
                H[p, q] *= diag[p] * diag[q]
            H[p, p] += 1e-14
            dx[p] = -g[p] * diag[p]
        cholesky_solve(H, dx)
        for p in range(d):
            x[p] += 1e-15 * dx[p] * diag[p]
        total += dx[0]
    return total


def step_inputs(grasp: Grasp, k_max: float) -> tuple:
    """The arguments of :func:`barrier_steps` for one grasp: its frames in the force
    coordinates, at y = 0 with r above the level excess at its largest angle (a point of the
    barrier's domain), no force limit, tb = 1e4."""
    F, E, N = (np.ascontiguousarray(x, float) for x in (grasp.equilibrating, grasp.basis,
                                                          grasp.normals))  # fmt: skip
    n, m = F.shape[0], E.shape[0]
    a0, al, tau0, T = np.empty(n), np.empty((n, m)), np.empty((n, 2)), np.empty((n, 2, m))
    scale, _ = _setup(F, E, N, a0, al, tau0, T)
    box = _coordinates(al, T)
    al, T = al @ box, _reduced(T, box)
    w = np.maximum(np.linalg.norm(np.column_stack([a0, tau0]), axis=1), 1e-6)
    theta = np.arctan2(np.linalg.norm(tau0, axis=1), a0)
    t = min(float(theta.max()), 1.5)
    ct, st = math.cos(t), math.sin(t)
    excess = (ct * np.linalg.norm(tau0, axis=1) - st * a0) / w
    x = np.zeros(box.shape[1] + 1)
    x[-1] = float(excess.max()) + 1.0
    return x, a0, al, tau0, T, box, float(k_max) / scale, math.inf, ct, st, w, 1e4


@numba.njit(cache=True)
def _setup(F, E, N, a0, al, tau0, T):
    return setup(F, E, N, a0, al, tau0, T)


@numba.njit(cache=True)
def _coordinates(al, T):
    return force_coordinates(al, T)


@numba.njit(cache=True)
def _reduced(T, box):
    return reduced(T, box)


def barrier_step_flops(inputs: tuple) -> int:
    """The operations of one :func:`barrier_steps` step on ``inputs``, counted."""
    interpreter = ConicInterpreter()
    steps = interpreter.kernel("barrier_steps")
    args = [counted_array(v) if isinstance(v, np.ndarray) else v for v in inputs]
    args = [counted_array(np.array(v, float))[()] if isinstance(v, float) else v for v in args]
    steps(*[a.copy() if isinstance(a, np.ndarray) else a for a in args], 1)
    one = interpreter.total()
    interpreter.reset()
    steps(*[a.copy() if isinstance(a, np.ndarray) else a for a in args], 3)
    return (interpreter.total() - one) // 2


def machine_rate(inputs: tuple, threads: int, seconds: float) -> tuple[float, float]:
    """Counted operations per second that :func:`barrier_steps` sustains on ``threads``
    threads at once (each on its own copy): (the mean over about ``seconds``, the best
    burst), as :func:`.limits.machine_rate` on the three- and four-finger step."""
    flops = barrier_step_flops(inputs)
    copies = [tuple(v.copy() if isinstance(v, np.ndarray) else v for v in inputs)
              for _ in range(threads)]  # fmt: skip
    barrier_steps(*copies[0], 10)
    repeats, done, best = 1 << 9, 0, 0.0
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        workers = [threading.Thread(target=barrier_steps, args=(*c, repeats)) for c in copies]
        t0 = time.perf_counter()
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join()
        best = max(best, threads * repeats / (time.perf_counter() - t0))
        done += threads * repeats
    return done * flops / elapsed, best * flops


class ConicLimit:
    """The arithmetic limit of a conic solve: its counted flops (on ``grasps``) and the
    machine's rate on the barrier Newton step, measured with :meth:`measure` beside the
    solver's own measurement of each mode ("single": one core; "batched": the threads
    ``solve_minimax`` uses)."""

    def __init__(self, grasps: list[Grasp], k_max: np.ndarray) -> None:
        self.n = grasps[0].equilibrating.shape[0]
        self.count = count_conic(grasps, k_max)
        self.inputs = step_inputs(grasps[0], float(k_max[0]))
        self.step_flops = barrier_step_flops(self.inputs)
        self.threads = _THREADS
        self.rate: dict[str, float] = {}
        self.best: dict[str, float] = {}

    def measure(self, mode: str, seconds: float) -> None:
        if mode not in ("single", "batched"):
            raise ValueError(f"mode must be 'single' or 'batched', got {mode!r}")
        threads = 1 if mode == "single" else self.threads
        self.rate[mode], self.best[mode] = machine_rate(self.inputs, threads, seconds)

    def solves(self, mode: str, best: bool = False) -> float:
        """The limit: solves per second the machine's rate allows for the counted flops."""
        return (self.best if best else self.rate)[mode] / self.count.flops

    def lines(self, speeds: dict[str, float], reference: float) -> list[str]:
        """The printed lines, against the solver's ``speeds`` and the reference's rate
        (solves/s) measured in the same run."""
        c = self.count
        units = ", ".join(f"{c.units[name]:,.1f} {name}s" for name, _ in UNITS)
        lines = [
            f"  limit: {c.flops:,.0f} flops a solve (counted from the kernels' source on "
            f"{c.counted} of the scenes, {c.departed} left out whose interpreted path departed; "
            f"the SVD's {c.svd:,.0f} estimated): {units}; a "
            f"barrier step {c.barrier_step:,.0f} flops with its line search, a KKT step "
            f"{c.kkt_step:,.0f}, an SQP step {c.sqp_step:,.0f}",
            f"    the machine sustains {self.rate['single'] / 1e9:.2f} Gflop/s on the barrier "
            f"Newton step ({self.step_flops:,} flops, compiled, cached data) on one core, "
            f"{self.rate['batched'] / 1e9:.2f} on {self.threads} threads (best bursts "
            f"{self.best['single'] / 1e9:.2f}, {self.best['batched'] / 1e9:.2f}): a limit "
            f"of {self.solves('single'):,.0f} solves/s single "
            f"({self.solves('single') / reference:,.0f} x the reference), "
            f"{self.solves('batched'):,.0f} batched "
            f"({self.solves('batched') / reference:,.0f} x)",
        ]
        reach = ", ".join(
            f"{mode} {speeds[mode] / self.solves(mode):.2f}" for mode in ("single", "batched")
        )
        lines.append(f"    the solver reaches, of the limit measured beside it: {reach}")
        return lines
