"""Throughput of the grasp environments beside Gymnasium's CartPole-v1, measured in one run.

    grasp-env bench envs [--seconds 2]

Single environments come from ``gym.make`` (with its default wrappers), vector environments
from ``gym.make_vec(..., vectorization_mode="vector_entry_point")`` at 4,096 sub-environments.
Actions are drawn beforehand (uniform in the action space) so that only the environments are
timed. Resets are included: the grasp environments run with ``terminate_on_slip=False`` so
that every episode covers its whole trajectory (random grips slip at once, which would turn
the measurement into one of resets alone), and CartPole runs its own random-policy episodes;
the random environment's resets draw and check new scenes and solve the expert along each new
trajectory. Exits with status 1 if a target of issue 3 is missed.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import gymnasium as gym

import grasp_env  # noqa: F401  (registers the environments)

NUM_ENVS = 4096
#: (environment, mode) -> steps per second required by issue 3
TARGETS = {
    ("grasp_env/CubeGrasp-v0", "single"): 30_000,
    ("grasp_env/CubeGraspRandom-v0", "single"): 3_000,
    ("grasp_env/CubeGrasp-v0", "vector"): 3_000_000,
    ("grasp_env/CubeGraspRandom-v0", "vector"): 50_000,
}


def timed(step: Callable[[int], int], seconds: float, warmup: int = 1) -> float:
    """Steps per second of ``step(i) -> steps taken``, called until ``seconds`` have passed,
    after ``warmup`` calls (compilation, first allocations, steady state of the resets)."""
    for i in range(warmup):
        step(i)
    done, calls, start = 0, warmup, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for _ in range(64):
            done += step(calls)
            calls += 1
    return done / elapsed


def single(env_id: str, seconds: float, **kwargs) -> float:
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(4096)]

    def step(i: int) -> int:
        _, _, terminated, truncated, _ = env.step(actions[i % len(actions)])
        if terminated or truncated:
            env.reset()
        return 1

    return timed(step, seconds)


def vector(env_id: str, seconds: float, **kwargs) -> float:
    envs = gym.make_vec(
        env_id, num_envs=NUM_ENVS, vectorization_mode="vector_entry_point", **kwargs
    )
    envs.reset(seed=0)
    envs.action_space.seed(0)
    actions = [envs.action_space.sample() for _ in range(8)]

    def step(i: int) -> int:
        envs.step(actions[i % len(actions)])  # autoreset: resets happen inside step
        return NUM_ENVS

    # All sub-environments start together: run a longest episode (61 poses) before timing, so
    # that the resets are spread over the steps as in a long run.
    return timed(step, seconds, warmup=64)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    args = parser.parse_args()
    grasp = {"terminate_on_slip": False}
    cartpole = {
        "single": single("CartPole-v1", args.seconds),
        "vector": vector("CartPole-v1", args.seconds),
    }
    print(f"CartPole-v1: single {cartpole['single']:,.0f} steps/s, vector ({NUM_ENVS} envs)"
          f" {cartpole['vector']:,.0f} env-steps/s")  # fmt: skip
    print(f"{'environment':<30} {'mode':<7} {'steps/s':>12} {'target':>11} {'x CartPole':>11}")
    failed = False
    for (env_id, mode), target in TARGETS.items():
        rate = (single if mode == "single" else vector)(env_id, args.seconds, **grasp)
        ok = rate >= target
        failed |= not ok
        print(
            f"{env_id.split('/')[1]:<30} {mode:<7} {rate:>12,.0f} {target:>11,}"
            f" {rate / cartpole[mode]:>10.3g}x  {'ok' if ok else 'MISSED'}"
        )
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
