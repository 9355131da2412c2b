"""Checks of the environments' keywords and options: one validator per rule, each raising a
ValueError that names the keyword and the accepted range."""

from __future__ import annotations

from typing import Any

import numpy as np

#: Default action scale of the environments: k_max = 2 w.
DEFAULT_K_MAX_RATIO = 2.0


def check_range(name: str, value: Any, low: float, high: float, *, open_low: bool = False) -> tuple:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a (low, high) pair, got {value!r}") from error
    below = lo <= low if open_low else lo < low
    if not (np.isfinite(lo) and np.isfinite(hi)) or below or hi > high or hi < lo:
        bracket = "(" if open_low else "["
        raise ValueError(
            f"{name} must satisfy low <= high within {bracket}{low}, {high}], got {value!r}"
        )
    return lo, hi


def check_fraction(name: str, value: Any, high: float = 1.0, *, closed: bool = False) -> float:
    """A number in [0, high) (or [0, high] if ``closed``)."""
    interval = f"[0, {high:g}{']' if closed else ')'}"
    try:
        value = float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number in {interval}, got {value!r}") from error
    if not (0.0 <= value <= high if closed else 0.0 <= value < high):
        raise ValueError(f"{name} must be in {interval}, got {value}")
    return value


def check_margin(value: Any) -> float:
    """``min_expert_margin_deg`` in [0, 45) degrees, returned in radians."""
    return float(np.deg2rad(check_fraction("min_expert_margin_deg", value, 45.0)))


def check_k_max_ratio(value: Any) -> float:
    """``k_max_ratio`` = k_max / w, a finite number > 0."""
    try:
        value = float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"k_max_ratio must be a finite number > 0, got {value!r}") from error
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"k_max_ratio must be a finite number > 0, got {value}")
    return value
