"""Training throughput: PPO steps/s and the expert-teacher's labelled states/s, with references.

- PPO on ``grasp_env/CubeGraspRandom-v0`` (the batched vector env behind grasp_env's SB3 adapter)
  with the PPO settings of ``configs/ppo.yaml``, against the same PPO on Gymnasium's
  ``CartPole-v1`` (SB3's DummyVecEnv), measured in the same run: the ratio says what our
  environment costs a PPO run beside the cheapest classic one.
- The imitation phase's data: states visited and labelled by the minimax expert per second,
  against stepping the same vector env with random actions (the ratio is the labelling cost).
- The supervised fit: samples per second through SB3's policy network, against a bare torch MLP
  of the same shape (the ratio is SB3's overhead); and the main job's network with the
  force-direction output against the same network outputting k (the ratio is the head's cost).

    grasp-env bench training [--seconds 8]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env

from grasp_env_agents.learning.algorithms import new_model
from grasp_env_agents.learning.envs import action_scale, make_vec_env
from grasp_env_agents.learning.imitation import StateCollector, fit, grasp_of, make_teacher
from grasp_env_agents.run.config import CONFIG_DIR, DEFAULT_CONFIG, load_config

STATES = 20_000  # the fits' data set
CHUNK = 2_000  # labelled states per collection


def rate(work: Callable[[], int], seconds: float) -> float:
    """Units per second of ``work`` (which returns the units it did), repeated until at least
    ``seconds`` have passed."""
    done, start = 0, time.perf_counter()
    while True:
        done += work()
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            return done / elapsed


def ppo_steps_per_second(env, config, seconds: float) -> float:
    model = new_model(config, env)
    rollout = config.n_envs * config.ppo.n_steps
    model.learn(2 * rollout)  # warm-up: compile, allocate

    def one_rollout() -> int:
        model.learn(rollout, reset_num_timesteps=False)
        return rollout

    return rate(one_rollout, seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=8.0, help="time per measurement")
    args = parser.parse_args()
    if not args.seconds > 0:
        parser.error(f"--seconds must be > 0, got {args.seconds}")
    seconds = args.seconds
    torch.set_num_threads(1)
    config = load_config(CONFIG_DIR / "ppo.yaml")
    ours = ppo_steps_per_second(
        make_vec_env(config.env_id, config.env_kwargs, config.n_envs, seed=0), config, seconds
    )
    # CartPole has no grasp to compute features from: the same MLP on its raw observation
    plain = config.replace(**{"policy.features": "observation"})
    cartpole = ppo_steps_per_second(
        sb3_make_vec_env("CartPole-v1", config.n_envs, seed=0), plain, seconds
    )
    print(
        f"PPO ({config.n_envs} envs, {config.policy.net_arch} {config.policy.activation} MLP on "
        f"{config.policy.features} features), {seconds:g} s each:"
    )
    print(f"  {config.env_id}: {ours:8.0f} steps/s")
    print(f"  CartPole-v1 (DummyVecEnv):  {cartpole:8.0f} steps/s   ratio {ours / cartpole:.2f}")

    kwargs = {"terminate_on_slip": False}
    collector = StateCollector("grasp_env/CubeGraspRandom-v0", kwargs, 256, seed=0)
    teacher = make_teacher(collector.envs)
    scale = action_scale(collector.envs)  # k_max / w, read back from the environment
    collector.collect(teacher.actions, CHUNK)  # warm-up
    labelled = rate(lambda: len(collector.collect(teacher.actions, CHUNK)[0]), seconds)
    rng = np.random.default_rng(0)
    obs, _ = collector.collect(lambda o: rng.uniform(-1, 1, (len(o), 3)), STATES)
    stepped = rate(
        lambda: len(collector.collect(lambda o: rng.uniform(-1, 1, (len(o), 3)), CHUNK)[0]),
        seconds,
    )
    print("Expert-labelled states (256 envs, the expert drives):")
    print(f"  labelled: {labelled:8.0f} states/s")
    print(f"  random actions, no labels: {stepped:8.0f} states/s   ratio {labelled / stepped:.2f}")

    model = PPO("MlpPolicy", make_vec_env(config.env_id, kwargs, 1, 0), device="cpu")
    labels = rng.uniform(-1, 1, (len(obs), 3)).astype(np.float32)
    generator = torch.Generator().manual_seed(0)

    def epoch(policy, *loss) -> int:
        """One epoch of the supervised fit (over the data set), in samples."""
        fit(policy, obs, labels, 1, 1024, 1e-3, generator, *loss)
        return len(obs)

    policy_rate = rate(lambda: epoch(model.policy), seconds)
    net = torch.nn.Sequential(
        torch.nn.Linear(obs.shape[1], 64),
        torch.nn.Tanh(),
        torch.nn.Linear(64, 64),
        torch.nn.Tanh(),
        torch.nn.Linear(64, 3),
    )  # fmt: skip  (SB3's default MlpPolicy actor)
    optimizer = torch.optim.Adam(net.parameters(), 1e-3)
    obs_t, labels_t = torch.as_tensor(obs), torch.as_tensor(labels)

    def bare_epoch() -> int:
        for i in range(0, len(obs), 1024):
            loss = torch.nn.functional.mse_loss(net(obs_t[i : i + 1024]), labels_t[i : i + 1024])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        return len(obs)

    bare_rate = rate(bare_epoch, seconds)
    print("Supervised fit (batch 1024, SB3's default 64 x 64 actor):")
    print(f"  through the SB3 policy: {policy_rate:8.0f} samples/s")
    ratio = policy_rate / bare_rate
    print(f"  bare torch MLP:         {bare_rate:8.0f} samples/s   ratio {ratio:.2f}")

    default = load_config(DEFAULT_CONFIG)
    rates = {}
    grasp = grasp_of(obs)
    for output in ("k", "force_directions"):
        env = make_vec_env(default.env_id, kwargs, default.n_envs, 0)
        model = new_model(default.replace(**{"policy.output": output}), env)
        rates[output] = rate(lambda: epoch(model.policy, grasp, 1.0, scale), seconds)  # noqa: B023
    print(f"Supervised fit of the main job ({default.policy.net_arch} MLP, angle loss):")
    print(f"  output k:                {rates['k']:8.0f} samples/s")
    ratio = rates["force_directions"] / rates["k"]
    print(
        f"  output force directions: {rates['force_directions']:8.0f} samples/s   ratio {ratio:.2f}"
    )


if __name__ == "__main__":
    main()
