"""The observation vector of the grasp environments: its layout, bounds and scaling.

One flat float32 vector, in units that make the problem scale-free (forces in units of the
object's weight w, lengths in units of its edge length L):

==================  ======  =========================================================  ==========
slice               size    content                                                    bounds
==================  ======  =========================================================  ==========
``rotation``        6       first two columns of R (the continuous "6D" representation) [-1, 1]
``positions``       3n      p_i / L = R (c_i - g) / L, contacts relative to the cg      [-√3, √3]
``normals``         3n      n_i = R nu_i, inward unit normals                          [-1, 1]
``force``           3       f / w = (0, 0, -1) + f_d / w, the load force               x, y [-1, 1];
                                                                                       z [-2, 0]
``torque``          3       tau_d / (w L), the extra load torque about the cg          [-1, 1]
``friction_limit``  1       theta_lim = atan(mu), radians                              [0, pi/2]
``phase``           1       steps taken / trajectory length                            [0, 1]
==================  ======  =========================================================  ==========

All vectors are in the world frame. |c_i - g| < √3 L because both points lie in the box; the
extra load is limited to |f_d| <= w and |tau_d| <= w L per component so that its slices are
bounded. Everything the minimax expert needs (positions, normals, load, friction limit) is in
the vector: scaling positions by L and the torque by w L leaves the equilibrating forces in
units of w unchanged, and the interaction directions and friction angles do not depend on
scale at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_SQRT3 = float(np.sqrt(3.0))


@dataclass(frozen=True)
class ObservationLayout:
    """Slices of the observation vector for ``n_contacts`` fingers (see the module docstring)."""

    n_contacts: int

    @classmethod
    def from_size(cls, size: int) -> ObservationLayout:
        """The layout whose vector has ``size`` elements: size = 14 + 6 n."""
        n, rest = divmod(size - 14, 6)
        if rest or n not in (3, 4):
            raise ValueError(
                f"an observation has 32 (3 fingers) or 38 (4 fingers) elements, got {size}"
            )
        return cls(n)

    @property
    def size(self) -> int:
        return 14 + 6 * self.n_contacts

    @property
    def rotation(self) -> slice:
        return slice(0, 6)

    @property
    def positions(self) -> slice:
        return slice(6, 6 + 3 * self.n_contacts)

    @property
    def normals(self) -> slice:
        return slice(6 + 3 * self.n_contacts, 6 + 6 * self.n_contacts)

    @property
    def force(self) -> slice:
        start = 6 + 6 * self.n_contacts
        return slice(start, start + 3)

    @property
    def torque(self) -> slice:
        start = 9 + 6 * self.n_contacts
        return slice(start, start + 3)

    @property
    def friction_limit(self) -> int:
        return 12 + 6 * self.n_contacts

    @property
    def phase(self) -> int:
        return 13 + 6 * self.n_contacts

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) float32 arrays of the observation space."""
        n = self.n_contacts
        low = np.concatenate(
            [
                -np.ones(6),
                np.full(3 * n, -_SQRT3),
                -np.ones(3 * n),
                [-1.0, -1.0, -2.0],
                -np.ones(3),
                [0.0, 0.0],
            ]
        )
        high = np.concatenate(
            [
                np.ones(6),
                np.full(3 * n, _SQRT3),
                np.ones(3 * n),
                [1.0, 1.0, 0.0],
                np.ones(3),
                [np.pi / 2, 1.0],
            ]
        )
        return low.astype(np.float32), high.astype(np.float32)
