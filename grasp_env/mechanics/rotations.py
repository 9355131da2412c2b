"""Rotations, batched over leading axes."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def axis_angle_matrix(axis: ArrayLike, angle: ArrayLike) -> np.ndarray:
    """Rotation by ``angle`` (radians) about ``axis``: Rodrigues' formula, paper eq. 5.

    ``axis`` has shape (..., 3) (normalised here), ``angle`` shape (...); the two broadcast.
    Returns (..., 3, 3).
    """
    axis = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    if np.any(~np.isfinite(axis)) or np.any(norm < 1e-12):
        raise ValueError("rotation axis must be a finite, non-zero 3-vector")
    r = axis / norm
    angle = np.asarray(angle, dtype=float)
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
    """Rotation matrix of a quaternion (w, x, y, z), shape (..., 4) -> (..., 3, 3)."""
    q = np.asarray(quaternion, dtype=float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(~np.isfinite(q)) or np.any(norm < 1e-12):
        raise ValueError("quaternion must be a finite, non-zero 4-vector (w, x, y, z)")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_quaternion(rotation: ArrayLike) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix, (..., 3, 3) -> (..., 4)."""
    m = np.asarray(rotation, dtype=float)
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
