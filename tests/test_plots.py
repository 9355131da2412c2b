"""The figures as a user reads them: labelled ticks, every curve in the legend and visible,
coinciding curves named, limits inside the frame, what is held fixed said."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from grasp_env.mechanics import Scene, Trajectory
from grasp_env_agents.commands.reproduce import run_sweep, theta1_figure
from grasp_env_agents.learning.envs import Episode
from grasp_env_agents.run.curve import curve_figure
from grasp_env_agents.studies.evaluation import grip_figure
from grasp_env_agents.studies.plotting import plot_series


def rows(*evaluations):
    return [
        {
            "phase": phase,
            "env_steps": str(steps),
            "wall_seconds": str(steps / 1000),
            "cpu_seconds": "0",
            "mean_gap_deg": str(mean),
            "p90_gap_deg": str(p90),
            "worst_gap_deg": "1",
            "success_rate": str(success),
            "mean_margin_deg": "5",
            "mean_force": "5",
        }
        for phase, steps, mean, p90, success in evaluations
    ]


def visible_labels(ax) -> list[str]:
    ax.figure.canvas.draw()
    low, high = ax.get_ylim()
    return [t.get_text() for t in ax.get_yticklabels() if low <= t.get_position()[1] <= high]


@pytest.mark.parametrize(
    "evaluations",
    [
        # under a decade, around 0.2 deg: the case that had no labels at all
        [("initial", 0, 0.24, 0.31, 0.99), ("ppo", 1000, 0.19, 0.26, 1.0)],
        [
            ("initial", 0, 40.0, 60.0, 0.0),
            ("imitation", 1000, 0.5, 0.9, 0.9),
            ("imitation", 2000, 0.2, 0.35, 1.0),
            ("ppo", 3000, 0.25, 0.4, 1.0),
        ],
    ],
)
def test_learning_curve_reads(evaluations):
    figure = curve_figure(rows(*evaluations))
    steps_axis = figure.axes[0]
    labels = visible_labels(steps_axis)
    assert len(labels) >= 2 and all(label and "^" not in label for label in labels)
    assert "0.2" in labels
    (legend,) = figure.legends  # one legend, outside the panels, for all three curves
    entries = [t.get_text() for t in legend.get_texts()]
    assert entries == ["mean gap", "p90 gap", "success (right axis)"]
    named = {t.get_text() for t in steps_axis.texts}
    phases = {phase for phase, *_ in evaluations} - {"initial"}
    titles = {"imitation": "imitation (expert as teacher)", "ppo": "PPO"}
    assert named == {titles[phase] for phase in phases}
    plt.close(figure)


def test_learning_curve_names_a_fit_with_no_expert():
    """A run whose imitation phase fits the reward alone (label_weight 0) is not drawn as
    taught by the expert."""
    evaluations = [("initial", 0, 4.0, 6.0, 0.8), ("imitation", 1000, 0.5, 0.9, 0.9)]
    for expert, name in ((True, "imitation (expert as teacher)"),
                         (False, "the reward's gradient (no expert)")):  # fmt: skip
        figure = curve_figure(rows(*evaluations), expert)
        assert {t.get_text() for t in figure.axes[0].texts} == {name}
        plt.close(figure)


def test_grip_plot_names_pairs_as_everywhere_and_keeps_the_limit_inside():
    alpha = np.arange(-15.0, 16.0)
    episode = Episode(
        max_theta=list(np.radians(np.full(31, 20.0))),
        expert_max_theta=list(np.zeros(31)),
        limit=float(np.arctan(0.5)),
        alpha_deg=list(alpha),
        k=[np.array([0.3, 0.4, 0.4])] * 31,
        expert_k=[np.array([1.0 + a / 30, 1.2, 1.2]) for a in alpha],
    )
    figure = grip_figure([episode])
    top, bottom = figure.axes[:2]
    legend = [t.get_text() for t in top.get_legend().get_texts()]
    pairs = ["k12", "k13", "k23"]
    assert legend == [f"learned {p}" for p in pairs] + [f"optimal {p}" for p in pairs]
    assert "optimal k13 = optimal k23 throughout" in top.texts[0].get_text()
    low, high = bottom.get_ylim()
    limit = np.degrees(episode.limit)
    assert low < 0 < limit < high and (high - limit) > 0.05 * (high - low)  # off both edges
    plt.close(figure)


def test_coinciding_curves_are_named():
    figure, ax = plt.subplots()
    x = np.arange(5.0)
    plot_series(ax, x, np.array([0 * x, 0 * x, x, x, 2 * x]), ["a", "b", "c", "d", "e"], "deg")
    (note,) = ax.texts
    assert note.get_text() == "the lines coincide: a, b are 0 deg throughout; c = d throughout"
    plt.close(figure)


def test_theta1_grid_says_what_k23_is_held_at():
    figure = theta1_figure(run_sweep(Scene(), Trajectory()))
    title = figure.get_suptitle()
    assert "k23 = 1.3608 N (held at the optimum; it does not act on finger 1)" in title
    plt.close(figure)
