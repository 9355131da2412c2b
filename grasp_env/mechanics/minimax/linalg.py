"""Dense linear algebra for the kernels: arrays in the calling kernel's stack frame, small
in-place helpers, Gaussian elimination and a Cholesky inverse (sizes <= 24, where loops beat
LAPACK calls).
"""

from __future__ import annotations

from collections.abc import Callable
from math import isfinite, sqrt

import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload
from numba.np.arrayobj import populate_array

from .jit import inline, kernel

#: The most items a vector (VECTOR_ITEMS) and a matrix (STACK_ITEMS) in a kernel's stack
#: frame hold, and a large matrix (LARGE_ITEMS, :func:`stack_large`): a solve's vectors have
#: n, m or up to 28 constraints' items, its matrices up to 49 with three fingers, and the
#: large ones (the KKT and constraint matrices of four fingers) up to 23 x 23. Every call site
#: has its own room, so these sizes set the stack a solve needs (see stack_empty).
VECTOR_ITEMS = 32
STACK_ITEMS = 64
LARGE_ITEMS = 576


def stack_room(ndim: int) -> int:
    """The items a stack array of ``ndim`` dimensions has room for."""
    return VECTOR_ITEMS if ndim == 1 else STACK_ITEMS


def _ndim(shape) -> int:  # type: ignore[no-untyped-def]
    """The dimensions of a shape's numba type (an integer or a tuple of them)."""
    return 1 if isinstance(shape, types.Integer) else len(shape)


def _stack_intrinsic(room: Callable[[int], int]):  # type: ignore[no-untyped-def]
    """An intrinsic ``(dtype, shape) -> array`` of ``room(ndim)`` items in the stack frame of
    the compiled function that calls it: an alloca in its entry block (one per call site,
    reused by every pass of a loop) viewed as a C-contiguous array with no meminfo, which
    needs no reference counts (the kernels compile without numba's runtime, see jit.py)."""

    @intrinsic
    def stack_array(typingctx, dtype, shape):  # type: ignore[no-untyped-def]
        item = dtype.dtype if isinstance(dtype, types.DType) else dtype.instance_type
        ndim = _ndim(shape)
        array_type = types.Array(item, ndim, "C")

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            data_type = context.get_data_type(item)
            data = cgutils.alloca_once(builder, data_type, size=room(ndim))
            shape_type, shape_value = signature.args[1], args[1]
            if isinstance(shape_type, types.Integer):
                dims = [context.cast(builder, shape_value, shape_type, types.intp)]
            else:
                dims = [
                    context.cast(
                        builder, builder.extract_value(shape_value, d), shape_type[d], types.intp
                    )
                    for d in range(ndim)
                ]
            itemsize = context.get_constant(types.intp, context.get_abi_sizeof(data_type))
            strides = []
            stride = itemsize
            for d in reversed(range(ndim)):
                strides.insert(0, stride)
                stride = builder.mul(stride, dims[d])
            array = context.make_array(array_type)(context, builder)
            populate_array(
                array, data=data, shape=dims, strides=strides, itemsize=itemsize, meminfo=None
            )
            return array._getvalue()

        return array_type(dtype, shape), codegen

    return stack_array


_stack_array = _stack_intrinsic(stack_room)
_large_stack_array = _stack_intrinsic(lambda ndim: LARGE_ITEMS)


def _items(shape):  # type: ignore[no-untyped-def]
    """The items of an array of ``shape`` (an int or a tuple of ints)."""


@overload(_items)
def _items_overload(shape):  # type: ignore[no-untyped-def]
    if isinstance(shape, types.Integer):
        return lambda shape: shape

    def items(shape):  # type: ignore[no-untyped-def]
        size = 1
        for s in shape:
            size *= s
        return size

    return items


def _room(shape):  # type: ignore[no-untyped-def]
    """The items a stack array of ``shape`` has room for (compiled code's stack_room)."""


@overload(_room)
def _room_overload(shape):  # type: ignore[no-untyped-def]
    room = stack_room(_ndim(shape))
    return lambda shape: room


@inline
def stack_empty(shape, dtype=np.float64):
    """``np.empty(shape, dtype)`` in the stack frame of the kernel this is inlined into: the
    solve's scratch arrays, with no heap allocation (about 40 ns each with its free, a sixth
    of a three-finger solve when they were numpy's) and no reference counts. Valid while that
    kernel runs, so never returned from a kernel; a call in a loop gives the same memory
    every pass. The rooms of every call site on a solve's deepest path need a thread stack
    of 64 KiB (48 KiB crashes; threads get 8 MiB on Linux, 512 KiB on macOS)."""
    if _items(shape) > _room(shape):
        raise ValueError("a stack array beyond its room (linalg.STACK_ITEMS)")
    return _stack_array(dtype, shape)


@inline
def stack_large(shape):
    """A float64 matrix of zeros of up to LARGE_ITEMS items, as :func:`stack_empty`."""
    if _items(shape) > LARGE_ITEMS:
        raise ValueError("a stack array beyond its room (linalg.LARGE_ITEMS)")
    x = _large_stack_array(np.float64, shape)
    x.fill(0)
    return x


@inline
def stack_zeros(shape, dtype=np.float64):
    """``np.zeros(shape, dtype)`` in the calling kernel's stack frame (see stack_empty)."""
    x = stack_empty(shape, dtype)
    x.fill(0)
    return x


@inline
def stack_copy(x):
    """``x.copy()`` of a C-contiguous array, in the calling kernel's stack frame."""
    y = stack_empty(x.shape, x.dtype)
    flat = y.flat
    for i, value in enumerate(x.flat):
        flat[i] = value
    return y


@inline
def all_finite(x):
    for value in x.flat:
        if not isfinite(value):
            return False
    return True


@inline
def zero(A):
    for p in range(A.shape[0]):
        for q in range(A.shape[1]):
            A[p, q] = 0.0


@inline
def copy_into(dst, src, count):
    for j in range(count):
        dst[j] = src[j]


@kernel
def lu_solve(A, b, size):
    """Solve A x = b in place (b <- x) by Gaussian elimination with partial pivoting.

    Returns False for a (numerically) singular matrix.
    """
    big = 0.0
    for r in range(size):
        for c in range(size):
            big = max(big, abs(A[r, c]))
    if big == 0.0:
        return False
    for c in range(size):
        p = c
        for r in range(c + 1, size):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if abs(A[p, c]) <= 1e-14 * big:
            return False
        if p != c:
            for cc in range(size):
                A[c, cc], A[p, cc] = A[p, cc], A[c, cc]
            b[c], b[p] = b[p], b[c]
        for r in range(c + 1, size):
            f = A[r, c] / A[c, c]
            if f != 0.0:
                for cc in range(c + 1, size):
                    A[r, cc] -= f * A[c, cc]
                b[r] -= f * b[c]
    for c in range(size - 1, -1, -1):
        s = b[c]
        for cc in range(c + 1, size):
            s -= A[c, cc] * b[cc]
        b[c] = s / A[c, c]
    return True


@inline
def bordered_least_squares(cols, rows, count, border, bordered, x):
    """x[:count] <- the combination of the columns cols[:rows, :count] of least norm,
    |sum_p x_p cols[:, p]|^2, with sum_p border[p] x_p = 1 over the first ``bordered``
    columns (x needs count + 1 items; x[count] is the constraint's multiplier). Solved by
    its KKT system [C'C e; e' 0], a relative 1e-12 added to C'C's diagonal; False if it is
    singular."""
    A = stack_large((count + 1, count + 1))
    big = 0.0
    for p in range(count):
        for q in range(count):
            s = 0.0
            for j in range(rows):
                s += cols[j, p] * cols[j, q]
            A[p, q] = s
        big = max(big, A[p, p])
    for p in range(count):
        A[p, p] += 1e-12 * big + 1e-300
        x[p] = 0.0
    for p in range(bordered):
        A[p, count] = border[p]
        A[count, p] = border[p]
    x[count] = 1.0
    return lu_solve(A, x, count + 1)


@kernel
def cholesky_inverse(H, size, out, L, Li):
    """out <- H^-1 for symmetric H via Cholesky (L, Li scratch); False unless H is positive
    definite."""
    for r in range(size):
        for c in range(size):
            L[r, c] = 0.0
            Li[r, c] = 0.0
    for j in range(size):
        s = H[j, j]
        for q in range(j):
            s -= L[j, q] * L[j, q]
        if s <= 1e-14 * max(1.0, abs(H[j, j])):
            return False
        L[j, j] = sqrt(s)
        for r in range(j + 1, size):
            s = H[r, j]
            for q in range(j):
                s -= L[r, q] * L[j, q]
            L[r, j] = s / L[j, j]
    # invert L (lower triangular), then out = L^-T L^-1
    for j in range(size):
        Li[j, j] = 1.0 / L[j, j]
        for r in range(j + 1, size):
            s = 0.0
            for q in range(j, r):
                s -= L[r, q] * Li[q, j]
            Li[r, j] = s / L[r, r]
    for r in range(size):
        for c in range(size):
            s = 0.0
            for q in range(max(r, c), size):
                s += Li[q, r] * Li[q, c]
            out[r, c] = s
    return True
