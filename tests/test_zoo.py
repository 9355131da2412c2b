"""The ecosystem: rl-zoo3 trains on our environment with configs/rl_zoo3/ppo.yml."""

from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from grasp_env_agents.run.config import ZOO_HYPERPARAMS


def test_zoo_config_covers_every_environment():
    import grasp_env

    hyperparams = yaml.safe_load(ZOO_HYPERPARAMS.read_text())
    batched = [env_id for env_id in grasp_env.ENV_IDS if "Mujoco" not in env_id]
    assert sorted(hyperparams) == sorted(batched)


@pytest.mark.slow
def test_rl_zoo3_trains_on_cube_grasp(tmp_path):
    steps = 1024
    command = [
        sys.executable, "-m", "rl_zoo3.train",
        "--algo", "ppo",
        "--env", "grasp_env/CubeGrasp-v0",
        "--gym-packages", "grasp_env",
        "-conf", str(ZOO_HYPERPARAMS),
        "-n", str(steps),
        "--hyperparams", "n_envs:2",
        "--eval-freq", "-1",
        "--seed", "0",
        "-f", str(tmp_path / "logs"),
    ]  # fmt: skip
    result = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]

    from stable_baselines3 import PPO

    (saved,) = (tmp_path / "logs" / "ppo").glob("*/grasp_env-CubeGrasp-v0.zip")
    model = PPO.load(saved, device="cpu")
    assert model.num_timesteps >= steps
    assert model.gamma == 0.0  # the zoo read our hyperparameters, not its defaults
