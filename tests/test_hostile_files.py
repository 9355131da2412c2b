"""Hostile and malformed files are refused in one line, quickly and in bounded memory: a zip
bomb from its directory before anything is inflated, JSON, YAML and pickles nested past
MAX_NESTING levels before Python's recursion fails, NaN weights by name, sweep files before Ray
starts, and options by their names and ranges.

Every hostile input here is small to build: the zip bombs deflate zeros written 1 MiB at a
time, so the test itself never holds more than a chunk.
"""

from __future__ import annotations

import argparse
import base64
import dataclasses
import io
import json
import sys
import zipfile
from collections import deque
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from stable_baselines3 import PPO

from grasp_env.envs.sb3 import SB3VecEnv
from grasp_env_agents import cli, safe_files
from grasp_env_agents.commands import gait
from grasp_env_agents.learning import checkpoints, models
from grasp_env_agents.learning.models import load_model, load_replay_buffer, load_vecnormalize
from grasp_env_agents.run.config import load_config, read_yaml
from grasp_env_agents.safe_files import MAX_NESTING, MODEL_ZIP, MiB
from grasp_env_agents.studies import sweep

ENV = "grasp_env/CubeGrasp-v0"
#: Deeper than Python's recursion limit (1,000): before the bounds, a RecursionError.
DEEP = 5_000
TINY = {
    "env_id": "grasp_env/CubeGraspRandom-v0",
    "env_kwargs": {"terminate_on_slip": False},
    "n_envs": 4,
    "seed": 0,
    "total_timesteps": 256,
    "eval_freq": 128,
    "eval_episodes": 8,
    "checkpoint_freq": 128,
    "torch_threads": 1,
    "policy": {"net_arch": [16], "features": "grasp"},
    "ppo": {"n_steps": 32, "batch_size": 64, "n_epochs": 1},
}


@pytest.fixture(scope="module")
def model_members(tmp_path_factory) -> dict[str, bytes]:
    """The members of an untrained PPO model file (SB3's save)."""
    path = tmp_path_factory.mktemp("model") / "model.zip"
    PPO("MlpPolicy", SB3VecEnv(ENV, num_envs=2), n_steps=16, device="cpu").save(path)
    with zipfile.ZipFile(path) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


def write_model(path: Path, members: dict[str, bytes], **changed: bytes) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in {**members, **changed}.items():
            archive.writestr(name, content)
    return path


def write_zeros(archive: zipfile.ZipFile, name: str, size: int, level: int = 1) -> None:
    """A member of ``size`` zero bytes, deflated, written 1 MiB at a time (a zip bomb)."""
    chunk = bytes(MiB)
    archive.compression, archive.compresslevel = zipfile.ZIP_DEFLATED, level
    with archive.open(name, "w", force_zip64=True) as member:
        for start in range(0, size, MiB):
            member.write(chunk[: min(MiB, size - start)])


def nothing_inflated(monkeypatch) -> None:
    """Any read of a zip member from here on fails the test."""

    def inflated(*args, **kwargs):
        raise AssertionError("a member was inflated")

    for name in ("read", "open", "testzip"):
        monkeypatch.setattr(zipfile.ZipFile, name, inflated)
    monkeypatch.setattr(torch, "load", inflated)


def deep_pickle(depth: int = DEEP) -> bytes:
    """A list in a list in a list ... ``depth`` deep (protocol 4: EMPTY_LIST, APPEND)."""
    return b"\x80\x04" + b"]" * depth + b"a" * (depth - 1) + b"."


def with_entry(members: dict[str, bytes], key: str, serialized: bytes) -> dict[str, bytes]:
    data = json.loads(members["data"])
    data[key] = {
        ":type:": "<class 'object'>",
        ":serialized:": base64.b64encode(serialized).decode(),
    }
    return {**members, "data": json.dumps(data).encode()}


# --- zip bombs -------------------------------------------------------------------------------


def test_a_member_inflating_past_its_bound_is_refused_from_the_directory(
    tmp_path, model_members, monkeypatch
):
    """A model.zip holding gigabytes of zeros was read into memory: 6.7 GB and 98 s to a
    MemoryError. Here a member 1 MiB over the bound: refused before anything is inflated."""
    path = tmp_path / "model.zip"
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in model_members.items():
            if name != "policy.pth":
                archive.writestr(name, content)
        write_zeros(archive, "policy.pth", MODEL_ZIP.member + MiB)
    assert path.stat().st_size < 2 * MiB
    nothing_inflated(monkeypatch)
    with pytest.raises(ValueError) as error:
        load_model(path)
    assert str(error.value) == (
        f"{path}: member 'policy.pth' would inflate to 257.0 MiB, more than the 256.0 MiB a"
        " member of a model file may hold; refused from the zip's directory, nothing inflated"
    )


def test_data_has_a_tighter_bound_and_a_bomb_is_refused_by_its_ratio(tmp_path, model_members):
    data = MODEL_ZIP.per_member["data"]
    path = tmp_path / "model.zip"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("policy.pth", model_members["policy.pth"])
        write_zeros(archive, "data", data + 1, level=1)
    with pytest.raises(ValueError, match=r"member 'data' would inflate to 16.0 MiB \(16,777,217"
                       r" bytes\), more than the 16.0 MiB a member of a model"):  # fmt: skip
        load_model(path)
    # 2 MiB of zeros deflate about 1,000 times: under every size bound, over the ratio
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in model_members.items():
            archive.writestr(name, content)
        write_zeros(archive, "extra.bin", 2 * MiB, level=9)
    with pytest.raises(ValueError) as error:
        load_model(path)
    message = str(error.value)
    assert message.startswith(f"{path}: member 'extra.bin' would inflate 1,0")
    assert message.endswith(
        "more than the 100 times a member of a model file compresses (a zip bomb); refused"
        " from the zip's directory, nothing inflated"
    )
    # a small member compresses any amount: a few KB of JSON do no harm
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in model_members.items():
            archive.writestr(name, content)
        write_zeros(archive, "notes.txt", 64 << 10, level=9)
    load_model(path)


def test_the_total_and_the_number_of_members_are_bounded(tmp_path):
    path = tmp_path / "small.zip"
    with zipfile.ZipFile(path, "w") as archive:
        for i in range(3):
            archive.writestr(f"m{i}", bytes(1024))
    tight = dataclasses.replace(MODEL_ZIP, total=2048)
    with zipfile.ZipFile(path) as archive:
        with pytest.raises(ValueError, match=r"small: the zip's members would inflate to 3.0 KiB"
                           r" in all, more than the 2.0 KiB a model file may hold"):  # fmt: skip
            safe_files.check_zip_directory(archive, "small", tight)
        with pytest.raises(ValueError, match="the zip holds 3 members, more than the 2 a model"):
            safe_files.check_zip_directory(archive, "small", dataclasses.replace(tight, members=2))
        safe_files.check_zip_directory(archive, "small", MODEL_ZIP)


def test_a_model_file_larger_than_the_total_is_not_read(tmp_path, monkeypatch):
    path = tmp_path / "model.zip"
    with path.open("wb") as file:  # sparse: no disk used
        file.truncate(MODEL_ZIP.total + 1)
    monkeypatch.setattr(Path, "read_bytes", lambda self: pytest.fail("the file was read"))
    with pytest.raises(ValueError, match=r"model.zip: 1.0 GiB \(1,073,741,825 bytes\), more than"
                       r" the 1.0 GiB a model file may hold; refused unread"):  # fmt: skip
        load_model(path)


def test_reads_stop_at_the_bound_whatever_the_header_declares():
    """The directory's sizes are a promise: a read takes at most the bound plus one byte."""
    asked = []

    class Stream(io.BytesIO):
        def read(self, size=-1):
            asked.append(size)
            return super().read(size)

    class Archive:  # declares 10 bytes, holds a MiB
        def getinfo(self, name):
            info = zipfile.ZipInfo(name)
            info.file_size = 10
            return info

        def open(self, name):
            return Stream(bytes(MiB))

    with pytest.raises(ValueError, match=r"member 'policy.pth' inflates past the 10 bytes its"
                       r" header declares"):  # fmt: skip
        safe_files.read_member(Archive(), "policy.pth", "model.zip", MODEL_ZIP)
    assert asked == [11]


def test_a_bomb_inside_the_torch_zip_is_refused_before_torch_reads_it(
    tmp_path, model_members, monkeypatch
):
    """policy.pth is a zip of its own (torch's format): its directory is checked too."""
    inner = io.BytesIO()
    with zipfile.ZipFile(inner, "w") as archive:
        write_zeros(archive, "archive/data/0", MODEL_ZIP.member + MiB)
    members = {"data": model_members["data"], "policy.pth": inner.getvalue()}
    path = write_model(tmp_path / "model.zip", members)
    monkeypatch.setattr(torch, "load", lambda *a, **k: pytest.fail("torch read the bomb"))
    with pytest.raises(ValueError) as error:
        load_model(path)
    assert str(error.value) == (
        f"{path}: policy.pth: member 'archive/data/0' would inflate to 257.0 MiB, more than the"
        " 256.0 MiB a member of a model file may hold; refused from the zip's directory,"
        " nothing inflated"
    )


def test_an_imitation_rounds_data_that_deflates_like_a_bomb_is_refused(tmp_path):
    path = tmp_path / "imitation_round_0.npz"
    with zipfile.ZipFile(path, "w") as archive:
        write_zeros(archive, "observations.npy", 2 * MiB, level=9)
    with pytest.raises(ValueError, match=r"imitation_round_0.npz: member 'observations.npy' would"
                       r" inflate 1,0\d\d times .* an imitation round's data"):  # fmt: skip
        checkpoints.load_round_data(path)
    checkpoints.save_round_data(tmp_path, 1, np.zeros((3, 2)), np.ones((3, 1)), 7)
    observations, labels, steps = checkpoints.load_round_data(
        checkpoints.imitation_checkpoint(tmp_path, 1).with_suffix(".npz")
    )
    assert observations.shape == (3, 2) and labels.shape == (3, 1) and steps == 7


# --- nesting ---------------------------------------------------------------------------------


def test_json_nested_100000_deep_in_data_is_refused_before_parsing(
    tmp_path, model_members, monkeypatch
):
    """It was a RecursionError traceback from json."""
    deep = b"[" * 100_000 + b"]" * 100_000
    path = write_model(tmp_path / "model.zip", model_members, data=deep)
    monkeypatch.setattr(models.json, "loads", lambda *a: pytest.fail("parsed"))
    with pytest.raises(ValueError) as error:
        load_model(path)
    assert str(error.value) == (
        f"{path}: its 'data' member is nested deeper than {MAX_NESTING} levels (JSON); refused"
    )


def test_json_depth_counts_brackets_outside_strings():
    assert safe_files.json_depth(b'{"a": "[[[[{{", "b": [1, [2, {"c": []}]]}') == 5
    assert safe_files.json_depth(b'"\\"[[[" ') == 0
    assert safe_files.json_depth(b"3") == 0
    limit = b"[" * MAX_NESTING + b"]" * MAX_NESTING
    safe_files.check_json_depth(limit, "x")
    with pytest.raises(ValueError, match=f"x is nested deeper than {MAX_NESTING} levels"):
        safe_files.check_json_depth(b"[" + limit + b"]", "x")


@pytest.mark.parametrize("entry", ["policy_class", "observation_space", "policy_kwargs"])
def test_a_deeply_nested_pickle_in_a_model_is_refused(tmp_path, model_members, entry):
    """policy_class and observation_space gave RecursionError tracebacks (their repr)."""
    path = write_model(tmp_path / "model.zip", with_entry(model_members, entry, deep_pickle()))
    with pytest.raises(ValueError) as error:
        load_model(path)
    assert str(error.value) == (
        f"{path}: entry {entry!r} is nested deeper than {MAX_NESTING} levels (a pickle); refused"
    )


@pytest.mark.parametrize("loader", [load_vecnormalize, load_replay_buffer])
def test_a_deeply_nested_statistics_or_buffer_pickle_is_refused(tmp_path, loader):
    path = tmp_path / "file.pkl"
    path.write_bytes(deep_pickle())
    with pytest.raises(ValueError) as error:
        loader(path)
    assert (
        str(error.value) == f"{path} is nested deeper than {MAX_NESTING} levels (a pickle); refused"
    )


def test_object_depth_sees_depth_behind_shared_containers_and_cycles():
    chain: list = []
    for _ in range(60):
        chain = [chain]
    shallow = [chain]  # reached first at depth 2, then again 60 deeper
    deep = shallow
    for _ in range(60):
        deep = [deep]
    # shallow is walked first (the last child is): reached again deeper, it is walked again
    assert safe_files.object_depth([deep, shallow]) == MAX_NESTING + 1
    assert safe_files.object_depth({"a": (1, {2}), "b": deque([[3]])}) == 3
    cycle: list = []
    cycle.append(cycle)
    assert safe_files.object_depth(cycle) > MAX_NESTING
    shared = [1, 2]
    assert safe_files.object_depth([shared, shared, [shared]]) == 3


@pytest.mark.parametrize(
    "text",
    [
        "env_kwargs: " + "[" * 100_000 + "]" * 100_000 + "\n",
        "env_kwargs:\n"
        + "".join("  " * i + f"k{i}:\n" for i in range(1, 400))
        + "  " * 400
        + "x: 1\n",
    ],
    ids=["flow", "block"],
)
def test_deeply_nested_yaml_in_a_config_or_a_sweep_file_is_refused(tmp_path, text):
    """It was a RecursionError traceback from PyYAML's composer."""
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump(TINY) + text.replace("env_kwargs", "extra"))
    with pytest.raises(ValueError, match=rf"config file '{config}', line \d+: nested deeper than"
                       rf" {MAX_NESTING} levels; refused$"):  # fmt: skip
        load_config(config)
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    study = tmp_path / "sweep.yaml"
    study.write_text("config: tiny.yaml\nspace:\n  " + text.replace("\n", "\n  "))
    with pytest.raises(ValueError, match=f"sweep file '{study}', line \\d+: nested deeper than"):
        sweep.load_sweep(study)


def test_yaml_nesting_is_counted_in_levels_up_to_the_bound(tmp_path):
    """The document's mapping is the first level: "a: [[...]]" nests 1 + the brackets."""
    path = tmp_path / "file.yaml"
    path.write_text("a: " + "[" * (MAX_NESTING - 1) + "]" * (MAX_NESTING - 1) + "\n")
    data = read_yaml(path, "file")["a"]
    for _ in range(MAX_NESTING - 2):
        (data,) = data
    assert data == []
    path.write_text("a: " + "[" * MAX_NESTING + "]" * MAX_NESTING + "\n")
    with pytest.raises(ValueError, match=f"file '{path}', line 1: nested deeper than 100 levels"):
        read_yaml(path, "file")


# --- numbers ---------------------------------------------------------------------------------


def test_nan_or_inf_weights_are_refused_by_name(tmp_path, model_members, capsys):
    """They were refused by a bare torch error when the model first predicted."""
    weights = torch.load(io.BytesIO(model_members["policy.pth"]), weights_only=True)
    name = "mlp_extractor.policy_net.0.weight"
    weights[name][1, 2] = float("nan")
    buffer = io.BytesIO()
    torch.save(weights, buffer)
    path = write_model(tmp_path / "model.zip", model_members, **{"policy.pth": buffer.getvalue()})
    with pytest.raises(ValueError) as error:
        load_model(path)
    assert str(error.value) == (
        f"{path}: model weights contain NaN or inf in {name} (policy.pth); refused"
    )
    weights[name][1, 2] = 0.0
    weights["log_std"][0] = -float("inf")
    buffer = io.BytesIO()
    torch.save(weights, buffer)
    write_model(path, model_members, **{"policy.pth": buffer.getvalue()})
    argv = ["verify", "--policy", str(path), "--env", ENV, "--out", str(tmp_path / "v")]
    assert cli.main(argv) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"grasp-env verify: error: {path}: model weights contain NaN or inf in log_std"
        " (policy.pth); refused"
    ]


def test_a_5000_digit_seed_is_refused_with_the_range(tmp_path, capsys):
    """Python's own message was the error: "Exceeds the limit (4300 digits) for integer
    string conversion"."""
    digits = "1" * 5000
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump({**TINY, "seed": 0}).replace("seed: 0", f"seed: {digits}"))
    with pytest.raises(ValueError) as error:
        load_config(config)
    line = config.read_text().splitlines().index(f"seed: {digits}") + 1
    assert str(error.value) == (
        f"config {str(config)!r}: seed must be in [0, 4294967295], got an integer of 5,000"
        f" digits (line {line})"
    )
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    study = tmp_path / "sweep.yaml"
    study.write_text(f"config: tiny.yaml\nseeds: [0, {digits}]\n")
    with pytest.raises(ValueError, match=r"seeds must be a non-empty list of integers in \[0,"
                       r" 4294967295\] \(a config's seed\), got \[0, an integer of 5,000 digits"
                       r" \(line 2\)\]"):  # fmt: skip
        sweep.load_sweep(study)
    parser = argparse.ArgumentParser(prog="grasp-env x")
    parser.add_argument("--seed", type=cli.seed_argument())
    with pytest.raises(SystemExit):
        parser.parse_args(["--seed", digits])
    assert capsys.readouterr().err.splitlines()[-1] == (
        "grasp-env x: error: argument --seed: must be an integer in [0, 4294967295], got"
        " '11111111111111111111'... (5,000 characters)"
    )
    assert parser.parse_args(["--seed", "4294967295"]).seed == 2**32 - 1
    with pytest.raises(SystemExit):
        parser.parse_args(["--seed", "4294967296"])
    # the command line's seeds: one short line, whatever the argument's length
    with pytest.raises(SystemExit):
        cli.main(["verify", "--agreement", "--seed", digits])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith("argument --seed: must be an integer >= 0, got '11111111111111111111'..."
                        " (5,000 characters)")  # fmt: skip


# --- sweeps ----------------------------------------------------------------------------------


@pytest.fixture
def no_ray(monkeypatch):
    """Ray and Tune fail the test if the sweep gets as far as starting them."""
    import ray

    def started(*args, **kwargs):
        raise AssertionError("Ray started")

    monkeypatch.setattr(ray, "init", started)
    monkeypatch.setattr(sweep, "tuner", started)


def sweep_file(tmp_path: Path, text: str | dict) -> Path:
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    path = tmp_path / "sweep.yaml"
    path.write_text(
        text if isinstance(text, str) else yaml.safe_dump({"config": "tiny.yaml", **text})
    )
    return path


@pytest.mark.parametrize("key", ["1", "null", "true", "2.5", "ppo..learning_rate", '""'])
def test_a_space_key_that_is_not_a_config_key_is_refused(tmp_path, no_ray, key):
    """An integer key gave an AttributeError traceback ('int' object has no attribute 'split')."""
    path = sweep_file(tmp_path, f"config: tiny.yaml\nspace:\n  {key}: {{grid: [1, 2]}}\n")
    shown = repr(yaml.safe_load(f"{key}: 0").popitem()[0])
    with pytest.raises(ValueError) as error:
        sweep.sweep(path, tmp_path / "out", num_cpus=1)
    assert str(error.value) == (
        f"space: the key {shown} is not a config key; space keys are config keys as text,"
        " dotted for nested ones (ppo.learning_rate, env_kwargs.k_max_ratio)"
    )


LONG = "1" + "0" * 5000  # 10^5000, past the 4,300 digits Python converts from text


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        (
            "seeds: [0, 4294967296]",
            r"seeds must be a non-empty list of integers in"
            r" \[0, 4294967295\] \(a config's seed\), got \[0, 4294967296\]",
        ),
        (
            "episodes: 100000000000",
            r"episodes must be in \[1, 1048576\] \(held-out scenes, one"
            r" environment each, as grasp-env evaluate --episodes\), got 100000000000",
        ),
        (
            "space: {env_kwargs.k_max_ratio: {grid: [2.0, 1.0e+9]}}",
            r"space.env_kwargs.k_max_ratio = 1000000000.0 gives a config a run refuses:"
            r" env_kwargs.k_max_ratio must be a finite number in \[0.001, 1000\], got"
            r" 1000000000.0",
        ),
        (
            "search: random\nspace: {env_kwargs.mu_range: {choice: [[0.5, 1], [2, 1]]}}",
            r"space.env_kwargs.mu_range = \[2, 1\] gives a config a run refuses:"
            r" env_kwargs.mu_range must be a \(low, high\) pair",
        ),
        (
            "search: random\nspace: {env_kwargs.k_max_ratio: {uniform: [1.0, 2000.0]}}",
            r"space.env_kwargs.k_max_ratio = 2000.0 gives a config a run refuses: .*k_max_ratio",
        ),
        (
            "space: {env_kwargs.bogus: 1}",
            r"space.env_kwargs.bogus = 1 gives a config a run"
            r" refuses: env_kwargs for .*unexpected keyword argument 'bogus'",
        ),
        (
            f"space: {{ppo.n_epochs: {{grid: [1, {LONG}]}}}}",
            r"space.ppo.n_epochs = an integer of"
            r" 5,001 digits \(line 2\) gives a config a run refuses: ppo.n_epochs must be in"
            r" \[1, 1000\], got an integer of 5,001 digits \(line 2\)",
        ),
    ],
    ids=["seeds", "episodes", "grid", "choice", "range-end", "plain", "long-integer"],
)
def test_every_value_a_sweep_would_run_is_checked_before_ray(tmp_path, no_ray, settings, message):
    """They passed the up-front check and failed only inside the trials, after Ray started."""
    path = sweep_file(tmp_path, f"config: tiny.yaml\n{settings}\n")
    with pytest.raises(ValueError, match=message):
        sweep.sweep(path, tmp_path / "out", num_cpus=1)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("record", "message"),
    [
        ("[" * DEEP + "]" * DEEP, "is nested too deep: not the record of a sweep"),
        ("- 1\n", r"is not the record of a sweep \(a mapping\)"),
        ("a: [\n", "is not valid YAML: not the record of a sweep"),
    ],
    ids=["deep", "list", "invalid"],
)
def test_a_sweep_folder_holding_a_damaged_record_is_refused(tmp_path, record, message):
    spec = sweep.load_sweep(sweep_file(tmp_path, {}))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "sweep.yaml").write_text(record)
    with pytest.raises(ValueError, match=f"out/sweep.yaml {message}; give a new --out"):
        sweep.check_same_sweep(spec, tmp_path / "out")


@pytest.mark.parametrize(
    ("search", "missing", "extra"),
    [
        ("grid", ["ray", "ray.tune"], "sweep"),
        ("optuna", ["optuna"], "sweep"),
        ("grid", ["rliable", "rliable.library"], "results"),
    ],
)
def test_a_missing_extra_is_named_before_ray_starts(
    tmp_path, no_ray, monkeypatch, capsys, search, missing, extra
):
    settings = {"search": search, "space": {"ppo.n_epochs": {"grid": [1, 2]}}}
    if search == "optuna":
        settings = {"search": search, "space": {"ppo.n_epochs": {"choice": [1, 2]}}}
    path = sweep_file(tmp_path, settings)
    for module in missing:
        monkeypatch.setitem(sys.modules, module, None)  # import then raises ImportError
    argv = ["sweep", str(path), "--out", str(tmp_path / "out"), "--num-cpus", "1"]
    assert cli.main(argv) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"grasp-env sweep: error: the sweep needs {missing[0].split('.')[0]} (")
    assert line.endswith(f'pip install "grasp-env[{extra}]"')
    assert not (tmp_path / "out").exists()


# --- grasp-env gait --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--finger-azimuths", "0"],
            "--finger-azimuths must give 2 to 5 azimuths besides the"
            " thumb, comma-separated in degrees (A1,...,An: a gait needs 3 to 6 fingers), got 1: 0",
        ),
        (
            ["--finger-azimuths", "0,90", "--no-thumb"],
            "--finger-azimuths must give 3 to 6"
            " azimuths without the thumb (--no-thumb), comma-separated in degrees (A1,...,An: a"
            " gait needs 3 to 6 fingers), got 2: 0,90",
        ),
        (
            ["--finger-azimuths", "0,nan,90"],
            "--finger-azimuths (finger_azimuths_deg) must be a sequence of at least"
            " one finite real number (degrees), got NaN or inf in [0.0, nan, 90.0]",
        ),
    ],
)
def test_gait_options_are_named_in_their_errors(tmp_path, monkeypatch, capsys, argv, message):
    """--finger-azimuths 0 named an internal array: "reach must be a (T, F, N) boolean array"."""
    monkeypatch.setattr(gait, "solve_gait", lambda *a: pytest.fail("solved"))
    assert cli.main(["gait", *argv, "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == f"grasp-env gait: error: {message}"


def test_gait_models_without_rliable_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    """rliable was found missing only when the table was printed, after all the work."""
    monkeypatch.setitem(sys.modules, "rliable", None)
    monkeypatch.setitem(sys.modules, "rliable.library", None)
    monkeypatch.setattr(gait, "solve_gait", lambda *a: pytest.fail("solved"))
    monkeypatch.setattr(gait, "load_models", lambda *a: pytest.fail("models loaded"))
    models_ = [str(tmp_path / "a.zip"), str(tmp_path / "b.zip")]
    assert cli.main(["gait", "--models", *models_, "--out", str(tmp_path / "g")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("grasp-env gait: error: --models with 2 models reports their IQM with")
    assert line.endswith('pip install "grasp-env[results]"')
