"""Batched numpy vector environments: N grasps stepped by one compiled kernel call.

``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` returns them. Step for
step they equal N single environments reset with the seeds seed, seed + 1, ..., seed + N - 1:
each sub-environment has its own generator and the single and vector environments share the
per-episode precomputation and the step kernel.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from numbers import Integral
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ...mechanics import Scene, contact_pairs
from ...mechanics.threads import available_cores, in_parts
from ..kernels import PARALLEL_FROM, step_batch
from ..validation import (
    MAX_ENVS,
    action_array,
    check_autoreset_mode,
    check_integer,
    check_max_episode_steps,
    check_seed,
    end_step,
    refuse_ended,
    split_reset_mask,
)
from .env import CubeGraspEnv, CubeGraspRandomEnv, _CubeGraspEnv
from .episodes import Episode, EpisodeBatch, build_episodes, sample_episodes
from .scenes import SceneBatch

_STORED = (  # in step_batch's order
    "forces_w", "directions", "normals", "observations", "alphas", "expert_k_w", "expert_reward",
)  # fmt: skip
#: The most pose rows the store of a vector environment may hold (about 3 GB with three
#: fingers, 4.6 GB with four): num_envs x (longest trajectory + 1) for random scenes.
MAX_STORE_ROWS = 1 << 23
#: Random episodes are drawn for at most this many sub-environments at a time (each draws from
#: its own generator, so the episodes do not depend on it): it bounds the memory a reset of
#: many sub-environments needs besides the store.
_RESET_CHUNK = 8192
#: Random episodes are drawn ahead for at most this many sub-environments (see
#: ``_CubeGraspVectorEnv._draw_ahead``): it bounds the memory of the episodes held ahead.
_AHEAD_ENVS = 8192
# Where a sub-environment's episode lives in the store: a shared episode (its index in
# _PoseStore.shared: the default episode, the latest scene option's, then earlier options' still
# run by sub-environments a masked reset left alone) or its own slot.
_DEFAULT, _OPTION, _SLOT = 0, 1, -1
_NO_CUT = np.iinfo(np.int64).max  # no max_episode_steps


def _step_parts(
    stored: tuple[np.ndarray, ...],
    rows: np.ndarray,
    actions: np.ndarray,
    k_max_ratio: float,
    per_env: tuple[np.ndarray, ...],
    outputs: tuple[np.ndarray, ...],
) -> None:
    """:func:`step_batch` over contiguous parts of the batch, one a thread (the caller's the
    first): ``stored`` the store's arrays and the pairs, ``per_env`` the weights and limits,
    ``outputs`` step_batch's."""

    def part(lo: int, hi: int) -> None:
        step_batch(
            *stored, rows[lo:hi], actions[lo:hi], k_max_ratio,
            *(x[lo:hi] for x in per_env), *(out[lo:hi] for out in outputs),
        )  # fmt: skip

    count = len(rows)
    in_parts("grasp-vector-step", count, part, available_cores() if count >= PARALLEL_FROM else 1)


def _padded(episode: Episode) -> dict[str, np.ndarray]:
    """An episode's stored arrays, padded to T + 1 rows like its observations (the last pose
    repeated)."""
    return {
        name: value if name == "observations" else np.concatenate([value, value[-1:]])
        for name in _STORED
        for value in [getattr(episode, name)]
    }


class _PoseStore:
    """The pose arrays of every running episode, stacked so that one kernel call serves all.

    The rows begin with the shared episodes (each stored once, whatever the number of
    sub-environments in it): ``shared[0]`` the environment's default episode (None for random
    scenes), ``shared[1]`` the episode of the last ``reset(options={"scene": ...})``, then the
    episodes of earlier scene options that sub-environments left out of a masked reset still
    run. After them each sub-environment owns a slot of ``capacity`` rows for episodes of its
    own (the slots grow, and move, when a longer episode comes). Row ``base + t`` holds pose t
    of an episode and its observation t (T + 1 observations).
    """

    def __init__(self, num_envs: int, default: Episode | None) -> None:
        self.num_envs = num_envs
        self.shared: list[Episode | None] = [default, None]
        self.capacity = 0
        self.arrays: dict[str, np.ndarray] = {}
        self.shared_bases = np.zeros(3, dtype=np.int64)  # per shared episode, then the slots
        self._lay_out(keep_slots=False)

    @property
    def default(self) -> Episode | None:
        return self.shared[_DEFAULT]

    @property
    def option(self) -> Episode | None:
        return self.shared[_OPTION]

    def _lay_out(self, keep_slots: bool) -> None:
        """Lay out the shared episodes, followed by the slots as they are (``keep_slots``) or
        none (no sub-environment runs an episode of its own)."""
        parts = [_padded(e) for e in self.shared if e is not None]
        sizes = [len(e) + 1 if e is not None else 0 for e in self.shared]
        slots = (
            {name: array[self.offset :] for name, array in self.arrays.items()}
            if keep_slots and self.capacity
            else {}
        )
        names = _STORED if parts else list(slots)
        self.arrays = {
            name: np.concatenate([*(p[name] for p in parts), *([slots[name]] if slots else [])])
            for name in names
        }
        if not slots:
            self.capacity = 0
        self.shared_bases = np.cumsum([0, *sizes])

    def share_option(self, episode: Episode, kept: np.ndarray) -> np.ndarray:
        """Store ``episode`` as the latest scene option's; ``kept`` are the store codes
        (``_where``) of the sub-environments that keep their episodes, returned as they are
        after the new layout (the options none of them runs are dropped)."""
        running = sorted({int(c) for c in kept if c >= _OPTION})
        recode = np.zeros(len(self.shared), np.int64)  # old code -> new code (options run)
        recode[running] = _OPTION + 1 + np.arange(len(running))
        self.shared = [self.default, episode, *(self.shared[c] for c in running)]
        self._lay_out(keep_slots=bool(np.any(kept == _SLOT)))
        return np.where(kept >= _OPTION, recode[np.maximum(kept, 0)], kept)

    @property
    def offset(self) -> int:
        """The first row of the slots."""
        return int(self.shared_bases[-1])

    def _grow(self, capacity: int, template: dict[str, np.ndarray]) -> None:
        grown = {}
        for name, sample in template.items():
            shape = (self.offset + self.num_envs * capacity, *sample.shape[1:])
            array = np.zeros(shape, sample.dtype)
            if name in self.arrays:
                old = self.arrays[name]
                array[: self.offset] = old[: self.offset]
                if self.capacity:
                    new_slots = array[self.offset :].reshape(self.num_envs, capacity, -1)
                    old_slots = old[self.offset :].reshape(self.num_envs, self.capacity, -1)
                    new_slots[:, : self.capacity] = old_slots
            grown[name] = array
        self.arrays = grown
        self.capacity = capacity

    def write(self, envs: np.ndarray, batch: EpisodeBatch) -> None:
        """Store episode j of ``batch`` in the slot of sub-environment ``envs[j]``."""
        lengths = batch.scenes.length
        if lengths.max() + 1 > self.capacity:
            template = {name: getattr(batch.poses, name) for name in _STORED}
            self._grow(max(int(lengths.max()) + 1, 2 * self.capacity), template)
        bases = self.offset + envs * self.capacity
        rows = np.repeat(bases - batch.starts, lengths) + np.arange(lengths.sum())
        for name in _STORED:
            self.arrays[name][rows] = getattr(batch.poses, name)
        self.arrays["observations"][bases + lengths] = batch.final_observations()

    def bases(self, where: np.ndarray) -> np.ndarray:
        """First rows of the sub-environments' episodes (slots move when the store grows)."""
        slots = self.offset + self.capacity * np.arange(self.num_envs, dtype=np.int64)
        return np.where(where == _SLOT, slots, self.shared_bases[np.maximum(where, 0)])


class _CubeGraspVectorEnv(VectorEnv):
    """N grasp environments in numpy; see the single environment for spaces, reward and info.

    Args:
        num_envs: number of sub-environments.
        autoreset_mode: ``AutoresetMode.NEXT_STEP`` (Gymnasium's default: the step after an
            episode ends resets that sub-environment, ignoring its action, with reward 0),
            ``AutoresetMode.SAME_STEP`` (it resets at once; the last observation and info are
            in ``info["final_obs"]`` and ``info["final_info"]``) or
            ``AutoresetMode.DISABLED`` (episodes never reset by themselves: reset the ended
            sub-environments with ``reset(options={"reset_mask": mask})``; stepping one that
            ended raises a RuntimeError). The modes' values ("NextStep", "SameStep",
            "Disabled") are accepted too.
        max_episode_steps: None (the default: an episode runs to its trajectory's end; -1
            means the same, as it does for ``gym.make``, which then drops an id's registered
            limit) or an integer >= 1: each sub-environment's episode is truncated after that
            many steps,
            as Gymnasium's ``TimeLimit`` truncates a single environment's (truncated is True
            at that step even if the episode terminated there too).
            ``gym.make_vec(id, ..., max_episode_steps=k)`` passes it (and an id's registered
            ``max_episode_steps``); ``vectorization_mode="sync"`` wraps each single env in a
            ``TimeLimit`` instead, with the same results.
        **kwargs: the single environment's keywords (``physics`` and ``render_mode`` are not
            supported: use ``vectorization_mode="sync"`` for those).

    ``reset(seed=..., options={"reset_mask": mask, ...})``, in every mode, resets only the
    sub-environments where ``mask`` (a numpy bool array of shape ``(num_envs,)``) is True, as
    Gymnasium's ``SyncVectorEnv``: they are seeded as in a full reset (the seeds of the others
    are not used) and take the other options; the observations of all are returned.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}  # noqa: RUF012
    _single: type[_CubeGraspEnv]

    def __init__(
        self,
        num_envs: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        num_envs = check_integer("num_envs", num_envs, 1, MAX_ENVS)
        mode = check_autoreset_mode(autoreset_mode)
        self.max_episode_steps = check_max_episode_steps(max_episode_steps)
        # The step at which an episode is truncated: min(trajectory length, this) (int64).
        self._cut = min(self.max_episode_steps or _NO_CUT, _NO_CUT)
        if kwargs.get("physics") is not None or kwargs.get("render_mode") is not None:
            raise ValueError(
                "this batched vector env takes neither physics nor render_mode: for physics make"
                " the ...Mujoco-v0 id (its vector env checks in MuJoCo), for render_mode use"
                ' gym.make_vec(..., vectorization_mode="sync")'
            )
        self.num_envs = num_envs
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.render_mode = None
        # A single environment holds the configuration: defaults, sampler, expert, spaces.
        self.template = self._single(**kwargs)
        self.single_observation_space = self.template.observation_space
        self.single_action_space = self.template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.terminate_on_slip = self.template.terminate_on_slip
        n = self.template.layout.n_contacts
        self._pairs = contact_pairs(n)
        self._n = n
        sampler = getattr(self.template, "sampler", None)
        if sampler is not None and self.num_envs * (sampler.max_length + 1) > MAX_STORE_ROWS:
            raise ValueError(
                f"num_envs x (longest trajectory + 1) = {self.num_envs} x"
                f" {sampler.max_length + 1} pose rows exceeds the vector env's"
                f" {MAX_STORE_ROWS:,}: use fewer sub-environments or a larger alpha_step_deg"
            )
        self._store = _PoseStore(self.num_envs, getattr(self.template, "_default_episode", None))
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        # Random episodes drawn ahead (_draw_ahead): batches by id, and of each
        # sub-environment the batch (-1: none) and row of its next episode.
        self._ahead: dict[int, EpisodeBatch] = {}
        self._ahead_id = 0
        self._ahead_of = np.full(self.num_envs, -1, dtype=np.int64)
        self._ahead_row = np.zeros(self.num_envs, dtype=np.int64)
        # (scene batch, index) of every sub-environment's episode; None: a shared episode
        self._scenes = np.full(self.num_envs, None, dtype=object)
        self._base = np.zeros(self.num_envs, dtype=np.int64)
        self._where = np.full(self.num_envs, _DEFAULT, dtype=np.int64)
        self._length = np.zeros(self.num_envs, dtype=np.int64)
        self._end = np.zeros(self.num_envs, dtype=np.int64)  # the step that truncates
        self._weight = np.zeros(self.num_envs)
        self._limit = np.zeros(self.num_envs)
        self._t = np.zeros(self.num_envs, dtype=np.int64)
        # Ended episodes not reset yet: NEXT_STEP resets them at the next step, DISABLED
        # refuses to step them.
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._started = False

    # -- episodes ------------------------------------------------------------------------------

    def _rng(self, env: int) -> np.random.Generator:
        if self._rngs[env] is None:
            self._rngs[env], _ = seeding.np_random()
        return self._rngs[env]  # type: ignore[return-value]

    def _start(self, envs: np.ndarray, scene: SceneBatch | None) -> None:
        """New episodes for sub-environments ``envs`` (from their own generators); a ``scene``
        (from the reset options, validated) starts for all of them."""
        if len(envs) == 0:
            return
        template = self.template
        store = self._store
        if scene is not None or (store.default is not None):
            if scene is not None:  # one explicit scene for all of them, stored once
                option = build_episodes(scene, template.k_max_ratio)
                others = np.ones(self.num_envs, bool)  # the episodes of these carry on
                others[envs] = False
                self._where[others] = store.share_option(option.episode(0), self._where[others])
            episode = store.option if scene is not None else store.default
            self._where[envs] = _OPTION if scene is not None else _DEFAULT
            self._length[envs] = len(episode)
            self._weight[envs] = episode.weight
            self._limit[envs] = episode.limit
            self._scenes[envs] = None
        else:
            self._draw_ahead(envs)
            for id_, members in self._ahead_groups(envs):
                batch = self._ahead[id_].take(self._ahead_row[members])
                store.write(members, batch)
                self._where[members] = _SLOT
                self._length[members] = batch.scenes.length
                self._weight[members] = batch.scenes.weight
                self._limit[members] = batch.poses.limit[batch.starts]
                for j, e in enumerate(members):
                    self._scenes[e] = (batch.scenes, j)
            self._drop_ahead(envs)
        self._base = store.bases(self._where)
        self._end[envs] = np.minimum(self._length[envs], self._cut)
        self._t[envs] = 0

    def _draw_ahead(self, envs: np.ndarray) -> None:
        """Make sure sub-environments ``envs`` have their next random episode drawn.

        Those that lack one get it drawn together with the next episode of every other
        sub-environment that lacks one (up to :data:`_AHEAD_ENVS` held ahead): resets then draw
        and solve many episodes a call, every few steps, instead of a few every step. Each
        generator draws its own episodes one after the other whenever it is asked, so the
        episodes are those drawn at each reset (as by the single environments); a new seed
        drops the one held ahead (``_reset``).
        """
        lacking = self._ahead_of < 0
        if not lacking[envs].any():
            return
        room = max(_AHEAD_ENVS - int(np.count_nonzero(~lacking)) - int(lacking[envs].sum()), 0)
        needed = envs[lacking[envs]]
        lacking[needed] = False
        draw = np.concatenate([needed, np.flatnonzero(lacking)[:room]])
        template = self.template
        for first in range(0, len(draw), _RESET_CHUNK):
            chunk = draw[first : first + _RESET_CHUNK]
            batch = sample_episodes(
                [self._rng(e) for e in chunk],
                template.sampler,
                template.k_max_ratio,
                template.min_expert_margin,
            )
            self._ahead_id += 1
            self._ahead[self._ahead_id] = batch
            self._ahead_of[chunk] = self._ahead_id
            self._ahead_row[chunk] = np.arange(len(chunk))

    def _ahead_groups(self, envs: np.ndarray) -> list[tuple[int, np.ndarray]]:
        """Sub-environments ``envs`` by the batch their episodes ahead were drawn in."""
        ids = self._ahead_of[envs]
        return [(int(id_), envs[ids == id_]) for id_ in np.unique(ids)]

    def _drop_ahead(self, envs: np.ndarray) -> None:
        """Forget the episodes ahead of ``envs`` (taken, or drawn from a generator since
        re-seeded), and the batches no sub-environment has an episode in any more."""
        self._ahead_of[envs] = -1
        for id_ in set(self._ahead) - set(np.unique(self._ahead_of).tolist()):
            del self._ahead[id_]

    def scene(self, env: int) -> Scene:
        """Sub-environment ``env``'s current :class:`~grasp_env.mechanics.Scene`."""
        if not self._started:
            raise RuntimeError("call reset() first")
        if self._scenes[env] is None:
            return self._store.shared[self._where[env]].scene
        scenes, index = self._scenes[env]
        return scenes.scene(index)

    def _seeds(self, seed: Any) -> list[int | None]:
        """Each sub-environment's seed: ``seed`` None, an int (env i gets seed + i) or a list."""
        if seed is None or isinstance(seed, Integral):
            first = check_seed("seed", seed)
            return [None if first is None else first + i for i in range(self.num_envs)]
        if isinstance(seed, Sequence | np.ndarray) and not isinstance(seed, str | bytes):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed must list {self.num_envs} seeds, got {len(seed)}")
            return [check_seed(f"seed[{i}]", s) for i, s in enumerate(seed)]
        raise ValueError(
            f"seed must be None, an integer >= 0 or a list of {self.num_envs}, got {seed!r}"
        )

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every sub-environment; ``seed`` is None, an int (env i gets seed + i) or a list.

        ``options={"scene": {...}}`` sets the scene of this episode of every sub-environment.
        ``options={"reset_mask": mask}`` (a numpy bool array of shape ``(num_envs,)``) resets
        only the sub-environments where it is True, as Gymnasium's vector envs do (seeded as
        in a full reset, the seeds of the others unused; a scene option applies to them); the
        observations of all sub-environments are returned, the others' as they were.
        """
        # Everything that can refuse the call is checked before any generator is seeded: a
        # refused reset changes nothing.
        seeds = self._seeds(seed)
        mask, options = split_reset_mask(options, self.num_envs)
        scene = self._scene_option(options)
        if mask is None or mask.all():
            envs = np.arange(self.num_envs)
        elif not self._started:
            raise RuntimeError(
                "the first reset() resets every sub-environment: call it without a reset_mask"
            )
        else:
            envs = np.flatnonzero(mask)
        self._reset(envs, seeds, scene)
        return self._store.arrays["observations"][self._base + self._t], {}

    def _scene_option(self, options: Mapping[str, Any] | None) -> SceneBatch | None:
        """The validated scene of the reset options (None without one), or a ValueError."""
        return self.template.scene_option(options)

    def _reset(self, envs: np.ndarray, seeds: list[int | None], scene: SceneBatch | None) -> None:
        """New episodes for sub-environments ``envs``, seeded by their ``seeds``."""
        seeded = np.array([e for e in envs if seeds[e] is not None], dtype=np.int64)
        for env in seeded:
            self._rngs[env], _ = seeding.np_random(seeds[env])
        self._drop_ahead(seeded)
        self._start(envs, scene)
        self._autoreset[envs] = False
        self._started = True

    # -- stepping ------------------------------------------------------------------------------

    def _actions(self, actions: Any) -> np.ndarray:
        return action_array(actions, self.action_space.shape)

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every sub-environment; k = clip(action, -1, 1) x k_max (see the single env)."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        self._refuse_ended()
        a = self._actions(actions)
        count = self.num_envs
        restarting = np.flatnonzero(self._autoreset)
        active = ~self._autoreset
        if not np.isfinite(a).all():  # checked before any state changes
            bad = np.flatnonzero(~np.isfinite(a).all(axis=1) & active)
            if bad.size:
                raise ValueError(f"actions must be finite; sub-environments {bad.tolist()} are not")
        if restarting.size:  # NEXT_STEP: these sub-environments reset and ignore their action
            self._start(restarting, None)
            a = np.where(active[:, None], a, 0.0)
        arrays = self._store.arrays
        rows = self._base + self._t
        n, m = self._n, len(self._pairs)
        observations = np.empty((count, arrays["observations"].shape[1]), np.float32)
        reward, expert_reward, gap, alpha = (np.empty(count) for _ in range(4))
        k, expert_k = np.empty((count, m)), np.empty((count, m))
        forces, equilibrating = np.empty((count, n, 3)), np.empty((count, n, 3))
        theta, margin = np.empty((count, n)), np.empty((count, n))
        stored = tuple(arrays[name] for name in _STORED)
        outputs = (
            observations, reward, k, forces, theta, margin, equilibrating, expert_k,
            expert_reward, gap, alpha,
        )  # fmt: skip
        _step_parts(
            (*stored, self._pairs), rows, a, self.template.k_max_ratio,
            (self._weight, self._limit), outputs,
        )  # fmt: skip
        terminated = reward < 0.0 if self.terminate_on_slip else np.zeros(count, bool)
        self._t += 1
        truncated = self._t == self._end  # the trajectory's end or max_episode_steps
        info = {
            "alpha_deg": alpha,
            "theta": theta,
            "margin": margin,
            "k": k,
            "contact_forces": forces,
            "equilibrating_forces": equilibrating,
            "expert_k": expert_k,
            "expert_reward": expert_reward,
            "optimality_gap": gap,
            # theta_i > theta_lim exactly when the rounded margin is negative (and the minimum)
            "slip": margin < 0.0,
        }
        if restarting.size:
            # Restarted sub-environments: observation 0, no reward, no info, nothing ended.
            reward[restarting] = 0.0
            terminated[restarting] = False
            truncated[restarting] = False
            self._t[restarting] = 0
            observations[restarting] = arrays["observations"][self._base[restarting]]
            mask = active
        else:
            mask = np.ones(count, bool)
        self._autoreset = end_step(
            self.autoreset_mode, observations, info, terminated | truncated, mask, self._restart
        )
        return observations, reward, terminated, truncated, info

    def _restart(self, envs: np.ndarray) -> np.ndarray:
        """Start new episodes in ``envs`` (SAME_STEP autoreset); their first observations."""
        self._start(envs, None)
        return self._store.arrays["observations"][self._base[envs]]

    def _refuse_ended(self) -> None:
        """With autoreset disabled, a RuntimeError if an ended episode was not reset (raised
        before any state changes; Gymnasium's SyncVectorEnv asserts)."""
        refuse_ended(self.autoreset_mode, self._autoreset)

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()


_VECTOR_DOC = """

    Step for step equal to single environments seeded seed, seed + 1, ...; the info is a dict
    of arrays with Gymnasium's ``_key`` masks. Episodes of the default scene share one copy of
    the precomputed arrays; random episodes are drawn and precomputed ahead, many
    sub-environments' in one batch (each from its own generator, in its own order).
"""


class CubeGraspVectorEnv(_CubeGraspVectorEnv):
    __doc__ = (
        "Batched `grasp_env/CubeGrasp-v0` (and `CubeGrasp4-v0`).\n\n    "
        + (_CubeGraspVectorEnv.__doc__ or "")
        + _VECTOR_DOC
    )
    _single = CubeGraspEnv


class CubeGraspRandomVectorEnv(_CubeGraspVectorEnv):
    __doc__ = (
        "Batched `grasp_env/CubeGraspRandom-v0`.\n\n    "
        + (_CubeGraspVectorEnv.__doc__ or "")
        + _VECTOR_DOC
    )
    _single = CubeGraspRandomEnv


__all__ = ["CubeGraspRandomVectorEnv", "CubeGraspVectorEnv"]
