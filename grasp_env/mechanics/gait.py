"""Finger gaits: when to phase a finger out or in along a trajectory (paper §II, docs/gait.md).

The object carries N contact **sites** (object-frame points on its faces); a :class:`~.hand.Hand`
has F fingers, each of which can push on a site only while the site's normal lies in its
cone. At every pose each finger touches one site or none. A **gait** says, pose by pose, which
finger touches which site and which fingers carry load; it obeys the hand's rules:

1. at every pose 3 or 4 fingers touch the object (three is the least that can grasp; the
   minimax solver takes at most four), each on a site it can reach at that pose;
2. at most one finger changes per pose (one **move**): a finger is **phased out** (lifted) at
   a pose where it still touches its site, reachable, but carries zero force; it is gone from
   the next pose on. A finger is **phased in** (placed) on a free site it can reach at a pose
   where it touches with zero force; it carries load from the next pose on. So a lift needs
   four fingers touching (three carry the load meanwhile) and a placement three (the placed
   finger makes four); every other touching finger carries load.

The margin of a pose is the certified minimax margin theta_lim - min_k max_i theta_i(k)
(eq. 2 and 4) of the site set that carries load there, over the action box |k_ij| <= k_max.
The optimal gait maximises the smallest margin over the whole trajectory; among those it takes
the fewest moves, then the largest sum of margins. It is found exactly by dynamic programming
over the hand's states (which finger touches which site), whose moves and values are known
pose by pose: :func:`optimal_gait`. Run on the certified upper bounds of the margins instead of
the attained ones, the same programme bounds what any gait could reach, so the gait is
certified optimal for the discretised trajectory within the gap (:func:`solve_gait`).

States and moves are encoded as integers: a state is an assignment (F,) of a site index to each
finger (-1: not touching); move 0 keeps the state, move 1 + f N + s toggles finger f on site s
(lifts it if it is there, places it if finger and site are both free).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from itertools import combinations

import numba
import numpy as np
from numpy.typing import ArrayLike

from .checks import real_array, real_number
from .forces import Grasp, grasp, load_wrench, n_pairs
from .hand import Hand
from .minimax import MinimaxResult, solve_minimax
from .rotations import check_rotations
from .scene import (
    DEFAULT_MU,
    DEFAULT_WEIGHT,
    FACES,
    ArrayRecord,
    Scene,
    box_size,
    face_point,
)
from .trajectory import PAPER_AXIS, Trajectory

#: Fewest and most fingers that carry load at a pose.
MIN_LOADED, MAX_LOADED = 3, 4
#: Most fingers touching at a pose (one of them may be being lifted or placed).
MAX_TOUCHING = MAX_LOADED
#: The default sites: one per face of the unit cube, off its centre (fractions of the
#: half-widths, see :func:`~.scene.face_point`), so that the normal lines do not all pass
#: through the centre of gravity (with face centres every optimum is 0 deg, docs/design.md §1).
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
    the origin; the load in the world frame, as in :class:`~.scene.Scene`).

    Args:
        sites: (N, 3) points on the faces of the box, 3 <= N <= 8, each on one face (not an
            edge); default one per face, off-centre (:data:`SITE_OFFSETS`).
        size, weight, mu, cg_offset, extra_force, extra_torque: as for :class:`~.scene.Scene`.

    The scene keeps its sites as its own read-only array (in its pickles and copies too), its
    numbers as floats and its vectors as tuples of floats. Like a :class:`~.scene.Scene` it
    compares by value (every field ``np.array_equal``) and equal scenes hash alike.
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
        """The :class:`~.scene.Scene` of the contacts at the given site indices (3 or 4);
        ValueError if they are collinear (3) or coplanar (4)."""
        return Scene(
            contacts=self.sites[np.asarray(sites, dtype=np.intp)],
            size=self.size,  # type: ignore[arg-type]
            weight=self.weight,
            mu=self.mu,
            cg_offset=self.cg_offset,  # type: ignore[arg-type]
            extra_force=self.extra_force,  # type: ignore[arg-type]
            extra_torque=self.extra_torque,  # type: ignore[arg-type]
        )


# ------------------------------------------------------------------------ per-pose values


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
        set's sites in increasing order (pairs as :func:`~.forces.contact_pairs`)."""
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
    """Solve the certified minimax (:func:`~.minimax.solve_minimax`) of every usable site set
    at every pose (rotations (T, 3, 3)), each set's poses solved in order, one batch per size.

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
    """Which finger can push on which site at every pose: (T, F, N) bool."""
    rotations = np.asarray(rotations, dtype=float)
    normals = np.einsum("tij,nj->tni", rotations, scene.normals)
    return hand.reach(normals)


# --------------------------------------------------------------------- states and moves


@dataclass(frozen=True, eq=False)
class GaitStates(ArrayRecord):
    """The hand's states (which finger touches which site) and their moves, as tables.

    Attributes:
        n_fingers, n_sites: F and N.
        states: (X, F) the site each finger touches (-1: none); 3 or 4 fingers touch.
        code: ((N + 1)^F,) state index of an assignment's code sum_f (a_f + 1) (N + 1)^f, -1
            where the assignment is not a state.
        ptr, move, next, loaded: the valid moves of state x are move[ptr[x]:ptr[x + 1]] (move
            codes, increasing: keep first), leading to state next[...] with the site set
            loaded[...] (an index into :func:`site_sets`) carrying load at the pose.
    """

    n_fingers: int
    n_sites: int
    states: np.ndarray
    code: np.ndarray
    ptr: np.ndarray
    move: np.ndarray
    next: np.ndarray
    loaded: np.ndarray

    @property
    def n_moves(self) -> int:
        return 1 + self.n_fingers * self.n_sites

    def index(self, assignment: ArrayLike, name: str = "assignment") -> int:
        """The state index of an assignment (F,) of sites (-1: not touching); ValueError,
        naming it ``name`` (the caller's keyword), if it is no state (not F integer sites, a
        site used twice, fewer than 3 or more than 4 fingers touching)."""
        try:
            a = np.asarray(assignment)
        except (TypeError, ValueError):  # ragged
            a = np.empty(0)
        # integers only: 2.7 is refused, not truncated to site 2
        if (
            a.shape != (self.n_fingers,)
            or a.dtype.kind not in "iu"
            or np.any(a < -1)
            or np.any(a >= self.n_sites)
        ):
            raise ValueError(
                f"{name} must give each of the {self.n_fingers} fingers a site in"
                f" [-1, {self.n_sites - 1}] (-1: none), got {a.tolist() if a.size else assignment}"
            )
        a = a.astype(np.int64)
        x = int(self.code[int(np.sum((a + 1) * (self.n_sites + 1) ** np.arange(self.n_fingers)))])
        if x < 0:
            raise ValueError(
                f"{name} {a.tolist()} is no state of the hand: sites must differ and"
                f" {MIN_LOADED} to {MAX_TOUCHING} fingers touch"
            )
        return x


@numba.njit(cache=True)
def _enumerate(F, N, set_code):
    """States, the code table and the moves in CSR form (see :class:`GaitStates`)."""
    base = N + 1
    total = base**F
    code = np.full(total, -1, np.int64)
    digits = np.empty(F, np.int64)
    states = np.empty((total, F), np.int64)
    count = 0
    for c in range(total):
        rest = c
        used = 0
        touching = 0
        ok = True
        for f in range(F):
            digits[f] = rest % base - 1
            rest //= base
            if digits[f] >= 0:
                bit = 1 << digits[f]
                if used & bit:
                    ok = False
                used |= bit
                touching += 1
        if ok and MIN_LOADED <= touching <= MAX_TOUCHING:
            code[c] = count
            states[count] = digits
            count += 1
    states = states[:count]
    M = 1 + F * N
    ptr = np.zeros(count + 1, np.int64)
    move = np.empty(count * M, np.int64)
    nxt = np.empty(count * M, np.int64)
    loaded = np.empty(count * M, np.int64)
    k = 0
    power = np.empty(F, np.int64)
    for f in range(F):
        power[f] = base**f
    for x in range(count):
        a = states[x]
        used = 0
        touching = 0
        c = 0
        for f in range(F):
            if a[f] >= 0:
                used |= 1 << a[f]
                touching += 1
            c += (a[f] + 1) * power[f]
        for m in range(M):
            if m == 0:  # keep: every touching finger carries load
                move[k], nxt[k], loaded[k] = 0, x, set_code[used]
                k += 1
                continue
            f = (m - 1) // N
            s = (m - 1) % N
            if a[f] == s:  # lift: zero force now, gone next
                if MIN_LOADED <= touching - 1 <= MAX_LOADED:
                    rest = used & ~(1 << s)
                    move[k], nxt[k], loaded[k] = m, code[c - (s + 1) * power[f]], set_code[rest]
                    k += 1
            elif a[f] < 0 and not used & (1 << s) and touching < MAX_TOUCHING:
                # place: touches now with zero force, loaded next
                move[k], nxt[k], loaded[k] = m, code[c + (s + 1) * power[f]], set_code[used]
                k += 1
        ptr[x + 1] = k
    return states, code, ptr, move[:k].copy(), nxt[:k].copy(), loaded[:k].copy()


def _size_ok(n_fingers: int, n_sites: int) -> bool:
    """Whether a hand of F fingers on N sites is within range: the site sets and the states
    grow combinatorially with them."""
    return 3 <= n_fingers <= _MAX_FINGERS and 3 <= n_sites <= _MAX_SITES


@cache
def gait_states(n_fingers: int, n_sites: int) -> GaitStates:
    """The state and move tables of a hand of F fingers on N sites (cached)."""
    if not _size_ok(n_fingers, n_sites):
        raise ValueError(
            f"a gait needs 3 to {_MAX_FINGERS} fingers and 3 to {_MAX_SITES} sites,"
            f" got {n_fingers} and {n_sites}"
        )
    set_code = np.full(1 << n_sites, -1, np.int64)
    for i, s in enumerate(site_sets(n_sites)):
        set_code[sum(1 << j for j in s)] = i
    arrays = _enumerate(n_fingers, n_sites, set_code)
    for array in arrays:
        array.flags.writeable = False
    return GaitStates(n_fingers, n_sites, *arrays)


def move_name(move: int, n_sites: int) -> tuple[int, int] | None:
    """(finger, site) a move toggles, or None for keep."""
    return None if move == 0 else ((move - 1) // n_sites, (move - 1) % n_sites)


# ----------------------------------------------------------------------- the programme


@numba.njit(cache=True)
def _state_ok(states, reach):
    """(T, X): every touching finger of state x can reach its site at pose t."""
    T = reach.shape[0]
    X, F = states.shape
    ok = np.ones((T, X), np.bool_)
    for t in range(T):
        for x in range(X):
            for f in range(F):
                s = states[x, f]
                if s >= 0 and not reach[t, f, s]:
                    ok[t, x] = False
                    break
    return ok


@numba.njit(cache=True)
def _pose_values(t, states, ptr, move, loaded, margin, reach, ok, out):
    """out[k]: the margin of pose t after move k (CSR) of its state, -inf where the move is
    not allowed there (a touching finger out of reach, or a placement out of reach)."""
    N = reach.shape[2]
    for x in range(states.shape[0]):
        for k in range(ptr[x], ptr[x + 1]):
            v = margin[t, loaded[k]] if ok[t, x] else -np.inf
            m = move[k]
            if m > 0:
                f = (m - 1) // N
                s = (m - 1) % N
                if states[x, f] < 0 and not reach[t, f, s]:  # a placement needs reach now
                    v = -np.inf
            out[k] = v


@numba.njit(cache=True)
def _programme(states, ptr, move, nxt, loaded, margin, reach, start):
    """Backward dynamic programme: bottleneck values, then fewest moves and the largest sum of
    margins among the gaits that keep the best bottleneck; the policy and the start state.

    ``start`` < 0: the best start. Returns (value (T + 1, X), policy (T, X), start, best).
    """
    T = margin.shape[0]
    X = states.shape[0]
    ok = _state_ok(states, reach)
    vals = np.empty(move.shape[0])
    value = np.empty((T + 1, X))
    value[T] = np.inf
    first = np.zeros((T, X), np.int64)
    # pass 1: max over moves of min(margin now, value from the next pose)
    for t in range(T - 1, -1, -1):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        for x in range(X):
            best = -np.inf
            arg = ptr[x]
            for k in range(ptr[x], ptr[x + 1]):
                v = min(vals[k], value[t + 1, nxt[k]])
                if v > best:
                    best = v
                    arg = k
            value[t, x] = best
            first[t, x] = arg
    if start < 0:
        bound = -np.inf
        for x in range(X):
            bound = max(bound, value[0, x])
    else:
        bound = value[0, start]
    # pass 2: among continuations that keep every margin >= bound, fewest moves, then the
    # largest sum of margins (both additive: exact)
    moves = np.empty((T + 1, X))
    total = np.empty((T + 1, X))
    moves[T] = 0.0
    total[T] = 0.0
    policy = np.empty((T, X), np.int64)
    for t in range(T - 1, -1, -1):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        for x in range(X):
            moves[t, x] = np.inf
            total[t, x] = -np.inf
            policy[t, x] = first[t, x]
            if not value[t, x] >= bound:
                continue
            for k in range(ptr[x], ptr[x + 1]):
                y = nxt[k]
                if not (vals[k] >= bound and value[t + 1, y] >= bound):
                    continue
                c = moves[t + 1, y] + (1.0 if move[k] > 0 else 0.0)
                s = total[t + 1, y] + vals[k]
                if c < moves[t, x] or (c == moves[t, x] and s > total[t, x]):
                    moves[t, x] = c
                    total[t, x] = s
                    policy[t, x] = k
    if start < 0:
        start = 0
        for x in range(X):
            if value[0, x] > value[0, start] or (
                value[0, x] == value[0, start]
                and (
                    moves[0, x] < moves[0, start]
                    or (moves[0, x] == moves[0, start] and total[0, x] > total[0, start])
                )
            ):
                start = x
    return value, policy, start, bound


@numba.njit(cache=True)
def _greedy(states, ptr, move, nxt, loaded, margin, reach):
    """The greedy rule from every state at every pose: the move that maximises the smaller of
    the margin now and the best margin the next pose then allows (ties: the larger margin now,
    then fewer moves). Returns (policy (T, X) CSR indices, score (T, X) of each choice)."""
    T = margin.shape[0]
    X = states.shape[0]
    ok = _state_ok(states, reach)
    vals = np.empty(move.shape[0])
    best = np.full((T + 1, X), np.inf)  # the best margin each state allows at each pose
    for t in range(T):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        for x in range(X):
            b = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                b = max(b, vals[k])
            best[t, x] = b
    policy = np.empty((T, X), np.int64)
    score = np.empty((T, X))
    for t in range(T):
        _pose_values(t, states, ptr, move, loaded, margin, reach, ok, vals)
        for x in range(X):
            arg = ptr[x]
            top = -np.inf
            now = -np.inf
            for k in range(ptr[x], ptr[x + 1]):
                look = min(vals[k], best[t + 1, nxt[k]])
                if k == ptr[x] or look > top or (look == top and vals[k] > now):
                    top, now, arg = look, vals[k], k
            policy[t, x] = arg
            score[t, x] = top
    return policy, score


@dataclass(frozen=True, eq=False)
class Gait(ArrayRecord):
    """A gait along T poses.

    Attributes:
        states: (T,) the hand's state at each pose, before its move (indices of ``table``).
        moves: (T,) the move made at each pose (0: none; see the module docstring).
        contacts: (T, F) the site each finger touches at each pose (-1: none), a finger being
            placed included.
        loaded: (T, F) bool, which fingers carry load.
        sets: (T,) the loaded site set (index into :func:`site_sets`).
        margins: (T,) the margin of each pose, radians.
        table: the state tables the indices refer to.
        policy: for the optimal and the greedy gait, (T, X) the move (CSR index) their rule
            takes from every state at every pose; else None.

    From the pose where a gait breaks the hand's rules (no allowed move is left: the hand
    would lose a site under load or drop below three fingers) its states, sets and contacts
    are -1 and its margins -inf.

    The gait functions return its arrays read-only; gaits compare and hash by value.
    """

    states: np.ndarray
    moves: np.ndarray
    contacts: np.ndarray
    loaded: np.ndarray
    sets: np.ndarray
    margins: np.ndarray
    table: GaitStates = field(repr=False)
    policy: np.ndarray | None = field(default=None, repr=False)

    @property
    def margin(self) -> float:
        """The smallest margin along the trajectory, radians."""
        return float(self.margins.min())

    @property
    def changes(self) -> int:
        """Number of phase changes (fingers lifted or placed)."""
        return int(np.count_nonzero(self.moves))

    def events(self) -> list[tuple[int, str, int, int]]:
        """(pose, "out" or "in", finger, site) of every phase change."""
        out = []
        for t in np.flatnonzero(self.moves):
            f, s = move_name(int(self.moves[t]), self.table.n_sites)  # type: ignore[misc]
            kind = "out" if self.table.states[self.states[t], f] == s else "in"
            out.append((int(t), kind, f, s))
        return out


def _check_inputs(margin: ArrayLike, reach: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    # reach first: its sizes bound the work of every later step (site_sets, gait_states)
    must = (
        "a (T, F, N) boolean array, which of F fingers can push on which of N sites,"
        f" F in [3, {_MAX_FINGERS}] and N in [3, {_MAX_SITES}]"
    )
    try:
        reach = np.ascontiguousarray(reach)
    except (TypeError, ValueError):  # ragged
        raise ValueError(f"reach must be {must}") from None
    # booleans only, as the physics' in_contact: 0.5 is no answer to "can it reach?"
    if reach.ndim != 3 or reach.dtype != bool or not _size_ok(*reach.shape[1:]):
        raise ValueError(f"reach must be {must}, got {reach.dtype} {reach.shape}")
    # -inf marks an unusable set, so real_array's finite check cannot serve here
    must = "a (T, S) array of real numbers, each finite or -inf (an unusable set)"
    try:
        margin = np.ascontiguousarray(margin)
    except (TypeError, ValueError):  # ragged
        raise ValueError(f"margin must be {must}") from None
    if margin.dtype.kind not in "iuf":  # no strings, booleans, None or complex numbers
        raise ValueError(f"margin must be {must}, got {margin.dtype}")
    margin = margin.astype(float, copy=False)
    if margin.ndim != 2 or margin.shape[0] != reach.shape[0]:
        raise ValueError(
            f"margin must be (T, S) and reach (T, F, N) with the same T, got {margin.shape}"
            f" and {reach.shape}"
        )
    if margin.shape[0] < 1:
        raise ValueError("a gait needs at least one pose")
    if margin.shape[1] != len(site_sets(reach.shape[2])):
        raise ValueError(
            f"margin must have one column per set of 3 or 4 of the {reach.shape[2]} sites"
            f" ({len(site_sets(reach.shape[2]))}), got {margin.shape[1]}"
        )
    if np.any(np.isnan(margin)) or np.any(margin == np.inf):
        raise ValueError("margins must be finite or -inf (an unusable set), not NaN or +inf")
    return margin, reach


def _follow(
    table: GaitStates, start: int, choices: np.ndarray, margin: np.ndarray, reach: np.ndarray
) -> Gait:
    """The gait of CSR move indices ``choices`` (T,) from state ``start``, with the margins
    it earns; it ends (-1, -inf) at the first pose where a choice is not allowed."""
    T, N = margin.shape[0], table.n_sites
    ok = _state_ok(table.states, reach)
    states = np.full(T, -1, np.int64)
    moves = np.zeros(T, np.int64)
    contacts = np.full((T, table.n_fingers), -1, np.int64)
    loaded = np.zeros((T, table.n_fingers), bool)
    sets = np.full(T, -1, np.int64)
    margins = np.full(T, -np.inf)
    x = start
    for t in range(T):
        k = int(choices[t])
        if k < 0 or not ok[t, x]:
            break
        a = table.states[x]
        m = int(table.move[k])
        lifted = placed = -1
        if m:
            f, s = move_name(m, N)  # type: ignore[misc]
            if a[f] == s:
                lifted = f
            elif reach[t, f, s]:
                placed = f
            else:
                break  # a placement out of reach
        states[t], moves[t] = x, m
        contacts[t] = a
        loaded[t] = a >= 0
        if lifted >= 0:
            loaded[t, lifted] = False  # zero force while it lifts
        if placed >= 0:
            contacts[t, placed] = s  # touches with zero force
        sets[t] = table.loaded[k]
        margins[t] = margin[t, sets[t]]
        x = int(table.next[k])
    arrays = (states, moves, contacts, loaded, sets, margins)
    for array in arrays:
        array.flags.writeable = False  # a result, compared and hashed by value
    return Gait(*arrays, table)


def _start_index(table: GaitStates, start: ArrayLike | None) -> int:
    return -1 if start is None else table.index(start, "start")


def _policy_choices(table: GaitStates, policy: np.ndarray, start: int) -> np.ndarray:
    choices = np.empty(len(policy), np.int64)
    x = start
    for t in range(len(policy)):
        choices[t] = policy[t, x]
        x = int(table.next[choices[t]])
    return choices


def optimal_gait(margin: ArrayLike, reach: ArrayLike, start: ArrayLike | None = None) -> Gait:
    """The gait that maximises the smallest margin (then: fewest moves, largest sum).

    Args:
        margin: (T, S) the margin of every site set (:func:`site_sets`) at every pose, -inf
            where a set is unusable.
        reach: (T, F, N) bool, which finger can push on which site at every pose.
        start: the hand's state at the first pose, an assignment (F,) of sites (-1: none);
            default the best one.

    Returns:
        The gait with its ``policy``, optimal from every state: a move that maximises the
        smallest margin from there on, and among those the gait's secondary choices (fewest
        moves, largest sum) wherever the gait's own smallest margin can still be kept. If no
        gait (from ``start``) keeps the rules at every pose, the best smallest margin is -inf
        and the gait drops at the first pose (states -1, margins -inf), not at an arbitrary
        one: check ``gait.margin > -inf``.
    """
    margin, reach = _check_inputs(margin, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    _, policy, x, best = _programme(
        table.states, table.ptr, table.move, table.next, table.loaded, margin, reach,
        _start_index(table, start),
    )  # fmt: skip
    policy.flags.writeable = False
    # every gait drops somewhere: none is optimal, so none is followed
    choices = _policy_choices(table, policy, x) if best > -np.inf else np.full(len(margin), -1)
    gait = _follow(table, x, choices, margin, reach)
    return Gait(**{**gait.__dict__, "policy": policy})


def greedy_gait(margin: ArrayLike, reach: ArrayLike, start: ArrayLike | None = None) -> Gait:
    """The greedy baseline: at each pose the move that maximises the smaller of that pose's
    margin and the best margin the next pose then allows (a one-pose lookahead, so that it
    lifts a finger before the finger loses its site, where it can); ties: the larger margin
    now, then fewer moves. Default start: its own best first choice. Its ``policy`` is the
    greedy rule from every state at every pose."""
    margin, reach = _check_inputs(margin, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    policy, score = _greedy(
        table.states, table.ptr, table.move, table.next, table.loaded, margin, reach
    )
    policy.flags.writeable = False
    x = int(np.argmax(score[0])) if start is None else table.index(start, "start")
    gait = _follow(table, x, _policy_choices(table, policy, x), margin, reach)
    return Gait(**{**gait.__dict__, "policy": policy})


def best_fixed(margin: ArrayLike, reach: ArrayLike) -> Gait:
    """The best gait without moves: one set of fingers on one set of sites throughout."""
    margin, reach = _check_inputs(margin, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    ok = _state_ok(table.states, reach)
    keep = table.ptr[:-1]  # a state's first move: keep, if at most four fingers touch
    worst = np.where(ok, margin[:, table.loaded[keep]], -np.inf).min(axis=0)
    worst[table.move[keep] != 0] = -np.inf
    x = int(np.argmax(worst))
    return _follow(table, x, np.full(len(margin), keep[x]), margin, reach)


def bottleneck_bound(
    margin_bound: ArrayLike, reach: ArrayLike, start: ArrayLike | None = None
) -> float:
    """The best smallest margin any gait could reach with margins ``margin_bound`` (pass 1 of
    the programme alone): an upper bound on the optimal gait's margin if these bound the
    margins from above."""
    margin, reach = _check_inputs(margin_bound, reach)
    table = gait_states(reach.shape[1], reach.shape[2])
    _, _, _, bound = _programme(
        table.states, table.ptr, table.move, table.next, table.loaded, margin, reach,
        _start_index(table, start),
    )  # fmt: skip
    return float(bound)


# ------------------------------------------------------------------------- everything


@dataclass(frozen=True, eq=False)  # compared by identity: a record of solver output
class GaitSolution:
    """The certified gait problem along a trajectory, solved.

    Attributes:
        scene, hand, trajectory: the problem.
        values: every site set's certified minimax at every pose.
        reach: (T, F, N) which finger reaches which site.
        optimal: the optimal gait on the attained margins.
        bound: the programme's value on the certified upper bounds: no gait has a smallest
            margin above it; ``optimal.margin <= bound <= optimal.margin + gap``. -inf when no
            gait holds (:attr:`holds`).
        bound_gait: the gait the programme picks on the upper bounds (its attained margin
            agrees with the optimal gait's within the gap).
        greedy: the greedy baseline's gait.
        fixed: the best gait without moves.
    """

    scene: GaitScene
    hand: Hand
    trajectory: Trajectory
    values: SetValues
    reach: np.ndarray
    optimal: Gait
    bound: float
    bound_gait: Gait
    greedy: Gait
    fixed: Gait

    @property
    def holds(self) -> bool:
        """Whether some gait keeps the rules at every pose (three fingers on usable sites within
        reach). If not, ``bound`` and ``optimal.margin`` are -inf and ``optimal`` drops at the
        first pose: exactly, as reach and usable sets are no solver's estimates."""
        return self.optimal.margin > -np.inf

    @property
    def gap(self) -> float:
        """Certificate gap of the optimal gait's margin, radians (0 when no gait holds: both
        ends are -inf)."""
        return self.bound - self.optimal.margin if self.holds else 0.0

    def _poses(self, gait: Gait):
        """(t, fingers in the set's site order, grasp of the set at t, its optimal k) of every
        pose the gait holds."""
        for t in range(len(gait.margins)):
            if gait.sets[t] < 0:
                continue
            fingers = np.flatnonzero(gait.loaded[t])
            fingers = fingers[np.argsort(gait.contacts[t, fingers])]  # the set's sites increase
            group, column = self.values._locate(int(gait.sets[t]))
            g = group.grasp
            pose = Grasp(
                g.positions[t, column],
                g.normals[t, column],
                g.equilibrating[t, column],
                g.basis[t, column],
                g.friction_limit,
            )
            yield t, fingers, pose, group.optimum.k[t, column], group.optimum.angles[t, column]

    def grips(self, gait: Gait) -> tuple[np.ndarray, np.ndarray]:
        """The certified optimal grip of a gait at every pose, per finger pair and per finger:
        k (T, F (F - 1) / 2), pairs (f, g) f < g as :func:`~.forces.contact_pairs` (F), 0 for
        pairs not both loaded, and friction angles (T, F), NaN for fingers not loaded; NaN
        rows after the gait breaks the rules."""
        F = self.hand.n_fingers
        pairs = {p: q for q, p in enumerate(combinations(range(F), 2))}
        T = len(gait.margins)
        k = np.where((gait.sets >= 0)[:, None], 0.0, np.nan) * np.ones((T, n_pairs(F)))
        angles = np.full((T, F), np.nan)
        for t, fingers, _, kt, at in self._poses(gait):
            angles[t, fingers] = at
            for q, (i, j) in enumerate(combinations(range(len(fingers)), 2)):
                k[t, pairs[tuple(sorted((fingers[i], fingers[j])))]] = kt[q]
        return k, angles

    def statuses(self, gait: Gait) -> np.ndarray:
        """The minimax :class:`~.minimax.Status` of the loaded set at every pose (T,) int8,
        -1 after the gait breaks the rules."""
        status = np.full(len(gait.margins), -1, np.int8)
        for t in np.flatnonzero(gait.sets >= 0):
            group, column = self.values._locate(int(gait.sets[t]))
            status[t] = group.optimum.status[t, column]
        return status

    def forces(self, gait: Gait) -> np.ndarray:
        """Each finger's contact force P_f on the object at the gait's grip, world frame,
        newtons: (T, F, 3), zero for fingers not loaded (a finger being lifted or placed
        touches with zero force), NaN after the gait breaks the rules."""
        T, F = gait.loaded.shape
        forces = np.where((gait.sets >= 0)[:, None, None], 0.0, np.nan) * np.ones((T, F, 3))
        for t, fingers, pose, kt, _ in self._poses(gait):
            forces[t, fingers] = pose.forces(kt)
        return forces

    def positions(self, gait: Gait) -> np.ndarray:
        """World-frame positions of the sites the fingers touch, relative to the centre of
        gravity, p = R (c - g): (T, F, 3), NaN where a finger touches nothing."""
        rotations = self.trajectory.rotations()
        relative = self.scene.sites - np.asarray(self.scene.cg_offset)
        world = np.einsum("tij,nj->tni", rotations, relative)  # (T, N, 3)
        sites = np.maximum(gait.contacts, 0)
        out = np.take_along_axis(world, sites[..., None], axis=1)
        out[gait.contacts < 0] = np.nan
        return out


def solve_gait(
    scene: GaitScene | None = None,
    hand: Hand | None = None,
    trajectory: Trajectory = PAPER_TURN,
    k_max: float | None = None,
    start: ArrayLike | None = None,
) -> GaitSolution:
    """The certified optimal gait, its bound, the greedy gait and the best fixed set along a
    trajectory (defaults: :class:`GaitScene`, :class:`~.hand.Hand`, :data:`PAPER_TURN`,
    k_max = 2 w). Check :attr:`GaitSolution.holds`: where no gait holds there is no optimum to
    report."""
    scene = GaitScene() if scene is None else scene
    hand = Hand() if hand is None else hand
    for name, value, kind in (
        ("scene", scene, GaitScene),
        ("hand", hand, Hand),
        ("trajectory", trajectory, Trajectory),
    ):
        if not isinstance(value, kind):
            raise ValueError(f"{name} must be a {kind.__name__}, got {type(value).__name__}")
    rotations = trajectory.rotations()
    values = set_values(scene, rotations, k_max)
    reach = site_reach(scene, hand, rotations)
    optimal = optimal_gait(values.margin, reach, start)
    bound_gait = optimal_gait(values.margin_bound, reach, start)
    bound = float(bound_gait.margin)
    # the bound's gait on the attained margins: the same moves, what its grips attain
    x = int(bound_gait.states[0])
    attained = bound_gait if x < 0 else _follow(
        bound_gait.table, x, _policy_choices(bound_gait.table, bound_gait.policy, x),
        values.margin, reach,
    )  # fmt: skip
    return GaitSolution(
        scene, hand, trajectory, values, reach, optimal, bound, attained,
        greedy_gait(values.margin, reach, start), best_fixed(values.margin, reach),
    )  # fmt: skip
