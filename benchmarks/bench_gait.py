"""The finger-gait programme's time and the gait environment's speed (docs/gait.md).

    grasp-env bench gait [--seconds 2]

1. The default long trajectory (the paper's axis over [-90, 90] deg, 181 poses) and the full
   turn about the vertical (361 poses): the time of the certified minimax of every site set at
   every pose, of the dynamic programme (both passes, on the attained margins), and of
   :func:`grasp_env.mechanics.solve_gait` in all (values, programme on the attained values and
   on the bounds, greedy gait, best fixed set), each the best of three.
2. ``grasp_env/CubeGait-v0`` against ``grasp_env/CubeGrasp4-v0`` (the four-finger
   environment), single (``gym.make``) and vector (4,096 sub-environments), random actions
   drawn beforehand, ``terminate_on_slip=False``; the two are measured in alternating rounds
   and the medians compared, so that the machine's load falls on both alike. Exits with 1 if
   the gait environment runs below 0.5x the four-finger one. ``grasp_env/CubeGaitMoves-v0``
   (the moves alone, the certified grip looked up) is measured in the same rounds and
   reported beside them.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.mechanics import (
    PAPER_TURN,
    VERTICAL_TURN,
    GaitScene,
    Hand,
    optimal_gait,
    set_values,
    site_reach,
    solve_gait,
)
from grasp_env_agents.commands.bench import Targets

from .bench_envs import NUM_ENVS, single, vector

TARGET = 0.5
GAIT, FOUR = "grasp_env/CubeGait-v0", "grasp_env/CubeGrasp4-v0"
MOVES = "grasp_env/CubeGaitMoves-v0"
ROUNDS = 5


def best_of(count: int, call) -> float:
    times = []
    for _ in range(count):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times)


def programme() -> None:
    scene, hand = GaitScene(), Hand()
    print(
        f"{'trajectory':<22} {'poses':>6} {'minimax (s)':>12} {'programme (s)':>14} {'all (s)':>9}"
    )
    for name, trajectory in (
        ("paper axis [-90, 90]", PAPER_TURN),
        ("vertical, full turn", VERTICAL_TURN),
    ):
        rotations = trajectory.rotations()
        solve_gait(scene, hand, trajectory)  # compile, warm up
        values = set_values(scene, rotations)
        reach = site_reach(scene, hand, rotations)
        minimax = best_of(3, lambda: set_values(scene, rotations))  # noqa: B023
        dp = best_of(3, lambda: optimal_gait(values.margin, reach))  # noqa: B023
        whole = best_of(3, lambda: solve_gait(scene, hand, trajectory))  # noqa: B023
        print(f"{name:<22} {len(trajectory):>6} {minimax:>12.3f} {dp:>14.3f} {whole:>9.3f}")


def environments(seconds: float, targets: Targets) -> None:
    kwargs = {"terminate_on_slip": False}
    for mode, measure in (("single", single), (f"vector ({NUM_ENVS})", vector)):
        rates: dict[str, list[float]] = {GAIT: [], FOUR: [], MOVES: []}
        for _ in range(ROUNDS):
            for env_id in (FOUR, GAIT, MOVES):
                rates[env_id].append(measure(env_id, seconds / ROUNDS, **kwargs))
        gait, four, moves = (float(np.median(rates[e])) for e in (GAIT, FOUR, MOVES))
        ratio = gait / four
        target = f"CubeGait-v0 {mode.split()[0]} >= {TARGET}x CubeGrasp4-v0"
        print(
            f"{mode:<14} CubeGait-v0 {gait:>12,.0f} steps/s  CubeGrasp4-v0 {four:>12,.0f}"
            f" steps/s  ratio {ratio:.2f}x (target {TARGET}x)"
            f" {targets.check(target, ratio >= TARGET)}"
        )
        print(
            f"{'':<14} CubeGaitMoves-v0 {moves:>12,.0f} steps/s, {moves / gait:.2f}x"
            " CubeGait-v0 (the certified grip looked up at every step)"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--seconds", type=float, default=2.0, help="time per environment measurement"
    )
    args = parser.parse_args()
    if not args.seconds > 0:
        parser.error(f"--seconds must be > 0, got {args.seconds}")
    programme()
    targets = Targets("gait")
    environments(args.seconds, targets)
    return targets.exit_code()


if __name__ == "__main__":
    sys.exit(main())
