"""Throughput of the object environments beside Gymnasium's CartPole-v1, in one run.

    grasp-env bench object_envs [--seconds 2] [--rounds 3]

Single environments from ``gym.make`` step random actions (uniform in the action space, drawn
beforehand) and reset when an episode ends, CPU time measured (the machine is shared): with
``terminate_on_slip`` on, as an untrained policy meets them (a random grip slips at the first
step, so nearly every step is followed by a reset), and off (every episode covers its
trajectory). The random environment's resets draw scenes and solve the expert's certified
optimum along each new trajectory, a growing batch of candidates at a time
(:class:`~grasp_env.envs.object_grasp.episodes.EpisodeStream`); its rate is printed with the
resets per second, the candidates drawn per episode and the solves per episode. Every figure
is the median of ``--rounds`` rounds, each measuring CartPole first; ratios are within a round.

Reported only (no goal is set): five and six contacts go through the conic solver at 2 to 5 ms a
pose, which bounds the random environment's resets.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.mechanics import minimax

CASES = (
    ("CartPole-v1", {}),
    ("grasp_env/ObjectGrasp-v0", {"object": "can"}),
    ("grasp_env/ObjectGraspRandom-v0", {}),
    ("grasp_env/ObjectGraspRandom-v0", {"contact_counts": (3, 4)}),
)


class _SolveCounter:
    """Counts the poses :func:`solve_minimax` is given while it is active."""

    def __init__(self) -> None:
        self.poses = 0
        self._solve = minimax.solve_minimax

    def __enter__(self) -> _SolveCounter:
        import grasp_env.envs.object_grasp.episodes as episodes

        def counting(grasp, *args, **kwargs):  # type: ignore[no-untyped-def]
            self.poses += int(np.prod(grasp.equilibrating.shape[:-2]))
            return self._solve(grasp, *args, **kwargs)

        self._module = episodes
        episodes.solve_minimax = counting
        return self

    def __exit__(self, *exc: object) -> None:
        self._module.solve_minimax = self._solve


def run(env_id: str, kwargs: dict, seconds: float, slip: bool) -> dict[str, float]:
    """Steps/s and resets/s (CPU time) of one single environment with random actions."""
    if env_id.startswith("grasp_env/"):
        kwargs = {**kwargs, "terminate_on_slip": slip}
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(1000)]
    steps = resets = 0
    with _SolveCounter() as counter:
        stream = getattr(env.unwrapped, "_stream", None)
        drawn = stream.drawn if stream else 0
        start = time.process_time()
        while time.process_time() - start < seconds:
            for action in actions[:100]:
                _, _, terminated, truncated, _ = env.step(action)
                steps += 1
                if terminated or truncated:
                    env.reset()
                    resets += 1
        elapsed = time.process_time() - start
    env.close()
    return {
        "steps": steps / elapsed,
        "resets": resets / elapsed,
        "drawn": ((stream.drawn - drawn) / resets) if stream and resets else 0.0,
        "solves": counter.poses / resets if resets else 0.0,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    results: dict[tuple, list[dict[str, float]]] = {}
    for _ in range(args.rounds):
        for slip in (True, False):
            cartpole = None
            for env_id, kwargs in CASES:
                if env_id == "CartPole-v1" and not slip:
                    continue
                result = run(env_id, kwargs, args.seconds, slip)
                if env_id == "CartPole-v1":
                    cartpole = result["steps"]
                    results.setdefault((env_id, "", "-"), []).append(result)
                    continue
                result["ratio"] = result["steps"] / cartpole if cartpole else float("nan")
                key = (env_id, str(kwargs), "slipping" if slip else "full episodes")
                results.setdefault(key, []).append(result)
            if cartpole is None:  # the full-episode rows take the slipping rows' CartPole
                for key, rows in results.items():
                    if key[2] == "full episodes":
                        rows[-1]["ratio"] = (
                            rows[-1]["steps"] / results[("CartPole-v1", "", "-")][-1]["steps"]
                        )
    print(f"median of {args.rounds} rounds, CPU time, single envs, random actions")
    for (env_id, kwargs, mode), rows in results.items():
        med = {k: float(np.median([r[k] for r in rows])) for k in rows[0]}
        line = f"{env_id} {kwargs} [{mode}]: {med['steps']:,.0f} steps/s"
        if "ratio" in med:
            line += (
                f" ({med['ratio']:.4f}x CartPole-v1), {med['resets']:,.1f} resets/s,"
                f" {med['drawn']:.2f} candidates and {med['solves']:.1f} solves an episode"
            )
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
