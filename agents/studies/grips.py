"""The grips that ``grasp-env verify`` checks in MuJoCo: the minimax expert's, the paper's equal-k
grip (eq. 8) and a saved model's (read by :func:`grasp_env_agents.learning.models.load_agent`,
which runs no code from the file), driven through a Gymnasium environment along a trajectory."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from grasp_env import ENV_IDS
from grasp_env.mechanics import (
    PHI,
    Scene,
    Trajectory,
    grasp_matrix,
    load_wrench,
    n_pairs,
    scene_grasp,
    solve_minimax,
)
from grasp_env_agents.studies.trajectory_agreement import TrajectoryCase

from ..run.folder import RunFolder
from ..run.folder import model_file as named_model

#: The environments that can drive a saved model's grip (``--env``): grasp_env's but the gait
#: ones, whose hand phases fingers in and out.
MODEL_ENV_IDS = tuple(env_id for env_id in ENV_IDS if "Gait" not in env_id)
DEFAULT_MODEL_ENV = "grasp_env/CubeGrasp-v0"


def expert_forces(scene: Scene, trajectory: Trajectory) -> np.ndarray:
    """The minimax grip at every pose, k_max = 2 w as in the environments: (T, n, 3)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    return grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)


def equal_k_forces(scene: Scene, trajectory: Trajectory) -> np.ndarray:
    """The paper's symmetric grip, k_ij = w tan(phi) / (3 sqrt 3) for every pair (eq. 8)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    k = scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(n_pairs(scene.n_contacts))
    return grasp.forces(k)


def model_name(path: Path) -> str:
    """A short name for a saved model in titles: its run directory's name, or the file's."""
    path = path.resolve()
    if path.is_dir():
        return path.name
    run = RunFolder.of_model(path)
    return path.stem if run is None else run.path.name


class SavedModel(NamedTuple):
    """A saved model to verify, and the environment that drives it."""

    path: Path  # its .zip, or a training run's directory
    algo: str | None  # None: the file's policy class says
    env_id: str
    env_kwargs: dict[str, Any]  # the run's (its grip depends on them: k_max_ratio, faces)


def model_setup(path: Path, algo: str | None, env_id: str | None) -> SavedModel:
    """The saved model at ``path``, the algorithm that wrote it and the environment that
    drives it: those of the run's ``config.yaml`` (its ``env_kwargs`` too) when ``path`` is a
    ``grasp-env train`` run directory (or its model.zip), else ``algo`` and ``env_id``
    (default :data:`DEFAULT_MODEL_ENV`) with the environment's defaults. An ``algo`` that
    contradicts the run's is refused."""
    from ..learning.models import ALGORITHMS

    if algo is not None and algo not in ALGORITHMS:
        raise ValueError(f"--algo must be one of {', '.join(ALGORITHMS)}, got {algo!r}")
    path = Path(path)
    run = RunFolder(path) if path.is_dir() else RunFolder.of_model(path)
    if run is None or not run.is_run():
        return SavedModel(path, algo, check_model_env(env_id or DEFAULT_MODEL_ENV), {})
    from ..run.config import load_config

    run_dir = run.path
    config = load_config(run.config)
    if algo is not None and algo != config.algo:
        raise ValueError(
            f"--algo {algo}: the run {run_dir} was trained with algo: {config.algo} (its"
            f" config.yaml); drop --algo or give --algo {config.algo}"
        )
    trained_on = config.env_id if config.env_id in MODEL_ENV_IDS else DEFAULT_MODEL_ENV
    return SavedModel(path, config.algo, check_model_env(env_id or trained_on), config.env_kwargs)


def check_model_env(env_id: str) -> str:
    """``env_id`` if it is one of :data:`MODEL_ENV_IDS` (ValueError naming --env if not)."""
    if env_id not in MODEL_ENV_IDS:
        raise ValueError(
            f"--env must be one of {', '.join(MODEL_ENV_IDS)} (the grasp environments that can"
            f" drive a saved model), got {env_id!r}"
        )
    return env_id


def model_forces(
    model: SavedModel, scene: Scene, trajectory: Trajectory
) -> tuple[Scene, np.ndarray]:
    """A saved model's grip, stepping its environment pinned to ``scene`` and ``trajectory``.

    The model is read by :func:`grasp_env_agents.learning.models.load_agent` (no code from the file
    runs; the ``vecnormalize.pkl`` beside it, if any, normalises the observations). Returns
    the environment's scene and the contact forces it applied, (T, n, 3).
    """
    return model_grips(model, [(scene, trajectory)])[0]


def model_env(model: SavedModel) -> Any:
    """The model's environment, made with the run's ``env_kwargs``; episodes run past a slip
    (the whole trajectory is verified)."""
    import gymnasium as gym  # the RL stack only when a model is verified

    import grasp_env  # noqa: F401  (registers the environments)

    kwargs = {**model.env_kwargs, "terminate_on_slip": False}
    try:
        return gym.make(model.env_id, **kwargs)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"the run's env_kwargs {model.env_kwargs} do not make {model.env_id}: {error}"
        ) from None


def model_fingers(model: SavedModel) -> int:
    """The number of fingers of the model's environment."""
    env = model_env(model)
    env.close()
    return len(env.unwrapped.faces)


def model_grips(
    model: SavedModel, problems: list[tuple[Scene, Trajectory]]
) -> list[tuple[Scene, np.ndarray]]:
    """:func:`model_forces` on several (scene, trajectory) problems, the model loaded once."""
    path, env_id = model.path, model.env_id
    model_file = named_model(path)
    if not model_file.is_file():
        raise ValueError(
            f"--policy must be 'expert', 'equal-k' or the path of a saved model; {model_file}"
            " is not a file"
        )
    from ..learning.models import load_agent, misfit

    agent = load_agent(path, model.algo)
    env = model_env(model)
    problem = misfit(agent.model, env, env_id)
    if problem:
        env.close()
        raise ValueError(
            f"--env {env_id} does not fit the model: {problem} (give --env the environment the"
            " model was trained on)"
        )
    grips = []
    for scene, trajectory in problems:
        options: dict = {
            "weight": scene.weight,
            "mu": scene.mu,
            "cg_offset": scene.cg_offset.tolist(),
            "trajectory": {
                "axis": tuple(trajectory.axis),
                "alpha_start_deg": trajectory.alpha_start_deg,
                "alpha_end_deg": trajectory.alpha_end_deg,
                "alpha_step_deg": trajectory.alpha_step_deg,
            },
        }
        if scene.n_contacts == len(env.unwrapped.faces):
            options["contacts"] = scene.contacts.tolist()
        obs, _ = env.reset(seed=0, options={"scene": options})
        env_scene = env.unwrapped.scene
        forces, done = [], False
        while not done:
            action, _ = agent.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            forces.append(info["contact_forces"])
            done = terminated or truncated
        forces = np.array(forces)
        # The forces must balance the load at our poses: a guard against a mismatched
        # trajectory.
        if len(forces) != len(trajectory) or not _balanced(env_scene, trajectory, forces):
            env.close()
            raise ValueError(f"the environment {env_id} did not follow the verified trajectory")
        grips.append((env_scene, forces))
    env.close()
    return grips


def _balanced(scene: Scene, trajectory: Trajectory, forces: np.ndarray) -> bool:
    """Whether ``forces`` (T, n, 3) balance ``scene``'s load at every pose: G P = -(f, tau)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    wrench = load_wrench(scene.weight, scene.extra_force, scene.extra_torque)
    residual = grasp_matrix(grasp.positions) @ forces.reshape(len(forces), -1, 1)
    return bool(np.allclose(residual[..., 0], -wrench, atol=1e-6 * scene.weight))


def learned_cases(cases: list[TrajectoryCase], model: SavedModel) -> list[TrajectoryCase]:
    """A saved model's grips (kind "learned") on the scenes and trajectories of the study's
    expert cases whose number of fingers is the model environment's (:func:`model_grips`)."""
    fingers = model_fingers(model)
    experts = [
        c for c in cases
        if c.kind == "expert" and c.trajectory is not None and c.scene.n_contacts == fingers
    ]  # fmt: skip
    if not experts:
        raise ValueError(
            f"--policy: no scene of the study has the model's {fingers} fingers (the scenes"
            " alternate three and four fingers, and skip a few): give more --scenes"
        )
    grips = model_grips(model, [(c.scene, c.trajectory) for c in experts])
    return [
        TrajectoryCase("learned", scene, c.alphas_deg, c.rotations, forces, None, c.trajectory)
        for c, (scene, forces) in zip(experts, grips, strict=True)
    ]
