"""``grasp-env verify``: check grip forces in MuJoCo physics.

Along a trajectory (the default): a policy chooses the grip at every pose of the paper's
trajectory, MuJoCo simulates it, and the table compares the analytic verdict (max friction
angle within atan(mu)) with MuJoCo's (no finger slides more than 0.1 mm in a 0.5 s hold).
Policies: ``expert`` (the minimax optimum over |k_ij| <= 2 w, the default), ``equal-k`` (the
paper's symmetric grip k_ij = w tan(phi) / (3 sqrt 3) for every pair, eq. 8) or the path of a
saved Stable-Baselines3 PPO model, driven through a Gymnasium environment. Writes
``verify.png``.

With ``--agreement``: the agreement study of ``grasp_env.physics.agreement`` (force sets from 0
to 40 deg max friction angle and within 0.01 to 1 deg of the cone's edge, mu = tan 10, 20 and
30 deg, several poses and contact layouts): the confusion matrix, the runtime, and a last line
with the overall agreement and the agreement at >= 0.05 deg from the edge. Writes
``agreement.png``. Exits with 1 if any set at >= 0.05 deg from the edge disagrees.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from grasp_env.mechanics import (
    PAPER_FACES,
    PHI,
    Scene,
    Trajectory,
    friction_angles,
    grasp_matrix,
    load_wrench,
    n_pairs,
    scene_grasp,
    solve_minimax,
)
from grasp_env.physics import SETTINGS, PhysicsReport, StabilityChecker
from grasp_env.physics.agreement import (
    EDGE_OFFSETS_DEG,
    FAR_FROM_EDGE_DEG,
    agreement_sets,
    check_sets,
    summarise,
)

from .scene_args import add_scene_arguments, scene_from_arguments

HELP = "check grip forces in MuJoCo physics along a trajectory (or --agreement)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--policy",
        default="expert",
        metavar="expert|equal-k|PATH",
        help="the grip: the minimax expert (default), the paper's equal-k grip, or a saved"
        " SB3 PPO model (a .zip, or a `grasp-env train` run directory)",
    )
    parser.add_argument(
        "--env",
        default="grasp_env/CubeGrasp-v0",
        help="environment that drives a saved model (default grasp_env/CubeGrasp-v0)",
    )
    add_scene_arguments(parser)
    parser.add_argument(
        "--agreement", action="store_true", help="run the analytic-vs-MuJoCo agreement study"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the agreement study")
    parser.add_argument("--out", type=Path, default=Path("results/verify"), help="output dir")


def run(args: argparse.Namespace) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    if args.agreement:
        return run_agreement(args.seed, args.out)
    scene = scene_from_arguments(args)
    trajectory = Trajectory()
    if args.policy == "expert":
        forces = expert_forces(scene, trajectory)
    elif args.policy == "equal-k":
        forces = equal_k_forces(scene, trajectory)
    else:
        scene, forces = model_forces(Path(args.policy), args.env, scene, trajectory)
    return run_trajectory(scene, trajectory, forces, args.policy, args.out)


# ------------------------------------------------------------------------------ the policies


def expert_forces(scene: Scene, trajectory: Trajectory) -> np.ndarray:
    """The minimax grip at every pose, k_max = 2 w as in the environments: (T, n, 3)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    return grasp.forces(solve_minimax(grasp, 2 * scene.weight).k)


def equal_k_forces(scene: Scene, trajectory: Trajectory) -> np.ndarray:
    """The paper's symmetric grip, k_ij = w tan(phi) / (3 sqrt 3) for every pair (eq. 8)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    k = scene.weight * np.tan(PHI) / (3 * np.sqrt(3)) * np.ones(n_pairs(scene.n_contacts))
    return grasp.forces(k)


def model_forces(
    path: Path, env_id: str, scene: Scene, trajectory: Trajectory
) -> tuple[Scene, np.ndarray]:
    """A saved PPO model's grip, stepping ``env_id`` pinned to ``scene`` and ``trajectory``.

    ``path`` is the model's .zip or a training run's directory (holding ``model.zip``).
    Observations are normalised with ``vecnormalize.pkl`` from the model's folder when it
    exists (SB3's VecNormalize statistics). Returns the environment's scene and the contact
    forces it applied, (T, n, 3).
    """
    if path.is_dir():
        path = path / "model.zip"
    if not path.is_file():
        raise ValueError(
            f"--policy must be 'expert', 'equal-k' or the path of a saved model; {path} is"
            " not a file"
        )
    import gymnasium as gym  # the RL stack only when a model is verified
    from stable_baselines3 import PPO

    import grasp_env  # noqa: F401  (registers the environments)

    env = gym.make(env_id, terminate_on_slip=False)
    model = PPO.load(path, device="cpu")
    normalise = _obs_normaliser(path.parent / "vecnormalize.pkl", env)
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
    if env.unwrapped.faces == PAPER_FACES:
        options["contacts"] = scene.contacts.tolist()
    obs, _ = env.reset(seed=0, options={"scene": options})
    env_scene = env.unwrapped.scene
    forces, done = [], False
    while not done:
        action, _ = model.predict(normalise(obs), deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        forces.append(info["contact_forces"])
        done = terminated or truncated
    env.close()
    forces = np.array(forces)
    # The forces must balance the load at our poses: a guard against a mismatched trajectory.
    if len(forces) != len(trajectory) or not _balanced(env_scene, trajectory, forces):
        raise ValueError(f"the environment {env_id} did not follow the verified trajectory")
    return env_scene, forces


def _balanced(scene: Scene, trajectory: Trajectory, forces: np.ndarray) -> bool:
    """Whether ``forces`` (T, n, 3) balance ``scene``'s load at every pose: G P = -(f, tau)."""
    grasp = scene_grasp(scene, trajectory.rotations())
    wrench = load_wrench(scene.weight, scene.extra_force, scene.extra_torque)
    residual = grasp_matrix(grasp.positions) @ forces.reshape(len(forces), -1, 1)
    return bool(np.allclose(residual[..., 0], -wrench, atol=1e-6 * scene.weight))


def _obs_normaliser(stats: Path, env):
    if not stats.is_file():
        return lambda obs: obs
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    vec = VecNormalize.load(str(stats), DummyVecEnv([lambda: env]))
    vec.training = False
    return vec.normalize_obs


# ------------------------------------------------------------------------------ the trajectory


def run_trajectory(
    scene: Scene, trajectory: Trajectory, forces: np.ndarray, policy: str, out: Path
) -> int:
    """Check every pose in MuJoCo; print the table; save the plot."""
    from rich.console import Console
    from rich.table import Table

    rotations = trajectory.rotations()
    normals = scene.normals @ np.swapaxes(rotations, -1, -2)
    angles = np.degrees(friction_angles(forces, normals).max(axis=-1))
    limit = float(np.degrees(scene.friction_limit))
    checker = StabilityChecker(scene)
    start = time.perf_counter()
    reports = [checker.check(r, f) for r, f in zip(rotations, forces, strict=True)]
    elapsed = time.perf_counter() - start
    checker.close()

    table = Table(title=f"MuJoCo check of the {policy} grip (limit atan(mu) = {limit:.2f} deg)")
    for column in ("alpha deg", "max theta deg", "predicted", "MuJoCo", "slip um", "drift um"):
        table.add_column(column, justify="right")
    verdict = {True: "[green]holds[/]", False: "[red]slips[/]"}
    for alpha, angle, report in zip(trajectory.alphas_deg, angles, reports, strict=True):
        table.add_row(
            f"{alpha:+.1f}",
            f"{angle:.3f}",
            verdict[bool(angle <= limit)],
            verdict[report.holds],
            f"{1e6 * report.slip.max():.3f}",
            f"{1e6 * report.drift:.3f}",
        )
    console = Console()
    console.print(table)
    held = sum(r.holds for r in reports)
    agree = sum(r.holds == (a <= limit) for r, a in zip(reports, angles, strict=True))
    path = out / "verify.png"
    _plot_trajectory(trajectory.alphas_deg, angles, limit, reports, policy, path)
    console.print(
        f"MuJoCo: holds at {held}/{len(reports)} poses; analytic and MuJoCo agree at"
        f" {agree}/{len(reports)}; {1e3 * elapsed / len(reports):.1f} ms per check; plot {path}"
    )
    return 0


def _plot_trajectory(alphas, angles, limit, reports: list[PhysicsReport], policy, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    holds = np.array([r.holds for r in reports])
    slip = np.array([max(r.slip.max(), 1e-12) for r in reports])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    top.plot(alphas, angles, "-", color="0.5", label="max friction angle (analytic)")
    top.axhline(limit, color="k", ls="--", lw=1, label="atan(mu)")
    top.scatter(alphas[holds], angles[holds], c="tab:green", zorder=3, label="MuJoCo: holds")
    top.scatter(alphas[~holds], angles[~holds], c="tab:red", marker="x", zorder=3,
                label="MuJoCo: slips")  # fmt: skip
    top.set_ylabel("max theta_i, deg")
    top.set_title(f"{policy} grip along the trajectory")
    top.legend(fontsize=8)
    bottom.semilogy(alphas, 1e3 * slip, "o-", ms=3)
    bottom.axhline(1e3 * SETTINGS["slip_threshold"], color="k", ls="--", lw=1, label="threshold")
    bottom.legend(fontsize=8)
    bottom.set_xlabel("alpha, deg")
    bottom.set_ylabel("max slip in MuJoCo, mm")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------------------ the agreement


def run_agreement(seed: int, out: Path) -> int:
    """The agreement study: confusion matrix, runtime and the one-line summary."""
    from rich.console import Console
    from rich.table import Table
    from tqdm import tqdm

    console = Console()
    start = time.perf_counter()
    sets = agreement_sets(seed)
    generated = time.perf_counter()
    reports = check_sets(sets, progress=lambda s: tqdm(s, desc="MuJoCo checks", unit="set"))
    checked = time.perf_counter()
    result = summarise(sets, np.array([r.holds for r in reports]))

    table = Table(title="analytic (rows) vs MuJoCo (columns)")
    table.add_column("")
    table.add_column("MuJoCo holds", justify="right")
    table.add_column("MuJoCo slips", justify="right")
    for label, row in zip(("analytic holds", "analytic slips"), result.confusion, strict=True):
        table.add_row(label, *(str(int(v)) for v in row))
    console.print(table)
    distance = np.array([s.edge_distance_deg for s in sets])
    predicted = np.array([s.predicted_holds for s in sets])
    observed = np.array([r.holds for r in reports])
    bands = Table(title="agreement by distance from the cone's edge")
    for column in ("distance, deg", "sets", "agree"):
        bands.add_column(column, justify="right")
    bands_deg = {
        f"{min(EDGE_OFFSETS_DEG)} to {FAR_FROM_EDGE_DEG}": distance < FAR_FROM_EDGE_DEG,
        f"{FAR_FROM_EDGE_DEG} to 1": (distance >= FAR_FROM_EDGE_DEG) & (distance <= 1.0 + 1e-9),
        "over 1": distance > 1.0 + 1e-9,
    }
    for label, band in bands_deg.items():
        agree = int(np.sum(predicted[band] == observed[band]))
        bands.add_row(label, str(int(band.sum())), str(agree))
    console.print(bands)
    path = out / "agreement.png"
    _plot_agreement(sets, reports, path)
    console.print(
        f"runtime: {checked - start:.1f} s ({generated - start:.1f} s generating {len(sets)}"
        f" force sets, {checked - generated:.1f} s in MuJoCo,"
        f" {1e3 * (checked - generated) / len(sets):.1f} ms per check); plot {path}"
    )
    print(result.line())
    return 0 if result.far == 1.0 else 1


def _plot_agreement(sets, reports: list[PhysicsReport], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    excess = np.array([s.max_angle_deg - s.limit_deg for s in sets])
    slip = np.array([max(r.slip.max(), 1e-12) for r in reports])
    holds = np.array([r.holds for r in reports])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.scatter(excess[holds], 1e3 * slip[holds], s=6, c="tab:green", label="MuJoCo: holds")
    ax.scatter(excess[~holds], 1e3 * slip[~holds], s=6, c="tab:red", label="MuJoCo: slips")
    ax.set_xscale("symlog", linthresh=0.01)
    ax.set_yscale("log")
    ax.axvline(0.0, color="k", lw=1)
    ax.set_xlabel("max friction angle - atan(mu), deg")
    ax.set_ylabel("max slip, mm")
    ax.set_title("analytic friction cone vs MuJoCo")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
