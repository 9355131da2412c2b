"""Compile the package's numba kernels ahead of their first use, on two cores: ``python -m
grasp_env.warm``.

A fresh checkout's numba cache is empty (``__pycache__`` next to the sources, or
``NUMBA_CACHE_DIR``): its first solves would compile the minimax solver. The test session
(``tests/conftest.py``) runs :func:`warm` once, before its xdist workers start, so that the
workers load every kernel from the cache instead of each compiling its own. The jobs, with the
CPU they took from an empty cache (numba 0.68, Python 3.11, one core each):

| job | compiles | CPU |
| --- | --- | --- |
| ``solve_batch`` | the solver's kernels, then ``driver.solve_batch`` | 64 s |
| ``conic`` | ``conic.solve_batch``, the solver of five or more contacts | 61 s |
| ``solve_grasp`` | ``driver.solve_grasp`` (``solve_one`` inlined again), kernels cached | 11 s |
| ``environments`` | the environments' step and pose kernels, float32 and float64 actions | 6 s |
| ``mujoco`` | the MuJoCo check's kernels | 6 s |

(December 8, measured in this order in one process, each job loading what the earlier ones
cached.) Every kernel is compiled once: the first wave compiles the two solvers side by side,
``solve_batch`` in one process and the conic solver (which links a few of the same kernels) in
the other; the second compiles ``solve_grasp``, whose kernels are then all cached, beside the
environments' jobs, which solve with ``solve_batch``. In two processes side by side,
``solve_batch`` and ``solve_grasp`` would each compile the kernels they share. numba writes a
cache entry atomically, so two processes may write one side by side. On one core
(``processes=1``) every job runs in one process, in turn.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The environment ids whose kernels the ``environments`` and ``mujoco`` jobs compile.
GRASP_IDS = ("grasp_env/CubeGrasp-v0", "grasp_env/CubeGraspRandom-v0", "grasp_env/CubeGrasp4-v0")
MUJOCO_IDS = ("grasp_env/CubeGraspMujoco-v0",)


def _solve(one_grasp: bool) -> None:
    """Three and four fingers (one signature): a batch of three poses, or one grasp."""
    from grasp_env.mechanics import (
        FOUR_FINGER_FACES,
        PAPER_AXIS,
        PAPER_FACES,
        Scene,
        pose_rotation,
        scene_grasp,
        solve_minimax,
    )

    rotations = np.stack([pose_rotation(PAPER_AXIS, np.radians(a)) for a in (-15.0, 0.0, 15.0)])
    for faces in (PAPER_FACES, FOUR_FINGER_FACES):
        scene = Scene.on_faces(faces)
        poses = rotations[0] if one_grasp else rotations
        solve_minimax(scene_grasp(scene, poses), 2.0 * scene.weight)


def _conic() -> None:
    """Five contacts on a cylinder: the conic solver."""
    from grasp_env.mechanics import Scene, scene_grasp, solve_minimax
    from grasp_env.mechanics.objects import Cylinder

    can = Cylinder(radius=0.033, height=0.115)
    sides = ((0, 0.3), (1.3, -0.2), (2.5, 0.1), (3.8, -0.3))
    fingers = [can.side_point(a, h) for a, h in sides] + [can.cap_point("+z", (0.2, 0.1))]
    scene = Scene(shape=can, contacts=fingers, weight=3.4)
    solve_minimax(scene_grasp(scene, np.eye(3)), 6.8)


def _step(env_ids: Sequence[str]) -> None:
    """One reset and step of each environment and of its vector version, with float32 actions
    (the action space's) and float64 ones (the expert's); then the expert reads an observation."""
    import gymnasium as gym

    import grasp_env

    for env_id in env_ids:
        env = gym.make(env_id)
        envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
        for dtype in (np.float32, np.float64):
            env.reset(seed=0)
            env.step(env.action_space.sample().astype(dtype))
            envs.reset(seed=0)
            envs.step(envs.action_space.sample().astype(dtype))
        grasp_env.MinimaxExpert().predict(env.reset(seed=0)[0])
        env.close()
        envs.close()


#: Each job by name.
JOBS: dict[str, Callable[[], None]] = {
    "solve_batch": lambda: _solve(one_grasp=False),
    "solve_grasp": lambda: _solve(one_grasp=True),
    "conic": _conic,
    "environments": lambda: _step(GRASP_IDS),
    "mujoco": lambda: _step(MUJOCO_IDS),
}

#: Two processes at a time: the waves in turn, each process of a wave running its jobs in turn.
WAVES: tuple[tuple[tuple[str, ...], ...], ...] = (
    (("solve_batch",), ("conic",)),
    (("solve_grasp",), ("environments", "mujoco")),
)


@dataclass
class Warmed:
    """What :func:`warm` did: its wall-clock and CPU seconds (user + system, of its
    processes) and a line for each process that failed."""

    seconds: float
    cpu_seconds: float
    failed: list[str] = field(default_factory=list)


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def warm(processes: int = 2) -> Warmed:
    """Compile (or load) every job's kernels in child processes that import the same sources
    as this one; ``processes`` is 1 (every job in one process) or 2 (:data:`WAVES`)."""
    if processes not in (1, 2):
        raise ValueError(f"warm: processes must be 1 or 2, got {processes!r}")
    waves = WAVES if processes == 2 else ((tuple(JOBS),),)
    # the sources the caller imports (a fresh clone's, or the installed ones)
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]))
    start, cpu = time.perf_counter(), _children_cpu()
    failed = []
    for wave in waves:
        running = [
            (
                jobs,
                subprocess.Popen(
                    [sys.executable, "-m", "grasp_env.warm", *jobs],
                    env=env,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.PIPE,
                    text=True,
                ),
            )
            for jobs in wave
        ]
        for jobs, process in running:
            _, err = process.communicate()
            if process.returncode:  # the tests that need it will fail and show why
                last = err.strip().splitlines()[-1:] or [f"exit code {process.returncode}"]
                failed.append(f"{', '.join(jobs)}: {last[0]}")
    return Warmed(time.perf_counter() - start, _children_cpu() - cpu, failed)


def main(argv: Sequence[str]) -> None:
    """Run the named jobs in turn in this process; with none, :func:`warm` on two cores."""
    unknown = [name for name in argv if name not in JOBS]
    if unknown:
        raise SystemExit(f"grasp_env.warm: unknown jobs {unknown}; the jobs are {list(JOBS)}")
    if argv:
        for name in argv:
            JOBS[name]()
        return
    done = warm(2 if (os.cpu_count() or 1) > 1 else 1)
    cpu = f"{done.cpu_seconds:.0f} s CPU"
    print(f"numba kernels compiled or loaded in {done.seconds:.0f} s ({cpu})")
    for line in done.failed:
        print(f"  failed: {line}")
    if done.failed:
        raise SystemExit(1)


if __name__ == "__main__":
    main(sys.argv[1:])
