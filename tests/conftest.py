"""Test session set-up.

Hypothesis draws the same examples on every run, so a test run (and CI) is reproducible;
``HYPOTHESIS_PROFILE=explore pytest`` draws new ones, to search further.

The numba kernels compile once, before the xdist workers start: each worker would otherwise
compile the minimax solver on its own, side by side, into an empty cache (about 100 s of CPU
for each of its two entry points, ``driver.solve_batch`` and ``driver.solve_grasp``, each of
one signature, for any number of fingers). :func:`pytest_configure` runs on the controller
only, in two rounds of two processes (the machine's two cores): the entry points, then the
environments' and the MuJoCo check's kernels through one reset and step of each environment
that ``pytest -m fast`` makes, and the conic solver of five or more contacts. The workers then
load it all from numba's cache (next to the sources, or ``NUMBA_CACHE_DIR``); a warm cache
costs the rounds about 2 s each. A run in one process (``-p no:xdist`` or ``-n 0``) compiles
as it goes, what its tests need only.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import settings

settings.register_profile("reproducible", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))

#: The warm-up rounds: each round's programs run side by side; a round starts when the one
#: before it has finished (the environments' episodes call the solver's batch entry point,
#: which the first round compiled).
_SOLVE = """
import numpy as np
from grasp_env.mechanics import (
    FOUR_FINGER_FACES, PAPER_AXIS, PAPER_FACES, Scene, pose_rotation, scene_grasp, solve_minimax,
)
rotations = np.stack([pose_rotation(PAPER_AXIS, np.radians(a)) for a in (-15.0, 0.0, 15.0)])
for faces in (PAPER_FACES, FOUR_FINGER_FACES):  # three and four fingers: one signature
    scene = Scene.on_faces(faces)
    solve_minimax(scene_grasp(scene, rotations{index}), 2.0 * scene.weight)
"""
_CONIC = """
from grasp_env.mechanics import Scene, scene_grasp, solve_minimax
from grasp_env.mechanics.objects import Cylinder
can = Cylinder(radius=0.033, height=0.115)
fingers = [can.side_point(a, h) for a, h in ((0, 0.3), (1.3, -0.2), (2.5, 0.1), (3.8, -0.3))]
fingers.append(can.cap_point("+z", (0.2, 0.1)))
scene = Scene(shape=can, contacts=fingers, weight=3.4)
solve_minimax(scene_grasp(scene, [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]), 6.8)  # five: conic
"""
_STEP = """
import gymnasium as gym
import numpy as np
import grasp_env
for env_id in {ids!r}:  # float32 actions (the action space's) and float64 ones (the expert's)
    env = gym.make(env_id)
    envs = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    for dtype in (np.float32, np.float64):
        env.reset(seed=0)
        env.step(env.action_space.sample().astype(dtype))
        envs.reset(seed=0)
        envs.step(envs.action_space.sample().astype(dtype))
    env.close()
    envs.close()
grasp_env.MinimaxExpert().predict(env.reset(seed=0)[0])  # the expert reads observations
"""
_ROUNDS = (
    {"solve_batch": _SOLVE.format(index=""), "solve_grasp": _SOLVE.format(index="[0]")},
    {
        "environments": _STEP.format(
            ids=[
                "grasp_env/CubeGrasp-v0",
                "grasp_env/CubeGraspRandom-v0",
                "grasp_env/CubeGrasp4-v0",
            ]
        ),
        "MuJoCo environment": _STEP.format(ids=["grasp_env/CubeGraspMujoco-v0"]),
        "conic solver": _CONIC,
    },
)


#: (seconds, failures) of the warm-up, for the report header
_WARMED = pytest.StashKey[tuple[float, list[str]]]()


def _warm_numba_cache() -> tuple[float, list[str]]:
    """Run the warm-up rounds; return the seconds and a line for each program that failed."""
    spec = importlib.util.find_spec("grasp_env")
    if spec is None or spec.origin is None:
        return 0.0, ["grasp_env is not importable"]
    # the sources the workers import (a fresh clone's, or the installed ones)
    prelude = f"import sys; sys.path.insert(0, {str(Path(spec.origin).parents[1])!r})\n"
    start = time.perf_counter()
    failed = []
    for programs in _ROUNDS:
        running = {
            name: subprocess.Popen(
                [sys.executable, "-c", prelude + program],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            )
            for name, program in programs.items()
        }
        for name, process in running.items():
            _, err = process.communicate()
            if process.returncode:  # the tests that need it will fail and show why
                last = err.strip().splitlines()[-1:] or [f"exit code {process.returncode}"]
                failed.append(f"{name}: {last[0]}")
    return time.perf_counter() - start, failed


def pytest_configure(config: pytest.Config) -> None:
    distributed = getattr(config.option, "dist", "no") != "no"
    workers = getattr(config.option, "numprocesses", None) or 0
    if hasattr(config, "workerinput") or not distributed or workers < 2:
        return
    if config.option.collectonly:
        return
    seconds, failed = _warm_numba_cache()
    config.stash[_WARMED] = (seconds, failed)


def pytest_report_header(config: pytest.Config) -> list[str]:
    if _WARMED not in config.stash:
        return []
    seconds, failed = config.stash[_WARMED]
    lines = [f"numba kernels compiled or loaded for the workers in {seconds:.0f} s"]
    return lines + [f"  numba warm-up failed: {line}" for line in failed]


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """``pytest -m fast`` does not import the test files that mark no test ``fast`` (collecting
    them, which imports torch, SB3 and Ray, took each worker about 6 s of CPU)."""
    if config.option.markexpr != "fast" or not collection_path.name.startswith("test_"):
        return None
    if collection_path.suffix != ".py" or "mark.fast" in collection_path.read_text():
        return None
    return True


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_a_test_folder(tmp_path_factory):
    """SB3 models made without a log folder would each leave an empty folder in /tmp."""
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))
