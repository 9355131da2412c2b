"""The object's contact sites (:class:`GaitScene`) and the per-pose values of a gait:
the certified minimax of every site set at every pose (:func:`set_values`) and which finger
reaches which site (:func:`site_reach`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike

from ..checks import real_array, real_number
from ..forces import Grasp, grasp, load_wrench
from ..hand import REACH_TOL, Hand, cone_reach  # noqa: F401 (REACH_TOL re-exported)
from ..minimax import MinimaxResult, solve_minimax
from ..rotations import check_rotations
from ..scene import (
    DEFAULT_MU,
    DEFAULT_WEIGHT,
    FACES,
    ArrayRecord,
    Scene,
    box_size,
    face_point,
)
from ..trajectory import PAPER_AXIS, Trajectory

#: Fewest and most fingers that carry load at a pose.
MIN_LOADED, MAX_LOADED = 3, 4
#: Most fingers touching at a pose (one of them may be being lifted or placed).
MAX_TOUCHING = MAX_LOADED
#: The default sites: one per face of the unit cube, off its centre (fractions of the
#: half-widths, see :func:`~grasp_env.mechanics.face_point`), so that the normal lines do not
#: all pass through the centre of gravity (with face centres every optimum is 0 deg,
#: docs/design.md §1).
SITE_FACES = ("-x", "-y", "-z", "+x", "+y", "+z")
SITE_OFFSETS = ((0.3, 0.1), (-0.2, 0.3), (0.1, -0.3), (0.2, -0.1), (-0.1, 0.2), (0.3, 0.2))
#: The default centre of gravity, relative to the cube's centre (metres).
GAIT_CG_OFFSET = (0.05, 0.0, 0.0)
#: The default long trajectories: the paper's axis over [-90, 90] deg, and a full turn about
#: the vertical (from the start pose, body diagonal vertical: the cube turns about its own
#: diagonal, the load fixed in the object's frame).
PAPER_TURN = Trajectory(tuple(PAPER_AXIS), -90.0, 90.0, 1.0)
VERTICAL_TURN = Trajectory((0.0, 0.0, 1.0), -180.0, 180.0, 1.0)
_MAX_SITES = 8
_MAX_FINGERS = 6  # (N + 1)^F assignment codes: 531,441 for 6 fingers on 8 sites
_TOL = 1e-9


def _default_sites() -> np.ndarray:
    return np.array([face_point(f, o) for f, o in zip(SITE_FACES, SITE_OFFSETS, strict=True)])


@dataclass(frozen=True, eq=False)
class GaitScene(ArrayRecord):
    """The object, its load and the sites its contacts may use (object frame, box centred at
    the origin; the load in the world frame, as in :class:`~grasp_env.mechanics.Scene`).

    Args:
        sites: (N, 3) points on the faces of the box, 3 <= N <= 8, each on one face (not an
            edge); default one per face, off-centre (:data:`SITE_OFFSETS`).
        size, weight, mu, cg_offset, extra_force, extra_torque: as for
            :class:`~grasp_env.mechanics.Scene`.

    The scene keeps its sites as its own read-only array (in its pickles and copies too), its
    numbers as floats and its vectors as tuples of floats. Like a
    :class:`~grasp_env.mechanics.Scene` it compares by value (every field ``np.array_equal``)
    and equal scenes hash alike.
    """

    sites: np.ndarray = field(default_factory=_default_sites)
    size: float | tuple[float, float, float] = 1.0
    weight: float = DEFAULT_WEIGHT
    mu: float = DEFAULT_MU
    cg_offset: tuple[float, float, float] = GAIT_CG_OFFSET
    extra_force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    extra_torque: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normals: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        must = f"an (N, 3) array of finite real numbers, 3 <= N <= {_MAX_SITES}"
        sites = np.array(real_array("sites", self.sites, must))  # the scene's own copy
        if sites.ndim != 2 or sites.shape[1] != 3 or not 3 <= len(sites) <= _MAX_SITES:
            raise ValueError(
                f"sites must have shape (N, 3), 3 <= N <= {_MAX_SITES}, got {sites.shape}"
            )
        sites.flags.writeable = False
        object.__setattr__(self, "sites", sites)
        half = box_size(self.size) / 2
        normals = np.zeros_like(sites)
        for i, c in enumerate(sites):
            distance = np.abs(c) - half
            scale = _TOL * max(1.0, float(half.max()))
            on = np.flatnonzero(np.abs(distance) <= scale)
            if np.any(distance > scale) or on.size != 1:
                raise ValueError(
                    f"site {i} at {c.tolist()} must lie on exactly one face of the box"
                    f" {(2 * half).tolist()} (not outside it, inside it or on an edge)"
                )
            normals[i, on[0]] = -np.sign(c[on[0]])
        for i, j in combinations(range(len(sites)), 2):
            if np.linalg.norm(sites[i] - sites[j]) <= 1e-6 * float(half.max()):
                raise ValueError(f"sites {i} and {j} coincide")
        normals.flags.writeable = False
        object.__setattr__(self, "normals", normals)
        # The scalars and the load, checked as a Scene checks them (on the first three sites;
        # that they may be collinear is no error here: that set is merely unusable).
        try:
            self.scene([0, 1, 2])
        except ValueError as error:
            if "collinear" not in str(error):
                raise
        # checked: now stored immutable, as a hashable record must be
        size = np.asarray(self.size, dtype=float)
        object.__setattr__(self, "size", float(size) if size.ndim == 0 else tuple(size.tolist()))
        for name in ("weight", "mu"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("cg_offset", "extra_force", "extra_torque"):
            vector = np.asarray(getattr(self, name), dtype=float)
            object.__setattr__(self, name, tuple(vector.tolist()))

    @classmethod
    def on_faces(
        cls,
        faces: tuple[str, ...] = SITE_FACES,
        offsets: ArrayLike = SITE_OFFSETS,
        **kwargs: float | ArrayLike,
    ) -> GaitScene:
        """One site per named face, moved from its centre by ``offsets`` (N, 2)."""
        if isinstance(faces, str) or not isinstance(faces, Sequence):
            raise ValueError(f"faces must be a sequence of face names from {sorted(FACES)}")
        shape = (len(faces), 2)
        must = f"an array of shape {shape} of finite fractions in (-1, 1)"
        offsets = real_array("offsets", offsets, must)
        if offsets.shape != shape:
            raise ValueError(f"offsets must have shape {shape}, got {offsets.shape}")
        for face in faces:
            if not isinstance(face, str) or face not in FACES:
                raise ValueError(f"unknown face {face!r}; expected one of {sorted(FACES)}")
        size = kwargs.get("size", 1.0)
        sites = np.array([face_point(f, o, size) for f, o in zip(faces, offsets, strict=True)])
        return cls(sites=sites, **kwargs)  # type: ignore[arg-type]

    @property
    def n_sites(self) -> int:
        return len(self.sites)

    @property
    def friction_limit(self) -> float:
        return float(np.arctan(self.mu))

    def scene(self, sites: ArrayLike) -> Scene:
        """The :class:`~grasp_env.mechanics.Scene` of the contacts at the given site indices
        (3 or 4); ValueError if they are collinear (3) or coplanar (4)."""
        return Scene(
            contacts=self.sites[np.asarray(sites, dtype=np.intp)],
            size=self.size,  # type: ignore[arg-type]
            weight=self.weight,
            mu=self.mu,
            cg_offset=self.cg_offset,  # type: ignore[arg-type]
            extra_force=self.extra_force,  # type: ignore[arg-type]
            extra_torque=self.extra_torque,  # type: ignore[arg-type]
        )


@cache
def site_sets(n_sites: int) -> tuple[tuple[int, ...], ...]:
    """Every set of 3 or 4 of ``n_sites`` sites, the threes first, each in increasing order."""
    return tuple(s for n in (MIN_LOADED, MAX_LOADED) for s in combinations(range(n_sites), n))


@dataclass(frozen=True, eq=False)  # compared by identity: a record of solver output
class SetGroup:
    """The site sets of one size n: their grasps and certified optima at every pose."""

    members: np.ndarray  # (S_n,) indices into site_sets(N)
    sites: np.ndarray  # (S_n, n) the sites of each set, in increasing order
    grasp: Grasp  # batched (T, S_n)
    optimum: MinimaxResult  # batched (T, S_n)


@dataclass(frozen=True, eq=False)  # compared by identity: a record of solver output
class SetValues:
    """The certified minimax of every usable site set at every pose of a trajectory.

    Attributes:
        sets: the S site sets, :func:`site_sets` (N).
        margin: (T, S) attained margin theta_lim - max_i theta_i(k*), radians; -inf for a set
            whose contacts are collinear or coplanar (unusable).
        margin_bound: (T, S) certified upper bound on any grip's margin (theta_lim minus the
            solver's lower bound); margin <= margin_bound <= margin + gap.
        groups: per set size (3, then 4), the grasps and optima of its usable sets.
    """

    sets: tuple[tuple[int, ...], ...]
    margin: np.ndarray
    margin_bound: np.ndarray
    groups: tuple[SetGroup, ...]

    def _locate(self, set_index: int) -> tuple[SetGroup, int]:
        for group in self.groups:
            hit = np.flatnonzero(group.members == set_index)
            if hit.size:
                return group, int(hit[0])
        raise ValueError(f"site set {self.sets[set_index]} is unusable (collinear or coplanar)")

    def grip(self, pose: int, set_index: int) -> tuple[np.ndarray, np.ndarray]:
        """The certified optimal k (m,) and friction angles (n,) of a set at a pose, for the
        set's sites in increasing order (pairs as :func:`~grasp_env.mechanics.contact_pairs`)."""
        group, column = self._locate(set_index)
        return group.optimum.k[pose, column], group.optimum.angles[pose, column]

    def set_grasp(self, set_index: int) -> Grasp:
        """The grasp (T,) of one set along the trajectory."""
        group, c = self._locate(set_index)
        g = group.grasp
        return Grasp(
            g.positions[:, c], g.normals[:, c], g.equilibrating[:, c], g.basis[:, c],
            g.friction_limit,
        )  # fmt: skip


def set_values(scene: GaitScene, rotations: ArrayLike, k_max: float | None = None) -> SetValues:
    """Solve the certified minimax (:func:`~grasp_env.mechanics.solve_minimax`) of every usable
    site set at every pose (rotations (T, 3, 3)), each set's poses solved in order, one batch
    per size.

    ``k_max`` defaults to 2 w, the environments' action box.
    """
    rotations = check_rotations(rotations, name="rotations")
    k_max = 2.0 * scene.weight if k_max is None else real_number("k_max", k_max, 0, open_low=True)
    sets = site_sets(scene.n_sites)
    T = len(rotations)
    margin = np.full((T, len(sets)), -np.inf)
    bound = np.full((T, len(sets)), -np.inf)
    relative = scene.sites - np.asarray(scene.cg_offset)
    wrench = load_wrench(scene.weight, scene.extra_force, scene.extra_torque)
    limit = scene.friction_limit
    groups = []
    for n in (MIN_LOADED, MAX_LOADED):
        members = []
        for index, s in enumerate(sets):
            if len(s) != n:
                continue
            try:
                scene.scene(s)
            except ValueError:
                continue  # collinear or coplanar: this set cannot grasp
            members.append(index)
        if not members:
            continue
        members = np.array(members)
        sites = np.array([sets[i] for i in members])
        # positions (S_n, T, n, 3): each set's poses one after the other, for `follows`
        g = grasp(
            relative[sites][:, None], scene.normals[sites][:, None], rotations[None], wrench, limit
        )
        follows = np.ones((len(members), T), bool)
        follows[:, 0] = False
        optimum = solve_minimax(g, k_max, follows=follows)
        margin[:, members] = limit - optimum.max_angle.T
        bound[:, members] = limit - optimum.lower_bound.T
        swap = lambda a: np.swapaxes(a, 0, 1)  # noqa: E731  (S_n, T, ...) -> (T, S_n, ...)
        groups.append(
            SetGroup(
                members,
                sites,
                Grasp(
                    swap(g.positions),
                    swap(g.normals),
                    swap(g.equilibrating),
                    swap(g.basis),
                    np.asarray(limit),
                ),
                MinimaxResult(
                    swap(optimum.k),
                    swap(optimum.angles),
                    optimum.max_angle.T,
                    optimum.lower_bound.T,
                    optimum.status.T,
                ),
            )
        )
    return SetValues(sets, margin, bound, tuple(groups))


def site_reach(scene: GaitScene, hand: Hand, rotations: ArrayLike) -> np.ndarray:
    """Which finger can push on which site at every pose: (T, F, N) bool
    (:func:`cone_reach` of the hand's approach directions and cone)."""
    rotations = np.asarray(rotations, dtype=float)
    normals = np.einsum("tij,nj->tni", rotations, scene.normals)
    return cone_reach(hand.approach, hand.cone_deg, normals)
