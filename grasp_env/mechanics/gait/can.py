"""The coke can's gait: turning a can about its axis in a hand of fingers that reach a patch of
its side each (docs/gait.md, "The can").

The paper's stretch: "turning a coke can about its axis requires phasing in and out of the
fingers". The can (``parse_object("can")``, a :class:`~grasp_env.mechanics.objects.Cylinder`
of radius 33 mm and height 115 mm, about 3.4 N) stands upright, its axis along world z, its
centre of gravity on the axis, and turns about that axis by alpha (a full turn, 0 to 360 deg).

**The hand** (:class:`CanHand`): F fingers, each pushing on the can's side from a fixed world
azimuth psi_f at its own height. Finger f reaches a side point while the point's inward normal
lies within ``reach_deg`` (c) of the finger's approach -(cos psi_f, sin psi_f, 0), i.e. while
the point's world azimuth is within c of psi_f (the cube's cone of normals on a surface that
curves about the axis alone). A finger is **placed** at the upstream edge of its patch, world
azimuth psi_f - c (the can turns towards larger azimuths, so that is where a contact stays
longest), and its contact, a point of the can (object frame, ``Cylinder.side_point``), turns
with the can: after a poses of delta deg it is at psi_f - c + a delta, reachable while
a delta <= 2 c (to within :data:`~grasp_env.mechanics.gait.sites.REACH_TOL`: the far edge is
within reach, deliberately). So a finger holds at most H = floor(2 c / delta) poses after the
one it is placed at, then must be lifted and placed again, at the upstream edge, on another
point of the can.

**The rules** are the cube's (:mod:`grasp_env.mechanics.gait`) with the sites replaced by the
fingers' **ages** (poses since placement): at every pose 3 to :data:`CAN_MAX_TOUCHING` fingers
touch and 3 to 5 carry load (the solver takes 3 to 8 contacts; five fingers may all touch);
at most one move per pose: a lift (zero force now, gone next), or a placement (touches at age
0 with zero force now, loaded from the next pose, at age 1). Every loaded finger has an age in
1..H.

**Margins.** The load is the weight along the axis and the centre of gravity lies on it, so a
rotation about the axis carries every grasp onto the same grasp turned: the margin of a pose
depends only on which fingers carry load and their ages (a **configuration**), not on alpha.
:func:`can_values` solves the certified minimax of every configuration once (one batch per
number of loaded fingers), and the dynamic programme reads margin[t, configuration].
Uncertified optima (``Status.UNCERTIFIED``, which the conic solver of five contacts may
return) are kept honestly: the programme uses the attained margin theta_lim - max_angle
(the returned grip attains it), the bound uses theta_lim - lower_bound (certified), so the
gait stays certified and its gap says how far; they are counted.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from itertools import combinations, product

import numpy as np
from numpy.typing import ArrayLike

from ..checks import real_array, real_number
from ..forces import grasp, load_wrench
from ..minimax import MinimaxResult, Status, solve_minimax
from ..objects import CAN_HEIGHT, CAN_RADIUS, Cylinder
from .sites import REACH_TOL

#: The can's weight, newtons: 330 ml of drink and its can, about 0.35 kg (docs/design.md §1).
CAN_WEIGHT = 3.4
#: Fewest and most fingers that carry load, and most that touch, on the can.
CAN_MIN_LOADED, CAN_MAX_LOADED = 3, 5
CAN_MAX_TOUCHING = 5
#: Loaded fingers at most by default in :func:`.can_programme.solve_can_gait`: four. Five
#: loaded need every
#: configuration of five fingers and H ages solved by the conic solver (H^5: 59,049 for the
#: default hand, about 500 solves a second), four need the kernels of three and four contacts;
#: five may still touch (one being placed or lifted beside four loaded).
CAN_DEFAULT_LOADED = 4
#: Most fingers of a can hand, and most poses a finger may hold (the state tables grow as
#: (H + 2)^F).
CAN_MAX_FINGERS, CAN_MAX_AGE = 5, 12


@dataclass(frozen=True)
class CanHand:
    """Fingers on the can's side, each reaching a patch of it (see the module docstring).

    Args:
        azimuths_deg: world azimuth psi_f of each finger's approach (it pushes along
            -(cos psi_f, sin psi_f, 0)), degrees; 3 to 5 fingers.
        heights: each finger's height on the side, a fraction of the half-height in (-1, 1)
            (distinct heights: two fingers never touch one point).
        reach_deg: half-width c of every finger's patch, degrees in (0, 90].
        names: the fingers' names (default finger1, ..., and the last ``thumb``).

    The default: five fingertips evenly round the can (72 deg apart, the thumb at 180 deg)
    at staggered heights, each reaching 60 deg either way: a contact lasts 120 deg of the
    turn, 12 poses of 10 deg. Contacts of 6 poses or fewer leave no gait that holds: each
    contact costs two moves (a placement, a lift), one move a pose, and three fingers must
    carry load at every pose (docs/gait.md, "The can").
    """

    azimuths_deg: tuple[float, ...] = (-36.0, 36.0, 108.0, 252.0, 180.0)
    heights: tuple[float, ...] = (0.5, 0.2, -0.1, -0.4, 0.05)
    reach_deg: float = 60.0
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        must = f"a sequence of 3 to {CAN_MAX_FINGERS} finite real numbers"
        azimuths = real_array("azimuths_deg", self.azimuths_deg, must)
        if azimuths.ndim != 1 or not 3 <= azimuths.size <= CAN_MAX_FINGERS:
            raise ValueError(f"azimuths_deg must be {must}, got {azimuths.tolist()}")
        heights = real_array("heights", self.heights, "fractions of the half-height in (-1, 1)")
        if heights.shape != azimuths.shape or np.any(np.abs(heights) >= 1):
            raise ValueError(
                f"heights must give each of the {azimuths.size} fingers a fraction of the"
                f" half-height in (-1, 1), got {heights.tolist()}"
            )
        if len(np.unique(heights)) != heights.size:
            raise ValueError(f"heights must differ (two fingers on one point), got {heights}")
        object.__setattr__(self, "azimuths_deg", tuple(azimuths.tolist()))
        object.__setattr__(self, "heights", tuple(heights.tolist()))
        reach = real_number("reach_deg", self.reach_deg, 0.0, 90.0, open_low=True)
        object.__setattr__(self, "reach_deg", reach)
        names = self.names
        if names is None:
            names = (*(f"finger{i + 1}" for i in range(azimuths.size - 1)), "thumb")
        if len(names) != azimuths.size or not all(isinstance(n, str) for n in names):
            raise ValueError(f"names must be {azimuths.size} strings, got {names!r}")
        object.__setattr__(self, "names", tuple(names))

    @property
    def n_fingers(self) -> int:
        return len(self.azimuths_deg)

    def max_age(self, step_deg: float) -> int:
        """H: the most poses of ``step_deg`` a finger holds after the one it is placed at
        (a delta <= 2 c, the far edge within reach to :data:`REACH_TOL`)."""
        span = 2 * self.reach_deg / step_deg
        return int(np.floor(span + REACH_TOL))

    def world_angles_deg(self, ages: ArrayLike, step_deg: float) -> np.ndarray:
        """World azimuth psi_f - c + a delta of each finger's contact at age a: (..., F)."""
        ages = np.asarray(ages, dtype=float)
        return np.asarray(self.azimuths_deg) - self.reach_deg + ages * step_deg


@dataclass(frozen=True)
class CanTurn:
    """The can's turn about its own (vertical) axis: alpha from ``start_deg`` to ``end_deg``
    in steps of ``step_deg`` (default a full turn in 10 deg steps, 37 poses)."""

    start_deg: float = 0.0
    end_deg: float = 360.0
    step_deg: float = 10.0

    def __post_init__(self) -> None:
        for name in ("start_deg", "end_deg"):
            object.__setattr__(self, name, real_number(name, getattr(self, name)))
        step = real_number("step_deg", self.step_deg, 0.0, 90.0, open_low=True)
        object.__setattr__(self, "step_deg", step)
        if self.end_deg < self.start_deg:
            raise ValueError(f"end_deg must be >= start_deg, got {self.end_deg} < {self.start_deg}")
        if len(self) > 10_000:
            raise ValueError(f"a can turn has at most 10,000 poses, got {len(self)}")

    def __len__(self) -> int:
        return int(np.floor((self.end_deg - self.start_deg) / self.step_deg + 1e-9)) + 1

    @property
    def alphas_deg(self) -> np.ndarray:
        return self.start_deg + self.step_deg * np.arange(len(self))

    def rotations(self) -> np.ndarray:
        """Rot(z, alpha) at every pose: (T, 3, 3)."""
        a = np.deg2rad(self.alphas_deg)
        c, s = np.cos(a), np.sin(a)
        R = np.zeros((len(a), 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
        return R


# ------------------------------------------------------------------ configurations


@cache
def can_configs(
    n_fingers: int, max_age: int, max_loaded: int = CAN_MAX_LOADED
) -> tuple[tuple[tuple[int, int], ...], ...]:
    """Every configuration: a set of 3 to ``max_loaded`` loaded fingers with an age in 1..H
    each, as ((finger, age), ...) in increasing finger order; by size, fingers, then ages."""
    out = []
    for n in range(CAN_MIN_LOADED, min(max_loaded, n_fingers) + 1):
        for fingers in combinations(range(n_fingers), n):
            for ages in product(range(1, max_age + 1), repeat=n):
                out.append(tuple(zip(fingers, ages, strict=True)))
    return tuple(out)


@dataclass(frozen=True, eq=False)  # compared by identity: a record of solver output
class CanValues:
    """The certified minimax of every configuration (:func:`can_configs`).

    Attributes:
        configs: the C configurations.
        margin: (C,) attained margin theta_lim - max_i theta_i(k*), radians.
        margin_bound: (C,) certified upper bound (theta_lim - lower_bound).
        optimum: per number of loaded fingers n (3, 4, 5), the solver's result over its
            configurations (in order), and ``members`` their indices.
        members: per n, (C_n,) indices into ``configs``.
    """

    configs: tuple[tuple[tuple[int, int], ...], ...]
    margin: np.ndarray
    margin_bound: np.ndarray
    optimum: tuple[MinimaxResult, ...]
    members: tuple[np.ndarray, ...]

    @property
    def uncertified(self) -> int:
        """Configurations whose optimum the solver left UNCERTIFIED (gap above 1e-9 rad)."""
        return int(sum(np.count_nonzero(o.status == Status.UNCERTIFIED) for o in self.optimum))

    def status(self, config: int) -> int:
        for members, optimum in zip(self.members, self.optimum, strict=True):
            hit = np.flatnonzero(members == config)
            if hit.size:
                return int(optimum.status[hit[0]])
        raise ValueError(f"configuration {config} is not in the table")

    def grip(self, config: int) -> tuple[np.ndarray, np.ndarray]:
        """k (m,) and the friction angles (n,) of a configuration, fingers in increasing order."""
        for members, optimum in zip(self.members, self.optimum, strict=True):
            hit = np.flatnonzero(members == config)
            if hit.size:
                return optimum.k[hit[0]], optimum.angles[hit[0]]
        raise ValueError(f"configuration {config} is not in the table")


def contact_points(
    can: Cylinder, hand: CanHand, step_deg: float, fingers: ArrayLike, ages: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """World-frame contact points (..., n, 3) relative to the can's centre and their inward
    normals, of ``fingers`` at ``ages`` (..., n) (the can's frame at alpha = 0; at any alpha
    the same grasp turned about the axis), from :meth:`Cylinder.side_point`."""
    fingers = np.asarray(fingers, dtype=np.intp)
    angles = np.deg2rad(hand.world_angles_deg(np.asarray(ages), step_deg))
    angles = np.take_along_axis(angles, fingers, axis=-1) if angles.ndim else angles
    heights = np.asarray(hand.heights)[fingers]
    flat_a, flat_h = angles.reshape(-1), heights.reshape(-1)
    points = np.array([can.side_point(a, h) for a, h in zip(flat_a, flat_h, strict=True)])
    normals = can.inward_normals(points)
    shape = (*fingers.shape, 3)
    return points.reshape(shape), normals.reshape(shape)


def can_values(
    hand: CanHand,
    step_deg: float,
    can: Cylinder | None = None,
    weight: float = CAN_WEIGHT,
    mu: float = 0.5,
    k_max: float | None = None,
    cg_height: float = 0.0,
    max_loaded: int = CAN_MAX_LOADED,
) -> CanValues:
    """Solve the certified minimax (:func:`~grasp_env.mechanics.solve_minimax`, eq. 2 and 4)
    of every configuration of ``hand`` at poses of ``step_deg``, one batch per number of loaded
    fingers. ``k_max`` defaults to 2 w (the environments' box); ``cg_height`` (metres) moves
    the centre of gravity along the axis (it stays on it: the margins stay alpha-free)."""
    can = Cylinder(radius=CAN_RADIUS, height=CAN_HEIGHT) if can is None else can
    weight = real_number("weight", weight, 0.0, open_low=True)
    mu = real_number("mu", mu, 0.0, open_low=True)
    k_max = 2.0 * weight if k_max is None else real_number("k_max", k_max, 0.0, open_low=True)
    cg = np.array([0.0, 0.0, real_number("cg_height", cg_height)])
    if not can.contains(cg):
        raise ValueError(f"cg_height {cg_height} m puts the centre of gravity outside the can")
    H = hand.max_age(step_deg)
    if not 1 <= H <= CAN_MAX_AGE:
        raise ValueError(
            f"a finger must hold 1 to {CAN_MAX_AGE} poses (2 reach_deg / step_deg), got {H}:"
            f" reach {hand.reach_deg:g} deg, step {step_deg:g} deg"
        )
    configs = can_configs(hand.n_fingers, H, max_loaded)
    limit = float(np.arctan(mu))
    margin = np.full(len(configs), -np.inf)
    bound = np.full(len(configs), -np.inf)
    wrench = load_wrench(weight)
    optima, members = [], []
    for n in range(CAN_MIN_LOADED, min(max_loaded, hand.n_fingers) + 1):
        index = np.array([i for i, c in enumerate(configs) if len(c) == n])
        fingers = np.array([[f for f, _ in configs[i]] for i in index])
        ages = np.array([[a for _, a in configs[i]] for i in index])
        all_ages = np.zeros((len(index), hand.n_fingers), np.int64)
        np.put_along_axis(all_ages, fingers, ages, axis=-1)
        points, normals = contact_points(can, hand, step_deg, fingers, all_ages)
        g = grasp(points - cg, normals, np.eye(3), wrench, limit)
        optimum = solve_minimax(g, k_max)
        margin[index] = limit - optimum.max_angle
        bound[index] = limit - optimum.lower_bound
        optima.append(optimum)
        members.append(index)
    for array in (margin, bound):
        array.flags.writeable = False
    return CanValues(configs, margin, bound, tuple(optima), tuple(members))
