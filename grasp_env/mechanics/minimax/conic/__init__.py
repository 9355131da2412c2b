"""The conic solver: the certified minimax grip for any number of contacts (five to eight in
:func:`~grasp_env.mechanics.minimax.solve_minimax`; three and four too, as a cross-check of
the kernels that solve those), by Dinkelbach's iterations over a log-barrier method, Newton's
method on the KKT system near the optimum, and a weak-duality certificate (docs/solver.md,
"Any number of contacts").

| module | role |
| --- | --- |
| ``codes`` | constants (copies of ``minimax.codes``, checked here) and the ``kernel`` decorator |
| ``frames`` | finger frames, forces, angles, the force coordinates y (k = B y), dense solves |
| ``barrier`` | the cone problem at a level by the barrier method; the duals' certificate |
| ``polish`` | Newton's method on the KKT system of the sets a barrier point shows |
| ``driver`` | ``solve_one`` (Dinkelbach, then the certificate) and the entry ``solve_batch`` |
"""

import os

from ..jit import register_package

register_package(os.path.dirname(__file__))  # before any kernel here is compiled or loaded

from .. import codes as _codes  # noqa: E402
from . import codes  # noqa: E402
from .driver import solve_batch, solve_one  # noqa: E402

for _name in (
    "GAP_TOL", "INTERIOR", "BOUNDARY", "NOT_PUSHING", "INVALID", "BAD_NORMAL", "BAD_LOAD",
    "BAD_K_MAX", "BAD_F_MAX", "UNIT_TOL", "LOAD_RANGE", "RATIO_RANGE",
):  # fmt: skip
    if getattr(codes, _name) != getattr(_codes, _name):
        raise ImportError(f"conic.codes.{_name} differs from minimax.codes.{_name}")
if codes.UNCERTIFIED != _codes.UNCERTIFIED_STATUS:
    raise ImportError("conic.codes.UNCERTIFIED differs from minimax.codes.UNCERTIFIED_STATUS")

__all__ = ["solve_batch", "solve_one"]
