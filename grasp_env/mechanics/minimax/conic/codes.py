"""The conic solver's constants and its numba decorator.

The status and refusal codes copy ``minimax.codes`` (numba freezes module constants, and this
package's cache is keyed on its own sources): ``conic/__init__.py`` checks them against it.
"""

from __future__ import annotations

from numba import njit

#: Accepted certificate gap, radians (as the three- and four-finger solver's GAP_TOL).
GAP_TOL = 1e-9
#: How far below the best grip a certificate is sought, radians: first within GAP_TOL, then
#: (the gap left open, status UNCERTIFIED) the nearest that a barrier's duals prove.
BOUND_BELOW = (9e-10, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
#: Barrier parameter growth per stage, and the most stages and Newton steps per centring.
GROWTH = 12.0
STAGES = 40
NEWTON_STEPS = 60
#: A point is centred when its Newton decrement (squared) is below this.
CENTRED = 1e-9
DINKELBACH_STEPS = 40
#: The barrier parameter (units of the load) past which polish() builds the certificate.
POLISH_FROM = 1e9
#: Rounds of polishing below the best grip (each may find a better one).
POLISH_ROUNDS = 6
#: A Dinkelbach level is solved until its bounds are within this fraction of each other.
LEVEL_GAP = 1e-4

# results (status codes as minimax.codes: INTERIOR, BOUNDARY, NOT_PUSHING, UNCERTIFIED)
INTERIOR = 0
BOUNDARY = 1
NOT_PUSHING = 2
UNCERTIFIED = 3
# refusals (as minimax.codes)
INVALID = -1
BAD_NORMAL = -2
BAD_LOAD = -3
BAD_K_MAX = -4
BAD_F_MAX = -5
UNIT_TOL = 1e-6
LOAD_RANGE = (1e-305, 1e305)
RATIO_RANGE = (1e-12, 1e12)

#: A compiled kernel of the conic solver (numba's runtime: its arrays are heap arrays).
kernel = njit(cache=True, nogil=True, error_model="numpy")
