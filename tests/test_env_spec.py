"""The environments' keyword records (grasp_env.envs.spec): one name, unit, default and range
each, used by the environments, the configs and the docs, and read back by the agents."""

from __future__ import annotations

import inspect
import math
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from grasp_env.envs import spec
from grasp_env.envs.cube_grasp.env import CubeGraspEnv, CubeGraspRandomEnv
from grasp_env.envs.cube_grasp.scenes import SceneSampler

DOCS = Path(__file__).resolve().parents[1] / "docs" / "environments.md"
NUMBERS = [p for p in spec.PARAMETERS.values() if p.kind == "number"]


@pytest.mark.fast
@pytest.mark.parametrize("parameter", NUMBERS, ids=lambda p: p.name)
def test_a_number_keyword_takes_its_closed_bounds_and_refuses_beyond_them(parameter):
    width = parameter.high - parameter.low
    for bound, is_open, outside in (
        (parameter.low, parameter.open_low, parameter.low - 1e-3 * width),
        (parameter.high, parameter.open_high, parameter.high + 1e-3 * width),
    ):
        if is_open:
            with pytest.raises(ValueError, match=re.escape(parameter.accepted().split(" ")[0])):
                parameter.check(bound)
        else:
            assert parameter.check(bound) == bound
        with pytest.raises(ValueError, match=f"^{parameter.name} must be"):
            parameter.check(outside)
    for bad in (True, "1", None, math.nan, 1j):
        with pytest.raises(ValueError, match=parameter.name):
            parameter.check(bad)


@pytest.mark.fast
def test_range_and_flag_keywords_refuse_what_they_do_not_accept():
    assert spec.MU_DRAWS.check((0.3, 0.5)) == (0.3, 0.5)
    for bad in ((0.5, 0.3), (0.3,), "0.3", (0.3, 2e3)):
        with pytest.raises(ValueError, match=r"^mu_range must be a"):
            spec.MU_DRAWS.check(bad)
    assert spec.TERMINATE_ON_SLIP.check(np.bool_(False)) is False
    with pytest.raises(ValueError, match="terminate_on_slip must be True or False, got 1"):
        spec.TERMINATE_ON_SLIP.check(1)


@pytest.mark.fast
def test_the_docs_table_states_every_keyword_as_its_record_does():
    rows = [line for line in DOCS.read_text().splitlines() if line.startswith("| `")]
    for parameter in spec.PARAMETERS.values():
        mine = [r for r in rows if r.startswith(f"| `{parameter.name}`")]
        assert mine, f"docs/environments.md has no row for {parameter.name}"
        assert any(parameter.accepted() in r for r in mine), (parameter.accepted(), mine)


@pytest.mark.fast
def test_the_environments_defaults_are_the_records():
    signature = inspect.signature(CubeGraspRandomEnv.__init__).parameters
    sampler = {f: getattr(SceneSampler(), f) for f in SceneSampler.__dataclass_fields__}
    for name, parameter in spec.PARAMETERS.items():
        if name in signature:
            assert signature[name].default == parameter.default, name
        if name in sampler:
            assert sampler[name] == parameter.default, name
    assert inspect.signature(CubeGraspEnv.__init__).parameters["k_max_ratio"].default == 2.0
    assert spec.K_MAX_RATIO.default == 2.0  # the paper's k_max = 2 w


@pytest.mark.fast
def test_the_object_family_defaults_are_the_records_or_its_stated_own():
    from grasp_env.envs.object_grasp.env import ObjectGraspRandomEnv
    from grasp_env.envs.object_grasp.scenes import ObjectSampler

    signature = inspect.signature(ObjectGraspRandomEnv.__init__).parameters
    sampler = ObjectSampler()
    for name, value in spec.OBJECT_DEFAULTS.items():
        assert spec.PARAMETERS[name].check(value) == value, name  # within its record's range
    for name, parameter in spec.PARAMETERS.items():
        default = spec.OBJECT_DEFAULTS.get(name, parameter.default)
        if name in signature:
            assert signature[name].default == default, name
        if hasattr(sampler, name):
            assert getattr(sampler, name) == default, name
    assert set(spec.OBJECT_DEFAULTS) < set(signature)


@pytest.mark.fast
def test_a_renamed_keyword_is_refused_with_its_new_name():
    from grasp_env_agents.run.config import config_path, load_config

    config = load_config(config_path("default"))
    for old, new in spec.RENAMED.items():
        assert new in spec.PARAMETERS
        with pytest.raises(ValueError, match=rf"^env_kwargs\.{old} is now {new}"):
            config.replace(env_kwargs={old: 0.1})
        with pytest.raises(TypeError, match=old):
            gym.make("grasp_env/CubeGraspRandom-v0", **{old: 0.1})


@pytest.mark.fast
def test_the_environments_check_their_keywords_with_the_records():
    for kwargs, message in (
        ({"k_max_ratio": 1e4}, spec.K_MAX_RATIO.accepted().removesuffix(" w")),
        ({"contact_offset": 1.0}, "contact_offset must be a finite number in [0, 1)"),
        ({"mu_range": (2.0, 1.0)}, "mu_range must be a (low, high) pair"),
    ):
        with pytest.raises(ValueError, match=re.escape(message)):
            gym.make("grasp_env/CubeGraspRandom-v0", **kwargs)


@pytest.mark.fast
def test_a_config_refuses_an_env_keyword_out_of_range_when_it_is_loaded():
    from grasp_env_agents.run.config import config_path, load_config

    config = load_config(config_path("default"))
    with pytest.raises(ValueError, match=r"env_kwargs\.k_max_ratio must be a finite number"):
        config.replace(env_kwargs={"k_max_ratio": 5000.0})
    with pytest.raises(ValueError, match=r"env_kwargs\.k_max_ratio \(with physics='mujoco'\)"):
        config.replace(env_kwargs={"k_max_ratio": 50.0, "physics": "mujoco"})
    assert config.replace(env_kwargs={"k_max_ratio": 3.0}).env_kwargs["k_max_ratio"] == 3.0


def test_the_agents_read_the_action_scale_back_from_the_environment():
    """A model's k_max / w is its environment's, whatever the config's dict says or omits."""
    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

    from grasp_env_agents.learning.algorithms import new_model
    from grasp_env_agents.learning.envs import action_scale, make_vec_env
    from grasp_env_agents.run.config import config_path, load_config

    venv = make_vec_env("grasp_env/CubeGraspRandom-v0", {"k_max_ratio": 3.0}, 2, 0)
    assert action_scale(venv) == 3.0
    vector = gym.make_vec(
        "grasp_env/CubeGrasp-v0", 2, vectorization_mode="vector_entry_point", k_max_ratio=0.5
    )
    assert action_scale(vector) == 0.5
    dummy = sb3_make_vec_env("grasp_env/CubeGrasp-v0", 1, env_kwargs={"k_max_ratio": 1.5})
    assert action_scale(dummy) == 1.5
    config = load_config(config_path("default")).replace(total_timesteps=64, n_envs=2)
    assert "k_max_ratio" not in config.env_kwargs
    model = new_model(config, venv)
    assert model.policy.k_max_ratio == 3.0
    for env in (venv, vector, dummy):
        env.close()
