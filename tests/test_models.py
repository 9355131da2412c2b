"""Model files: shared ones run no code when loaded, damaged ones are named, and every model the
package has written (under its current and its earlier import name) loads and predicts the same.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import pickle
import sys
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

import grasp_env_agents
import grasp_env_agents.learning.features
import grasp_env_agents.learning.policy
from grasp_env.envs.sb3 import SB3VecEnv
from grasp_env_agents import cli
from grasp_env_agents.commands.train import train
from grasp_env_agents.learning.baselines import TrainedAgent
from grasp_env_agents.learning.models import load_agent, load_model, load_vecnormalize
from grasp_env_agents.run.config import config_from_dict, save_config

ENV = "grasp_env/CubeGrasp-v0"
TINY = {
    "env_id": ENV,
    "env_kwargs": {"terminate_on_slip": False},
    "n_envs": 2,
    "seed": 3,
    "total_timesteps": 64,
    "eval_freq": 0,
    "eval_episodes": 2,
    "checkpoint_freq": 0,
    "policy": {"net_arch": [16, 16]},
    "ppo": {"n_steps": 32, "batch_size": 32, "n_epochs": 1},
}


class Payload:
    """Unpickling this runs a shell command that creates ``marker``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def observations(env_id: str = ENV, steps: int = 3) -> np.ndarray:
    venv = SB3VecEnv(env_id, num_envs=4, terminate_on_slip=False)
    venv.seed(5)
    obs = [venv.reset()]
    rng = np.random.default_rng(0)
    for _ in range(steps):
        obs.append(venv.step(rng.uniform(-1, 1, (4, venv.action_space.shape[0])))[0])
    return np.concatenate(obs)


def save_untrained(path: Path, **kwargs) -> PPO:
    model = PPO("MlpPolicy", SB3VecEnv(ENV, num_envs=2), n_steps=16, device="cpu", **kwargs)
    model.save(path)
    return model


def rewrite(path: Path, member: str, content: bytes) -> None:
    """Replace one member of a zip file."""
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members[member] = content
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)


def with_entry(path: Path, key: str, value: object) -> None:
    """Put a pickled object into one serialized entry of a model's ``data``."""
    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data"))
    serialized = base64.b64encode(pickle.dumps(value)).decode()
    data[key] = {":type:": "<class 'object'>", ":serialized:": serialized}
    rewrite(path, "data", json.dumps(data).encode())


# --- nothing runs --------------------------------------------------------------------------


@pytest.mark.parametrize("entry", ["policy_class", "observation_space", "policy_kwargs"])
def test_a_pickle_payload_in_a_model_runs_nothing(tmp_path, entry):
    path, marker = tmp_path / "model.zip", tmp_path / "ran"
    save_untrained(path)
    with_entry(path, entry, Payload(marker))
    # the file is live: SB3's own loader runs the command (and what it does next does not matter)
    with warnings.catch_warnings(), contextlib.suppress(Exception):
        warnings.simplefilter("ignore")
        PPO.load(path, device="cpu")
    assert marker.exists()
    marker.unlink()

    with pytest.raises(
        ValueError, match=rf"model.zip: entry '{entry}' names posix.system.*refused"
    ):
        load_model(path)
    assert not marker.exists()


def test_a_payload_in_a_schedule_is_not_decoded(tmp_path):
    """Schedules may legitimately be code (SB3 takes functions): they are skipped, not run."""
    path, marker = tmp_path / "model.zip", tmp_path / "ran"
    saved = save_untrained(path)
    with_entry(path, "lr_schedule", Payload(marker))
    with pytest.warns(UserWarning, match=r"\['lr_schedule'\] are code in the file and were not"):
        model = load_model(path)
    assert not marker.exists()
    obs = observations()
    expected = saved.predict(obs, deterministic=True)[0]
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], expected)
    # an agent loaded to play (evaluate, gait --models) does not need its schedules: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        agent = load_agent(path)
    np.testing.assert_array_equal(agent.predict(obs, deterministic=True)[0], expected)
    assert not marker.exists()


def test_a_payload_in_vecnormalize_or_in_the_tensors_runs_nothing(tmp_path):
    marker = tmp_path / "ran"
    statistics = tmp_path / "vecnormalize.pkl"
    statistics.write_bytes(pickle.dumps(Payload(marker)))
    with pytest.raises(ValueError, match=r"vecnormalize.pkl: the pickle names posix.system"):
        load_vecnormalize(statistics)

    path = tmp_path / "model.zip"
    save_untrained(path)
    buffer = io.BytesIO()
    torch.save({"weights": Payload(marker)}, buffer)
    rewrite(path, "policy.pth", buffer.getvalue())
    with pytest.raises(ValueError, match=r"model.zip: policy.pth is damaged or not a model file"):
        load_model(path)
    assert not marker.exists()


def test_evaluate_refuses_a_malicious_model_clearly(tmp_path, capsys):
    run, marker = tmp_path / "run", tmp_path / "ran"
    run.mkdir()
    save_config(config_from_dict(TINY), run / "config.yaml")
    save_untrained(run / "model.zip")
    with_entry(run / "model.zip", "policy_class", Payload(marker))
    assert cli.main(["evaluate", str(run), "--episodes", "1", "--physics-episodes", "0"]) == 2
    err = capsys.readouterr().err
    assert "grasp-env evaluate: error:" in err and "entry 'policy_class' names posix.system" in err
    assert not marker.exists()


# --- damaged files -------------------------------------------------------------------------


def truncated(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def garbage(path: Path) -> None:
    path.write_bytes(np.random.default_rng(0).bytes(5000))


def no_weights(path: Path) -> None:
    with zipfile.ZipFile(path) as archive:
        data = archive.read("data")
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", data)


def damaged_weights(path: Path) -> None:
    rewrite(path, "policy.pth", b"PK\x03\x04 not really tensors")


def other_network(path: Path) -> None:
    other = path.with_name("other.zip")
    save_untrained(other, policy_kwargs={"net_arch": [8]})
    with zipfile.ZipFile(other) as archive:
        rewrite(path, "policy.pth", archive.read("policy.pth"))


def bad_json(path: Path) -> None:
    rewrite(path, "data", b"{not json")


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (truncated, "not a complete SB3 model file \\(truncated"),
        (garbage, "not a readable zip archive"),
        (no_weights, r"not a complete SB3 model file.*it has no \['policy.pth'\] member"),
        (damaged_weights, "policy.pth is damaged or not a model file"),
        (other_network, "cannot rebuild the model it describes"),
        (bad_json, "its 'data' member is damaged"),
    ],
)
def test_a_damaged_model_file_is_named(tmp_path, damage, message):
    path = tmp_path / "model.zip"
    save_untrained(path)
    damage(path)
    with pytest.raises(ValueError, match=rf"{path}: {message}"):
        load_model(path)


def test_damaged_statistics_are_named(tmp_path):
    path = tmp_path / "vecnormalize.pkl"
    VecNormalize(SB3VecEnv(ENV, num_envs=2)).save(str(path))
    truncated(path)
    with pytest.raises(ValueError, match=rf"{path}: the file is damaged or not a model file"):
        load_vecnormalize(path)
    path.write_bytes(pickle.dumps({"obs_rms": 1}))
    with pytest.raises(ValueError, match="not VecNormalize statistics"):
        load_vecnormalize(path)


# --- what the package wrote keeps loading --------------------------------------------------


@pytest.mark.parametrize(
    "changes",
    [
        {"normalize": True},
        {"normalize": False, "ppo": {"n_steps": 32, "batch_size": 32, "lr_schedule": "linear"}},
        {
            "env_id": "grasp_env/CubeGraspRandom-v0",
            "total_timesteps": 0,
            "policy": {"net_arch": [16], "features": "grasp", "output": "force_directions"},
            "imitation": {"samples_per_round": 64, "epochs": 1, "n_envs": 4},
        },
    ],
    ids=["k-vecnormalize", "k-linear-schedule", "force-directions"],
)
def test_a_run_the_package_wrote_loads_and_predicts_the_same(tmp_path, changes):
    config = config_from_dict({**TINY, **changes})
    model = train(config, tmp_path / "run", progress_bar=False)
    agent = load_agent(tmp_path / "run")
    assert type(agent.model.policy) is type(model.policy)
    assert (agent.normalizer is not None) == config.normalize
    obs = observations(config.env_id)
    trained = TrainedAgent(model, model.get_vec_normalize_env())
    expected = trained.predict(obs, deterministic=True)[0]
    np.testing.assert_array_equal(agent.predict(obs, deterministic=True)[0], expected)
    if config.normalize:  # without its statistics, the run's model would see raw observations
        (tmp_path / "run" / "vecnormalize.pkl").rename(tmp_path / "elsewhere.pkl")
        with pytest.raises(ValueError, match="says normalize: true, but the observation stat"):
            load_agent(tmp_path / "run")


def test_models_pickled_under_the_earlier_import_name_load(tmp_path, monkeypatch):
    """Until the rename the package was importable as ``agents``: its files name
    agents.policy.ForceDirectionPolicy and agents.features.GraspFeatures, and the linear
    learning-rate schedule was a lambda, pickled by value."""
    for old, module in (
        ("agents", grasp_env_agents),
        ("agents.policy", grasp_env_agents.learning.policy),
        ("agents.features", grasp_env_agents.learning.features),
    ):
        monkeypatch.setitem(sys.modules, old, module)
    monkeypatch.setattr(
        grasp_env_agents.learning.policy.ForceDirectionPolicy, "__module__", "agents.policy"
    )
    monkeypatch.setattr(
        grasp_env_agents.learning.features.GraspFeatures, "__module__", "agents.features"
    )
    env = SB3VecEnv("grasp_env/CubeGraspRandom-v0", num_envs=2)
    rate = 1e-3
    saved = PPO(
        grasp_env_agents.learning.policy.ForceDirectionPolicy,
        env,
        learning_rate=lambda progress: progress * rate,
        n_steps=16,
        policy_kwargs={
            "net_arch": [16],
            "features_extractor_class": grasp_env_agents.learning.features.GraspFeatures,
            "k_max_ratio": 2.0,
        },
        device="cpu",
    )
    saved.save(tmp_path / "model.zip")
    monkeypatch.undo()
    assert "agents" not in sys.modules and "agents.policy" not in sys.modules
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        data = json.loads(archive.read("data"))
    policy_pickle = base64.b64decode(data["policy_class"][":serialized:"])
    assert b"agents.policy" in policy_pickle and b"grasp_env_agents" not in policy_pickle

    with pytest.warns(UserWarning, match="are code in the file and were not loaded"):
        model = load_model(tmp_path / "model.zip")
    assert type(model.policy) is grasp_env_agents.learning.policy.ForceDirectionPolicy
    obs = observations("grasp_env/CubeGraspRandom-v0")
    expected = saved.predict(obs, deterministic=True)[0]
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], expected)


@pytest.mark.parametrize("loader", ["safe", "sb3"])
def test_models_saved_under_the_flat_module_paths_load(tmp_path, monkeypatch, loader):
    """Before the package was split by role its modules were flat: a model saved then names
    grasp_env_agents.policy.ForceDirectionPolicy and grasp_env_agents.features.GraspFeatures.
    Both the safe loader and SB3's own (through the alias modules) still load it."""
    import grasp_env_agents.features
    import grasp_env_agents.policy

    policy = grasp_env_agents.learning.policy.ForceDirectionPolicy
    features = grasp_env_agents.learning.features.GraspFeatures
    assert grasp_env_agents.policy.ForceDirectionPolicy is policy
    assert grasp_env_agents.features.GraspFeatures is features
    monkeypatch.setattr(policy, "__module__", "grasp_env_agents.policy")
    monkeypatch.setattr(features, "__module__", "grasp_env_agents.features")
    env = SB3VecEnv("grasp_env/CubeGraspRandom-v0", num_envs=2)
    saved = PPO(
        policy,
        env,
        n_steps=16,
        policy_kwargs={"net_arch": [16], "features_extractor_class": features, "k_max_ratio": 2.0},
        device="cpu",
    )
    saved.save(tmp_path / "model.zip")
    monkeypatch.undo()
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        data = json.loads(archive.read("data"))
    policy_pickle = base64.b64decode(data["policy_class"][":serialized:"])
    assert b"grasp_env_agents.policy" in policy_pickle
    assert b"grasp_env_agents.learning" not in policy_pickle

    model = (
        load_model(tmp_path / "model.zip")
        if loader == "safe"
        else PPO.load(tmp_path / "model.zip", device="cpu")
    )
    assert type(model.policy) is policy
    obs = observations("grasp_env/CubeGraspRandom-v0")
    expected = saved.predict(obs, deterministic=True)[0]
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], expected)
