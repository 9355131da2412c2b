"""Speed of the MuJoCo checks, against a bare MuJoCo step loop measured in the same run.

    grasp-env bench physics [--seconds 1]

1. One pose check of the paper's optimal grip (settle and hold) and one continuous rollout of
   the 31-pose trajectory (:class:`grasp_env.physics.TrajectoryChecker`), each against the
   reference: ``mj_step`` on the same model, from the same state, for the same number of steps,
   with no Python in between (the ratio is what the check adds to MuJoCo itself). Targets: a
   pose check <= 5 ms, a 31-pose rollout <= 0.5 s.
2. Batched checks (64 pose checks, and 8 rollouts) on 2 threads against 1, measured in
   alternating rounds so that the machine's load falls on both alike. Target: >= 1.7x. Each
   is printed with its reference: a bare ``mujoco.rollout`` of the same runs (initial states
   and controls, one call, nothing measured) on 2 threads against 1, in the same rounds. On a
   machine whose cores others are using, that ratio is the ceiling: it measures the share of
   the second core we get.

Exits with 1 if a target is missed.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

import mujoco
import numpy as np
from mujoco import rollout

from grasp_env.mechanics import PHI, Scene, Trajectory, scene_grasp, solve_minimax
from grasp_env.physics import StabilityChecker, TrajectoryChecker
from grasp_env.physics.motion import plan_poses
from grasp_env.physics.simulation import _controls, available_cores, in_parallel
from grasp_env_agents.commands.bench import Targets

POSE_TARGET_MS = 5.0
ROLLOUT_TARGET_S = 0.5
THREADS_TARGET = 1.7
ROUNDS = 7


def paired_times(
    call, reference, seconds: float, least: int = 5
) -> tuple[float, float, float, float]:
    """Timings of ``call()`` and ``reference()`` alternated over about ``seconds`` (at least
    ``least`` each), so that the machine's load falls on both alike: the medians of each, the
    median of the pairs' ratios, and the ratio of the fastest of each (on a loaded machine the
    longer call is preempted more often: the fastest runs show what the code itself costs)."""
    ours: list[float] = []
    bare: list[float] = []
    while len(ours) < least or sum(ours) + sum(bare) < seconds:
        for times, run in ((ours, call), (bare, reference)):
            start = time.perf_counter()
            run()
            times.append(time.perf_counter() - start)
    ratio = np.median(np.array(ours) / np.array(bare))
    best = min(ours) / min(bare)
    return float(np.median(ours)), float(np.median(bare)), float(ratio), float(best)


def bare_loop(physics, motion):
    """``mj_step`` over the run's number of steps from its initial state, the first step's
    controls held: the reference."""
    model, data = physics.model, mujoco.MjData(physics.model)
    state = physics.initial_state(motion.contact[0])
    steps = len(motion)
    nu = 3 * physics.n

    def run() -> None:
        mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        data.ctrl[:nu] = motion.forces[0].ravel()
        data.xfrc_applied[physics.object] = motion.load[0]
        mujoco.mj_step(model, data, nstep=steps)

    return run


def single_runs(seconds: float, targets: Targets) -> None:
    scene = Scene()
    trajectory = Trajectory()
    rotations = trajectory.rotations()
    grasp = scene_grasp(scene, rotations)
    optimal = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    middle = len(rotations) // 2

    poses = StabilityChecker(scene, threads=1)
    assert poses.check(rotations[middle], optimal[middle]).holds
    one = slice(middle, middle + 1)
    (motion,) = plan_poses(scene, rotations[one], optimal[one], None, poses.settings)
    pose, pose_bare, pose_ratio, pose_best = paired_times(
        lambda: poses.check(rotations[middle], optimal[middle]),
        bare_loop(poses.physics, motion),
        seconds,
    )

    rollouts = TrajectoryChecker(scene, threads=1)
    assert rollouts.check(rotations, optimal).holds
    run = rollouts.plan(rotations, optimal)
    rollout, rollout_bare, rollout_ratio, rollout_best = paired_times(
        lambda: rollouts.check(rotations, optimal), bare_loop(rollouts.physics, run), seconds
    )

    pose_verdict = targets.check(
        f"one pose check <= {POSE_TARGET_MS:g} ms", 1e3 * pose <= POSE_TARGET_MS
    )
    rollout_verdict = targets.check(
        f"31-pose rollout <= {ROLLOUT_TARGET_S:g} s", rollout <= ROLLOUT_TARGET_S
    )
    step_ms = 1e3 * poses.settings["timestep"]
    print(f"one pose check, paper optimum ({len(motion)} steps of {step_ms:g} ms):")
    print(
        f"  median {1e3 * pose:.2f} ms (target <= {POSE_TARGET_MS:.0f} ms: "
        f"{pose_verdict}); bare mj_step loop {1e3 * pose_bare:.2f} ms;"
        f" check / bare = {pose_ratio:.2f} (median of alternated pairs; fastest of each:"
        f" {pose_best:.2f})"
    )
    print(f"31-pose continuous rollout, paper optimum ({len(run)} steps):")
    print(
        f"  median {rollout:.3f} s (target <= {ROLLOUT_TARGET_S} s: "
        f"{rollout_verdict}); bare mj_step loop {rollout_bare:.3f} s;"
        f" rollout / bare = {rollout_ratio:.2f} (fastest of each: {rollout_best:.2f})"
    )


def thread_ratios(cases: dict[str, tuple[int, Callable[[int], object]]]) -> dict[str, float]:
    """Throughput on 2 threads over 1 of each case (count, check(threads)), measured in
    alternating rounds over all the cases, medians compared."""
    times = {name: {1: [], 2: []} for name in cases}
    for _, check in cases.values():  # warm up the pools and the models' MjData
        check(1)
        check(2)
    for _ in range(ROUNDS):
        for name, (_, check) in cases.items():
            for threads in (1, 2):
                start = time.perf_counter()
                check(threads)
                times[name][threads].append(time.perf_counter() - start)
    ratios = {}
    for name, (count, _) in cases.items():
        one, two = float(np.median(times[name][1])), float(np.median(times[name][2]))
        ratios[name] = one / two
        print(
            f"  {name}: {count / one:.1f}/s on 1 thread, {count / two:.1f}/s on 2;"
            f" 2 / 1 = {one / two:.2f}x"
        )
    return ratios


def bare_rollout(physics, motions: list) -> Callable[[int], object]:
    """The reference: one ``mujoco.rollout`` call of the same runs (their initial states and
    controls, padded to the longest), on the model at the scene's mu (no settle switch, no
    measurement), on 1 or 2 threads."""
    length = max(len(motion) for motion in motions)
    state = np.stack([physics.initial_state(motion.contact[0]) for motion in motions])
    controls = np.empty((len(motions), length, physics.ncontrol))
    for r, motion in enumerate(motions):
        row = _controls([physics], motion.forces[None], motion.load[None], motion.contact[None])
        controls[r, : len(motion)] = row[0]
        controls[r, len(motion) :] = row[0, -1]
    models = [physics.model] * len(motions)
    data = [mujoco.MjData(physics.model) for _ in range(2)]
    pools = {1: rollout.Rollout(nthread=0), 2: rollout.Rollout(nthread=2)}
    control_spec = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED
    return lambda threads: pools[threads].rollout(
        models, data[:threads], state, controls, control_spec=control_spec
    )


def batched(targets: Targets) -> None:
    scene = Scene(mu=0.1)
    rotations = Trajectory().rotations()
    grasp = scene_grasp(scene, rotations)
    optimal = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    equal_k = grasp.forces(np.full(3, scene.weight * np.tan(PHI) / (3 * np.sqrt(3))))  # eq. 8
    poses = StabilityChecker(scene)
    pose_rotations = np.concatenate([rotations, rotations, rotations[:2]])
    pose_forces = np.concatenate([optimal, equal_k, optimal[:2]])
    rollouts = TrajectoryChecker(scene)
    grips = [(rotations, optimal, None), (rotations, equal_k, None)] * 4
    pose_motions = plan_poses(scene, pose_rotations, pose_forces, None, poses.settings)
    grip_motions = [rollouts.plan(*grip) for grip in grips]
    pose_name = f"{len(pose_rotations)} pose checks"
    grip_name = f"{len(grips)} 31-pose rollouts"

    def plan_all(part: list) -> list:
        return [rollouts.plan(*grip) for grip in part]

    print(f"batched checks, 2 threads against 1 ({available_cores()} cores available):")
    ratios = thread_ratios(
        {
            pose_name: (
                len(pose_rotations),
                lambda threads: poses.check_batch(pose_rotations, pose_forces, threads=threads),
            ),
            f"{pose_name}, bare mujoco.rollout": (
                len(pose_motions),
                bare_rollout(poses.physics, pose_motions),
            ),
            grip_name: (len(grips), lambda threads: rollouts.check_batch(grips, threads=threads)),
            f"{grip_name}, their planning alone": (
                len(grips),
                lambda threads: in_parallel(plan_all, grips, threads),
            ),
            f"{grip_name}, bare mujoco.rollout": (
                len(grip_motions),
                bare_rollout(rollouts.physics, grip_motions),
            ),
        }
    )
    for name in (pose_name, grip_name):
        ours, bare = ratios[name], ratios[f"{name}, bare mujoco.rollout"]
        target = f"{name} on 2 threads >= {THREADS_TARGET}x on 1"
        verdict = targets.check(target, ours >= THREADS_TARGET)
        print(
            f"  {name}: 2 / 1 = {ours:.2f}x (target >= {THREADS_TARGET}x:"
            f" {verdict}); bare mujoco.rollout of the same"
            f" runs {bare:.2f}x (the machine's ceiling); ours / bare = {ours / bare:.2f}"
        )
    print(
        f"  what bounds the rollouts: their own Python, planning and measuring, on the GIL"
        f" (the planning alone, the path and its timing, scales"
        f" {ratios[f'{grip_name}, their planning alone']:.2f}x on 2 threads)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="time per measurement")
    args = parser.parse_args(argv)
    targets = Targets("physics")
    single_runs(args.seconds, targets)
    batched(targets)
    return targets.exit_code()


if __name__ == "__main__":
    sys.exit(main())
