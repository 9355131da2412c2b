"""``grasp-env evaluate RUN``: the trained agent against the minimax expert and baselines.

Every policy plays the same seeded held-out scenes (run to the end of each trajectory, slips
counted but not ending the episode): the trained agent, the minimax expert
(:class:`grasp_env.MinimaxExpert`), the paper's equal-k grip, no interaction force, and random
actions. Per policy: the mean min-margin min_i (theta_lim - theta_i); the mean, 90th-percentile
and worst optimality gap over all steps; the success rate (no finger slipped along the whole
trajectory); the total grip force sum_i |P_i| against the expert's; and the success rate that
MuJoCo confirms (:class:`grasp_env.physics.StabilityChecker`) on the first few scenes.

Writes ``report.md``, ``comparison.csv`` and ``grip_along_alpha.png`` (learned and optimal
k_ij and max friction angle along alpha on held-out scenes). ``grasp-env train`` writes them
into the run directory, as the run's report; ``grasp-env evaluate RUN`` into
``RUN/evaluation-<N>-scenes/`` (N held-out scenes), or ``--out DIR``, so that it never replaces
the run's own report unless asked to (``--out RUN``). The same run, scenes and options give
the same report, so writing it again to the same folder replaces it with the same numbers
(unless the run has trained further since).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..cli import folder_argument, integer_argument, path_argument
from ..run.config import load_config
from ..run.folder import RunFolder
from ..studies.evaluation import (
    PHYSICS_EPISODES,
    check_episodes,
    evaluate_run,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # dest "run" would shadow the CLI's args.run (the command's entry point)
    parser.add_argument(
        "run_dirs",
        type=path_argument,
        nargs="+",
        metavar="RUN",
        help="run directories written by grasp-env train; with several, also the report across"
        " them (IQM and 95%% bootstrap intervals over seeds, runs grouped by config; two runs"
        " of one config and seed are refused)",
    )
    parser.add_argument(
        "--episodes",
        type=integer_argument(1),
        help="held-out scenes (default: the run's eval_episodes)",
    )
    parser.add_argument(
        "--physics-episodes",
        type=integer_argument(0),
        help=f"of those, scenes also checked in MuJoCo (default {PHYSICS_EPISODES}; 0: none)",
    )
    parser.add_argument(
        "--out",
        type=folder_argument,
        metavar="DIR",
        help="folder for the report, comparison.csv and the plot (default:"
        " RUN/evaluation-<N>-scenes; --out RUN replaces the run's own report); with several"
        " runs, the folder of the report across them (default: none, printed only)",
    )


def run(args: argparse.Namespace) -> int:
    runs = [Path(run_dir) for run_dir in args.run_dirs]
    seen: dict[Path, Path] = {}  # by the directory it is
    for run_dir in runs:
        first = seen.setdefault(run_dir.resolve(), run_dir)
        if first is not run_dir:  # the same directory again, maybe by another path
            same = "twice" if first == run_dir else f"twice (as {first} and {run_dir})"
            raise ValueError(f"RUN {first} is given {same}: give each run once")
        if not RunFolder(run_dir).is_run():  # before evaluating any
            raise ValueError(
                f"RUN {run_dir} is not a grasp-env train run directory (it has no config.yaml)"
            )
    check_episodes(args.episodes)
    if len(runs) > 1:  # before evaluating any: runs of one config and seed are not two seeds
        from ..studies.results import group_dirs

        group_dirs(runs)
    for run_dir in runs:
        out = args.out if len(runs) == 1 else None
        if out is None:
            episodes = args.episodes or load_config(RunFolder(run_dir).config).eval_episodes
            out = RunFolder(run_dir).evaluation(episodes).path
        comparison = evaluate_run(run_dir, args.episodes, args.physics_episodes, out)
        print(comparison.markdown)
        print(f"\nreport: {comparison.report}\n")
    if len(runs) > 1:
        from ..studies.results import group_runs, plot_curves, table, write_csv

        episodes = args.episodes or load_config(RunFolder(runs[0]).config).eval_episodes
        groups = group_runs(runs, episodes)
        markdown = table(groups, episodes)
        print(markdown)
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / "results.md").write_text(markdown + "\n")
            write_csv(groups, args.out / "results.csv")
            plot_curves(groups, args.out / "learning_curves.png")
            print(f"\nacross the runs: {args.out / 'results.md'}, learning_curves.png")
    return 0
