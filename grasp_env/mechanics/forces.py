"""Contact forces: grasp matrix, equilibrating and interaction forces, friction angles.

Everything is batched over leading axes: p has shape (..., n, 3) for n contacts, and pairs
(i, j), i < j, are ordered as :func:`contact_pairs` lists them (k12, k13, k23 for n = 3).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike

from .checks import is_integer, real_array
from .rotations import check_rotations
from .scene import Scene

#: The most contacts a grasp may have for :func:`contact_pairs` and :func:`n_pairs` (the
#: scenes have 3 or 4, a gait's hand at most 6 fingers on 8 sites).
MAX_CONTACTS = 64


def _contact_count(n_contacts: int) -> int:
    """``n_contacts`` as an int: an integer (not a boolean) in [2, MAX_CONTACTS]."""
    if type(n_contacts) is int and 2 <= n_contacts <= MAX_CONTACTS:  # the usual case, fast
        return n_contacts
    if not is_integer(n_contacts) or not 2 <= n_contacts <= MAX_CONTACTS:
        raise ValueError(
            f"n_contacts must be an integer in [2, {MAX_CONTACTS}] (a pair needs two contacts),"
            f" got {n_contacts!r}"
        )
    return int(n_contacts)


def contact_pairs(n_contacts: int) -> np.ndarray:
    """The pairs (i, j), i < j, that carry an interaction scalar k_ij: shape (m, 2), for
    ``n_contacts`` an integer in [2, :data:`MAX_CONTACTS`] (one array per count, shared:
    do not write to it)."""
    return _contact_pairs(_contact_count(n_contacts))


@cache
def _contact_pairs(n_contacts: int) -> np.ndarray:
    return np.array(list(combinations(range(n_contacts), 2)))


def n_pairs(n_contacts: int) -> int:
    """m = n (n - 1) / 2, the number of :func:`contact_pairs` of ``n_contacts`` in
    [2, :data:`MAX_CONTACTS`]."""
    n = _contact_count(n_contacts)
    return n * (n - 1) // 2


def skew(v: np.ndarray) -> np.ndarray:
    """[v]x, the cross-product matrix: (..., 3) -> (..., 3, 3)."""
    x, y, z = np.moveaxis(np.asarray(v, dtype=float), -1, 0)
    zero = np.zeros_like(x)
    return np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2
    )


def grasp_matrix(positions: ArrayLike) -> np.ndarray:
    """G = [I ... I; [p_1]x ... [p_n]x], shape (..., 6, 3n), with G P = (sum P_i, sum p_i x P_i)."""
    p = np.asarray(positions, dtype=float)
    n = p.shape[-2]
    eye = np.broadcast_to(np.eye(3), (*p.shape[:-2], n, 3, 3))
    blocks = np.concatenate([eye, skew(p)], axis=-2)  # (..., n, 6, 3)
    return np.moveaxis(blocks, -3, -2).reshape(*p.shape[:-2], 6, 3 * n)


def load_wrench(
    weight: ArrayLike, extra_force: ArrayLike = 0.0, extra_torque: ArrayLike = 0.0
) -> np.ndarray:
    """External wrench (f, tau) on the object about its centre of gravity, world frame: (..., 6).

    f = (0, 0, -w) + f_d, tau = tau_d.
    """
    weight = np.asarray(weight, dtype=float)
    force = np.zeros((*weight.shape, 3))
    force[..., 2] = -weight
    force = force + np.asarray(extra_force, dtype=float)
    torque = np.broadcast_to(np.asarray(extra_torque, dtype=float), force.shape)
    return np.concatenate([force, torque], axis=-1)


def equilibrating_forces(positions: ArrayLike, wrench: ArrayLike) -> np.ndarray:
    """Minimum-norm forces balancing ``wrench`` (Kumar & Waldron): F = G^+ (-(f, tau)), (..., n, 3).

    Closed form of G^+ = G^T (G G^T)^-1: the minimum-norm solution lies in G's row space,
    F_i = lambda + mu x p_i. With q_i = p_i - c about the contacts' centroid c, force balance
    gives F_i = -f / n + mu x q_i, and moment balance J mu = c x f - tau with the contacts'
    "inertia" J = sum_i (|q_i|^2 I - q_i q_i^T), positive definite unless the contacts are
    collinear (:func:`grasp` refuses them). Unlike the paper's screw-pitch form it has no
    singularity at zero torque, and it costs a 3 x 3 solve instead of a 6 x 6 one.

    F is linear in the load and unchanged when the positions and the torque scale alike, so
    it is computed in units of the contacts' spread and of the load: the 3 x 3 solve
    multiplies terms of order |q|^4 by |tau|, which in metres and newtons would under- or
    overflow at the ends of the sizes and loads accepted. Both units are powers of two, so
    the results are those of the plain arithmetic, bit for bit, wherever that neither under-
    nor overflows.
    """
    p = np.asarray(positions, dtype=float)
    wrench = np.asarray(wrench, dtype=float)
    force, torque = wrench[..., :3], wrench[..., 3:]
    centroid = p.mean(axis=-2)
    q = p - centroid[..., None, :]
    length = _power_of_two(np.abs(q).max(axis=(-2, -1)))[..., None]
    torque = torque / length  # a force
    load = _power_of_two(np.maximum(np.abs(force).max(axis=-1), np.abs(torque).max(axis=-1)))
    load = load[..., None]
    force, torque = force / load, torque / load
    q = q / length[..., None]
    qq = np.swapaxes(q, -1, -2) @ q
    inertia = np.trace(qq, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - qq
    mu = _solve_symmetric_3x3(inertia, _cross(centroid / length, force) - torque)
    return (-force[..., None, :] / p.shape[-2] + _cross(mu[..., None, :], q)) * load[..., None, :]


def vector_norms(vectors: ArrayLike) -> np.ndarray:
    """|v| of vectors (..., 3) without squaring what would under- or overflow (a 1e-300 N
    force, a 1e300 N one): each is scaled by a power of two near its largest component first."""
    v = np.asarray(vectors, dtype=float)
    scale = _power_of_two(np.abs(v).max(axis=-1, keepdims=True))
    return scale[..., 0] * np.linalg.norm(v / scale, axis=-1)


def _power_of_two(x: np.ndarray) -> np.ndarray:
    """The power of two in (x / 2, x] (1/2 for x = 0): dividing by it is exact, and brings x
    to [1, 2)."""
    return np.ldexp(1.0, np.frexp(x)[1] - 1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (broadcasting); a lean np.cross for small batched vectors."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _solve_symmetric_3x3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b for symmetric positive definite (..., 3, 3) a, by the adjugate."""
    a00, a01, a02 = a[..., 0, 0], a[..., 0, 1], a[..., 0, 2]
    a11, a12, a22 = a[..., 1, 1], a[..., 1, 2], a[..., 2, 2]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return (
        np.stack(
            [
                c00 * b0 + c01 * b1 + c02 * b2,
                c01 * b0 + c11 * b1 + c12 * b2,
                c02 * b0 + c12 * b1 + c22 * b2,
            ],
            axis=-1,
        )
        / det[..., None]
    )


def interaction_basis(positions: ArrayLike) -> np.ndarray:
    """The interaction directions e_ij as (..., m, n, 3): +u_ij at contact i, -u_ij at contact j.

    u_ij = (p_j - p_i) / |p_j - p_i|; with k_ij > 0 the pair squeezes along its common line.
    G e_ij = 0 for every pair.
    """
    p = np.asarray(positions, dtype=float)
    pairs = contact_pairs(p.shape[-2])
    d = p[..., pairs[:, 1], :] - p[..., pairs[:, 0], :]
    # over a power of two near its largest component (exact), so that |d| cannot under- or
    # overflow whatever the contacts' scale
    d = d / _power_of_two(np.abs(d).max(axis=-1, keepdims=True))
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    basis = np.zeros((*p.shape[:-2], len(pairs), p.shape[-2], 3))
    rows = np.arange(len(pairs))
    basis[..., rows, pairs[:, 0], :] = u
    basis[..., rows, pairs[:, 1], :] = -u
    return basis


def net_forces(equilibrating: ArrayLike, basis: ArrayLike, k: ArrayLike) -> np.ndarray:
    """P = F + sum_{i<j} k_ij e_ij (paper eq. 4): (..., n, 3) from F (..., n, 3) and k (..., m)."""
    return np.asarray(equilibrating) + np.einsum("...m,...mnc->...nc", np.asarray(k), basis)


def friction_angles(forces: ArrayLike, normals: ArrayLike) -> np.ndarray:
    """theta_i in [0, pi], the angle between P_i and the inward normal n_i (paper eq. 2).

    Computed as atan2(|P x n|, P . n), accurate near zero where acos is not.
    """
    forces = np.asarray(forces, dtype=float)
    normals = np.asarray(normals, dtype=float)
    tangential = np.linalg.norm(np.cross(forces, normals), axis=-1)
    return np.arctan2(tangential, np.sum(forces * normals, axis=-1))


@dataclass(frozen=True, eq=False)  # compared by identity: its arrays may be large batches
class Grasp:
    """The contact geometry and equilibrating forces of a scene at one or many poses (world frame).

    Attributes (leading axes ``...`` are the batch of poses):
        positions: (..., n, 3) contact points relative to the centre of gravity, p_i = R (c_i - g).
        normals: (..., n, 3) inward unit normals n_i = R nu_i.
        equilibrating: (..., n, 3) the equilibrating forces F_i.
        basis: (..., m, n, 3) the interaction directions e_ij.
        friction_limit: theta_lim = atan(mu), radians (broadcasts against the batch).

    :func:`scene_grasp` and :func:`grasp` make checked ones. Made directly (a record of
    arrays, e.g. slices of another grasp), a Grasp refuses arrays of anything but real
    numbers, non-finite ``positions`` and a ``friction_limit`` outside [0, pi/2]; the arrays
    :func:`~.minimax.solve_minimax` reads (equilibrating, basis, normals) are checked there.
    """

    positions: np.ndarray
    normals: np.ndarray
    equilibrating: np.ndarray
    basis: np.ndarray
    friction_limit: np.ndarray

    def __post_init__(self) -> None:
        # cheap: the dtypes, and two reductions (none over the big basis)
        for name in ("positions", "normals", "equilibrating", "basis", "friction_limit"):
            value = getattr(self, name)
            if not isinstance(value, np.ndarray | float) or (
                isinstance(value, np.ndarray) and value.dtype.kind not in "iuf"
            ):
                real_array(f"grasp {name}", value)  # a ValueError unless it is numeric
        if not np.isfinite(self.positions).all():
            raise ValueError("grasp positions must be finite real numbers, got NaN or inf")
        limit = self.friction_limit
        if np.ndim(limit) == 0:  # the usual case, without numpy's reductions
            inside = 0.0 <= float(limit) <= _RIGHT  # NaN is not
        else:
            limit = np.asarray(limit)
            inside = bool(((limit >= 0.0) & (limit <= _RIGHT)).all())
        if not inside:
            raise ValueError(
                "grasp friction_limit must be finite angles in [0, pi/2] radians (atan(mu)),"
                f" got {np.unique(limit)[:5].tolist()}"
            )

    def forces(self, k: ArrayLike) -> np.ndarray:
        """Net contact forces P for interaction scalars k (..., m)."""
        return net_forces(self.equilibrating, self.basis, k)

    def angles(self, k: ArrayLike) -> np.ndarray:
        """Friction angles theta_i (..., n) for interaction scalars k."""
        return friction_angles(self.forces(k), self.normals)

    def margins(self, k: ArrayLike) -> np.ndarray:
        """Margins theta_lim - theta_i (..., n), radians: >= 0 where a finger holds."""
        return np.asarray(self.friction_limit)[..., None] - self.angles(k)


#: The largest friction limit accepted, radians: pi/2 (mu -> infinity), and the 1e-6 rad of
#: rounding that lets float32 data in (a float32 pi/2 lies above the float64 one).
_RIGHT = np.pi / 2 + 1e-6


def grasp(
    relative_contacts: ArrayLike,
    object_normals: ArrayLike,
    rotation: ArrayLike,
    wrench: ArrayLike,
    friction_limit: ArrayLike,
) -> Grasp:
    """The grasp at orientation ``rotation`` (..., 3, 3), all inputs broadcasting over ``...``.

    ``relative_contacts`` are c_i - g and ``object_normals`` nu_i, both object frame (..., n, 3);
    ``wrench`` is the world-frame load (..., 6) from :func:`load_wrench`; ``friction_limit``
    theta_lim = atan(mu) in [0, pi/2] radians. Every input must be finite real numbers and
    ``rotation`` proper rotation matrices (:func:`~.rotations.check_rotations`); the shapes
    must broadcast; the contacts (3 to :data:`MAX_CONTACTS` of them) must neither coincide
    nor all lie on one line, to within 1e-7 of their spread (a pair's direction u_ij, or the
    equilibrating forces, would be undefined). Anything else raises a ValueError naming the
    input.
    """
    rotation = check_rotations(rotation, batch=True)
    contacts = real_array("relative_contacts", relative_contacts, "(..., n, 3) finite numbers")
    normals = real_array("object_normals", object_normals, "(..., n, 3) finite numbers")
    wrench = real_array("wrench", wrench, "(..., 6) finite numbers")
    limit = real_array("friction_limit", friction_limit, "finite angles in [0, pi/2] radians")
    n = contacts.shape[-2] if contacts.ndim >= 2 else 0
    if contacts.shape[-1:] != (3,) or not 3 <= n <= MAX_CONTACTS:
        raise ValueError(
            f"relative_contacts must have shape (..., n, 3) with 3 <= n <= {MAX_CONTACTS}"
            f" contacts (two lie on one line), got {contacts.shape}"
        )
    for name, array, item in (("object_normals", normals, (n, 3)), ("wrench", wrench, (6,))):
        if array.shape[max(array.ndim - len(item), 0) :] != item:
            raise ValueError(
                f"{name} must have shape (..., {', '.join(map(str, item))}), got {array.shape}"
            )
    if np.any(limit < 0) or np.any(limit > _RIGHT):
        raise ValueError(
            f"friction_limit must be finite angles in [0, pi/2] radians, got"
            f" {np.unique(limit)[:5].tolist()}"
        )
    batches = {
        "rotation": rotation.shape[:-2],
        "relative_contacts": contacts.shape[:-2],
        "object_normals": normals.shape[:-2],
        "wrench": wrench.shape[:-1],
        "friction_limit": limit.shape,
    }
    try:
        np.broadcast_shapes(*batches.values())
    except ValueError:
        listed = ", ".join(f"{name} {shape}" for name, shape in batches.items())
        raise ValueError(f"the inputs' batch shapes must broadcast, got {listed}") from None
    _check_layout(contacts)
    return _grasp(contacts, normals, rotation, wrench, limit)


#: Contacts closer than this, or all this near one line, in units of their spread, are refused
#: by :func:`grasp`: float64 resolves far less (1e-16), and every layout a Scene accepts (it
#: refuses them at 1e-6 of the box's edge) stays above it.
_DEGENERATE = 1e-7


def _check_layout(contacts: np.ndarray) -> None:
    """A ValueError naming ``relative_contacts`` (..., n, 3) if two coincide (u_ij undefined)
    or all lie on one line (J singular: no force resists a torque about it)."""
    q = contacts - contacts.mean(axis=-2, keepdims=True)
    q = q / _power_of_two(np.abs(q).max(axis=(-2, -1)))[..., None, None]  # the spread is 1 to 2
    pairs = contact_pairs(q.shape[-2])
    gaps = np.linalg.norm(q[..., pairs[:, 1], :] - q[..., pairs[:, 0], :], axis=-1)
    if not (gaps > _DEGENERATE).all():
        where = np.unravel_index(np.argmin(gaps), gaps.shape)
        i, j = pairs[where[-1]]
        raise ValueError(
            f"relative_contacts {i} and {j} coincide (within {_DEGENERATE:g} of the contacts'"
            f" spread){_in_batch(where[:-1])}: their interaction direction is undefined"
        )
    # the contacts' distances from the line through their centroid and the farthest of them
    radii = np.linalg.norm(q, axis=-1)
    far = np.take_along_axis(q, np.argmax(radii, axis=-1)[..., None, None], axis=-2)
    off = np.linalg.norm(_cross(q, far), axis=-1).max(axis=-1) / radii.max(axis=-1)
    if not (off > _DEGENERATE).all():
        where = np.unravel_index(np.argmin(off), off.shape)
        raise ValueError(
            f"relative_contacts all lie on one line (within {_DEGENERATE:g} of their spread)"
            f"{_in_batch(where)}: no contact force resists a torque about it, so the"
            " equilibrating forces are undefined"
        )


def _in_batch(index: tuple[np.intp, ...]) -> str:
    return f" at batch index {tuple(int(i) for i in index)}" if index else ""


def _grasp(
    relative_contacts: np.ndarray,
    object_normals: np.ndarray,
    rotation: np.ndarray,
    wrench: np.ndarray,
    friction_limit: np.ndarray,
) -> Grasp:
    """:func:`grasp` of checked arrays."""
    rotation = rotation[..., None, :, :]
    positions = (rotation @ relative_contacts[..., None])[..., 0]
    normals = (rotation @ object_normals[..., None])[..., 0]
    return Grasp(
        positions=positions,
        normals=normals,
        equilibrating=equilibrating_forces(positions, wrench),
        basis=interaction_basis(positions),
        friction_limit=friction_limit,
    )


def scene_grasp(scene: Scene, rotation: ArrayLike) -> Grasp:
    """The grasp of ``scene`` at one or many orientations ``rotation``: proper rotation
    matrices (orthonormal within 1e-6, det +1, finite), (3, 3) or (..., 3, 3); anything else
    raises a ValueError naming ``rotation`` (:func:`~.rotations.check_rotations`)."""
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a grasp_env.mechanics.Scene, got {type(scene).__name__}")
    rotation = check_rotations(rotation, batch=True)
    wrench = load_wrench(scene.weight, scene.extra_force, scene.extra_torque)
    return _grasp(
        scene.relative_contacts(),
        scene.normals,
        rotation,
        wrench,
        np.asarray(scene.friction_limit, dtype=float),
    )
