"""Results across runs: interquartile means with 95% stratified-bootstrap confidence intervals
(rliable, Agarwal et al. 2021) and aggregate learning curves with bands.

A *group* is a set of runs of one recipe that differ only in their seed (two runs of one
seed are the same experiment twice, not two seeds: a group that has them is refused, and so is
one whose runs' configs differ in anything else). For each group:

- the final held-out metrics of every run (``comparison.csv``, which ``grasp-env evaluate``
  writes, on a stated number of scenes), and for each metric the interquartile mean (IQM: the
  mean of the middle 50% of runs) across runs with its 95% confidence interval from rliable's
  stratified bootstrap over runs (one task, so the strata are that task);
- the training cost: the wall and CPU minutes of training (the last row of each run's
  ``learning_curve.csv``), whose ratio says how loaded the machine was;
- the learning curve: at each evaluation point the IQM across the group's runs and its 95%
  interval, drawn against environment steps and against CPU minutes.

A *results spec* (YAML) lists the groups of a table::

    episodes: 2048                       # held-out scenes every run is evaluated on
    groups:
      - label: PPO from scratch, force directions
        config: configs/ppo.yaml         # what produces the runs (printed in the table)
        runs: runs/ppo-seed*             # a glob, or a list of run directories
      - label: the paper's equal-k grip (eq. 8)
        runs: runs/ppo-seed*
        policy: equal k (paper eq. 8)    # another row of the same evaluations: a baseline

``grasp-env results SPEC`` (:func:`run`) evaluates any run not yet evaluated on that many
scenes, writes ``results.md``, ``results.csv`` and ``learning_curves.png`` beside the spec (or
into ``--out``) and, with ``--readme``, rewrites the README's table between the markers
:data:`BEGIN` and :data:`END`, so that the table is regenerated from the runs, never typed.
"""

from __future__ import annotations

import argparse

from ..cli import folder_argument, path_argument
from ..studies.results import (
    _around_table,
    build_groups,
    plot_curves,
    replace_table,
    table,
    write_csv,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", type=path_argument, metavar="SPEC", help="a results spec (YAML)")
    parser.add_argument(
        "--out", type=folder_argument, help="output folder (default: the spec's folder)"
    )
    parser.add_argument("--readme", type=path_argument, help="rewrite the table in this README")


def run(args: argparse.Namespace) -> int:
    if args.readme is not None:
        _around_table(args.readme)  # its markers checked before any evaluation
    episodes, groups = build_groups(args.spec)
    out = args.out or args.spec.parent
    out.mkdir(parents=True, exist_ok=True)
    markdown = table(groups, episodes)
    (out / "results.md").write_text(markdown + "\n")
    write_csv(groups, out / "results.csv")
    plot_curves(groups, out / "learning_curves.png")
    if args.readme is not None:
        replace_table(args.readme, markdown)
    print(markdown)
    print(f"\nwritten: {out / 'results.md'}, {out / 'results.csv'}, {out / 'learning_curves.png'}")
    return 0
