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
#: A Dinkelbach level's centring that takes this many Newton steps has stalled (a finger
#: near its cone's apex: full steps, the decrement constant): the level ends there, its best
#: point the next level's start (the levels that decide a sign keep NEWTON_STEPS).
STALLED = 25
#: A point is centred when its Newton decrement (squared) is below this.
CENTRED = 1e-9
DINKELBACH_STEPS = 40
#: Dinkelbach's iterations stop when a level lowers the best angle by at most this (rad);
#: the KKT polish, on the sets of the last level's barrier point, finishes.
CONVERGED = 1e-12
#: The barrier parameter (units of the load) past which polish() builds the certificate.
POLISH_FROM = 1e9
#: Rounds of polishing below the best grip (each may find a better one).
POLISH_ROUNDS = 6
#: A Dinkelbach level is solved until its bounds are within this fraction of each other
#: (LEVEL_GAP_CAREFUL in the careful search, the fallback where the fast one leaves a gap).
LEVEL_GAP = 1e-2
LEVEL_GAP_CAREFUL = 1e-4

#: A compiled kernel of the conic solver (numba's runtime: its arrays are heap arrays).
kernel = njit(cache=True, nogil=True, error_model="numpy")
#: The active-set attempt (``active``): its SQP's most steps, the predicted decrease of the
#: largest angle (rad) below which it stops, and the share of the largest force below which
#: a finger is released, and the push along its normal that holds it there (units of the
#: load: its angle 0, within rounding of its cone's apex).
ACTIVE_STEPS = 60
ACTIVE_TOL = (1e-5, 1e-10)
RELEASE_AT = 1e-3
RELEASE_PUSH = 1e-10
#: The force (share of the largest) with which a released finger pushes again where its
#: multipliers say that pushing lowers the largest angle.
UNRELEASE = 1e-2
