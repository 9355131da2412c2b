"""``grasp-env gait --models`` with sb3-contrib's MaskablePPO: the model file is recognised,
played with the masks it was trained with (read from the file, or a gait_masks.json beside it),
refused without them; SB3's own models play as before; damaged and foreign files are refused."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.gait import GaitMoveMasks
from grasp_env_agents.cli import main
from grasp_env_agents.commands import gait, gait_models
from grasp_env_agents.learning.models import load_agent, load_model

MOVES_ID = "grasp_env/CubeGaitMoves-v0"
#: 19 poses (alpha -90 to 90 deg by 10): seconds, not minutes.
ARGV = ["--alpha-step", "10", "--no-plots"]
MASKS = {"hold": True, "lookahead": True}


def _kwargs() -> dict:
    parser = argparse.ArgumentParser()
    gait.add_arguments(parser)
    return gait_models.env_kwargs(parser.parse_args(ARGV))


def _reference(model, kwargs: dict) -> tuple[int, float | None]:
    """Poses held and the alpha it ended at: the loop of benchmarks/study_gait_rl.py's score,
    written out, on the options' environment."""
    env = GaitMoveMasks(gym.make(MOVES_ID, **kwargs), **MASKS)
    obs, _ = env.reset(seed=0)
    rewards, terminated, truncated, info = [], False, False, {}
    while not (terminated or truncated):
        action = model.predict(obs, deterministic=True, action_masks=env.action_masks())[0]
        obs, reward, terminated, truncated, info = env.step(int(action))
        rewards.append(reward)
    env.close()
    return len(rewards) - int(terminated), (info["alpha_deg"] if terminated else None)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A MaskablePPO of 256 steps (seed 1) with the study's masks, saved with its settings
    (as benchmarks/study_gait_rl.py saves them), and the same weights saved without."""
    from sb3_contrib import MaskablePPO

    folder = tmp_path_factory.mktemp("run")
    env = GaitMoveMasks(gym.make(MOVES_ID, trajectory={"alpha_step_deg": 10.0}), **MASKS)
    model = MaskablePPO(
        "MlpPolicy", env, n_steps=128, batch_size=64, n_epochs=2, seed=1, device="cpu"
    )
    model.learn(256)
    model.save(folder / "bare.zip")  # no settings: the file alone does not say its masks
    model.gait_masks = dict(MASKS)
    model.save(folder / "model.zip")
    return folder


def _row(printed: str, label: str) -> list[str]:
    (line,) = [line for line in printed.splitlines() if label in line]
    return [cell.strip() for cell in line.strip("│ \n").split("│")]


def test_a_maskable_ppo_is_played_with_the_masks_its_file_names(
    trained, tmp_path, capsys, monkeypatch
):
    """The model copied alone to another folder, the command run from a third: its row
    printed, the episode that of the masks it was trained with, each step's masks passed."""
    monkeypatch.setenv("COLUMNS", "240")
    elsewhere = tmp_path / "shared" / "agent.zip"
    elsewhere.parent.mkdir()
    shutil.copy(trained / "model.zip", elsewhere)
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    out = tmp_path / "gait"
    assert main(["gait", *ARGV, "--out", str(out), "--models", str(elsewhere)]) == 0
    printed = capsys.readouterr().out
    label = "shared/agent.zip (with its masks: hold=True, lookahead=True)"
    cells = _row(printed, label)
    kwargs = _kwargs()
    held, ended = _reference(load_model(trained / "model.zip"), kwargs)
    assert cells[1:3] == [str(held), "held to the end" if ended is None else f"{ended:g}"]
    assert (out / "gait.csv").is_file()

    (loaded,) = gait_models.load_models(_args(str(elsewhere)))
    agent = loaded[1]
    assert isinstance(agent, gait_models.MaskedAgent) and agent.masks == MASKS
    calls = []
    predict = agent.model.predict

    def spy(obs, deterministic=True, action_masks=None):
        action, state = predict(obs, deterministic=deterministic, action_masks=action_masks)
        calls.append((np.array(action_masks), int(action)))
        return action, state

    monkeypatch.setattr(agent.model, "predict", spy)
    episode = gait_models.play(agent, kwargs)
    assert (episode.held, episode.ended_deg) == (held, ended)
    assert len(calls) == held + (ended is not None)  # one call a step, the slip's step too
    assert all(masks.dtype == bool and masks[action] for masks, action in calls)
    assert any(not masks.all() for masks, _ in calls)  # the masks did mask something


def _args(*models: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    gait.add_arguments(parser)
    return parser.parse_args([*ARGV, "--models", *models] if models else ARGV)


def test_without_its_masks_the_model_plays_another_gait_or_is_refused(trained):
    """The masks are part of the policy: the same network unmasked plays another episode
    (seed 1's: 5 poses against 7), and the masked agent refuses to act without masks."""
    kwargs = _kwargs()
    bare = load_agent(trained / "model.zip")  # SB3's predict, no masks
    agent = gait_models.MaskedAgent(bare, MASKS)
    masked, unmasked = gait_models.play(agent, kwargs), gait_models.play(bare, kwargs)
    assert (masked.held, masked.ended_deg) == _reference(bare.model, kwargs)
    assert (masked.held, masked.ended_deg, masked.worst) != (
        unmasked.held,
        unmasked.ended_deg,
        unmasked.worst,
    )
    obs = np.zeros(bare.model.observation_space.shape, np.float32)
    with pytest.raises(ValueError, match="acts with the action masks it was trained with"):
        agent.predict(obs)


def test_a_maskable_ppo_without_mask_settings_is_refused_naming_what_is_missing(
    trained, tmp_path, capsys
):
    bare = tmp_path / "bare.zip"
    shutil.copy(trained / "bare.zip", bare)
    out = tmp_path / "gait"
    assert main(["gait", *ARGV, "--out", str(out), "--models", str(bare)]) == 2
    err = capsys.readouterr().err
    assert f"{bare}: a MaskablePPO model" in err and "no 'gait_masks' entry" in err
    assert str(tmp_path / "gait_masks.json") in err and not out.exists()  # before solving
    # the JSON beside it gives them
    (tmp_path / "gait_masks.json").write_text(json.dumps(MASKS))
    (loaded,) = gait_models.load_models(_args(str(bare)))
    assert loaded[1].masks == MASKS
    # beside a file that has them, it must agree
    shutil.copy(trained / "model.zip", tmp_path / "model.zip")
    (tmp_path / "gait_masks.json").write_text('{"hold": true}')
    with pytest.raises(ValueError, match="says GaitMoveMasks\\(hold=True, lookahead=True\\)"):
        gait_models.load_models(_args(str(tmp_path / "model.zip")))
    for text, message in (
        ('{"hold": true, "lookahead": "yes"}', "lookahead must be true or false, got 'yes'"),
        ('{"lookahead": true}', "lookahead masks among the moves that hold: it needs hold"),
        ('{"hold": true, "slip": false}', "has \\['slip'\\], which GaitMoveMasks does not"),
        ("[true, true]", "must be a mapping of GaitMoveMasks's keywords"),
        ('{"hold": tru', "not JSON"),
    ):
        (tmp_path / "gait_masks.json").write_text(text)
        with pytest.raises(ValueError, match=message):
            gait_models.load_models(_args(str(bare)))


def test_sb3_models_play_as_before_beside_a_masks_file(tmp_path):
    """A PPO of the moves: played unmasked (SB3's predict), a gait_masks.json beside it
    ignored (PPO has no masks), its episode that of its own predict loop."""
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", gym.make(MOVES_ID), n_steps=64, batch_size=64, seed=0)
    model.save(tmp_path / "ppo.zip")
    (tmp_path / "gait_masks.json").write_text(json.dumps(MASKS))
    ((label, agent),) = gait_models.load_models(_args(str(tmp_path / "ppo.zip")))
    assert type(agent).__name__ == "TrainedAgent" and label.endswith("/ppo.zip")
    kwargs = _kwargs()
    env = gym.make(MOVES_ID, **kwargs)
    obs, _ = env.reset(seed=0)
    steps, done = 0, False
    while not done:
        obs, _, terminated, truncated, _ = env.step(model.predict(obs, deterministic=True)[0])
        steps, done = steps + 1, terminated or truncated
    assert gait_models.play(agent, kwargs).held == steps - int(terminated)


def test_damaged_foreign_and_mislabelled_files_get_the_clear_errors(
    trained, tmp_path, capsys, monkeypatch
):
    raw = (trained / "model.zip").read_bytes()
    cut = tmp_path / "cut.zip"
    cut.write_bytes(raw[: len(raw) // 2])
    text = tmp_path / "notes.zip"
    text.write_text("not a model\n")
    for path in (cut, text):
        assert main(["gait", *ARGV, "--out", str(tmp_path / "g"), "--models", str(path)]) == 2
        err = capsys.readouterr().err
        assert f"{path}: not a" in err and ("readable zip" in err or "complete SB3" in err)
    with pytest.raises(ValueError, match=r"a MaskablePPO model .*, not PPO"):
        load_model(trained / "model.zip", "ppo")
    assert type(load_model(trained / "model.zip", "maskable_ppo")).__name__ == "MaskablePPO"
    # sb3-contrib not installed: the error names the extra, not a damaged file
    for name in [name for name in sys.modules if name.split(".")[0] == "sb3_contrib"]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "sb3_contrib", None)
    extra = r'needs sb3-contrib .* pip install "grasp-env\[agents\]"'
    with pytest.raises(ValueError, match=extra):
        load_model(trained / "model.zip")


def test_the_gait_rl_studys_models_play_as_the_study_scores_them(tmp_path):
    """benchmarks/study_gait_rl.py saves its masks' settings in each model: --models finds
    them in the file and plays the study's own episode (181 poses, with the masks)."""
    from grasp_env_agents.benchmarks.study_gait_rl import train

    held, worst, _ = train(0, 2048, tmp_path / "seed0")
    parser = argparse.ArgumentParser()
    gait.add_arguments(parser)
    args = parser.parse_args(["--models", str(tmp_path / "seed0" / "model.zip")])
    ((label, agent),) = gait_models.load_models(args)
    assert label == "seed0/model.zip" and agent.masks == MASKS
    episode = gait_models.play(agent, gait_models.env_kwargs(args))
    assert episode.held == held and abs(np.rad2deg(episode.worst) - worst) < 1e-9
