"""The counted arithmetic behind ``benchmarks/limits.py``: the solver's kernels run as Python
with every floating-point operation counted.

The solver's kernels are numba functions whose Python source (``py_func``) is the code numba
compiles. :class:`Interpreter` runs that source, unedited, in
Python: every kernel is rebuilt on copies of its module's globals in which the kernels call
each other's counting copies, ``np.empty`` / ``zeros`` / ``ones`` / ``full`` make arrays of
:class:`Counted` floats, and the ``math`` functions count themselves. A :class:`Counted`
float counts each addition or subtraction, multiplication, division, square root and
transcendental function (atan, atan2, cos, sin, log, powers other than squares) as one
floating-point operation; x ** 2 is one multiplication; negation, abs, min, max and
comparisons are not counted (the compiled code does them with sign masks, min/max and
compare instructions, not the floating-point pipeline's arithmetic), nor operations on
constants alone (folded by the compiler). The grasp's data and limits enter as Counted
floats, so every operation on values derived from them is counted, on the path the solve
really takes (the interpreted solve returns the compiled one's certified path and optimum:
checked on every grasp counted). The counts are broken down by kernel (operations done in a
kernel's own code, its calls, and the calls it makes), which gives the units of work: an
SQP step (``sqp`` calls ``quadprog`` once a step), a Newton step on a KKT system (``polish``
calls ``lu_solve`` once a step), a certificate (``certify``), a friction-angle evaluation
(``evaluate``). The leaf kernels' counts have closed forms in n and m (``*_flops`` in
limits.py; tests/test_bench_limits.py checks them against the interpreter).
"""

from __future__ import annotations

import importlib
import math
import types
from collections import defaultdict
from collections.abc import Callable
from typing import ClassVar

import numpy as np
from numba.core.dispatcher import Dispatcher

#: The kernel modules, callees before callers.
MODULES = ("linalg", "fingers", "starts", "sqp", "certificate", "newton", "barrier", "driver")
#: The kinds of operation counted, in the order of Counted's tallies.
KINDS = ("add", "mul", "div", "sqrt", "transcendental")
ADD, MUL, DIV, SQRT, TRANS = range(5)


class _Tally:
    """The tallies of the kernel running now (the interpreter swaps them per call)."""

    current: ClassVar[list[int]] = [0] * len(KINDS)
    #: every operation counted so far, in any kernel
    grand: ClassVar[list[int]] = [0]


def _inexact(x: float, y: float, op: Callable[[np.float64, np.float64], np.float64]) -> float:
    with np.errstate(all="ignore"):  # the kernels' error model: IEEE results, no exceptions
        return float(op(np.float64(x), np.float64(y)))


class Counted(float):
    """A float whose arithmetic counts itself into the running kernel's tallies."""

    __slots__ = ()

    def _count(self, kind: int, value: float) -> Counted:
        _Tally.current[kind] += 1
        _Tally.grand[0] += 1
        return Counted(value)

    def __add__(self, other):  # type: ignore[no-untyped-def]
        return self._count(ADD, float(self) + float(other))

    __radd__ = __add__

    def __sub__(self, other):  # type: ignore[no-untyped-def]
        return self._count(ADD, float(self) - float(other))

    def __rsub__(self, other):  # type: ignore[no-untyped-def]
        return self._count(ADD, float(other) - float(self))

    def __mul__(self, other):  # type: ignore[no-untyped-def]
        return self._count(MUL, float(self) * float(other))

    __rmul__ = __mul__

    def __truediv__(self, other):  # type: ignore[no-untyped-def]
        y = float(other)
        value = float(self) / y if y != 0.0 else _inexact(self, y, np.divide)
        return self._count(DIV, value)

    def __rtruediv__(self, other):  # type: ignore[no-untyped-def]
        x, y = float(other), float(self)
        return self._count(DIV, x / y if y != 0.0 else _inexact(x, y, np.divide))

    def __pow__(self, other):  # type: ignore[no-untyped-def]
        if other == 2:
            return self._count(MUL, float(self) * float(self))
        return self._count(TRANS, _inexact(self, float(other), np.power))

    def __rpow__(self, other):  # type: ignore[no-untyped-def]
        return self._count(TRANS, _inexact(float(other), self, np.power))

    def __neg__(self) -> Counted:
        return Counted(-float(self))

    def __pos__(self) -> Counted:
        return self

    def __abs__(self) -> Counted:
        return Counted(abs(float(self)))


def _counting(kind: int, function: Callable[..., float]) -> Callable[..., Counted]:
    def counted(*args: float) -> Counted:
        _Tally.current[kind] += 1
        _Tally.grand[0] += 1
        with np.errstate(all="ignore"):
            return Counted(float(function(*(np.float64(x) for x in args))))

    return counted


#: The math functions the kernels import, as counting copies (numpy's, for IEEE results).
MATH = {
    "sqrt": _counting(SQRT, np.sqrt),
    "atan": _counting(TRANS, np.arctan),
    "atan2": _counting(TRANS, np.arctan2),
    "cos": _counting(TRANS, np.cos),
    "sin": _counting(TRANS, np.sin),
    "log": _counting(TRANS, np.log),
}


def _is_float(dtype: object) -> bool:
    return dtype is None or dtype is float or np.dtype(dtype) == np.float64


class _CountingNumpy:
    """numpy for the interpreted kernels: float arrays hold Counted floats (object arrays)."""

    def __getattr__(self, name: str) -> object:
        return getattr(np, name)

    @staticmethod
    def full(shape, value, dtype=None):  # type: ignore[no-untyped-def]
        if not _is_float(dtype):
            return np.full(shape, value, dtype)
        array = np.empty(shape, dtype=object)
        array.fill(value if isinstance(value, Counted) else Counted(value))
        return array

    @staticmethod
    def zeros(shape, dtype=None):  # type: ignore[no-untyped-def]
        return _CountingNumpy.full(shape, 0.0, dtype)

    @staticmethod
    def empty(shape, dtype=None):  # type: ignore[no-untyped-def]
        if _is_float(dtype):
            return _CountingNumpy.zeros(shape)
        return np.empty(shape, dtype)

    @staticmethod
    def ones(shape, dtype=None):  # type: ignore[no-untyped-def]
        return _CountingNumpy.full(shape, 1.0, dtype)


#: The interpreted kernels' arrays in a stack frame, as the compiled ones' (linalg.py).
_STACK = {
    "stack_empty": _CountingNumpy.empty,
    "stack_zeros": _CountingNumpy.zeros,
    "stack_large": _CountingNumpy.zeros,
    "stack_copy": lambda x: x.copy(),
}


def counted_array(array: np.ndarray) -> np.ndarray:
    """An object array of Counted floats with the values of ``array``."""
    out = np.empty(np.shape(array), dtype=object)
    out.ravel()[:] = [Counted(x) for x in np.ravel(array)]
    return out


class Interpreter:
    """The kernels' own Python source, run with counted arithmetic.

    ``kernel(name)`` is the counting copy of a kernel (by its function name). After calls,
    ``own[name]`` holds the operations done in that kernel's own code (tallies by KINDS),
    ``inclusive[name]`` those done in it and in everything it called, ``calls[name]`` its
    calls and ``edges[(caller, callee)]`` the calls between kernels.
    """

    def __init__(self, extra: dict[str, types.ModuleType] | None = None) -> None:
        self.own: dict[str, list[int]] = defaultdict(lambda: [0] * len(KINDS))
        self.inclusive: dict[str, int] = defaultdict(int)
        self.calls: dict[str, int] = defaultdict(int)
        self.edges: dict[tuple[str, str], int] = defaultdict(int)
        self._stack = ["(outside)"]
        self._copies: dict[object, Callable] = {}
        modules = [importlib.import_module(f"grasp_env.mechanics.minimax.{m}") for m in MODULES]
        modules += list((extra or {}).values())
        self._globals = {module.__name__: dict(vars(module)) for module in modules}
        for names in self._globals.values():
            for name, value in list(names.items()):
                if name in _STACK:
                    names[name] = _STACK[name]
                elif isinstance(value, Dispatcher):
                    names[name] = self._copy(value)
                elif name == "np":
                    names[name] = _CountingNumpy()
                elif name in MATH and value is getattr(math, name):
                    names[name] = MATH[name]
        self._names = {
            name: value
            for names in self._globals.values()
            for name, value in names.items()
            if getattr(value, "counted_kernel", False)
        }

    def _copy(self, dispatcher: Dispatcher) -> Callable:
        source = dispatcher.py_func
        if source in self._copies:
            return self._copies[source]
        body = types.FunctionType(
            source.__code__,
            self._globals[source.__module__],
            source.__name__,
            source.__defaults__,
            source.__closure__,
        )
        name = source.__name__

        def counting(*args):  # type: ignore[no-untyped-def]
            self.calls[name] += 1
            self.edges[(self._stack[-1], name)] += 1
            outer = _Tally.current
            _Tally.current = self.own[name]
            self._stack.append(name)
            before = _Tally.grand[0]
            try:
                return body(*args)
            finally:
                self._stack.pop()
                _Tally.current = outer
                if name not in self._stack:  # (recursion would count twice)
                    self.inclusive[name] += _Tally.grand[0] - before

        counting.counted_kernel = True  # type: ignore[attr-defined]
        self._copies[source] = counting
        return counting

    def kernel(self, name: str) -> Callable:
        return self._names[name]

    def reset(self) -> None:
        self.own.clear()
        self.inclusive.clear()
        self.calls.clear()
        self.edges.clear()

    def total(self) -> int:
        return sum(sum(tallies) for tallies in self.own.values())

    def by_kind(self) -> dict[str, int]:
        return {kind: sum(t[i] for t in self.own.values()) for i, kind in enumerate(KINDS)}

    def solve(
        self,
        F: np.ndarray,
        E: np.ndarray,
        N: np.ndarray,
        k_max: float,
        f_max: float,
        nearby: tuple[np.ndarray, ...] | None = None,
    ) -> tuple[np.ndarray, float, int, int]:
        """``solve_one`` on one grasp (world-frame arrays), counted: (k, lower, status, path).

        nearby: (k_near, k_before, theta_near, F_near, E_near, N_near), the two previous
        poses' optima, the previous optimum's angles and the previous pose, to start as
        ``solve_batch`` does along a trajectory (secant).
        """
        n, m = F.shape[0], E.shape[0]
        k = counted_array(np.zeros(m))
        theta = counted_array(np.zeros(n))
        grasp = counted_array(F), counted_array(E), counted_array(N)
        near = (k, k, theta, False, False, *grasp)
        if nearby is not None:
            k_near, k_before, theta_near, *previous = (
                counted_array(np.array(x, float)) for x in nearby
            )
            near = (k_near, k_before, theta_near, True, True, *previous)
        lower, status, path = self.kernel("solve_one")(
            *grasp, Counted(k_max), Counted(f_max), k, theta, *near
        )
        return np.array(k, dtype=float), float(lower), int(status), int(path)


__all__ = [
    "ADD", "DIV", "KINDS", "MATH", "MODULES", "MUL", "SQRT", "TRANS",
    "Counted", "Interpreter", "counted_array",
]  # fmt: skip
