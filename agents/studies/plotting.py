"""Plot helpers shared by the commands' figures: curves that may coincide stay visible."""

from __future__ import annotations

from typing import Any

import numpy as np

STYLES = ["-", "--", ":", "-.", (0, (5, 1)), (0, (1, 3))]


def plot_series(
    ax: Any,
    x: np.ndarray,
    series: np.ndarray,
    names: list[str],
    unit: str,
    *,
    scale: float | None = None,
    **style: Any,
) -> list[Any]:
    """One curve per row of ``series``, larger hollow markers under smaller ones (so curves
    that coincide all show), and a note on the plot naming those that do (within 1e-6 of
    ``scale``, the size of the quantity, e.g. the weight for forces; default the largest
    value or 1, whichever is larger)."""
    lines = []
    for i, (values, name) in enumerate(zip(series, names, strict=True)):
        size = 9 - 2.5 * min(i, 3)
        options = {"ls": STYLES[i % len(STYLES)], "marker": "o", "ms": size, "mfc": "none"}
        lines += ax.plot(x, values, label=name, **(options | style))
    note_coincidences(ax, series, names, unit, scale=scale)
    return lines


def note_coincidences(
    ax: Any, series: np.ndarray, names: list[str], unit: str, *, scale: float | None = None
) -> None:
    """Say on the plot which curves coincide (all zero, k13 = k23...), within 1e-6 of
    ``scale`` (:func:`plot_series`), in a band added above everything drawn so far."""
    tolerance = 1e-6 * (max(np.abs(series).max(), 1.0) if scale is None else scale)
    groups: list[list[int]] = []
    for i in range(len(series)):
        same = [g for g in groups if np.allclose(series[i], series[g[0]], atol=tolerance)]
        if same:
            same[0].append(i)
        else:
            groups.append([i])
    notes = []
    for group in (g for g in groups if len(g) > 1):
        members = [names[i] for i in group]
        if np.allclose(series[group[0]], 0.0, atol=tolerance):
            notes.append(f"{', '.join(members)} are 0 {unit} throughout")
        else:
            notes.append(f"{' = '.join(members)} throughout")
    if notes:
        low, high = ax.get_ylim()
        ax.set_ylim(low, high + 0.12 * (high - low))
        box = {"facecolor": "white", "alpha": 0.85, "linewidth": 0}
        text = "the lines coincide: " + "; ".join(notes)
        ax.text(0.02, 0.97, text, transform=ax.transAxes, va="top", fontsize=8, bbox=box)
