"""The conic solver: the certified minimax grip for any number of contacts (five to eight in
:func:`~grasp_env.mechanics.minimax.solve_minimax`; three and four too, as a cross-check of
the kernels that solve those), by Dinkelbach's iterations over a log-barrier method, Newton's
method on the KKT system near the optimum, and a weak-duality certificate (docs/solver.md,
"Any number of contacts").

| module | role |
| --- | --- |
| ``codes`` | its constants and the ``kernel`` decorator (the codes are ``minimax.codes``') |
| ``frames`` | forces, angles, the force coordinates y (k = B y), the dense solves |
| ``barrier`` | the cone problem at a level by the barrier method; the duals' certificate |
| ``polish`` | Newton's method on the KKT system of the sets a barrier point shows |
| ``driver`` | ``search`` (fast or careful), ``solve_one`` and the entry ``solve_batch`` |
"""

import os

from ..jit import register_package

# before any kernel here is compiled or loaded; the kernels link the finger frames and codes
# of the parent package, so its sources key this cache too
register_package(os.path.dirname(__file__), os.path.dirname(os.path.dirname(__file__)))

from .driver import solve_batch, solve_one  # noqa: E402

__all__ = ["solve_batch", "solve_one"]
