"""A sweep on Ray Tune: the sweep file's schema and checks, the search space, one trial (a training
run, evaluated), and the report across the trials (``grasp-env sweep``)."""

from __future__ import annotations

import csv
import importlib
import itertools
import os
import signal
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from grasp_env.envs.validation import MAX_ENVS

from ..cli import MAX_SEED
from ..run.curve import last_steps
from ..run.folder import RunFolder

SEARCHES = ("grid", "random", "optuna")


DISTRIBUTIONS = ("grid", "choice", "uniform", "loguniform", "randint")


SWEEP_KEYS = (
    "config",
    "search",
    "num_samples",
    "metric",
    "seeds",
    "cpus_per_trial",
    "episodes",
    "space",
)


#: Final held-out metrics a trial reports to Tune (``metric`` must be one).
REPORTED = ("mean_gap_deg", "p90_gap_deg", "success_rate", "wall_minutes", "cpu_minutes")


#: Searched metrics that are maximised (the others are minimised).
MAXIMISED = ("success_rate",)


#: The Tune experiment's name under OUT (its state, for resuming).
EXPERIMENT = "tune"


#: What a sweep imports (module, what for, the package's extra that installs it).
EXTRAS = (
    ("ray.tune", "Ray Tune runs the trials", "sweep"),
    ("optuna", "search: optuna", "sweep"),
    ("rliable.library", "the report's IQM and bootstrap intervals", "results"),
)


class MissingExtra(ValueError, ImportError):
    """A module the sweep needs is not installed (a ValueError: the CLI's one-line error)."""


def load_sweep(path: Path) -> dict[str, Any]:
    """Read and check a sweep file (every key and distribution), with its defaults filled in."""
    from ..run.config import read_yaml

    sweep = read_yaml(path, "sweep file", SWEEP_KEYS)
    if "config" not in sweep:
        raise ValueError("sweep file needs config: a shipped config's name or a path")
    sweep = {
        "search": "grid",
        "num_samples": 1,
        "metric": "mean_gap_deg",
        "seeds": None,
        "cpus_per_trial": 1,
        "episodes": 2048,
        "space": {},
        **sweep,
    }
    if sweep["search"] not in SEARCHES:
        raise ValueError(f"search must be one of {list(SEARCHES)}, got {sweep['search']!r}")
    if sweep["metric"] not in REPORTED:
        raise ValueError(f"metric must be one of {list(REPORTED)}, got {sweep['metric']!r}")
    if not isinstance(sweep["config"], str) or not sweep["config"].strip():
        raise ValueError(
            f"config must be a shipped config's name or a path, got {sweep['config']!r}"
        )
    for key in ("num_samples", "cpus_per_trial", "episodes"):
        if not _is_integer(sweep[key]) or sweep[key] < 1:
            raise ValueError(f"{key} must be a positive integer, got {sweep[key]!r}")
    if sweep["episodes"] > MAX_ENVS:  # as grasp-env evaluate --episodes: one env a scene
        raise ValueError(
            f"episodes must be in [1, {MAX_ENVS}] (held-out scenes, one environment each, as"
            f" grasp-env evaluate --episodes), got {sweep['episodes']}"
        )
    seeds = sweep["seeds"]
    if seeds is not None and (
        not isinstance(seeds, list)
        or not seeds
        or not all(_is_integer(s) and 0 <= s <= MAX_SEED for s in seeds)
    ):
        raise ValueError(
            f"seeds must be a non-empty list of integers in [0, {MAX_SEED}] (a config's seed),"
            f" got {seeds!r}"
        )
    if not isinstance(sweep["space"], Mapping):
        raise ValueError("space must map dotted config keys to values or distributions")
    for key, value in sweep["space"].items():
        check_key(key)
        check_distribution(key, value)
        if sweep["search"] == "optuna" and _is_grid(value):
            raise ValueError(f"space.{key}: optuna takes choice, not grid")
    check_repeats(sweep)
    if "seed" in sweep["space"] and seeds is not None:
        raise ValueError(
            "space.seed: the seeds are given by the seeds key (every point of the space runs "
            f"with each of {seeds}); drop seed from space, or drop seeds to search it as a key"
        )
    if sweep["search"] == "optuna" and seeds is not None:
        raise ValueError(
            "optuna suggests one config per trial: search the seed as a key "
            "(space: {seed: {choice: [...]}}) or use grid or random search with seeds"
        )
    from ..run.config import config_path

    config = Path(sweep["config"])
    if not config.is_absolute() and (path.parent / config).is_file():
        config = path.parent / config
    # absolute: Tune runs each trial in a directory of its own
    sweep["config"] = str(config_path(config).resolve())
    base_config(sweep)  # the base config must load
    return sweep


def check_repeats(sweep: Mapping[str, Any]) -> None:
    """Refuse a sweep that would run one config with one seed twice: the report would refuse
    the runs' group (the same experiment twice is not two seeds), after all the training."""
    seeds = sweep["seeds"] or []
    twice = sorted({seed for seed in seeds if seeds.count(seed) > 1})
    if twice:
        raise ValueError(f"seeds lists {twice} more than once: the same runs again, not more seeds")
    for key, value in sweep["space"].items():
        values = value["grid"] if _is_grid(value) else []
        if len(values) != len({yaml_key(v) for v in values}):
            raise ValueError(f"space.{key}.grid lists a value twice, got {values!r}")
    sampled = any(isinstance(v, Mapping) and not _is_grid(v) for v in sweep["space"].values())
    if sweep["num_samples"] > 1 and not sampled:
        raise ValueError(
            f"num_samples: {sweep['num_samples']} repeats every point of a space with nothing"
            " to sample (grid and plain values) with the same seeds: the same runs again, not"
            " more seeds; set num_samples: 1 and give more seeds"
        )


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_key(key: Any) -> None:
    """Raise ValueError unless ``key`` is a dotted config key (``ppo.learning_rate``)."""
    if not isinstance(key, str) or not all(part.strip() for part in key.split(".")):
        raise ValueError(
            f"space: the key {key!r} is not a config key; space keys are config keys as text,"
            " dotted for nested ones (ppo.learning_rate, env_kwargs.k_max_ratio)"
        )


def yaml_key(value: Any) -> str:
    """A value as comparable text (a grid's values may be lists or mappings; anything YAML
    cannot write, such as a :class:`~grasp_env_agents.run.config.LongInteger`, by its repr)."""
    import yaml

    class Dumper(yaml.SafeDumper):
        pass

    Dumper.add_representer(None, lambda dumper, item: dumper.represent_str(repr(item)))
    return yaml.dump(value, Dumper=Dumper, sort_keys=True)


def _is_grid(value: Any) -> bool:
    return isinstance(value, Mapping) and set(value) == {"grid"}


def check_distribution(key: str, value: Any) -> None:
    """Raise ValueError unless ``value`` is a plain value or one distribution."""
    if not isinstance(value, Mapping):
        return
    if len(value) != 1 or next(iter(value)) not in DISTRIBUTIONS:
        raise ValueError(
            f"space.{key} must be a plain value or one of {{{', '.join(DISTRIBUTIONS)}}}: "
            f"[...], got {dict(value)!r}"
        )
    (kind, args), *_ = value.items()
    if not isinstance(args, list) or not args:
        raise ValueError(f"space.{key}.{kind} must be a non-empty list, got {args!r}")
    if kind in ("uniform", "loguniform", "randint"):
        if len(args) != 2 or not all(isinstance(a, int | float) for a in args):
            raise ValueError(f"space.{key}.{kind} must be [low, high], got {args!r}")
        low, high = args
        if not low < high or (kind == "loguniform" and low <= 0):
            raise ValueError(f"space.{key}.{kind} needs 0 < low < high, got {args!r}")


def base_config(sweep: Mapping[str, Any]) -> dict[str, Any]:
    """The base config as plain data (checked by loading it)."""
    from ..run.config import config_path, load_config, read_yaml

    path = config_path(sweep["config"])
    load_config(path)
    return read_yaml(path, "config file")


def with_overrides(data: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with dotted keys (``ppo.learning_rate``) set: nested dicts copied, not shared."""
    out = _copy(data)
    for dotted, value in overrides.items():
        *parents, last = dotted.split(".")
        node = out
        for part in parents:
            child = node.get(part)
            node[part] = child = {} if child is None else child
            if not isinstance(child, dict):
                raise ValueError(f"{dotted}: {part} is not a section of the config")
            node = child
        node[last] = value
    return out


def _copy(data: Any) -> Any:
    if isinstance(data, Mapping):
        return {key: _copy(value) for key, value in data.items()}
    if isinstance(data, list):
        return [_copy(value) for value in data]
    return data


def trial_config(sweep: Mapping[str, Any], params: Mapping[str, Any]) -> Any:
    """The TrainConfig of one trial: the base config with the trial's keys, checked."""
    from ..run.config import config_from_dict

    return config_from_dict(with_overrides(base_config(sweep), params))


def check_space(sweep: Mapping[str, Any]) -> None:
    """Every config the space can produce must load, and make its environment, as a single run
    does (a bad key or value fails here, not in a trial an hour later): each grid point with
    every other key at its first value, then every value of each choice and both ends of each
    range in turn. The error names the value of the space that gives the refused config."""
    space = dict(sweep["space"])
    grids = {k: v["grid"] for k, v in space.items() if _is_grid(v)}
    plain = {k: _values(v)[0] for k, v in space.items() if not _is_grid(v)}
    environments: set[str] = set()
    for values in itertools.product(*grids.values()):
        params = {**plain, **dict(zip(grids, values, strict=True))}
        shown = ", ".join(f"space.{k} = {v!r}" for k, v in params.items()) or "the base config"
        _check_trial(sweep, params, shown, environments)
    first = {**plain, **{k: v[0] for k, v in grids.items()}}
    for key in plain:
        for value in _values(space[key])[1:]:
            _check_trial(sweep, {**first, key: value}, f"space.{key} = {value!r}", environments)


def _check_trial(
    sweep: Mapping[str, Any], params: Mapping[str, Any], shown: str, environments: set[str]
) -> None:
    """The trial config of ``params`` loads, and its environment can be made (once for each
    distinct environment: ``environments`` holds those made)."""
    try:
        config = trial_config(sweep, params)
        environment = yaml_key({"env_id": config.env_id, "env_kwargs": config.env_kwargs})
        if environment not in environments:
            from ..learning.envs import make_vec_env

            make_vec_env(config.env_id, config.env_kwargs, 1, config.seed).close()
            environments.add(environment)
    except ValueError as error:
        raise ValueError(f"{shown} gives a config a run refuses: {error}") from None


def _values(value: Any) -> list[Any]:
    """A plain value, a choice's values, or the values at a range's ends (randint's high is
    excluded)."""
    if not isinstance(value, Mapping):
        return [value]
    (kind, args), *_ = value.items()
    return [args[0], args[1] - 1] if kind == "randint" else list(args)


def tune_space(sweep: Mapping[str, Any]) -> dict[str, Any]:
    """The sweep's space in Tune's terms (seeds as one more grid dimension)."""
    from ray import tune

    makers = {
        "grid": tune.grid_search,
        "choice": tune.choice,
        "uniform": lambda a: tune.uniform(*a),
        "loguniform": lambda a: tune.loguniform(*a),
        "randint": lambda a: tune.randint(*a),
    }
    space = {}
    for key, value in sweep["space"].items():
        if isinstance(value, Mapping):
            (kind, args), *_ = value.items()
            space[key] = makers[kind](args)
        else:
            space[key] = value
    if sweep["seeds"] is not None:
        space["seed"] = tune.grid_search(list(sweep["seeds"]))
    return space


def run_trial(params: dict[str, Any], sweep: dict[str, Any], out: str) -> None:
    """One Tune trial: a training run in ``OUT/runs/<trial>``, resumed if it was started."""
    import torch
    from ray import tune

    from ..commands.train import train
    from .evaluation import evaluate_run
    from .results import read_run

    config = trial_config(sweep, params)
    run_dir = Path(out) / "runs" / tune.get_context().get_trial_name()
    torch.set_num_threads(config.torch_threads)
    run = RunFolder(run_dir)
    started = run.is_run()
    trains = not run.is_finished() or not _finished(run_dir, config)
    if trains:
        train(config, run_dir, resume=started, progress_bar=False)
    episodes = sweep["episodes"]
    # a trial Tune runs again after a killed driver keeps its evaluation (report.md is
    # written last)
    if trains or not run.evaluation(episodes).report.is_file():
        evaluate_run(run_dir, episodes, 0, run.evaluation(episodes).path)
    result = read_run(run_dir, episodes)
    metrics = {**result.metrics, "wall_minutes": result.wall_minutes}
    tune.report({**metrics, "cpu_minutes": result.cpu_minutes, "run_dir": str(run_dir)})


def _finished(run_dir: Path, config: Any) -> bool:
    """Whether the run did all its imitation rounds and all its algorithm's steps (the curve's
    steps count the imitation's labelled states first, then the algorithm's)."""
    path = RunFolder(run_dir).curve
    if not (RunFolder(run_dir).is_finished() and path.is_file()):
        return False
    with path.open() as file:
        rows = list(csv.DictReader(file))
    rounds = sum(row["phase"] == "imitation" for row in rows)
    if config.imitation is not None and rounds < config.imitation.rounds:
        return False
    if config.total_timesteps == 0:
        return bool(rows)
    imitation_steps = last_steps(path, "imitation")
    steps = [int(row["env_steps"]) - imitation_steps for row in rows if row["phase"] == config.algo]
    return bool(steps) and steps[-1] >= config.total_timesteps


def tuner(sweep: dict[str, Any], out: Path) -> Any:
    """The Tune experiment: restored from ``out/tune`` if it exists (an interrupted sweep)."""
    from ray import tune

    trainable = tune.with_resources(
        tune.with_parameters(run_trial, sweep=sweep, out=str(out)),
        {"cpu": sweep["cpus_per_trial"]},
    )
    path = out / EXPERIMENT
    if tune.Tuner.can_restore(str(path)):
        return tune.Tuner.restore(str(path), trainable, resume_errored=True)
    mode = "max" if sweep["metric"] in MAXIMISED else "min"
    search_alg = None
    if sweep["search"] == "optuna":
        from ray.tune.search.optuna import OptunaSearch

        search_alg = OptunaSearch(seed=0)
    return tune.Tuner(
        trainable,
        param_space=tune_space(sweep),
        tune_config=tune.TuneConfig(
            metric=sweep["metric"],
            mode=mode,
            search_alg=search_alg,
            num_samples=sweep["num_samples"],
            # the trial's index in the name: its run directory, stable across a restore
            trial_name_creator=lambda trial: f"trial_{trial.trial_id}",
            trial_dirname_creator=lambda trial: f"trial_{trial.trial_id}",
        ),
        run_config=tune.RunConfig(name=EXPERIMENT, storage_path=str(out), verbose=1),
    )


def sweep(path: Path, out: Path, address: str | None = None, num_cpus: int | None = None) -> Any:
    """Run (or resume) the sweep in ``path`` into ``out``; returns the results' groups."""
    spec = load_sweep(path)
    check_space(spec)
    if address is None:
        num_cpus = local_cpus(spec, num_cpus)
    check_extras(spec)

    import ray

    from .results import Group, plot_curves, read_run, table, write_csv

    out = out.resolve()
    check_same_sweep(spec, out)
    if address is None:
        ray.init(num_cpus=num_cpus, include_dashboard=False)
    else:
        ray.init(address=address)
    # SIGTERM as Ctrl-C: Tune stops the trials cleanly (Ray's own handler only ends the driver)
    terminate = signal.signal(signal.SIGTERM, lambda *_: os.kill(os.getpid(), signal.SIGINT))
    try:
        grid = tuner(spec, out).fit()
    finally:
        signal.signal(signal.SIGTERM, terminate)
        ray.shutdown()
    errors = [result.error for result in grid if result.error is not None]
    if errors:
        raise ValueError(f"{len(errors)} trial(s) failed; the first: {errors[0]}")
    unfinished = sum("run_dir" not in (result.metrics or {}) for result in grid)
    if unfinished:  # Tune stops cleanly on Ctrl-C, with the trials under way unreported
        raise KeyboardInterrupt(
            f"{unfinished} of {len(grid)} trials unfinished: run the same command again to"
            " resume the sweep"
        )
    searched = [k for k, v in spec["space"].items() if isinstance(v, Mapping) and k != "seed"]
    groups: dict[str, dict[int, Any]] = {}
    for result in grid:  # one group per point of the search (the seeds and fixed keys pooled)
        params = {k: v for k, v in result.config.items() if k in searched}
        label = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                          for k, v in sorted(params.items())) or "base config"  # fmt: skip
        run = read_run(Path(result.metrics["run_dir"]), spec["episodes"])
        seeds = groups.setdefault(label, {})
        if run.seed in seeds:  # a random search drew a point twice: one experiment, twice
            print(f"{run.run_dir.name} repeats {seeds[run.seed].run_dir.name} ({label}, seed"
                  f" {run.seed}): reported once")  # fmt: skip
            continue
        seeds[run.seed] = run
    ordered = [
        Group(label, list(runs.values()), _shown(spec["config"])) for label, runs in groups.items()
    ]
    markdown = table(ordered, spec["episodes"])
    (out / "results.md").write_text(markdown + "\n")
    write_csv(ordered, out / "results.csv")
    plot_curves(ordered, out / "learning_curves.png")
    print(markdown)
    return ordered


def check_extras(sweep: Mapping[str, Any]) -> None:
    """Raise :class:`MissingExtra` (naming the package's extra to install) unless every module
    the sweep imports, for its trials, its search and its report, imports: a missing one would
    otherwise fail after Ray started, or after all the training."""
    for module, why, extra in EXTRAS:
        if module == "optuna" and sweep["search"] != "optuna":
            continue
        try:
            importlib.import_module(module)
        except ImportError as error:
            raise MissingExtra(
                f"the sweep needs {module.split('.')[0]} ({why}), which does not import"
                f' ({error}): pip install "grasp-env[{extra}]"'
            ) from None


def check_same_sweep(spec: Mapping[str, Any], out: Path) -> None:
    """Record the sweep (its file with the base config's contents) in ``out/sweep.yaml``, or,
    if ``out`` holds one already, refuse another: Tune would restore the old experiment and
    silently ignore the edit."""
    import yaml

    record = {k: v for k, v in spec.items() if k != "cpus_per_trial"}  # resources only
    record["base_config"] = base_config(spec)
    path = out / "sweep.yaml"
    if path.is_file():
        try:
            held = yaml.safe_load(path.read_text()) or {}
        except (yaml.YAMLError, RecursionError) as error:  # not the record this package wrote
            reason = "nested too deep" if isinstance(error, RecursionError) else "not valid YAML"
            raise ValueError(
                f"{path} is {reason}: not the record of a sweep; give a new --out"
            ) from None
        if not isinstance(held, dict):
            raise ValueError(f"{path} is not the record of a sweep (a mapping); give a new --out")
        differ = sorted(k for k in record.keys() | held.keys() if record.get(k) != held.get(k))
        if differ:
            raise ValueError(
                f"{out} holds another sweep (its sweep.yaml differs in {', '.join(differ)}):"
                " run the sweep file it was made with to resume it, or give a new --out"
            )
        return
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(record, sort_keys=True))


def local_cpus(sweep: Mapping[str, Any], num_cpus: int | None) -> int | None:
    """The cores of the local Ray (``num_cpus``, else the machine's), checked against
    ``cpus_per_trial``: Ray would leave a trial that needs more pending forever."""
    cpus = num_cpus or os.cpu_count()
    if cpus is not None and sweep["cpus_per_trial"] > cpus:
        given = "--num-cpus" if num_cpus else "the machine's cores"
        raise ValueError(
            f"cpus_per_trial is {sweep['cpus_per_trial']} but the local Ray has {cpus} CPU(s)"
            f" ({given}): no trial could ever start; set cpus_per_trial to at most {cpus}, or run"
            " on a cluster with --address"
        )
    return cpus


def _shown(config: str) -> str:
    """The config's path as the report shows it: from the working directory if it lies under
    it (``configs/default.yaml``), else its file name (never the machine's absolute path)."""
    relative = os.path.relpath(config)
    return Path(config).name if relative.startswith("..") else relative
