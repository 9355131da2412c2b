"""Throughput of the grasp environments beside Gymnasium's CartPole-v1, measured in one run,
with the arithmetic limit of an environment step and what bounds the random scenes.

    grasp-env bench envs [--seconds 2] [--rounds 3]

Single environments come from ``gym.make`` (with its default wrappers), vector environments
from ``gym.make_vec(..., vectorization_mode="vector_entry_point")`` at 4,096
sub-environments. Actions are drawn beforehand (uniform in the action space) so that only the
environments are timed. Resets are included: the grasp environments run with
``terminate_on_slip=False`` so that every episode covers its whole trajectory (random grips
slip at once, which would turn the measurement into one of resets alone), and CartPole runs
its own random-policy episodes; the random environment's single env is also timed as an
untrained policy meets it ("slipping": ``terminate_on_slip`` on, a reset nearly every step,
its episodes drawn ahead in batches by :class:`~grasp_env.envs.cube_grasp.episodes.EpisodeStream`);
the random environment's resets draw and check new scenes and
solve the expert's certified optimum along each new trajectory (ahead, for every
sub-environment without a next episode at once: a draw every twenty-odd steps). The machine
is shared: every figure is the median of ``--rounds`` rounds, each measuring CartPole and the
grasp environments one after the other, and the ratios are taken within a round.

Targets, the speeds the environments were asked to reach (relative to CartPole so that a step
costs about what the simplest classic environment's does, and a learning run's time goes to
learning): ``CubeGrasp-v0`` single >= 0.8x CartPole-v1, vector >= 0.6x CartPole's vector env;
``CubeGraspRandom-v0`` vector >= 500,000 env-steps/s. The other environments are reported
beside them. Resets with ``render_mode="rgb_array"`` (what SB3's ``make_vec_env`` passes to
every environment, rendered or not) run at >= 0.9x the rate without: the renderer is built on
the first ``render()``, not at a reset; measured on the random environments, whose every reset
is a new scene.

**The limit of a step.** :func:`~grasp_env.envs.kernels.grip_row` is the arithmetic of one
env step: its floating-point operations are counted below from the kernel, and the rate the
machine sustains on that code is measured by running it, compiled, over poses that stay in
the cache (no Python, no memory traffic); that rate over the count is the most env-steps per
second one core can compute. The vector env splits its step's kernel across the cores it may
use (:mod:`grasp_env.envs.cube_grasp.vector`), so both limits are printed: one core's and
that many cores'. **The hand-off.** The vector step's split
(:func:`~grasp_env.mechanics.threads.in_parts`) measures how long after the calling thread
the others start their parts; that lag, and the rows the caller steps to fill it, are
printed. **The random scenes' bound.** Every pose of a new episode needs the expert's
certified optimum: the solves per env-step are counted while the random vector env runs,
and the solver's rate on the same kind of batch (poses along trajectories, each starting
from the previous optimum, both cores) is measured in the same round.

Exits with status 1 if a target is missed.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections.abc import Callable

import gymnasium as gym
import numba
import numpy as np

import grasp_env  # noqa: F401  (registers the environments)
from grasp_env.envs.cube_grasp import episodes
from grasp_env.envs.cube_grasp.scenes import SceneSampler
from grasp_env.envs.kernels import grip_row
from grasp_env.mechanics import Grasp, contact_pairs
from grasp_env.mechanics.threads import LEAD_SECONDS, available_cores, caller_items, hand_off
from grasp_env_agents.commands.bench import Targets

NUM_ENVS = 4096
#: Environments whose resets are timed with and without render_mode="rgb_array", and the target.
RESET_ENVS = ("CubeGraspRandom-v0", "CubeGraspRandomMujoco-v0")
RESET_TARGET = 0.9
#: vector steps of the random env measured for its bound, at least: about ten of its draws
#: ahead, so that the solves counted in the window are those of its steps
RANDOM_STEPS = 256
#: (environment, mode) -> (target, whether it is a ratio to CartPole); None: reported only
TARGETS: dict[tuple[str, str], tuple[float, bool] | None] = {
    ("CubeGrasp-v0", "single"): (0.8, True),
    ("CubeGrasp-v0", "vector"): (0.6, True),
    ("CubeGrasp4-v0", "single"): None,
    ("CubeGrasp4-v0", "vector"): None,
    ("CubeGraspRandom-v0", "single"): None,
    # an untrained policy as it is: its random grips slip at once, so nearly every step resets
    ("CubeGraspRandom-v0", "slipping"): None,
    ("CubeGraspRandom-v0", "vector"): (500_000, False),
    ("CubeGait-v0", "single"): None,
    ("CubeGait-v0", "vector"): None,
}


def timed(step: Callable[[int], int], seconds: float, warmup: int = 1) -> float:
    """Steps per second of ``step(i) -> steps taken``, called until ``seconds`` have passed,
    after ``warmup`` calls (compilation, first allocations, steady state of the resets)."""
    for i in range(warmup):
        step(i)
    done, calls, start = 0, warmup, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for _ in range(8):
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

    return timed(step, seconds, warmup=64)


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


def resets(env_id: str, seconds: float) -> tuple[float, float]:
    """(resets per second without a render mode, the rate with rgb_array over it): two copies
    of the environment, seeded alike so that their i-th resets draw the same scene, reset in
    turn (a drift of the shared machine hits both alike); ratio of the total times."""
    envs = {mode: gym.make(env_id, render_mode=mode) for mode in (None, "rgb_array")}
    spent = dict.fromkeys(envs, 0.0)
    for env in envs.values():
        env.reset(seed=0)
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds or count < 16:
        for mode, env in envs.items():
            t0 = time.perf_counter()
            env.reset()
            spent[mode] += time.perf_counter() - t0
        count += 1
    for env in envs.values():
        env.close()
    return count / spent[None], spent[None] / spent["rgb_array"]


# ------------------------------------------------------------------------- the step's limit


def step_flops(n: int) -> int:
    """Floating-point operations of one :func:`grip_row` (sqrt, division and atan counted as
    one each), from the kernel's code: per pair 11 (k / w and k in newtons, then k u_ij added
    to one finger and taken from the other: 3 multiplications, 6 additions); per finger 26 (P
    in newtons 3, the cross product with the normal 9, its norm 6, the normal component 5, the
    division, the atan and the margin)."""
    m = n * (n - 1) // 2
    return 11 * m + 26 * n


@numba.njit(nogil=True)
def _cached_steps(forces, directions, normals, pairs, actions, weight, limit, repeats):
    """The step's arithmetic (grip_row, as every environment runs it) over the same few poses
    ``repeats`` times (their data stays in the cache), into rows of small outputs."""
    rows, m = forces.shape[0], directions.shape[1]
    n = forces.shape[1]
    k, net, unit = np.empty((rows, m)), np.empty((rows, n, 3)), np.empty((n, 3))
    theta, margin = np.empty((rows, n)), np.empty((rows, n))
    total = 0.0
    for r in range(repeats):
        row = r % rows
        _, reward = grip_row(
            forces, directions, normals, pairs, row, actions, row, 2.0, weight, limit,
            k, net, theta, margin, unit,
        )  # fmt: skip
        total += reward
    return total


def machine_steps(n: int, seconds: float) -> float:
    """Steps per second of the compiled step on cache-resident poses, one core."""
    env = gym.make("grasp_env/CubeGrasp-v0" if n == 3 else "grasp_env/CubeGrasp4-v0").unwrapped
    env.reset(seed=0)
    episode = env.episode
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (len(episode), len(contact_pairs(n))))
    arrays = (episode.forces_w, episode.directions, episode.normals, contact_pairs(n), actions)
    _cached_steps(*arrays, episode.weight, episode.limit, 10)
    repeats, best = 1 << 16, 0.0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        t0 = time.perf_counter()
        _cached_steps(*arrays, episode.weight, episode.limit, repeats)
        best = max(best, repeats / (time.perf_counter() - t0))
    return best


# ------------------------------------------------------------------ the random scenes' bound


class SolveCounter:
    """Counts the poses the episodes solve (the expert's optimum) while installed."""

    def __init__(self) -> None:
        self.solves = 0
        self._solve = episodes.solve_minimax

    def __enter__(self) -> SolveCounter:
        def counting(grasp: Grasp, *args, **kwargs):
            self.solves += grasp.equilibrating.shape[0]
            return self._solve(grasp, *args, **kwargs)

        episodes.solve_minimax = counting
        return self

    def __exit__(self, *exc: object) -> None:
        episodes.solve_minimax = self._solve


def random_vector_with_solves(seconds: float) -> tuple[float, float]:
    """(env-steps per second, solves per env-step) of the random vector env."""
    envs = gym.make_vec(
        "grasp_env/CubeGraspRandom-v0",
        num_envs=NUM_ENVS,
        vectorization_mode="vector_entry_point",
        terminate_on_slip=False,
    )
    envs.reset(seed=0)
    envs.action_space.seed(0)
    actions = [envs.action_space.sample() for _ in range(8)]
    for i in range(64):
        envs.step(actions[i % 8])
    with SolveCounter() as counter:
        # four of the longest episodes and about ten draws ahead: the resets and draws
        # inside the window are then those of a long run (a few steps would catch a handful
        # of resets, or none)
        steps, start = 0, time.perf_counter()
        while steps < RANDOM_STEPS or time.perf_counter() - start < seconds:
            envs.step(actions[steps % 8])
            steps += 1
        elapsed = time.perf_counter() - start
    return steps * NUM_ENVS / elapsed, counter.solves / (steps * NUM_ENVS)


def solver_rate(seconds: float) -> float:
    """Solves per second of the expert's optimum on the random env's own poses: whole
    trajectories of freshly sampled scenes, each pose starting from the previous optimum."""
    sampler = SceneSampler()
    scenes = sampler.scenes(sampler.raw(np.random.default_rng(1), 256))
    poses = episodes.build_episodes(scenes, 2.0).poses  # compiled and warm
    n = scenes.contacts.shape[1]
    pairs = contact_pairs(n)
    grasp = Grasp(
        np.zeros_like(poses.forces_w),
        poses.normals,
        poses.forces_w,
        episodes.interaction_basis(poses.directions, pairs, n),
        poses.limit,
    )
    first = np.concatenate([[0], np.cumsum(scenes.length)[:-1]])
    follows = np.ones(len(poses.limit), bool)
    follows[first] = False
    done, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        episodes.expert_optimum(grasp, 2.0, follows)
        done += len(follows)
    return done / (time.perf_counter() - start)


# ------------------------------------------------------------------------------------ main


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    parser.add_argument("--rounds", type=int, default=3, help="rounds (medians are printed)")
    args = parser.parse_args()
    grasp = {"terminate_on_slip": False}
    rows: dict[str, list[float]] = {}

    def record(key: str, value: float) -> None:
        rows.setdefault(key, []).append(value)

    for _ in range(args.rounds):
        cartpole = {
            "single": single("CartPole-v1", args.seconds),
            "vector": vector("CartPole-v1", args.seconds),
        }
        record("CartPole single", cartpole["single"])
        record("CartPole vector", cartpole["vector"])
        for (name, mode), _target in TARGETS.items():
            env_id = f"grasp_env/{name}"
            if env_id not in gym.registry:
                continue
            if (name, mode) == ("CubeGraspRandom-v0", "vector"):
                rate, solves = random_vector_with_solves(args.seconds)
                record("solves per env-step", solves)
            elif mode == "slipping":
                rate = single(env_id, args.seconds)  # terminate_on_slip: its default, True
            else:
                rate = (single if mode == "single" else vector)(env_id, args.seconds, **grasp)
            if (name, mode) == ("CubeGrasp-v0", "vector"):
                lag, per_item = hand_off("grasp-vector-step") or (math.nan, math.nan)
                record("hand-off lag", lag)
                record("hand-off per row", per_item)
                record("hand-off share", caller_items("grasp-vector-step", NUM_ENVS, 2) / NUM_ENVS)
            record(f"{name} {mode}", rate)
            record(
                f"{name} {mode} ratio", rate / cartpole["vector" if mode == "vector" else "single"]
            )
        for name in RESET_ENVS:
            plain, ratio = resets(f"grasp_env/{name}", args.seconds)
            record(f"{name} resets", plain)
            record(f"{name} resets rgb_array ratio", ratio)
        record("step limit 3", machine_steps(3, args.seconds))
        record("step limit 4", machine_steps(4, args.seconds))
        record("solver", solver_rate(args.seconds))

    def median(key: str) -> float:
        return statistics.median(rows[key])

    print(f"median of {args.rounds} rounds; ratios to CartPole taken within each round")
    print(
        f"CartPole-v1: single {median('CartPole single'):,.0f} steps/s, vector ({NUM_ENVS} envs)"
        f" {median('CartPole vector'):,.0f} env-steps/s"
    )
    print(f"{'environment':<22} {'mode':<8} {'steps/s':>12} {'x CartPole':>11} {'target':>12}")
    targets = Targets("envs")
    for (name, mode), target in TARGETS.items():
        if f"{name} {mode}" not in rows:
            continue
        rate, ratio = median(f"{name} {mode}"), median(f"{name} {mode} ratio")
        verdict = ""
        if target is not None:
            value, is_ratio = target
            ok = (ratio if is_ratio else rate) >= value
            want = f">= {value:g}x" if is_ratio else f">= {value:,.0f}"
            whole = f"{want} CartPole-v1" if is_ratio else f"{want} env-steps/s"
            verdict = f"{want:>12}  {targets.check(f'{name} {mode} {whole}', ok)}"
        print(f"{name:<22} {mode:<8} {rate:>12,.0f} {ratio:>10.3g}x {verdict}")
    for name in RESET_ENVS:
        ratio = median(f"{name} resets rgb_array ratio")
        target = f"{name} resets with render_mode='rgb_array' >= {RESET_TARGET:g}x without"
        verdict = targets.check(target, ratio >= RESET_TARGET)
        print(
            f"{name} resets: {median(f'{name} resets'):,.0f}/s; with render_mode='rgb_array'"
            f" {ratio:.3g}x that (target >= {RESET_TARGET:g}x)  {verdict}"
        )
    cores = available_cores()
    for n in (3, 4):
        flops, limit = step_flops(n), median(f"step limit {n}")
        reached = median("CubeGrasp-v0 vector" if n == 3 else "CubeGrasp4-v0 vector")
        print(
            f"step limit, {n} fingers: {flops} flops a step (grip_row, counted), the machine"
            f" sustains {limit * flops / 1e9:.2f} Gflop/s on it (compiled, cached poses, one"
            f" core): {limit:,.0f} steps/s on one core, {cores * limit:,.0f} on the {cores}"
            f" the vector step is split across; the vector env reaches {reached / limit:.3f} of"
            f" the one-core limit, {reached / (cores * limit):.3f} of the {cores}-core one"
        )
    lag, per_row = median("hand-off lag"), median("hand-off per row")
    if math.isnan(lag):
        print("vector step hand-off: none (one core: the step is not split)")
    else:
        caller = median("hand-off share")
        print(
            f"vector step hand-off (CubeGrasp-v0, measured by in_parts): the other threads"
            f" start their parts {lag * 1e6:.0f} us after the caller starts its own, which takes"
            f" {per_row * 1e9:.0f} ns a sub-environment; so the caller steps {caller:.0%} of the"
            f" {NUM_ENVS:,} rows, its extra rows filling that lag and the"
            f" {LEAD_SECONDS * 1e6:.0f} us by which the others should end before it"
        )
    solves, solver = median("solves per env-step"), median("solver")
    bound = solver / solves
    random_rate = median("CubeGraspRandom-v0 vector")
    print(
        f"random scenes: {solves:.3f} certified solves per env-step (counted), the solver"
        f" {solver:,.0f} solves/s on trajectories of random scenes ({cores} core"
        f"{'s' if cores > 1 else ''}): a bound of"
        f" {bound:,.0f} env-steps/s; the vector env reaches {random_rate / bound:.2f} of it"
    )
    return targets.exit_code()


if __name__ == "__main__":
    sys.exit(main())
