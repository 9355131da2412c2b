"""``grasp-env sweep SWEEP.yaml``: hyperparameter sweeps on Ray Tune, on one machine or a cluster.

A sweep file names a base config, a search and the space to search over, by the config's own
dotted keys::

    config: ppo                      # a shipped config's name, or a path (relative to this file)
    search: grid                     # grid, random or optuna
    num_samples: 1                   # grid: repeats of the grid; random, optuna: trials
    metric: mean_gap_deg             # what random and optuna minimise (held-out, at the end)
    seeds: [0, 1, 2, 3, 4]           # every point of the space with each seed (grid, random)
    cpus_per_trial: 1
    episodes: 2048                   # held-out scenes of every trial's final evaluation
    space:
      ppo.learning_rate: {grid: [1.0e-4, 3.0e-4]}
      policy.log_std_init: {uniform: [-4.0, -2.0]}
      ppo.n_epochs: {choice: [5, 10]}

A value of the space is ``{grid: [...]}``, ``{choice: [...]}``, ``{uniform: [low, high]}``,
``{loguniform: [low, high]}``, ``{randint: [low, high]}`` (high excluded), or a plain value.
A sweep that would train one config with one seed twice (a seed or a grid value listed twice,
``num_samples`` above 1 over a space with nothing to sample) is refused before any trial: the
report refuses such runs as one group's seeds
(:func:`grasp_env_agents.studies.results.check_seeds`); a point a random search happens to
draw twice is reported once. Every value the space can
draw (each grid and choice value, each range's ends) is checked before any trial, as a single
run checks its config (every key and value) and its environment (``env_kwargs``, by making
it); so are the seeds (the config's range, [0, 2^32 - 1]), ``episodes`` (``grasp-env evaluate
--episodes``'s range) and the extras the sweep imports (Ray Tune, Optuna for ``search:
optuna``, rliable for the report), before Ray starts.
Every trial is one training run (:func:`grasp_env_agents.commands.train.train`) with its own run
directory under ``OUT/runs/`` (config, checkpoints, learning curve, model, held-out report);
Ray Tune schedules the trials, ``cpus_per_trial`` cores each, on a local Ray with the
machine's cores, or on an existing cluster with ``--address`` (then OUT must be a path every
node sees). Run the same command again and an interrupted sweep resumes: Tune restores the
experiment from ``OUT/tune`` and every unfinished trial continues its run from its newest
checkpoint. ``OUT/sweep.yaml`` records the sweep (its file and the base config's contents):
another sweep into the same OUT is refused, since Tune would restore the old one. The sweep
ends with the aggregate report of :mod:`grasp_env_agents.studies.results` over the trials,
grouped by everything but the seed (``OUT/results.md``, ``learning_curves.png``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..cli import folder_argument, integer_argument, path_argument
from ..studies.sweep import (
    sweep,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "sweep_file", type=path_argument, metavar="SWEEP", help="a sweep file (YAML)"
    )
    parser.add_argument(
        "--out", type=folder_argument, help="the sweep's folder (default: sweeps/<sweep file name>)"
    )
    parser.add_argument(
        "--address",
        help="an existing Ray cluster, run from one of its nodes: auto, or the head's HOST:6379",
    )
    parser.add_argument(
        "--num-cpus",
        type=integer_argument(1),
        help="cores of the local Ray (default: the machine's)",
    )


def run(args: argparse.Namespace) -> int:
    out = args.out or Path("sweeps") / args.sweep_file.stem
    sweep(args.sweep_file, out, args.address, args.num_cpus)
    print(f"\nsweep: {out.resolve()} (results.md, learning_curves.png, runs/)")
    return 0
