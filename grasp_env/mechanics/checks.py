"""Checks of the mechanics' inputs, each raising a ValueError that names the input and its
accepted range (the environments' checks, ``grasp_env.envs.validation``, follow the same rules).

Numbers must be real numbers (Python or numpy ints and floats, or arrays of them): booleans,
complex numbers, strings and None are refused rather than converted.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import numpy as np


def is_real(value: Any) -> bool:
    """Whether ``value`` is one real number (not a boolean): a Python or numpy int or float,
    or a 0-d numeric array."""
    if isinstance(value, np.ndarray):
        return value.ndim == 0 and value.dtype.kind in "iuf"
    return isinstance(value, Real) and not isinstance(value, bool | np.bool_)


def is_integer(value: Any) -> bool:
    """Whether ``value`` is one integer (not a boolean): a Python or numpy int."""
    return isinstance(value, Integral) and not isinstance(value, bool | np.bool_)


def interval(low: float, high: float, *, open_low: bool = False, open_high: bool = False) -> str:
    """The range [low, high] in words: "> 0", ">= 1", "<= 2" or "in (0, 1]"."""
    if math.isinf(high) and math.isinf(low):
        return "(any)"
    if math.isinf(high):
        return f"{'>' if open_low else '>='} {low:g}"
    if math.isinf(low):
        return f"{'<' if open_high else '<='} {high:g}"
    return f"in {'(' if open_low else '['}{low:g}, {high:g}{')' if open_high else ']'}"


def real_number(
    name: str,
    value: Any,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    open_low: bool = False,
    open_high: bool = False,
) -> float:
    """``value`` as a float: a finite real number in [low, high] (ends excluded with
    ``open_low`` / ``open_high``), or a ValueError naming ``name`` and the range."""
    words = interval(low, high, open_low=open_low, open_high=open_high)
    message = f"{name} must be a finite number" + ("" if words == "(any)" else f" {words}")
    if not is_real(value):
        raise ValueError(f"{message}, got {value!r}")
    number = float(value)
    below = number <= low if open_low else number < low
    above = number >= high if open_high else number > high
    if not math.isfinite(number) or below or above:
        raise ValueError(f"{message}, got {value!r}")
    return number


def real_array(name: str, value: Any, must: str = "finite real numbers") -> np.ndarray:
    """``value`` as a float64 array of finite real numbers (no booleans, complex numbers or
    strings), or a ValueError "``name`` must be ``must``, got ...". The caller checks the
    shape (``must`` describes it for the message). The caller's float64 array comes back as
    it is: a new array only where a conversion needs one."""
    description = f"{name} must be {must}"
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):  # ragged nesting
        raise ValueError(f"{description}, got {_short(value)}") from None
    if array.dtype == object:  # mixed types: every element must be a real number
        if not all(is_real(v) for v in array.flat):
            raise ValueError(f"{description}, got {_short(value)}")
        array = array.astype(np.float64)
    elif array.dtype.kind not in "iuf":
        raise ValueError(f"{description}, got dtype {array.dtype}: {_short(value)}")
    elif isinstance(value, list | tuple) and _has_bool(value):
        # numpy turns [True, 0.5] into floats silently
        raise ValueError(f"{description}, got booleans in {_short(value)}")
    if array.dtype != np.float64:
        array = array.astype(np.float64)
    if not np.isfinite(array).all():
        raise ValueError(f"{description}, got NaN or inf in {_short(array)}")
    return array


def _has_bool(value: Any) -> bool:
    if isinstance(value, list | tuple):
        return any(_has_bool(v) for v in value)
    return isinstance(value, bool | np.bool_)


def _short(value: Any) -> str:
    """A value for a message, cut short if long."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 200 else text[:200] + " ..."
