"""Vector environments of the ``...Mujoco-v0`` ids: the batched numpy step, then every
sub-environment's forces checked in MuJoCo in one parallel call.

``gym.make_vec("grasp_env/CubeGraspMujoco-v0", num_envs=N,
vectorization_mode="vector_entry_point")`` returns them. A step is the batched step of
:mod:`grasp_env.envs.cube_grasp.vector` (analytic termination off), then one
``mujoco.rollout`` batch over all sub-environments' poses (each sub-environment's scene keeps
its own MuJoCo model; runs of one model structure share rollout calls), and at the end of
episodes one batch of continuous rollouts (:func:`grasp_env.physics.check_trajectories`) over
the sub-environments whose episode ended. MuJoCo's verdicts do not depend on batching or
threads, so step for step these equal single environments seeded seed, seed + 1, ...
(``info["physics"]``, ``info["physics_trajectory"]`` and termination included). With
``max_episode_steps`` an episode it cuts also gets its ``info["physics_trajectory"]``, which a
single environment in Gymnasium's ``TimeLimit`` cannot give (the wrapper truncates it from
outside).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

from ..validation import DEFAULT_K_MAX_RATIO, check_bool, check_mujoco_k_max_ratio
from .env import MUJOCO_DRAWS, mujoco_draws_error, physics_info
from .episodes import Episode
from .scenes import SceneBatch, check_mujoco_scene, mujoco_fits, pose_arrays
from .vector import _OPTION, CubeGraspRandomVectorEnv, CubeGraspVectorEnv, _CubeGraspVectorEnv


def trajectory_rotations(scenes: SceneBatch, index: np.ndarray) -> list[np.ndarray]:
    """The rotations (T, 3, 3) of trajectories ``index`` of ``scenes``, by the kernel that
    builds the episodes (so bit for bit the single environment's; the vector env's store
    keeps no rotations)."""
    rotations = pose_arrays(scenes, index)["rotations"]
    return np.split(rotations, np.cumsum(scenes.length[index])[:-1])


class _MujocoVectorEnv(_CubeGraspVectorEnv):
    """N grasp environments checked in MuJoCo; see the single environment with
    ``physics="mujoco"`` for spaces, reward, termination and info.

    Args:
        num_envs: number of sub-environments.
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (default), ``AutoresetMode.SAME_STEP``
            (the ended episodes' last info, ``physics_trajectory`` included, is in
            ``info["final_info"]``) or ``AutoresetMode.DISABLED`` (episodes never reset by
            themselves: reset the ended ones with ``reset(options={"reset_mask": mask})``;
            stepping one that ended raises a RuntimeError).
        physics: "mujoco" (the only engine; the registered ids pass it).
        terminate_on_slip: end an episode when MuJoCo's pose check finds that the grip does
            not hold (the single environment's).
        max_episode_steps: None (the default) or an integer >= 1: each sub-environment's
            episode is truncated after that many steps, as Gymnasium's ``TimeLimit``
            truncates a single environment's (``gym.make_vec(id, ..., max_episode_steps=k)``
            passes it). Unlike a ``TimeLimit`` around the single environment, which truncates
            it from outside, a cut episode gets its ``physics_trajectory`` at that step: the
            rollout of the steps it took.
        **kwargs: the single environment's keywords (``render_mode`` is not supported).

    The info is a dict of arrays with Gymnasium's ``_key`` masks, as the numpy vector env's;
    ``info["physics"]`` is a dict of arrays (N,) or (N, n) (``holds``, ``slip``,
    ``contact_lost``, ``released``, ``drift``, ``rotation_deg``, ``time``) with its own masks
    (with ``SAME_STEP`` the pose checks of the episodes that ended are in
    ``info["final_info"]["physics"]``, masked for those alone, as ``SyncVectorEnv`` has them),
    and ``info["physics_trajectory"]`` (the sub-environments whose episode ended at this step:
    terminated, at its trajectory's end or cut by ``max_episode_steps``) a dict in the layout
    Gymnasium's ``SyncVectorEnv`` gives: per-pose lists in object arrays.

    ``reset(options={"reset_mask": mask, ...})`` resets only the sub-environments where
    ``mask`` is True (as the numpy vector env's); their MuJoCo checkers and the grips of their
    rollouts start afresh, the others' carry on.

    Scenes are refused, and random ones drawn again, as the single environment's: where a grip
    in the action box would press a finger harder than the MuJoCo contact carries.
    """

    def __init__(
        self,
        num_envs: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        physics: str | None = "mujoco",
        terminate_on_slip: bool = True,
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        if physics != "mujoco":
            raise ValueError(f'physics must be "mujoco" for this vector env, got {physics!r}')
        check_mujoco_k_max_ratio(kwargs.get("k_max_ratio", DEFAULT_K_MAX_RATIO))
        terminate = check_bool("terminate_on_slip", terminate_on_slip)
        # The batched step runs without analytic termination: MuJoCo's verdict terminates.
        super().__init__(
            num_envs, autoreset_mode, max_episode_steps, terminate_on_slip=False, **kwargs
        )
        self.terminate_on_slip = terminate
        # Per sub-environment: its episode's rotations, its MuJoCo checker (its own for a drawn
        # scene, shared for the default scene and a scene option) and the forces of its steps.
        self._rotations: list[np.ndarray | None] = [None] * self.num_envs
        self._checkers: list[Any] = [None] * self.num_envs
        self._own = np.zeros(self.num_envs, bool)
        self._default_checker: Any = None
        # The checkers of scene options' episodes, by id(episode): (episode, checker).
        self._option_checkers: dict[int, tuple[Episode, Any]] = {}
        self._grips: list[list[np.ndarray]] = [[] for _ in range(self.num_envs)]
        if self._store.default is not None:  # a fixed scene, refused as the single env's
            check_mujoco_scene("scene", self._store.default.scenes, self.template.k_max_ratio)

    # -- episodes ------------------------------------------------------------------------------

    def _shared_checker(self, episode: Episode) -> Any:
        """The checker of a shared episode: the default scene's (kept) or a scene option's
        (kept while its episode is in the store: sub-environments a masked reset left out may
        still run an earlier option's)."""
        from ...physics import StabilityChecker

        if episode is self._store.default:
            if self._default_checker is None:
                self._default_checker = StabilityChecker(episode.scene)
            return self._default_checker
        stored = {id(e) for e in self._store.shared[_OPTION:]}
        for key in [key for key in self._option_checkers if key not in stored]:
            self._option_checkers.pop(key)[1].close()  # no sub-environment runs its episode
        if id(episode) not in self._option_checkers:
            self._option_checkers[id(episode)] = (episode, StabilityChecker(episode.scene))
        return self._option_checkers[id(episode)][1]

    def _check_open(self) -> None:
        if self.closed:  # its MuJoCo checkers are freed
            raise RuntimeError(f"this {type(self).__name__} is closed: make a new one")

    def _scene_option(self, options: Mapping[str, Any] | None) -> SceneBatch | None:
        # Checked by reset() before it seeds anything: a refused reset changes nothing.
        self._check_open()
        scene = super()._scene_option(options)
        if scene is not None:  # refused as the single env refuses it
            check_mujoco_scene("reset option 'scene'", scene, self.template.k_max_ratio)
        return scene

    def _start(self, envs: np.ndarray, scene: SceneBatch | None) -> None:
        self._check_open()
        super()._start(envs, scene)
        if len(envs) == 0:
            return
        from ...physics import StabilityChecker

        for e in envs:
            if self._own[e]:
                self._checkers[e].close()
            self._own[e] = False
            self._grips[e] = []
        if self._scenes[envs[0]] is None:  # a shared episode, the same for all of envs
            episode = self._store.option if scene is not None else self._store.default
            checker = self._shared_checker(episode)
            for e in envs:
                self._rotations[e] = episode.rotations
                self._checkers[e] = checker
            return
        self._redraw(envs)
        for batch, members, index in self._drawn(envs):
            for e, j, rotations in zip(
                members, index, trajectory_rotations(batch, index), strict=True
            ):
                self._rotations[e] = rotations
                self._checkers[e] = StabilityChecker(batch.scene(int(j)))
                self._own[e] = True

    def _drawn(self, envs: np.ndarray) -> list[tuple[SceneBatch, np.ndarray, np.ndarray]]:
        """Sub-environments ``envs`` (drawn scenes) by the batch their scenes were drawn in:
        (batch, its sub-environments, their scenes' indices in it)."""
        groups: dict[int, list[int]] = {}
        for e in envs:
            groups.setdefault(id(self._scenes[e][0]), []).append(int(e))
        return [
            (
                self._scenes[members[0]][0],
                np.array(members),
                np.array([self._scenes[e][1] for e in members]),
            )
            for members in groups.values()
        ]

    def _overloaded(self, envs: np.ndarray) -> np.ndarray:
        """Those of ``envs`` (drawn scenes) whose scene the MuJoCo contact cannot carry under
        every grip in the action box."""
        k_max_ratio = self.template.k_max_ratio
        return np.concatenate(
            [
                members[~mujoco_fits(batch.take(index), k_max_ratio)]
                for batch, members, index in self._drawn(envs)
            ]
        )

    def _redraw(self, envs: np.ndarray) -> None:
        """Draw the overloaded scenes of ``envs`` again, each from its own generator, as the
        single environment does (at most :data:`MUJOCO_DRAWS` draws in all)."""
        for _ in range(MUJOCO_DRAWS - 1):  # the first draw is done
            envs = self._overloaded(envs)
            if len(envs) == 0:
                return
            super()._start(envs, None)
        if len(self._overloaded(envs)):
            raise mujoco_draws_error(self.template.k_max_ratio)

    # -- stepping ------------------------------------------------------------------------------

    def _check_poses(self, envs: np.ndarray, poses: np.ndarray, forces: np.ndarray) -> list:
        """MuJoCo pose checks of sub-environments ``envs`` at their poses, in one parallel
        batch over all their models: what each one's ``StabilityChecker.check`` computes, the
        poses of one checker planned together."""
        from ...physics.motion import plan_poses
        from ...physics.simulation import simulate
        from ...physics.stability import pose_report

        groups: dict[int, list[int]] = {}
        for j, e in enumerate(envs):
            groups.setdefault(id(self._checkers[e]), []).append(j)
        runs: list[tuple[Any, Any]] = [(None, None)] * len(envs)
        for members in groups.values():
            checker = self._checkers[envs[members[0]]]
            rotations = np.stack([self._rotations[envs[j]][poses[j]] for j in members])
            motions = plan_poses(
                checker.scene, rotations, forces[members], None, checker.settings, checked=True
            )
            for j, motion in zip(members, motions, strict=True):
                runs[j] = (checker, motion)
        traces = simulate([(checker.physics, motion) for checker, motion in runs])
        return [
            pose_report(checker.scene, motion, trace, checker.settings)
            for (checker, motion), trace in zip(runs, traces, strict=True)
        ]

    def _check_trajectories(self, envs: np.ndarray) -> list:
        from ...physics import check_trajectories

        cases = []
        for e in envs:
            grips = np.stack(self._grips[e])
            cases.append((self._checkers[e].scene, self._rotations[e][: len(grips)], grips, None))
        return check_trajectories(cases)

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every sub-environment, then check their forces in MuJoCo (see the class)."""
        self._check_open()
        self._refuse_ended()  # before the batched step below, which runs as NEXT_STEP
        mode, terminate = self.autoreset_mode, self.terminate_on_slip
        # The batched step, as NEXT_STEP without termination: the resets wait for MuJoCo.
        self.autoreset_mode, self.terminate_on_slip = AutoresetMode.NEXT_STEP, False
        try:
            observations, reward, _, truncated, info = super().step(actions)
        finally:
            self.autoreset_mode, self.terminate_on_slip = mode, terminate
        active = info["_alpha_deg"]
        data = {key: value for key, value in info.items() if not key.startswith("_")}
        count = self.num_envs
        acting = np.flatnonzero(active)
        poses = self._t[acting] - 1
        forces = data["contact_forces"][acting]
        reports = self._check_poses(acting, poses, forces)
        checks = {int(e): physics_info(r.as_dict()) for e, r in zip(acting, reports, strict=True)}
        holds = np.ones(count, bool)
        for e, f, report in zip(acting, forces, reports, strict=True):
            holds[e] = report.holds
            self._grips[e].append(f.copy())
        terminated = ~holds if terminate else np.zeros(count, bool)
        done = terminated | truncated
        ended = np.flatnonzero(done)
        trajectories = self._gather(
            zip(ended, (r.as_dict() for r in self._check_trajectories(ended)), strict=True)
        )
        if mode == AutoresetMode.SAME_STEP:
            # As SyncVectorEnv: an ended episode's pose check goes to final_info, a running
            # one's to info, each dict with masks of its own.
            self._autoreset[:] = False
            data["physics"] = self._gather((e, checks[e]) for e in np.flatnonzero(active & ~done))
            info = {**data, **{f"_{key}": active & ~done for key in data}}
            if ended.size:
                final_obs = np.full(count, None, dtype=object)
                final_obs[ended] = list(observations[ended])
                final = {
                    **data,
                    "physics": self._gather((e, checks[e]) for e in ended),
                    "physics_trajectory": trajectories,
                }
                final_info = {**final, **{f"_{key}": done for key in final}}
                observations[ended] = self._restart(ended)
                info.update(
                    final_obs=final_obs, _final_obs=done, final_info=final_info, _final_info=done
                )
        else:  # NEXT_STEP resets the ended episodes at the next step, DISABLED never
            self._autoreset = done
            data["physics"] = self._gather(checks.items())
            info = {**data, **{f"_{key}": active for key in data}}
            if ended.size:
                info.update(physics_trajectory=trajectories, _physics_trajectory=done)
        return observations, reward, terminated, truncated, info

    def _gather(self, infos: Iterable[tuple[int, dict[str, Any]]]) -> dict[str, Any]:
        """Sub-environments' info dicts gathered as SyncVectorEnv gathers them (Gymnasium's
        ``_add_info``): arrays whose masks, nested ones too, are set for these alone."""
        gathered: dict[str, Any] = {}
        for e, info in infos:
            gathered = self._add_info(gathered, info, int(e))
        return gathered

    def close_extras(self, **kwargs: Any) -> None:
        own = [c for c, mine in zip(self._checkers, self._own, strict=True) if mine]
        options = [checker for _, checker in self._option_checkers.values()]
        for checker in [*own, self._default_checker, *options]:
            if checker is not None:
                checker.close()
        self._checkers = [None] * self.num_envs
        self._own[:] = False
        self._default_checker, self._option_checkers = None, {}
        super().close_extras(**kwargs)


class CubeGraspMujocoVectorEnv(_MujocoVectorEnv, CubeGraspVectorEnv):
    __doc__ = "Batched `grasp_env/CubeGraspMujoco-v0` (and `CubeGrasp4Mujoco-v0`).\n\n    " + (
        _MujocoVectorEnv.__doc__ or ""
    )


class CubeGraspRandomMujocoVectorEnv(_MujocoVectorEnv, CubeGraspRandomVectorEnv):
    __doc__ = "Batched `grasp_env/CubeGraspRandomMujoco-v0`.\n\n    " + (
        _MujocoVectorEnv.__doc__ or ""
    )


__all__ = ["CubeGraspMujocoVectorEnv", "CubeGraspRandomMujocoVectorEnv", "trajectory_rotations"]
