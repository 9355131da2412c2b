"""Speed of the MuJoCo stability check, against a bare MuJoCo step loop measured in the same run.

One check of a holding grip simulates the whole settle and hold (550 steps of 1 ms); a slipping
grip stops at the first slip check past the threshold. The reference is ``mj_step`` on the same
model, from the same state, for the same simulated time, with no Python in between: the ratio is
what the check adds to MuJoCo itself. Then the agreement study (``grasp-env verify
--agreement``) is timed end to end. Target: one check <= 20 ms median.

    grasp-env bench physics
"""

from __future__ import annotations

import time

import mujoco
import numpy as np

from grasp_env.mechanics import Scene, Trajectory, scene_grasp, solve_minimax
from grasp_env.physics import StabilityChecker
from grasp_env.physics.agreement import agreement_sets, check_sets, summarise
from grasp_env.physics.model import pose_qpos

TARGET_MS = 20.0
REPEATS = 3


def median_ms(function, cases) -> float:
    times = []
    for _ in range(REPEATS):
        for case in cases:
            start = time.perf_counter()
            function(*case)
            times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def main() -> None:
    scene = Scene()
    trajectory = Trajectory()
    rotations = trajectory.rotations()
    grasp = scene_grasp(scene, rotations)
    optimal = grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)
    slipping = grasp.forces(np.array([-1.0, 2.0, 0.5]))  # about 30 to 60 deg: slips at once
    checker = StabilityChecker(scene)
    holds = [(r, f) for r, f in zip(rotations, optimal, strict=True)]
    slips = [(r, f) for r, f in zip(rotations, slipping, strict=True)]
    assert all(checker.check(*case).holds for case in holds)
    assert not any(checker.check(*case).holds for case in slips)

    model, data = checker.model, checker.data
    steps = round((checker.settings["settle_time"] + checker.settings["hold_time"]) / 1e-3)

    def bare(rotation: np.ndarray, forces: np.ndarray) -> None:
        mujoco.mj_resetData(model, data)
        data.qpos[:] = pose_qpos(scene, rotation)
        data.ctrl[:] = forces.ravel()
        mujoco.mj_step(model, data, nstep=steps)

    check_hold = median_ms(checker.check, holds)
    check_slip = median_ms(checker.check, slips)
    reference = median_ms(bare, holds)
    checker.close()
    verdict = "ok" if check_hold <= TARGET_MS else "MISSED"
    print(f"one check, paper grip, holds ({steps} steps of 1 ms):")
    print(f"  median {check_hold:.2f} ms (target <= {TARGET_MS:.0f} ms: {verdict})")
    print(f"  reference, bare mj_step loop, same model and steps: median {reference:.2f} ms")
    print(f"  check / reference = {check_hold / reference:.2f}")
    print(f"one check, slipping grip (stops at the first slip): median {check_slip:.2f} ms")
    print(f"  check / bare full-length reference = {check_slip / reference:.2f}")

    start = time.perf_counter()
    sets = agreement_sets()
    generated = time.perf_counter()
    reports = check_sets(sets)
    done = time.perf_counter()
    result = summarise(sets, np.array([r.holds for r in reports]))
    print(
        f"agreement study: {done - start:.1f} s for {len(sets)} force sets"
        f" ({generated - start:.1f} s generating, {done - generated:.1f} s checking,"
        f" {1e3 * (done - generated) / len(sets):.2f} ms per check = "
        f"{1e3 * (done - generated) / len(sets) / reference:.2f} x reference)"
    )
    print(result.line())


if __name__ == "__main__":
    main()
