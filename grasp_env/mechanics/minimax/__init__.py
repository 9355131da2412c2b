"""The minimax grip: k* = argmin over the box |k_ij| <= k_max of max_i theta_i(k)
(docs/design.md §1). Three and four contacts are solved by the kernels of this package, as
below; five to eight by the conic solver (:mod:`.conic`, docs/solver.md, "Any number of
contacts").

The problem is quasi-convex: theta_i <= t < 90 deg exactly when P_i(k) = F_i + A_i k (eq. 4)
lies in the cone |P_i - (n_i . P_i) n_i| <= tan(t) (n_i . P_i), convex in k. The solver
(numba kernels in the modules of this package, see docs/solver.md) works in three stages
for each grasp:

1. **Primal.** From the k that minimises the tangential forces (exact when they can all
   vanish: the paper's scene, whose normal lines meet at the centre of gravity, has optimum
   0), Newton's method on the KKT system of min t s.t. theta_i(k) <= t (eq. 2) with every
   finger at the maximum (the typical optimum, the paper's closing observation) is tried
   first for three fingers without a force limit; otherwise an SQP method with a line search
   on max_i theta_i finds the active set (fingers at the maximum, k_ij on the box, fingers
   at the force limit) and Newton's method on its KKT system converges (to a residual of
   1e-12, within about as much of the optimum). With four fingers one of them may let go at
   the optimum (P_i = 0, the cone's apex, where theta_i is singular and the SQP stalls):
   each finger is then tried released, and restarts cover stalls near the apex that are not
   optimal. Along a trajectory (``follows``), Newton's method starts from the previous
   pose's optimum and the sets it nearly has, first: 19 poses in 20 of the random
   environment's trajectories need no more.
2. **Certificate.** Weak duality: for weights l_i >= 0 and |y_i| <= 1 the vectors
   z_i = l_i (cos t B_i y_i - sin t n_i) satisfy z_i . P <= 0 for every P in the cone, and
   for any u_i, u_i . P - |u_i| f_max <= 0 for every |P| <= f_max, so if
       L(t) = sum_i (z_i + u_i) . F_i - |u_i| f_max  -  k_max || sum_i A_i' (z_i + u_i) ||_1 > 0
   no k in the box has every theta_i <= t within the force limits (the minimum over the box
   of an affine function). The KKT multipliers at the optimum t* give L(t*) = 0 only in
   exact arithmetic; moved to t* - 1e-11 rad and corrected (Gauss-Newton, minimum norm) so
   that the free components of the L1 term vanish, they give L > 0: ``lower_bound`` is that
   t, computed, not assumed (released fingers add their own dual terms). The corrections
   cost only second-order terms because every dual direction may turn (u_i is a full
   3-vector, not a multiple of P_i / |P_i|). At t = 90 deg the same bound certifies NOT_PUSHING.
3. **Fallback.** Whatever is not certified to 1e-9 rad goes to robust methods: Dinkelbach
   iterations on t (with Crouzeix-Ferland-Schaible weights) over the convex cone problem at
   fixed t, each solved by a log-barrier method started 1% towards a centre of the box and
   the force limits; stage 2 from its point (where the optimum is degenerate, with more
   active constraints than unknowns, Newton's method drops the weakly active one); and, last,
   bisection on t, each step decided by the barrier's primal point or by the certificate of
   stage 2 built at the minimiser of the cone problem (the barrier's own duals are spoilt by
   rounding below about 1e-6 rad). It also decides NOT_PUSHING and infeasible force limits,
   each with its certificate.

Forces are scaled by the largest equilibrating force inside the kernels, so the tolerances
mean the same for any weight. The kernels compile once (about a minute) into numba's cache.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from ..forces import Grasp, n_pairs, vector_norms
from ..threads import available_cores, thread_pool
from . import codes, conic
from .codes import Path, Status

__all__ = ["MinimaxResult", "Path", "Status", "solve_minimax"]
from .driver import solve_batch, solve_grasp

_THREADS = available_cores()
_PARALLEL_FROM = 64  # smaller batches are not worth the hand-off to threads
_CHUNKS_PER_THREAD = 4
_CONIC_CHUNK = 16  # grasps a chunk of the conic solver's (1 to 30 ms each)
_FLOAT = np.dtype(float)
#: the shapes of one grasp's basis and normals, by the shape of its equilibrating forces
_ONE_GRASP = {(3, 3): ((3, 3, 3), (3, 3)), (4, 3): ((6, 4, 3), (4, 3))}
_STATUSES = tuple(np.int8(status) for status in Status)  # made once: np.int8() takes 0.4 us


class MinimaxResult(NamedTuple):
    """Solution of the minimax problem, batched like the grasp (a named tuple: made once
    per solve, and a solve of one grasp takes microseconds).

    Attributes:
        k: (..., m) optimal interaction scalars, m = n (n - 1) / 2. With five or more
            contacts they are redundant, and k is the minimum-norm k of the optimal
            interaction force (the one the box bounds; docs/solver.md, "Any number of
            contacts").
        angles: (..., n) friction angles at k, radians.
        max_angle: (...) max_i angles, the optimum (attained by k).
        lower_bound: (...) certified lower bound: no k in the box has a smaller max angle.
            Within 1e-9 rad of ``max_angle`` but where ``status`` is UNCERTIFIED (then
            ``gap`` says how far it is) or NOT_PUSHING, where pi/2 certifies that no k keeps
            every finger below 90 deg (within f_max, if given).
        status: (...) :class:`Status` codes (int8). NOT_PUSHING also covers an f_max that no
            k in the box can meet (no grip: then k exceeds the limits least, and its angles
            may be < 90 deg); UNCERTIFIED marks a gap above 1e-9 rad.
    """

    k: np.ndarray
    angles: np.ndarray
    max_angle: np.ndarray
    lower_bound: np.ndarray
    status: np.ndarray

    @property
    def gap(self) -> np.ndarray:
        """Certificate gap max_angle - lower_bound, radians."""
        return self.max_angle - self.lower_bound


def _broadcast(name: str, array: np.ndarray, batch: tuple[int, ...]) -> np.ndarray:
    try:
        return np.broadcast_to(array, batch)
    except ValueError:
        raise ValueError(
            f"{name} must broadcast to the grasp's batch shape {batch}, got shape {array.shape}"
        ) from None


def _positive_limit(name: str, value: ArrayLike, batch: tuple[int, ...]) -> np.ndarray:
    try:
        numbers = np.asarray(value)
        if numbers.dtype.kind not in "iuf":  # not "10" or True, which numpy would convert
            raise TypeError
        numbers = numbers.astype(float, copy=False)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be finite and > 0 (newtons), got {value!r}") from None
    array = _broadcast(name, numbers, batch)
    if not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"{name} must be finite and > 0 (newtons), got {np.unique(array)[:5]}")
    # a kernel array: a read-only one would make numba compile the whole solver again
    return _kernel_array(array.reshape(-1))


def _scalar(value: ArrayLike | None) -> bool:
    """Whether value is one number (or None), cheaply for Python and numpy floats."""
    return value is None or isinstance(value, float | int) or np.ndim(value) == 0


def _positive_number(name: str, value: ArrayLike) -> float:
    if type(value) is float or type(value) is np.float64:  # the usual case, fast
        number = value
    else:
        try:
            if isinstance(value, bool | np.bool_ | str | bytes):  # which float() would convert
                raise TypeError
            number = float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            number = math.nan
    if not 0 < number < math.inf:  # (NaN is not)
        raise ValueError(f"{name} must be finite and > 0 (newtons), got {value!r}")
    return number


def _kernel_array(array: np.ndarray) -> np.ndarray:
    """Float64, C-contiguous and writable: the one array type the kernels are compiled for."""
    if array.dtype is _FLOAT and array.flags.carray:  # (carray: C-contiguous, aligned, writable)
        return array
    return np.array(array, dtype=float, order="C")


def _flat_bool(name: str, value: ArrayLike, batch: tuple[int, ...]) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype != bool:
        raise ValueError(f"{name} must be boolean, got dtype {array.dtype}")
    # a copy: a broadcast view is read-only, and a read-only array is another type to numba
    # (a second compilation of the whole solver, minutes)
    return np.array(_broadcast(name, array, batch), order="C").reshape(-1)


def _flat(array: np.ndarray, batch: tuple[int, ...], item: tuple[int, ...]) -> np.ndarray:
    """Broadcast to (*batch, *item) and flatten the batch, as a kernel array."""
    shape = (*batch, *item)
    if array.shape != shape:  # (a broadcast view is read-only: _kernel_array copies it)
        array = np.broadcast_to(array, shape)
    return _kernel_array(array).reshape(-1, *item)


def _refused(
    path: np.ndarray, F: np.ndarray, N: np.ndarray, k_lim: np.ndarray, f_lim: np.ndarray
) -> ValueError:
    """The ValueError for the first grasp the kernels refused (path < 0), naming the input."""

    b = int(np.flatnonzero(path < 0)[0])
    code = int(path[b])
    where = f" (grasp {b} of the flattened batch)" if path.size > 1 else ""
    scale = float(vector_norms(F[b]).max()) if code != codes.INVALID else 0.0
    low, high = codes.RATIO_RANGE
    if code == codes.BAD_NORMAL:
        return ValueError(
            f"grasp normals must be unit vectors (length within {codes.UNIT_TOL:g} of 1), "
            f"got lengths {np.round(vector_norms(N[b]), 9).tolist()}{where}"
        )
    if code == codes.BAD_LOAD:
        return ValueError(
            "the load's scale (the largest equilibrating force |F_i|) must be 0 or within "
            f"[{codes.LOAD_RANGE[0]:g}, {codes.LOAD_RANGE[1]:g}] N, got {scale:.3g} N{where}"
        )
    for name, value, bad in (
        ("k_max", k_lim[b], codes.BAD_K_MAX),
        ("f_max", f_lim[b], codes.BAD_F_MAX),
    ):
        if code == bad:
            return ValueError(
                f"{name} must be within [{low:g}, {high:g}] x the load's scale (the largest "
                f"equilibrating force, {scale:.3g} N here), i.e. [{low * scale:.3g}, "
                f"{high * scale:.3g}] N, got {value:.3g} N{where}"
            )
    return ValueError("the grasp's equilibrating forces, basis or normals contain NaN or inf")


def _run_batch(kernel, arrays: tuple[np.ndarray, ...], bounds: np.ndarray) -> None:  # type: ignore[no-untyped-def]
    """kernel(*arrays, lo, hi) over the chunks between consecutive bounds: on this thread for
    a small batch, else on the solver's threads (the kernels release the GIL; a core that
    finishes its chunk early takes the next, since hard grasps cluster)."""
    if bounds[-1] < _PARALLEL_FROM or _THREADS == 1:
        kernel(*arrays, 0, int(bounds[-1]))
        return
    pool = thread_pool("minimax", _THREADS)
    chunks = [pool.submit(kernel, *arrays, lo, hi) for lo, hi in itertools.pairwise(bounds)]
    for chunk in chunks:
        chunk.result()


def _solve_one(
    F: np.ndarray, E: np.ndarray, N: np.ndarray, k_max: ArrayLike, f_max: ArrayLike | None
) -> MinimaxResult:
    """One grasp (shapes checked): the lean path and entry (numpy's and numba's per-call
    costs, 0.1 to 0.5 us for each array or scalar made, passed or checked, would rival the
    kernel's 13 us)."""
    k_lim = _positive_number("k_max", k_max)
    f_lim = math.inf if f_max is None else _positive_number("f_max", f_max)
    F, E, N = _kernel_array(F), _kernel_array(E), _kernel_array(N)
    k = np.empty(E.shape[0])
    angles = np.empty(F.shape[0])
    largest, lower, status, path = solve_grasp(F, E, N, k_lim, f_lim, k, angles)
    if path < 0:
        raise _refused(np.array([path]), F[None], N[None], np.array([k_lim]), np.array([f_lim]))
    if largest - lower > codes.GAP_TOL and status != codes.NOT_PUSHING:
        status = codes.UNCERTIFIED_STATUS
    # (_make: a third of the keyword constructor's cost)
    result = (k, angles, np.float64(largest), np.float64(lower), _STATUSES[status])
    return MinimaxResult._make(result)


def solve_minimax(
    grasp: Grasp,
    k_max: ArrayLike,
    f_max: ArrayLike | None = None,
    *,
    follows: ArrayLike | None = None,
) -> MinimaxResult:
    """Globally minimise the largest friction angle over |k_ij| <= k_max (and |P_i| <= f_max).

    Args:
        grasp: one grasp or a batch of them (any leading axes), from :func:`scene_grasp`,
            with 3 to 8 contacts (5 to 8 by the conic solver, :mod:`.conic`).
        k_max: the box half-width, > 0, in the unit of the grasp's forces F_i (newtons for a
            grasp in newtons; the environments solve in units of the weight and pass
            ``k_max_ratio``, see :mod:`grasp_env.envs.spec`); broadcasts against the batch.
            With five or more contacts it bounds the minimum-norm pair scalars of the
            interaction force.
        f_max: optional limit on each finger's force |P_i|, in the same unit, > 0; broadcasts.
        follows: optional bool, broadcasts against the batch: grasp b (in C order) is the
            next pose, along a trajectory, after grasp b - 1, whose optimum is then its first
            start (along 1-degree steps 1.8x to 2x faster with three fingers, about 4x
            with four; not read with five or more). Every optimum is certified as without
            it; where the optimum is not unique (the box binds), k may be another optimal
            point than a solve on its own would return.

    Returns:
        The optimum with its certificate; see :class:`MinimaxResult`. Never NaN.

    Accepted inputs (anything else raises ValueError naming the argument and its range):
    the grasp's equilibrating forces, basis and normals finite (the arrays read here; its
    positions and friction_limit are not read, and a :class:`Grasp` refuses non-finite
    positions and a friction_limit outside [0, pi/2] when it is made), its normals unit
    vectors (length within 1e-6 of 1); the load's scale s, the largest equilibrating force
    |F_i|, either 0 (no load: k = 0, every angle 0) or within [1e-305, 1e305] N; k_max and
    f_max within [1e-12, 1e12] x s (the friction angles depend on k_max / s and f_max / s
    only, and the solver works in units of s, so every weight in that range gives the same
    angles).
    """
    if not isinstance(grasp, Grasp):
        raise ValueError(f"grasp must be a Grasp (from scene_grasp), got {type(grasp).__name__}")
    F, E, N = grasp.equilibrating, grasp.basis, grasp.normals
    if (
        type(F) is np.ndarray
        and type(E) is np.ndarray
        and type(N) is np.ndarray
        and _ONE_GRASP.get(F.shape) == (E.shape, N.shape)
        and _scalar(k_max)
        and _scalar(f_max)
    ):
        return _solve_one(F, E, N, k_max, f_max)  # the usual single grasp, checked cheaply
    F = np.asarray(F, dtype=float)
    E = np.asarray(E, dtype=float)
    N = np.asarray(N, dtype=float)
    low, high = codes.CONTACTS_RANGE
    if F.ndim < 2 or F.shape[-1] != 3 or not low <= F.shape[-2] <= high:
        raise ValueError(
            f"grasp forces must have shape (..., n, 3) with {low} <= n <= {high} contacts,"
            f" got {F.shape}"
        )
    n = F.shape[-2]
    m = n_pairs(n)
    if E.shape[-3:] != (m, n, 3) or N.shape[-2:] != (n, 3):
        raise ValueError(
            f"grasp basis must be (..., {m}, {n}, 3) and normals (..., {n}, 3), "
            f"got {E.shape} and {N.shape}"
        )
    if n <= 4 and F.ndim == 2 and E.ndim == 3 and N.ndim == 2 and _scalar(k_max) and _scalar(f_max):
        return _solve_one(F, E, N, k_max, f_max)
    try:
        batch = np.broadcast_shapes(F.shape[:-2], N.shape[:-2], E.shape[:-3])
    except ValueError:
        raise ValueError("the grasp's arrays have incompatible batch shapes") from None
    k_lim = _positive_limit("k_max", k_max, batch)
    f_lim = (
        np.full(k_lim.shape, np.inf) if f_max is None else _positive_limit("f_max", f_max, batch)
    )
    size = k_lim.size
    follows = np.zeros(size, bool) if follows is None else _flat_bool("follows", follows, batch)
    F = _flat(F, batch, (n, 3))
    E = _flat(E, batch, (m, n, 3))
    N = _flat(N, batch, (n, 3))
    k = np.empty((size, m))
    angles = np.empty((size, n))
    lower = np.empty(size)
    status = np.empty(size, dtype=np.int8)
    path = np.empty(size, dtype=np.int8)
    if n > 4:
        arrays = (F, E, N, k_lim, f_lim, k, angles, lower, status)
        _run_batch(conic.solve_batch, arrays, np.append(np.arange(0, size, _CONIC_CHUNK), size))
        path = np.where(status < 0, status, 0)  # (the conic kernels put refusals in status)
        status[status < 0] = 0
    elif size < _PARALLEL_FROM or _THREADS == 1:
        solve_batch(F, E, N, k_lim, f_lim, k, angles, lower, status, path, follows, 0, size)
    else:
        # the kernel releases the GIL: the cores share a few contiguous chunks each, so that
        # one that finishes early takes the next (hard grasps cluster along trajectories);
        # chunks begin where no grasp follows its predecessor, so that the results do not
        # depend on the number of threads
        heads = np.append(np.flatnonzero(~follows), size)
        even = np.linspace(0, size, _CHUNKS_PER_THREAD * _THREADS + 1).astype(int)
        bounds = np.unique(heads[np.searchsorted(heads, even)])
        bounds = np.unique(np.append(0, bounds))
        arrays = (F, E, N, k_lim, f_lim, k, angles, lower, status, path, follows)
        _run_batch(solve_batch, arrays, bounds)
    if np.any(path < 0):
        raise _refused(path, F, N, k_lim, f_lim)
    angles = angles.reshape(*batch, n)
    if n <= 4:  # (the conic kernels set UNCERTIFIED themselves)
        gap = angles.max(axis=-1).reshape(-1) - lower
        status[(gap > codes.GAP_TOL) & (status != codes.NOT_PUSHING)] = Status.UNCERTIFIED
    return MinimaxResult(
        k=k.reshape(*batch, m),
        angles=angles,
        max_angle=angles.max(axis=-1),
        lower_bound=lower.reshape(batch),
        status=status.reshape(batch),
    )
