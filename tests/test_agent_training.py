"""A tiny training run end to end: interrupt and resume, checkpoints, evaluations, determinism."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml
from agent_helpers import TINY, curve, tensorboard_events, tensorboard_steps, tiny
from stable_baselines3 import PPO

from grasp_env_agents import cli
from grasp_env_agents.commands.train import RecordEvaluation, train
from grasp_env_agents.learning.checkpoints import checkpoint_steps
from grasp_env_agents.run.config import config_from_dict, load_config, save_config


@pytest.mark.slow
def test_tiny_run_end_to_end(tmp_path, capsys):
    """grasp-env train writes the run, then grasp-env evaluate compares it with the expert."""
    config_path = tmp_path / "tiny.yaml"
    config_path.write_text(yaml.safe_dump(TINY))
    run = tmp_path / "run"
    assert cli.main(["train", "--config", str(config_path), "--run-dir", str(run)]) == 0
    printed = capsys.readouterr().out
    assert "| minimax expert |" in printed and "| trained agent |" in printed

    for name in ("model.zip", "config.yaml", "learning_curve.csv", "learning_curve.png",
                 "eval/evaluations.npz", "report.md", "grip_along_alpha.png"):  # fmt: skip
        assert (run / name).is_file(), name
    assert list((run / "tb").glob("ppo/events.out.tfevents.*"))
    assert load_config(run / "config.yaml") == config_from_dict(TINY)
    assert [int(r["env_steps"]) for r in curve(run)] == [0, 128, 256]

    model = PPO.load(run / "model.zip", device="cpu")
    assert model.num_timesteps == 256
    action, _ = model.predict(np.zeros(model.observation_space.shape, np.float32))
    assert action.shape == (3,)

    report = (run / "report.md").read_text()
    assert cli.main(["evaluate", str(run), "--episodes", "1", "--physics-episodes", "1"]) == 0
    # evaluate writes beside the run's report, which it leaves alone
    assert (run / "report.md").read_text() == report
    assert "`../learning_curve.png`" in (run / "evaluation-1-scenes" / "report.md").read_text()
    with (run / "evaluation-1-scenes" / "comparison.csv").open() as file:
        rows = {row["policy"]: row for row in csv.DictReader(file)}
    expert, zero = rows["minimax expert"], rows["zero interaction"]
    # In the paper's scene the optimum is 0 deg at every pose: the expert is the reference
    # (gap 0) and holds, also in MuJoCo; with no interaction force the side fingers slip.
    # (to the float32 rounding of its action: the gap is against the exact optimum)
    assert float(expert["mean_gap_deg"]) == pytest.approx(0.0, abs=1e-4)
    assert float(expert["success_rate"]) == 1.0
    assert float(expert["physics_success_rate"]) == 1.0
    assert float(zero["success_rate"]) == 0.0
    assert float(zero["physics_success_rate"]) == 0.0
    assert float(zero["mean_gap_deg"]) > 10.0


def test_interrupt_saves_and_resume_continues_the_step_count(tmp_path, monkeypatch):
    config = tiny(normalize=True)
    run = tmp_path / "run"
    record = RecordEvaluation._on_step

    def ctrl_c_after_first_evaluation(self):
        record(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(RecordEvaluation, "_on_step", ctrl_c_after_first_evaluation)
    with pytest.raises(KeyboardInterrupt):
        train(config, run, progress_bar=False)
    (saved,) = (run / "checkpoints").glob("ppo_*_steps.zip")
    assert checkpoint_steps(saved) == 128
    assert (run / "model.zip").is_file()
    assert (saved.parent / "ppo_vecnormalize_128_steps.pkl").is_file()

    monkeypatch.setattr(RecordEvaluation, "_on_step", record)
    model = train(config, run, resume=True, progress_bar=False)
    assert model.num_timesteps == 256
    model = train(config.replace(total_timesteps=384), run, resume=True)
    assert model.num_timesteps == 384
    assert [int(r["env_steps"]) for r in curve(run)] == [0, 128, 256, 384]
    with np.load(run / "eval" / "evaluations.npz") as log:
        assert log["timesteps"].tolist() == [128, 256, 384]
    assert (run / "vecnormalize.pkl").is_file()


#: The held-out metrics of a learning curve's row and of an evaluation's.
HELD_OUT = ("mean_gap_deg", "p90_gap_deg", "worst_gap_deg", "success_rate", "mean_margin_deg")


def final_metrics(run: Path) -> dict[str, float]:
    """The trained agent's metrics in the run's report (model.zip on the curve's scenes)."""
    from grasp_env_agents.studies.evaluation import evaluate_run

    agent = evaluate_run(run, physics_episodes=0).metrics["trained agent"]
    return {key: agent[key] for key in HELD_OUT}


def row_metrics(row: dict[str, str]) -> dict[str, float]:
    return {key: float(row[key]) for key in HELD_OUT}


def test_each_evaluation_is_of_the_weights_its_steps_trained(tmp_path):
    """The audit: the curve's last point was evaluated during the last rollout, before PPO's
    last update, yet labelled with the final steps (3.84 deg where the report said 4.29). Now a
    point labelled N is the model trained on N steps, and the last point the final model."""
    imitation = {"rounds": 2, "samples_per_round": 124, "epochs": 2, "n_envs": 4}
    runs = {}
    for steps in (128, 256):  # rollouts of 2 x 32 steps, evaluations every 128
        runs[steps] = tmp_path / f"ppo-{steps}"
        train(tiny(total_timesteps=steps, imitation=imitation), runs[steps], progress_bar=False)
    rows = curve(runs[256])
    taught = int(rows[2]["env_steps"])
    assert [(r["phase"], int(r["env_steps"]) - taught) for r in rows[3:]] == [
        ("ppo", 128),
        ("ppo", 256),
    ]
    assert row_metrics(rows[-1]) == pytest.approx(final_metrics(runs[256]), rel=1e-9)
    # the point at 128 PPO steps is the model of a run that stopped there
    assert row_metrics(rows[3]) == pytest.approx(final_metrics(runs[128]), rel=1e-9)
    assert row_metrics(rows[3]) != pytest.approx(row_metrics(rows[4]), rel=1e-9)
    # TensorBoard's last held-out point is the final model's too, at the final steps
    events = tensorboard_events(runs[256] / "tb" / "ppo")
    step, gap = events["held_out/mean_gap_deg"][-1]
    assert (step, gap) == (taught + 256, pytest.approx(float(rows[-1]["mean_gap_deg"]), 1e-6))
    for tag, pairs in events.items():  # an evaluation between rollouts writes only its own
        assert len({s for s, _ in pairs}) == len(pairs), tag


def test_an_off_policy_curve_ends_with_the_final_model(tmp_path):
    """TD3 and SAC evaluate in the step that passes eval_freq, before its update (the steps
    before it label the point); the final weights, after the last update, are evaluated too."""
    settings = {key: value for key, value in TINY.items() if key != "ppo"}
    offpolicy = {"learning_starts": 32, "batch_size": 32, "buffer_size": 512}
    run = tmp_path / "sac"
    config = config_from_dict({**settings, "algo": "sac", "offpolicy": offpolicy})
    train(config, run, progress_bar=False)
    rows = curve(run)
    assert [int(r["env_steps"]) for r in rows] == [0, 128 - TINY["n_envs"], 256]
    assert row_metrics(rows[-1]) == pytest.approx(final_metrics(run), rel=1e-9)


def test_an_interrupted_rollout_is_not_counted_in_the_checkpoint(tmp_path, monkeypatch):
    """Ctrl-C in the middle of a PPO rollout saved the weights of the rollout's start under the
    steps counted so far, so a resumed run was labelled with steps it never trained on."""
    from grasp_env_agents.commands.train import TrainedSteps

    step = TrainedSteps._on_step

    def ctrl_c_mid_rollout(self):
        if self.model.num_timesteps == 160:  # rollouts of 64 steps: 128 < 160 < 192
            raise KeyboardInterrupt
        return step(self)

    run = tmp_path / "run"
    monkeypatch.setattr(TrainedSteps, "_on_step", ctrl_c_mid_rollout)
    with pytest.raises(KeyboardInterrupt):
        train(tiny(), run, progress_bar=False)
    saved = sorted(checkpoint_steps(p) for p in (run / "checkpoints").glob("ppo_*_steps.zip"))
    assert saved == [128]
    assert PPO.load(run / "model.zip", device="cpu").num_timesteps == 128
    monkeypatch.setattr(TrainedSteps, "_on_step", step)
    assert train(tiny(), run, resume=True, progress_bar=False).num_timesteps == 256
    assert [int(r["env_steps"]) for r in curve(run)] == [0, 128, 256]


def test_a_damaged_newest_checkpoint_is_skipped(tmp_path, capsys):
    run = tmp_path / "run"
    train(tiny(), run, progress_bar=False)
    newest = run / "checkpoints" / "ppo_256_steps.zip"
    newest.write_bytes(newest.read_bytes()[:1000])  # a copy cut short, a full disk
    capsys.readouterr()
    model = train(tiny(total_timesteps=384), run, resume=True, progress_bar=False)
    out = capsys.readouterr().out
    assert "resume: skipping checkpoints/ppo_256_steps.zip: " in out
    assert "not a readable zip archive" in out
    assert "resume: from " in out and "ppo_128_steps.zip" in out
    assert model.num_timesteps == 384
    # the killed run's evaluation at 256 was dropped and made again: each step once
    assert [int(r["env_steps"]) for r in curve(run)] == [0, 128, 256, 384]
    for tag, steps in tensorboard_steps(run / "tb" / "ppo").items():
        assert len(steps) == len(set(steps)), tag


def test_sigterm_saves_the_run_as_ctrl_c_does(tmp_path):
    """SIGTERM (a scheduler's or a container's stop) saves a checkpoint at the step reached and
    says how to resume, as Ctrl-C does; exit status 130."""
    import signal
    import subprocess
    import sys
    import time

    config = tiny(total_timesteps=1 << 20, eval_freq=0, checkpoint_freq=0)
    path, run = tmp_path / "config.yaml", tmp_path / "run"
    save_config(config, path)
    command = [sys.executable, "-m", "grasp_env_agents.cli", "train", "--config", str(path)]
    process = subprocess.Popen(
        [*command, "--run-dir", str(run)], cwd=tmp_path, stdout=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not list(run.glob("tb/ppo/*")):
            time.sleep(0.05)  # learning has started
        time.sleep(1.0)
        process.send_signal(signal.SIGTERM)
        output, _ = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 130
    assert "interrupted: saved the model" in output and "--resume" in output
    saved = [checkpoint_steps(p) for p in (run / "checkpoints").glob("ppo_*_steps.zip")]
    assert saved and max(saved) > 0


@pytest.mark.slow
def test_sigkill_then_resume_logs_every_step_once(tmp_path):
    """A run killed (SIGKILL) between checkpoints and resumed: TensorBoard, the learning curve
    and SB3's evaluation log hold each step once, and the run reaches its steps."""
    import signal
    import subprocess
    import sys
    import time

    config = tiny(total_timesteps=1 << 20, eval_freq=64, checkpoint_freq=256)
    path, run = tmp_path / "config.yaml", tmp_path / "run"
    save_config(config, path)
    command = [sys.executable, "-m", "grasp_env_agents.cli", "train", "--config", str(path)]
    process = subprocess.Popen([*command, "--run-dir", str(run)], cwd=tmp_path)
    try:
        # kill once the run has logged steps after its latest checkpoint
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and process.poll() is None:
            saved = [checkpoint_steps(p) for p in (run / "checkpoints").glob("ppo_*_steps.zip")]
            try:  # the file may be mid-write
                logged = int(curve(run)[-1]["env_steps"])
            except (OSError, IndexError, TypeError, ValueError):
                logged = -1
            if saved and logged >= max(saved) + 128:
                break
            time.sleep(0.02)
        process.send_signal(signal.SIGKILL)
    finally:
        process.wait()
    killed_at = int(curve(run)[-1]["env_steps"])
    checkpoint = max(checkpoint_steps(p) for p in (run / "checkpoints").glob("ppo_*_steps.zip"))
    assert killed_at > checkpoint  # steps that the resumed run logs again
    before = tensorboard_steps(run / "tb" / "ppo")
    assert max(before["rollout/ep_rew_mean"]) > checkpoint

    total = killed_at + 256
    model = train(config.replace(total_timesteps=total), run, resume=True, progress_bar=False)
    assert model.num_timesteps == total
    steps = [int(r["env_steps"]) for r in curve(run)]
    assert steps == sorted(set(steps)) and steps[-1] == total
    with np.load(run / "eval" / "evaluations.npz") as log:
        assert log["timesteps"].tolist() == sorted(set(log["timesteps"].tolist()))
    after = tensorboard_steps(run / "tb" / "ppo")
    for tag in ("rollout/ep_rew_mean", "train/loss", "held_out/mean_gap_deg"):
        assert len(after[tag]) == len(set(after[tag])), tag
        assert max(after[tag]) > killed_at  # the resumed run logged on past the kill
    assert sorted(after["held_out/mean_gap_deg"]) == [s for s in steps]


@pytest.mark.parametrize("label_weight", [1.0, 0.0])
def test_interrupted_imitation_resumes_after_its_last_round(tmp_path, monkeypatch, label_weight):
    """Rounds done are checkpointed with their data: a resumed run does only the rest (with
    the expert's labels, and with none: label_weight 0)."""
    import grasp_env_agents.learning.imitation as imitation
    from grasp_env_agents.learning.checkpoints import load_round_data

    config = tiny(
        total_timesteps=0,
        imitation={
            "rounds": 3,
            "samples_per_round": 124,
            "epochs": 2,
            "n_envs": 4,
            "label_weight": label_weight,
            "gap_weight": 1.0,
        },
    )
    run = tmp_path / "run"
    fit, calls = imitation.fit, []

    def interrupted_third_fit(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return fit(*args, **kwargs)

    monkeypatch.setattr(imitation, "fit", interrupted_third_fit)
    with pytest.raises(KeyboardInterrupt):
        train(config, run, progress_bar=False)
    assert [r["phase"] for r in curve(run)] == ["initial", "imitation", "imitation"]
    assert sorted(p.name for p in (run / "checkpoints").glob("imitation_round_*")) == [
        "imitation_round_0.npz", "imitation_round_0.zip",
        "imitation_round_1.npz", "imitation_round_1.zip",
    ]  # fmt: skip
    obs, labels, _ = load_round_data(run / "checkpoints" / "imitation_round_1.npz")
    assert obs.shape == (124, 32) and labels.shape == (124, 3 if label_weight else 0)

    calls.clear()
    train(config, run, resume=True, progress_bar=False)
    assert len(calls) == 1  # round 2 only
    rows = curve(run)
    assert [r["phase"] for r in rows] == ["initial", "imitation", "imitation", "imitation"]
    # the resumed round refits on all three rounds' states
    assert not list((run / "checkpoints").glob("*.npz"))  # the data go with the phase
    assert (run / "checkpoints" / "ppo_0_steps.zip").is_file()
    logged = tensorboard_steps(run / "tb" / "imitation")
    assert logged["imitation/labelled_states"] == [int(r["env_steps"]) for r in rows[1:]]
    assert logged["held_out/mean_gap_deg"] == [int(r["env_steps"]) for r in rows]
    # imitation alone (total_timesteps 0): the last round's evaluation is the final model's
    assert row_metrics(rows[-1]) == pytest.approx(final_metrics(run), rel=1e-9)


def test_same_seed_same_first_evaluation(tmp_path):
    def first_ppo_evaluation(seed: int, name: str) -> dict[str, str]:
        train(tiny(seed=seed, total_timesteps=128), tmp_path / name, progress_bar=False)
        (row,) = [r for r in curve(tmp_path / name) if r["phase"] == "ppo"]
        return {k: v for k, v in row.items() if k not in ("wall_seconds", "cpu_seconds")}

    first = first_ppo_evaluation(7, "a")
    assert first_ppo_evaluation(7, "b") == first
    assert first_ppo_evaluation(8, "c") != first


def test_a_run_directory_is_not_overwritten(tmp_path, capsys):
    run = tmp_path / "run"
    # a config that cannot build its environments leaves no run behind to block the retry
    with pytest.raises(ValueError, match="env_kwargs for grasp_env/CubeGrasp-v0"):
        train(tiny(env_kwargs={"bogus": 3}), run, progress_bar=False)
    # nor an empty directory; a value out of its range is refused with the config, named
    with pytest.raises(ValueError, match=r"env_kwargs\.k_max_ratio must be a finite number"):
        train(tiny(env_kwargs={"k_max_ratio": -1}), run, progress_bar=False)
    assert not run.exists()
    train(tiny(total_timesteps=64), run, progress_bar=False)
    with pytest.raises(ValueError, match="already holds a run; use --resume"):
        train(tiny(total_timesteps=64), run, progress_bar=False)
    # --resume takes the run's own config and directory, and cannot shorten the run
    assert cli.main(["train", "--resume", str(run), "--config", "dagger"]) == 2
    assert "give it without --config and --run-dir" in capsys.readouterr().err
    before = (run / "config.yaml").read_text()
    assert cli.main(["train", "--resume", str(run), "--total-timesteps", "32"]) == 2
    assert "total_timesteps 32 is below the 64 PPO steps" in capsys.readouterr().err
    assert (run / "config.yaml").read_text() == before  # the run's record stands
