"""The trained agent against the minimax expert and the baselines on the same held-out scenes: the
metrics per policy, the report and the grip plot (grasp-env evaluate, the end of
grasp-env train)."""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.evaluation import evaluate_policy

from grasp_env import MinimaxExpert
from grasp_env.envs.validation import MAX_ENVS
from grasp_env.mechanics import contact_pairs

from ..learning.baselines import ConstantPolicy, RandomPolicy, equal_k_policy
from ..learning.envs import (
    HELD_OUT_SEED,
    Episode,
    action_scale,
    find_held_out,
    make_held_out_env,
    summarise,
)
from ..learning.models import load_agent, misfit
from ..progress import status
from ..run.config import load_config
from ..run.folder import EvaluationFolder, RunFolder
from .plotting import plot_series

#: Default number of held-out scenes also checked in MuJoCo physics.
PHYSICS_EPISODES = 4


COLUMNS = (
    ("mean_margin_deg", "mean min-margin (deg)", "{:.2f}"),
    ("mean_gap_deg", "mean gap (deg)", "{:.2f}"),
    ("p90_gap_deg", "p90 gap (deg)", "{:.2f}"),
    ("worst_gap_deg", "worst gap (deg)", "{:.2f}"),
    ("success_rate", "success", "{:.1%}"),
    ("force_ratio", "grip force / expert's", "{:.2f}"),
    ("physics_success_rate", "MuJoCo success", "{:.0%}"),
)


@dataclass(frozen=True)
class Comparison:
    """Metrics per policy (:func:`grasp_env_agents.learning.envs.summarise`), the markdown,
    its path."""

    metrics: dict[str, dict[str, float]]
    markdown: str
    report: Path


def _cell(fmt: str, value: float) -> str:
    text = fmt.format(value)
    # what rounds to zero reads 0, not -0 (the expert against itself differs by ~1e-14 rad)
    return text[1:] if text.startswith("-") and float(text.rstrip("%")) == 0 else text


def check_episodes(episodes: int | None) -> None:
    """ValueError naming --episodes if ``episodes`` is given and outside [1, MAX_ENVS] (one
    environment per held-out scene)."""
    if episodes is not None and not 1 <= episodes <= MAX_ENVS:
        raise ValueError(f"--episodes must be in [1, {MAX_ENVS}], got {episodes}")


def evaluate_run(
    run_dir: Path,
    episodes: int | None = None,
    physics_episodes: int | None = None,
    out: Path | None = None,
) -> Comparison:
    """Compare the run's agent with the expert and the baselines; write the report and plots
    into ``out`` (default: the run directory).

    ``episodes`` defaults to the run's ``eval_episodes``, ``physics_episodes`` (how many of
    them MuJoCo also checks) to :data:`PHYSICS_EPISODES` or all if fewer.
    """
    run_dir = Path(run_dir)
    run = RunFolder(run_dir)
    out = run_dir if out is None else Path(out)
    if not run.is_run():
        raise ValueError(f"{str(run_dir)!r} is not a run directory (no config.yaml)")
    config = load_config(run.config)
    check_episodes(episodes)
    episodes = config.eval_episodes if episodes is None else episodes
    if physics_episodes is None:
        physics_episodes = min(PHYSICS_EPISODES, episodes)
    if not 0 <= physics_episodes <= episodes:
        raise ValueError(f"--physics-episodes must be in [0, {episodes}], got {physics_episodes}")

    if not run.is_finished():
        raise ValueError(f"{str(run_dir)!r} holds no model.zip: not a finished training run")
    with status(f"evaluate: loading the agent and {episodes} held-out scenes"):
        env = make_held_out_env(config.env_id, config.env_kwargs, episodes)
        m = env.action_space.shape[0]
        k_max_ratio = action_scale(env)
        agent = load_agent(run_dir, config.algo)
        problem = misfit(agent.model, env, config.env_id)
        if problem:
            raise ValueError(
                f"{run.model} does not fit its run's environment (config.yaml): {problem}"
            )
        policies: dict[str, Any] = {
            "trained agent": agent,
            "minimax expert": MinimaxExpert(k_max_ratio),
            "equal k (paper eq. 8)": equal_k_policy(m, k_max_ratio),
            "zero interaction": ConstantPolicy(np.zeros(m)),
            "random": RandomPolicy(m, seed=config.seed),
        }
    metrics, played = {}, {}
    for name, policy in policies.items():
        with status(f"evaluate: {name} on {episodes} held-out scenes"):
            evaluate_policy(policy, env, n_eval_episodes=episodes, warn=False)
        played[name] = list(find_held_out(env).episodes)
        metrics[name] = summarise(played[name])
        if physics_episodes:
            with status(f"evaluate: {name} in MuJoCo on {physics_episodes} scenes"):
                metrics[name]["physics_success_rate"] = physics_success(
                    policy, config.env_id, config.env_kwargs, physics_episodes
                )
    expert_force = metrics["minimax expert"]["mean_force"]
    for row in metrics.values():
        row["force_ratio"] = row["mean_force"] / expert_force

    out.mkdir(parents=True, exist_ok=True)
    written = EvaluationFolder(out)
    with status("evaluate: drawing grip_along_alpha.png"):
        plot_grip(played["trained agent"][:3], written.grip_plot)
    with written.comparison.open("w", newline="") as file:
        fields = ["policy", *next(iter(metrics.values()))]
        writer = csv.DictWriter(file, fields)
        writer.writeheader()
        writer.writerows({"policy": name, **row} for name, row in metrics.items())
    markdown = report(run_dir, out, config.env_id, episodes, physics_episodes, metrics)
    written.report.write_text(markdown)
    return Comparison(metrics, markdown, written.report)


def physics_success(policy: Any, env_id: str, env_kwargs: dict[str, Any], episodes: int) -> float:
    """Fraction of the first ``episodes`` held-out scenes held at every pose, as MuJoCo says.

    The single environment with ``physics="mujoco"`` checks each step's contact forces in
    MuJoCo; with the same seeds it plays the same scenes as the vector env.
    """
    kwargs = {**env_kwargs, "physics": "mujoco", "terminate_on_slip": False}
    env = gym.make(env_id, **kwargs)
    held = 0
    try:
        for index in range(episodes):
            obs, _ = env.reset(seed=HELD_OUT_SEED + index)
            holds, done = True, False
            while not done:
                action, _ = policy.predict(obs[None], deterministic=True)
                obs, _, terminated, truncated, info = env.step(action[0])
                holds &= bool(info["physics"]["holds"])
                done = terminated or truncated
            held += holds
    finally:
        env.close()
    return held / episodes


def report(
    run_dir: Path,
    out: Path,
    env_id: str,
    episodes: int,
    physics_episodes: int,
    metrics: dict[str, dict[str, float]],
) -> str:
    """The comparison as a markdown report."""
    columns = [c for c in COLUMNS if c[0] in next(iter(metrics.values()))]
    physics = f"; MuJoCo success on the first {physics_episodes} scenes" if physics_episodes else ""
    lines = [
        f"# {run_dir.name}: learned vs optimised grip forces",
        "",
        f"{episodes} held-out scenes of `{env_id}` (seeds {HELD_OUT_SEED}...), every pose of "
        "every trajectory; the gap is the expert's min-margin minus the policy's, over all "
        f"steps; success: no finger slipped along the whole trajectory{physics}.",
        "",
        "| policy | " + " | ".join(title for _, title, _ in columns) + " |",
        "|---" * (len(columns) + 1) + "|",
    ]
    for name, row in metrics.items():
        cells = [_cell(fmt, row[key]) for key, _, fmt in columns]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    curve = RunFolder(run_dir).curve
    if curve.is_file():
        with curve.open() as file:
            rows = list(csv.DictReader(file))
        if rows:
            last = rows[-1]
            minutes = float(last["wall_seconds"]) / 60
            learning_curve = os.path.relpath(RunFolder(run_dir).curve_plot, out)
            lines += [
                "",
                f"Training: {int(last['env_steps']):,} environment steps in {minutes:.1f} min "
                f"(learning curve: `{learning_curve}`); grip along alpha: "
                "`grip_along_alpha.png`.",
            ]
    return "\n".join(lines) + "\n"


def plot_grip(episodes: list[Episode], path: Path) -> None:
    """Save :func:`grip_figure` of a few played episodes."""
    import matplotlib.pyplot as plt

    figure = grip_figure(episodes)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def grip_figure(episodes: list[Episode]) -> Any:
    """Learned vs optimal k_ij, and the max friction angle, along alpha for a few scenes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(episodes), figsize=(5 * len(episodes), 7), squeeze=False)
    for column, episode in enumerate(episodes):
        alpha = np.array(episode.alpha_deg)
        k, expert_k = np.array(episode.k), np.array(episode.expert_k)
        n_contacts = round((1 + np.sqrt(1 + 8 * k.shape[1])) / 2)  # m = n (n - 1) / 2 pairs
        names = [f"k{i + 1}{j + 1}" for i, j in contact_pairs(n_contacts)]
        top, bottom = axes[0, column], axes[1, column]
        for name, learned in zip(names, k.T, strict=True):
            top.plot(alpha, learned, "--", label=f"learned {name}")
        top.set_prop_cycle(None)  # the optimal k_ij in their learned ones' colours
        plot_series(top, alpha, expert_k.T, [f"optimal {n}" for n in names], "N", ls="-")
        top.set_title(f"held-out scene {column + 1}")
        top.set_ylabel("interaction force k_ij (N)")
        optimal, learned = np.degrees(episode.expert_max_theta), np.degrees(episode.max_theta)
        limit = np.degrees(episode.limit)
        bottom.plot(alpha, optimal, "-", label="optimal")
        bottom.plot(alpha, learned, "--", label="learned")
        bottom.axhline(limit, color="k", lw=0.8, ls=":", label="friction limit atan(mu)")
        # the limit and a zero curve inside the frame, not on its edges
        top_deg = 1.15 * max(limit, optimal.max(), learned.max())
        bottom.set_ylim(-0.04 * top_deg, top_deg)
        bottom.set_xlabel("alpha (deg)")
        bottom.set_ylabel("max friction angle (deg)")
    for row in axes:  # beside the last column, clear of every curve and note
        row[-1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.suptitle("Learned and optimal grip along each held-out trajectory")
    fig.tight_layout()
    return fig
