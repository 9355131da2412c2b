"""A run's learning curve: held-out evaluations over training, as CSV and as a plot.

``learning_curve.csv`` has one row per evaluation: the phase (``initial``, ``imitation``, or
the algorithm: ``ppo``, ``td3``, ``sac``), the environment steps the evaluated weights were
trained on (imitation's labelled states, then the algorithm's steps after them; not the steps
collected when the evaluation ran, which for PPO include a rollout not yet learnt from), the
wall and CPU seconds of training, and the held-out metrics of
:func:`grasp_env_agents.learning.envs.summarise`. The last row of a finished run is its final model
(``model.zip``, which the run's report evaluates on the same scenes).
``learning_curve.png`` draws the mean and p90 gap and the success rate against steps and
against wall time, the phases shaded.
"""

from __future__ import annotations

import csv
import time
from pathlib import Path
from typing import Any

import numpy as np

FIELDS = (
    "phase",
    "env_steps",
    "wall_seconds",
    "cpu_seconds",
    "mean_gap_deg",
    "p90_gap_deg",
    "worst_gap_deg",
    "success_rate",
    "mean_margin_deg",
    "mean_force",
)
#: Gaps below this are drawn at it (a log axis has no 0): the expert's own level.
GAP_FLOOR_DEG = 0.01
PHASES = {
    "imitation": ("imitation (expert as teacher)", "tab:blue"),
    # the imitation phase of a run whose fit has no expert (imitation.label_weight 0)
    "reward_gradient": ("the reward's gradient (no expert)", "tab:blue"),
    "ppo": ("PPO", "tab:orange"),
    "td3": ("TD3", "tab:green"),
    "sac": ("SAC", "tab:purple"),
}


class Clock:
    """Wall and CPU seconds of training so far, continuing from a resumed run's times.

    The CPU time of this process tells how long the run would take on an idle machine when
    the wall time is stretched by other processes sharing the cores.
    """

    def __init__(self, wall: float = 0.0, cpu: float = 0.0) -> None:
        self.wall = time.perf_counter() - wall
        self.cpu = time.process_time() - cpu

    def __call__(self) -> tuple[float, float]:
        return time.perf_counter() - self.wall, time.process_time() - self.cpu


def last_steps(path: Path, phase: str) -> int:
    """The environment steps of a phase's last evaluation in a curve file (0: none)."""
    if not path.is_file():
        return 0
    with path.open() as file:
        steps = [int(r["env_steps"]) for r in csv.DictReader(file) if r["phase"] == phase]
    return steps[-1] if steps else 0


class LearningCurve:
    """Held-out evaluations over training, appended to a CSV as they happen.

    ``keep_until`` (a resumed run): keep the rows of an existing file up to that many
    environment steps and drop the later ones, which the killed run logged after its
    checkpoint and the resumed run evaluates again. None starts a new file.
    """

    def __init__(self, path: Path, keep_until: int | None = None, expert: bool = True) -> None:
        self.path = path
        self.expert = expert  # who the imitation phase learns from, for the plot
        self.rows: list[dict[str, str]] = []
        if keep_until is not None and path.is_file():
            with path.open() as file:
                self.rows = [r for r in csv.DictReader(file) if int(r["env_steps"]) <= keep_until]
        with path.open("w", newline="") as file:
            writer = csv.DictWriter(file, FIELDS)
            writer.writeheader()
            writer.writerows(self.rows)

    def append(
        self, phase: str, env_steps: int, seconds: tuple[float, float], metrics: dict
    ) -> None:
        """One evaluation: ``seconds`` is (wall, cpu) since the run started."""
        row = {
            "phase": phase,
            "env_steps": env_steps,
            "wall_seconds": round(seconds[0], 2),
            "cpu_seconds": round(seconds[1], 2),
        }
        row |= {key: metrics[key] for key in FIELDS[4:]}
        self.rows.append({key: str(value) for key, value in row.items()})
        with self.path.open("a", newline="") as file:
            csv.DictWriter(file, FIELDS).writerow(row)

    def last(self, field: str, phase: str | None = None) -> float:
        """The latest value of a numeric field (of a phase), 0 if there is none."""
        rows = [row for row in self.rows if phase is None or row["phase"] == phase]
        return float(rows[-1][field]) if rows else 0.0

    def plot(self, path: Path) -> None:
        """Mean and p90 gap and success rate against steps and wall time (:func:`plot_curve`)."""
        if self.rows:
            plot_curve(self.rows, path, self.expert)


def plot_curve(rows: list[dict[str, str]], path: Path, expert: bool = True) -> None:
    """Save :func:`curve_figure` of the learning curve's rows."""
    import matplotlib.pyplot as plt

    figure = curve_figure(rows, expert)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def curve_figure(rows: list[dict[str, str]], expert: bool = True) -> Any:
    """The learning curve's rows as a figure: gaps on a log axis with plain-number ticks
    (0.2, 0.5, 1, 2 deg...), the success rate on its own axis, the phases shaded and named
    (``expert`` False: the imitation phase fitted the reward alone, with no expert)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import EngFormatter, FuncFormatter, LogLocator, NullFormatter

    data = {key: np.array([float(r[key]) for r in rows]) for key in FIELDS[1:]}
    phase_of = {} if expert else {"imitation": "reward_gradient"}
    phases = np.array([phase_of.get(r["phase"], r["phase"]) for r in rows])
    gaps = {
        "mean gap": np.maximum(data["mean_gap_deg"], GAP_FLOOR_DEG),
        "p90 gap": np.maximum(data["p90_gap_deg"], GAP_FLOOR_DEG),
    }
    top = max(g.max() for g in gaps.values())
    bottom = min(g.min() for g in gaps.values())
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), sharey=True)
    for ax, x, label in (
        (axes[0], data["env_steps"], "environment steps"),
        (axes[1], data["wall_seconds"] / 60, "wall time of training (min)"),
    ):
        for phase, (name, colour) in PHASES.items():
            # a phase spans from the evaluation before its first one to its last
            inside = np.flatnonzero(phases == phase)
            if inside.size:
                ax.axvspan(x[max(inside[0] - 1, 0)], x[inside[-1]], color=colour, alpha=0.08)
                middle = (x[max(inside[0] - 1, 0)] + x[inside[-1]]) / 2
                ax.text(middle, 1.01, name, transform=ax.get_xaxis_transform(), ha="center",
                        va="bottom", fontsize=8, color=colour)  # fmt: skip
        lines = [
            ax.plot(x, gaps["mean gap"], "o-", color="tab:purple", label="mean gap")[0],
            ax.plot(x, gaps["p90 gap"], "s--", color="tab:red", label="p90 gap")[0],
        ]
        ax.set_yscale("log")
        ax.set_ylim(bottom / 1.5, top * 1.5)
        # labelled ticks at 1, 2 and 5 of every decade, so a span under a decade has labels too
        ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(label)
        ax.grid(True, which="major", alpha=0.3)
        twin = ax.twinx()
        success = 100 * data["success_rate"]
        lines += twin.plot(x, success, "^:", color="tab:green", label="success (right axis)")
        twin.set_ylim(0, 105)
        if ax is axes[1]:
            twin.set_ylabel("held-out success (%)", color="tab:green")
        else:
            twin.set_yticklabels([])
    axes[0].xaxis.set_major_formatter(EngFormatter())  # 100k, not 100000 (labels overlap)
    axes[0].set_ylabel("optimality gap (deg, log scale)")
    fig.suptitle("Held-out scenes over training", y=0.99)
    fig.legend(handles=lines, loc="lower center", ncol=3, frameon=False)
    if min(data["mean_gap_deg"].min(), data["p90_gap_deg"].min()) < GAP_FLOOR_DEG:
        note = f"gaps below {GAP_FLOOR_DEG} deg are drawn at {GAP_FLOOR_DEG}"
        fig.text(0.99, 0.01, note, ha="right", va="bottom", fontsize=7, color="0.4")
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    return fig


if __name__ == "__main__":  # redraw a run's curve: python -m grasp_env_agents.run.curve RUN
    import sys

    from .config import load_config
    from .folder import RunFolder

    run = RunFolder(Path(sys.argv[1]))
    expert = load_config(run.config).expert_teaches
    with run.curve.open() as file:
        plot_curve(list(csv.DictReader(file)), run.curve_plot, expert)
