"""The conic solver: the certified minimax grip for any number of contacts (five to eight in
:func:`~grasp_env.mechanics.minimax.solve_minimax`; three and four too, as a cross-check of
the kernels that solve those), by Dinkelbach's iterations over a log-barrier method, Newton's
method on the KKT system near the optimum, and a weak-duality certificate (:mod:`.kernels`,
docs/solver.md, "Any number of contacts").

Its kernels keep copies of the solver's codes (numba freezes module constants, and this
package's cache is keyed on its own sources): they are checked against ``codes`` here.
"""

from .. import codes
from . import kernels
from .kernels import solve_batch, solve_one

for _name in (
    "GAP_TOL", "INTERIOR", "BOUNDARY", "NOT_PUSHING", "INVALID", "BAD_NORMAL", "BAD_LOAD",
    "BAD_K_MAX", "BAD_F_MAX", "UNIT_TOL", "LOAD_RANGE", "RATIO_RANGE",
):  # fmt: skip
    if getattr(kernels, _name) != getattr(codes, _name):
        raise ImportError(f"conic.kernels.{_name} differs from codes.{_name}")
if kernels.UNCERTIFIED != codes.UNCERTIFIED_STATUS:
    raise ImportError("conic.kernels.UNCERTIFIED differs from codes.UNCERTIFIED_STATUS")

__all__ = ["solve_batch", "solve_one"]
