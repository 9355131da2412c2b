"""The conic solver's constants and its numba decorator; its status and refusal codes are
``minimax.codes``' (its cache is keyed on that package's sources too, see ``__init__``)."""

from __future__ import annotations

from numba import njit

#: How far below the best grip a certificate is sought, radians: first within GAP_TOL, then
#: (the gap left open, status UNCERTIFIED) the nearest that a barrier's duals prove (GAP_TOL
#: is the three- and four-finger solver's).
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

#: A compiled kernel of the conic solver (numba's runtime: its arrays are heap arrays).
kernel = njit(cache=True, nogil=True, error_model="numpy")
