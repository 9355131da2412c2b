"""The grip whose finger forces point along given directions: a weighted least squares, batched,
and its gradient.

A grip k sets the contact forces P_i(k) = F_i + B_i k (eq. 4; B_i = (e_1i ... e_mi), 3 x m).
Given a direction d_i per finger, the grip that points the forces best along them is the least
squares of their components across the directions, (I - d_i d_i^T) P_i(k) = 0, each finger's
two equations weighted by w_i. Its normal equations

    A k = b,  A = sum_i w_i^2 M_i + r I,  b = -sum_i w_i^2 L_i,
    M_i = B_i^T B_i - a_i a_i^T,  L_i = B_i^T F_i - a_i (d_i . F_i),  a_i = B_i^T d_i,

with a ridge r = RIDGE tr(A - r I) / m (m the pairs in use) so that k stays finite where the
directions leave a squeeze free (two opposed fingers both along their line). The first solve
weighs the fingers equally; each next one by w_i = 1 / |P_i| at the previous grip, so that a
residual measures the angle between P_i and d_i and a finger that nearly lets go is matched as
closely as the others.
The residual is blind to a force's sign: where the directions are inconsistent, re-weighting can
drive a nearly released finger through zero to a pull, so of the solves the grip returned is the
one with the smallest largest friction angle (eq. 2) once clipped to the box |k_ij| <= k_max.

:func:`grip_along` does this for a batch; :func:`grip_along_gradient` differentiates the chosen
solve (its weights held fixed) with respect to the directions: with lambda = A^-1 dL/dk,

    dL/dd_i = w_i^2 [(d_i . P_i) B_i lambda + (lambda . a_i) P_i]
              + 2 (lambda . k) (RIDGE / m) w_i^2 B_i a_i.

A grasp padded with absent contacts (zero forces, normals and pair columns) has the grip of
the real contacts alone: their pairs add nothing to A but the ridge, and m counts the pairs in
use.

Compiled with numba: a learner calls them on every minibatch, where torch spent a few hundred
small tensor operations per call (``agents/policy.py`` wraps them as a torch function).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike

from .checks import is_integer, real_array, real_number

#: Least-squares solves per grip: equal weights, then re-weighted by 1 / |P_i|.
SOLVES = 3
#: Smallest force magnitude (units of w) a weight 1 / |P_i| is computed from.
MIN_FORCE = 1e-3
#: Ridge added to the normal equations, relative to their mean diagonal: it moves a consistent
#: solution by < 1e-5 where it is not needed.
RIDGE = 1e-9

# Every division is by a pivot of a ridged positive semi-definite matrix, a count, or a clamped
# norm; a singular system (contacts whose pairs leave the grip undetermined) gives inf or nan,
# which grip_along refuses.
_kernel = numba.njit(cache=True, nogil=True, error_model="numpy")


@_kernel
def _solve(a, b, out):
    """out = a^-1 b by Gaussian elimination with partial pivoting (a, b overwritten).

    This module's own (minimax.linalg has one): numba keys a kernel's cache on its own file
    only, so a callee from another file could go stale in it (``minimax/jit.py``)."""
    m = len(b)
    for col in range(m):
        pivot = col
        for row in range(col + 1, m):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if pivot != col:
            for c in range(m):
                a[col, c], a[pivot, c] = a[pivot, c], a[col, c]
            b[col], b[pivot] = b[pivot], b[col]
        for row in range(col + 1, m):
            factor = a[row, col] / a[col, col]
            for c in range(col, m):
                a[row, c] -= factor * a[col, c]
            b[row] -= factor * b[col]
    for row in range(m - 1, -1, -1):
        s = b[row]
        for c in range(row + 1, m):
            s -= a[row, c] * out[c]
        out[row] = s / a[row, row]


@_kernel
def _projections(d, f, e, along, matrices, loads):
    """a_i = B_i^T d_i, M_i and L_i of one grasp (module docstring) into the given arrays."""
    m, n = e.shape[0], e.shape[1]
    for i in range(n):
        d_dot_f = d[i, 0] * f[i, 0] + d[i, 1] * f[i, 1] + d[i, 2] * f[i, 2]
        for q in range(m):
            along[i, q] = e[q, i, 0] * d[i, 0] + e[q, i, 1] * d[i, 1] + e[q, i, 2] * d[i, 2]
        for q in range(m):
            loads[i, q] = (
                e[q, i, 0] * f[i, 0] + e[q, i, 1] * f[i, 1] + e[q, i, 2] * f[i, 2]
            ) - along[i, q] * d_dot_f
            for r in range(m):
                gram = e[q, i, 0] * e[r, i, 0] + e[q, i, 1] * e[r, i, 1] + e[q, i, 2] * e[r, i, 2]
                matrices[i, q, r] = gram - along[i, q] * along[i, r]


@_kernel
def _normal_matrix(squared, matrices, ridge, a):
    """A = sum_i w_i^2 M_i + r I into ``a``; returns the count of pairs in use (those with a
    non-zero diagonal: a padded grasp's pairs of absent contacts have none), over which the
    ridge's mean diagonal is taken, so that padding does not change the grip."""
    n, m = matrices.shape[0], matrices.shape[1]
    trace = 0.0
    used = 0
    for q in range(m):
        for r in range(m):
            s = 0.0
            for i in range(n):
                s += squared[i] * matrices[i, q, r]
            a[q, r] = s
        trace += a[q, q]
        if a[q, q] > 0.0:
            used += 1
    for q in range(m):
        a[q, q] += ridge * trace / max(used, 1)
    return max(used, 1)


@_kernel
def _net(f, e, k, out):
    """P_i = F_i + sum_q k_q e_qi (eq. 4) of one grasp into ``out`` (n, 3)."""
    m, n = e.shape[0], e.shape[1]
    for i in range(n):
        for c in range(3):
            s = f[i, c]
            for q in range(m):
                s += k[q] * e[q, i, c]
            out[i, c] = s


@_kernel
def _grips_along(directions, forces, basis, normals, k_max, solves, min_force, ridge, k, weights):
    batch, n, m = forces.shape[0], forces.shape[1], basis.shape[1]
    along = np.empty((n, m))
    matrices = np.empty((n, m, m))
    loads = np.empty((n, m))
    a = np.empty((m, m))
    rhs = np.empty(m)
    grip = np.empty(m)
    clipped = np.empty(m)
    squared = np.empty(n)
    net = np.empty((n, 3))
    for b in range(batch):
        f, e = forces[b], basis[b]
        _projections(directions[b], f, e, along, matrices, loads)
        for i in range(n):
            squared[i] = 1.0
        best = -np.inf
        for solve in range(solves):
            _normal_matrix(squared, matrices, ridge, a)
            for q in range(m):
                s = 0.0
                for i in range(n):
                    s -= squared[i] * loads[i, q]
                rhs[q] = s
            _solve(a, rhs, grip)
            # the grip as the environment plays it: clipped to the box
            for q in range(m):
                clipped[q] = min(max(grip[q], -k_max), k_max)
            _net(f, e, clipped, net)
            # the largest friction angle (eq. 2) as the smallest cos theta_i = P_n / |P_i|,
            # which falls as the angle grows over [0, pi]: no arctangent needed to compare
            smallest = np.inf
            for i in range(n):
                size = math.sqrt(net[i, 0] ** 2 + net[i, 1] ** 2 + net[i, 2] ** 2)
                normal = (
                    net[i, 0] * normals[b, i, 0]
                    + net[i, 1] * normals[b, i, 1]
                    + net[i, 2] * normals[b, i, 2]
                )
                smallest = min(smallest, normal / size if size > 0.0 else 1.0)
            if smallest > best or solve == 0:  # the first of equals, as an argmin of angles
                best = smallest
                for q in range(m):
                    k[b, q] = grip[q]
                for i in range(n):
                    weights[b, i] = squared[i]
            if solve + 1 < solves:  # the next solve's weights: 1 / |P_i|^2 at this grip
                _net(f, e, grip, net)
                for i in range(n):
                    size = max(
                        math.sqrt(net[i, 0] ** 2 + net[i, 1] ** 2 + net[i, 2] ** 2), min_force
                    )
                    squared[i] = 1.0 / (size * size)


def _grasp(
    directions: ArrayLike, forces: ArrayLike, basis: ArrayLike, normals: ArrayLike | None = None
) -> list[np.ndarray]:
    """The arrays as float64, or a ValueError naming the one that is not finite or not of the
    shapes (B, n, 3) and (B, m, n, 3) (a kernel would read past its end)."""
    directions = real_array("directions", directions, "finite real numbers of shape (B, n, 3)")
    batch_shape = directions.shape
    # three contacts at least, as grasp() takes: with two, directions along their line leave
    # the squeeze undetermined (the normal equations vanish)
    if directions.ndim != 3 or batch_shape[2] != 3 or batch_shape[1] < 3:
        raise ValueError(
            f"directions must have shape (B, n, 3) with n >= 3 contacts, got {batch_shape}"
        )
    batch, n = batch_shape[:2]
    arrays = [directions]
    for name, value in (("forces", forces), ("normals", normals)):
        if value is None:
            continue
        array = real_array(name, value, f"finite real numbers of shape {batch_shape}")
        if array.shape != batch_shape:
            raise ValueError(
                f"{name} must have the directions' shape {batch_shape}, got {array.shape}"
            )
        arrays.append(array)
    basis = real_array("basis", basis, f"finite real numbers of shape ({batch}, m, {n}, 3)")
    if (
        basis.ndim != 4
        or basis.shape[0] != batch
        or basis.shape[2:] != (n, 3)
        or not basis.shape[1]
    ):
        raise ValueError(
            f"basis must have shape ({batch}, m, {n}, 3) with m >= 1, got {basis.shape}"
        )
    return [*arrays[:2], basis, *arrays[2:]]


def grip_along(
    directions: ArrayLike,
    forces: ArrayLike,
    basis: ArrayLike,
    normals: ArrayLike,
    k_max: float,
    solves: int = SOLVES,
) -> tuple[np.ndarray, np.ndarray]:
    """The grips (B, m) whose forces F_i + B_i k best point along ``directions`` (module
    docstring), and the squared weights (B, n) of the solve each grip came from.

    Args:
        directions: unit directions d_i (B, n, 3).
        forces: equilibrating forces F_i (B, n, 3), in units of w.
        basis: the interaction basis e_ij (B, m, n, 3) in the same frame.
        normals: the contact normals n_i (B, n, 3) in the same frame.
        k_max: the box |k_ij| <= k_max (units of w, > 0) the grips are judged clipped to.
        solves: least-squares solves per grip (an integer >= 1).
    """
    directions, forces, basis, normals = _grasp(directions, forces, basis, normals)
    k_max = real_number("k_max", k_max, 0.0, open_low=True)
    if not is_integer(solves) or solves < 1:
        raise ValueError(f"solves must be an integer >= 1, got {solves!r}")
    batch, n = forces.shape[:2]
    k = np.empty((batch, basis.shape[1]))
    weights = np.empty((batch, n))
    _grips_along(
        directions, forces, basis, normals, k_max, int(solves), MIN_FORCE, RIDGE, k, weights
    )
    singular = np.flatnonzero(~np.isfinite(k).all(1))
    if len(singular):
        raise ValueError(
            f"the least squares is singular for grasps {singular[:10].tolist()}"
            f"{' ...' if len(singular) > 10 else ''} of the batch: their interaction basis"
            " leaves the grip undetermined (collinear contacts?)"
        )
    return k, weights


@_kernel
def _gradients(directions, forces, basis, weights, k, grad_k, ridge, out):
    batch, n, m = forces.shape[0], forces.shape[1], basis.shape[1]
    along = np.empty((n, m))
    matrices = np.empty((n, m, m))
    loads = np.empty((n, m))
    a = np.empty((m, m))
    g = np.empty(m)
    lam = np.empty(m)
    net = np.empty((n, 3))
    for b in range(batch):
        d, f, e = directions[b], forces[b], basis[b]
        _projections(d, f, e, along, matrices, loads)
        used = _normal_matrix(weights[b], matrices, ridge, a)
        for q in range(m):
            g[q] = grad_k[b, q]
        _solve(a, g, lam)  # A is symmetric: lambda = A^-T dL/dk = A^-1 dL/dk
        _net(f, e, k[b], net)
        lam_dot_k = 0.0
        for q in range(m):
            lam_dot_k += lam[q] * k[b, q]
        for i in range(n):
            w2 = weights[b, i]
            d_dot_p = d[i, 0] * net[i, 0] + d[i, 1] * net[i, 1] + d[i, 2] * net[i, 2]
            lam_dot_a = 0.0
            for q in range(m):
                lam_dot_a += lam[q] * along[i, q]
            for c in range(3):
                b_lam = 0.0
                b_a = 0.0
                for q in range(m):
                    b_lam += e[q, i, c] * lam[q]
                    b_a += e[q, i, c] * along[i, q]
                out[b, i, c] = w2 * (
                    d_dot_p * b_lam + lam_dot_a * net[i, c] + 2.0 * lam_dot_k * ridge / used * b_a
                )


def grip_along_gradient(
    directions: ArrayLike,
    forces: ArrayLike,
    basis: ArrayLike,
    weights: ArrayLike,
    k: ArrayLike,
    grad_k: ArrayLike,
) -> np.ndarray:
    """dL/dd (B, n, 3) of the grips ``k`` that :func:`grip_along` returned with ``weights``,
    given dL/dk (B, m): the chosen solve differentiated with its weights held fixed."""
    directions, forces, basis = _grasp(directions, forces, basis)
    batch, m, n = basis.shape[:3]
    arrays = []
    for name, value, shape in (
        ("weights", weights, (batch, n)),
        ("k", k, (batch, m)),
        ("grad_k", grad_k, (batch, m)),
    ):
        array = real_array(name, value, f"finite real numbers of shape {shape}")
        if array.shape != shape:
            raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
        arrays.append(array)
    out = np.empty(directions.shape)
    _gradients(directions, forces, basis, *arrays, RIDGE, out)
    return out
