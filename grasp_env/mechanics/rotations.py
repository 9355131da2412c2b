"""Rotations, batched over leading axes, and the checks of rotation matrices and axes."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .checks import real_array

#: Largest deviation of R^T R from the identity accepted in a rotation matrix.
ORTHONORMAL_TOL = 1e-6
# Vectors whose largest |component| lies in this range are normalised by their norm directly
# (no overflow or underflow in it); others are first divided by that component.
_SAFE_SCALE = (1e-150, 1e150)


def unit_vectors(name: str, vectors: ArrayLike, single: bool = False, size: int = 3) -> np.ndarray:
    """``vectors`` (..., size), or (size,) with ``single``, as unit vectors: each finite and
    non-zero, of any length. A vector too long or too short for its norm to be computed
    directly is divided by its largest |component| first, so that nothing overflows or
    underflows. A ValueError names ``name`` otherwise."""
    words = (
        f"a finite non-zero {size}-vector (any length)"
        if single
        else f"finite non-zero {size}-vectors (any length), shape (..., {size})"
    )
    v = real_array(name, vectors, words)
    if v.shape[-1:] != (size,) or (single and v.ndim != 1):
        raise ValueError(f"{name} must be {words}, got shape {v.shape}")
    scale = np.abs(v).max(axis=-1, keepdims=True)
    if not scale.all():
        raise ValueError(f"{name} must be {words}, got a zero vector in {v.tolist()}")
    low, high = _SAFE_SCALE
    if scale.size and not (scale.min() >= low and scale.max() <= high):  # (min() needs a size)
        v = v / scale
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def check_rotations(
    rotations: ArrayLike, single: bool = False, *, batch: bool = False, name: str = "rotation"
) -> np.ndarray:
    """``rotations`` as a float64 array of proper rotation matrices (finite, orthonormal
    within :data:`ORTHONORMAL_TOL`, det +1), or a ValueError naming ``name``, what it must be
    and what is wrong.

    The shape: (T, 3, 3) with T >= 1 (the default), one (3, 3) matrix with ``single``, or
    any (..., 3, 3) with ``batch`` (an empty batch included). Vectorised: a few numpy calls
    whatever the batch. The caller's float64 array comes back as it is (not copied).
    """
    proper = "a proper rotation (finite, orthonormal, det = +1)"
    if single:
        must = f"a (3, 3) matrix, {proper}"
    elif batch:
        must = f"a (3, 3) matrix or an array of them, shape (..., 3, 3), each {proper}"
    else:
        must = f"an array of (3, 3) matrices, shape (T, 3, 3) with T >= 1, each {proper}"
    array = real_array(name, rotations, must)
    if single:
        wrong = array.shape != (3, 3)
    elif batch:
        wrong = array.ndim < 2 or array.shape[-2:] != (3, 3)
    else:
        wrong = array.ndim != 3 or array.shape[1:] != (3, 3)
    if wrong:
        raise ValueError(f"{name} must be {must}, got shape {array.shape}")
    if not array.size:
        if batch:
            return array
        raise ValueError(f"{name} must hold at least one pose: {must}, got shape {array.shape}")
    # entries beyond 1 first, so that R^T R cannot overflow
    if np.abs(array).max() <= 1.0 + ORTHONORMAL_TOL:
        error, det = _orthonormality(array)
        bad = (error > ORTHONORMAL_TOL) | (det <= 0)
        if not bad.any():
            return array
        first = int(np.argmax(bad))
        what = (
            f"|R^T R - I| = {error.flat[first]:.3g}, det = {det.flat[first]:.3g}"
            if error.flat[first] > ORTHONORMAL_TOL
            else f"det = {det.flat[first]:.3g}"
        )
        where = np.unravel_index(first, bad.shape) if bad.ndim else ()
    else:
        first = int(np.argmax(np.abs(array) > 1.0 + ORTHONORMAL_TOL))
        where = np.unravel_index(first, array.shape)[:-2]
        what = f"an entry {array.flat[first]:.3g} (a rotation's entries lie in [-1, 1])"
    pose = f" at pose {tuple(int(i) for i in where)}" if where else ""
    raise ValueError(f"{name} must be {must}; got {what}{pose}")


def _orthonormality(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """max |R^T R - I| and det R of each matrix of ``r`` (..., 3, 3), each of shape (...)."""
    if r.size <= 9 * 64:  # a few matrices: numpy's per-call costs dominate
        gram = np.swapaxes(r, -1, -2) @ r
        return np.abs(gram - np.eye(3)).max(axis=(-2, -1)), np.linalg.det(r)
    # many: the columns' dot products and triple product on contiguous rows (2x faster than
    # batched matmul and det, which are slow on 3 x 3 matrices)
    x0, y0, z0, x1, y1, z1, x2, y2, z2 = np.ascontiguousarray(r.reshape(-1, 9).T)
    errors = np.stack(
        [
            x0 * x0 + x1 * x1 + x2 * x2 - 1.0,
            y0 * y0 + y1 * y1 + y2 * y2 - 1.0,
            z0 * z0 + z1 * z1 + z2 * z2 - 1.0,
            x0 * y0 + x1 * y1 + x2 * y2,
            x0 * z0 + x1 * z1 + x2 * z2,
            y0 * z0 + y1 * z1 + y2 * z2,
        ]
    )
    det = x0 * (y1 * z2 - y2 * z1) + x1 * (y2 * z0 - y0 * z2) + x2 * (y0 * z1 - y1 * z0)
    batch = r.shape[:-2]
    return np.abs(errors).max(axis=0).reshape(batch), det.reshape(batch)


def axis_angle_matrix(axis: ArrayLike, angle: ArrayLike) -> np.ndarray:
    """Rotation by ``angle`` (radians) about ``axis``: Rodrigues' formula, paper eq. 5.

    ``axis`` has shape (..., 3), finite and non-zero, of any length (normalised here, see
    :func:`unit_vectors`), ``angle`` shape (...), finite; the two must broadcast (a ValueError
    naming both shapes otherwise). Returns (..., 3, 3), empty for an empty batch.
    """
    r = unit_vectors("rotation axis", axis)
    angle = real_array("rotation angle", angle, "finite real numbers (radians)")
    try:
        np.broadcast_shapes(r.shape[:-1], angle.shape)
    except ValueError:
        raise ValueError(
            "rotation axis (..., 3) and rotation angle (...) must have batch shapes that"
            f" broadcast, got axis shape {r.shape} and angle shape {angle.shape}"
        ) from None
    c, s = np.cos(angle)[..., None, None], np.sin(angle)[..., None, None]
    rx, ry, rz = r[..., 0], r[..., 1], r[..., 2]
    zero = np.zeros_like(rx)
    cross = np.stack(
        [
            np.stack([zero, -rz, ry], -1),
            np.stack([rz, zero, -rx], -1),
            np.stack([-ry, rx, zero], -1),
        ],
        -2,
    )
    outer = r[..., :, None] * r[..., None, :]
    # R = cos(phi) I + vers(phi) r r^T + sin(phi) [r]x  (eq. 5 written out)
    return c * np.eye(3) + (1.0 - c) * outer + s * cross


def quaternion_matrix(quaternion: ArrayLike) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z) of any length, (..., 4) -> (..., 3, 3)."""
    w, x, y, z = np.moveaxis(unit_vectors("quaternion (w, x, y, z)", quaternion, size=4), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_quaternion(rotation: ArrayLike) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix, (..., 3, 3) -> (..., 4);
    a ValueError unless each matrix is a proper rotation (:func:`check_rotations`)."""
    m = check_rotations(rotation, batch=True)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # Four candidate magnitudes; take each component's sign from the largest one (stable).
    cand = np.stack(
        [
            1 + trace,
            1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
            1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
        ],
        -1,
    )
    best = np.argmax(cand, axis=-1)
    pairs = np.stack(
        [
            cand[..., 0],
            m[..., 2, 1] - m[..., 1, 2],
            m[..., 0, 2] - m[..., 2, 0],
            m[..., 1, 0] - m[..., 0, 1],
            cand[..., 1],
            m[..., 1, 0] + m[..., 0, 1],
            m[..., 0, 2] + m[..., 2, 0],
            cand[..., 2],
            m[..., 2, 1] + m[..., 1, 2],
            cand[..., 3],
        ],
        -1,
    )
    # Row b of `rows` holds 4 q_b q_j for j = w, x, y, z (a symmetric 4x4 built from `pairs`).
    sym = np.array([[0, 1, 2, 3], [1, 4, 5, 6], [2, 5, 7, 8], [3, 6, 8, 9]])
    rows = np.take_along_axis(pairs, sym[best].reshape(*best.shape, 4), axis=-1)
    q = rows / np.linalg.norm(rows, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)
