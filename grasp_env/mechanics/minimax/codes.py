"""The solver's codes and contract constants, shared by the kernels and the Python API.

The kernels read the module constants (numba freezes them at compile time); Python code
uses the IntEnums built from the same numbers.
"""

from __future__ import annotations

from enum import IntEnum

#: Accepted certificate gap, radians (1e-6 deg is 1.7e-8 rad).
GAP_TOL = 1e-9

# Where the optimum lies (MinimaxResult.status).
INTERIOR = 0
BOUNDARY = 1
NOT_PUSHING = 2
UNCERTIFIED_STATUS = 3  #: the gap exceeds GAP_TOL (Status.UNCERTIFIED; set in Python)

# Which attempt certified the optimum (diagnostic; solve_one's path).
APEX = 0  #: every finger along its normal: 0 is attained and is the bound
DIRECT = 1  #: Newton's method straight from the start (three fingers, no force limit)
SQP = 2  #: the SQP, then Newton's method on its sets
RELEASED = 3  #: a finger released (four fingers)
RESTARTED = 4  #: the SQP restarted with the weakest finger pushing (four fingers)
FALLBACK = 5  #: Dinkelbach iterations with the barrier method, then Newton's method
UNCERTIFIED = 6  #: no attempt closed the gap to GAP_TOL
NEARBY = 7  #: Newton's method from the previous pose's optimum (``follows``)
BISECTION = 8  #: bisection on t with a certificate at each step
# Inputs refused (negative paths; solve_minimax raises ValueError).
INVALID = -1  #: NaN or inf in the grasp
BAD_NORMAL = -2  #: a normal not of unit length
BAD_LOAD = -3  #: a load's scale outside LOAD_RANGE
BAD_K_MAX = -4  #: k_max outside RATIO_RANGE x the load's scale
BAD_F_MAX = -5  #: f_max outside RATIO_RANGE x the load's scale

#: Accepted scale of the load, the largest equilibrating force (newtons), besides 0.
LOAD_RANGE = (1e-305, 1e305)
#: Accepted k_max and f_max in units of the load: beyond them float64 cannot hold the
#: equilibrating forces beside the interaction forces (or the reverse).
RATIO_RANGE = (1e-12, 1e12)
#: Accepted deviation of a normal's length from 1.
UNIT_TOL = 1e-6
#: The contacts a grasp may have for the solver: three and four by the kernels of this
#: package, five to eight by the conic solver (:mod:`.conic`).
CONTACTS_RANGE = (3, 8)


class Status(IntEnum):
    """Where the optimum lies."""

    INTERIOR = INTERIOR  #: the box does not limit the optimum
    BOUNDARY = BOUNDARY  #: the optimum is on the box: the interaction forces would grow
    NOT_PUSHING = NOT_PUSHING  #: no k in the box keeps every finger pushing (>= 90 deg)
    #: no attempt closed the certificate's gap to GAP_TOL: ``lower_bound`` is still certified,
    #: ``gap`` says how far it is
    UNCERTIFIED = UNCERTIFIED_STATUS


class Path(IntEnum):
    """The attempt that certified a result, or why an input was refused (diagnostic)."""

    APEX = APEX
    DIRECT = DIRECT
    SQP = SQP
    RELEASED = RELEASED
    RESTARTED = RESTARTED
    FALLBACK = FALLBACK
    UNCERTIFIED = UNCERTIFIED
    NEARBY = NEARBY
    BISECTION = BISECTION
    INVALID = INVALID
    BAD_NORMAL = BAD_NORMAL
    BAD_LOAD = BAD_LOAD
    BAD_K_MAX = BAD_K_MAX
    BAD_F_MAX = BAD_F_MAX
