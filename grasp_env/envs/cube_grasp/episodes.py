"""Episodes: a scene held along its trajectory, with everything that does not depend on the
agent's actions computed once when the episode starts.

The grasp geometry, the equilibrating forces, the observations and the expert's certified
optimum at every pose are computed batched over poses and episodes; a step then only forms
P = F + sum k_ij e_ij (eq. 4) and the friction angles (eq. 2) with
:func:`~grasp_env.envs.kernels.evaluate_grips`. Forces are stored in units of the weight w
(``*_w`` arrays), so that nothing depends on its scale; newtons are w times these.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from ...mechanics import START_ROTATION, Grasp, Scene, Status, contact_pairs, solve_minimax
from ..kernels import pose_geometry
from ..observation import ObservationLayout
from .scenes import EDGE, SCENE_ARRAYS, SceneBatch, SceneSampler, layout_ok, load_ok

_BOUNDS = {n: ObservationLayout(n).bounds() for n in (3, 4)}


def _read_only(*arrays: np.ndarray) -> None:
    # Episodes are shared (between environments, through the cache): keep them unchangeable.
    for array in arrays:
        array.flags.writeable = False


@dataclass(frozen=True)
class Poses:
    """World-frame data of P poses (flattened over episodes), ready for
    :func:`~grasp_env.envs.kernels.evaluate_grips`; forces in units of w."""

    rotations: np.ndarray  # (P, 3, 3)
    forces_w: np.ndarray  # (P, n, 3) equilibrating forces F_i / w
    directions: np.ndarray  # (P, m, 3) u_ij
    normals: np.ndarray  # (P, n, 3)
    observations: np.ndarray  # (P, size) float32
    alphas: np.ndarray  # (P,) degrees
    limit: np.ndarray  # (P,) theta_lim
    weight: np.ndarray  # (P,) w, newtons
    expert_k_w: np.ndarray  # (P, m) the optimal grip k* / w
    expert_reward: np.ndarray  # (P,) theta_lim - the certified optimum

    def take(self, rows: np.ndarray) -> Poses:
        return Poses(*(np.take(getattr(self, f.name), rows, axis=0) for f in fields(Poses)))


def interaction_basis(directions: np.ndarray, pairs: np.ndarray, n: int) -> np.ndarray:
    """The vectors e_ij (..., m, n, 3): +u_ij in block i, -u_ij in block j (eq. 4)."""
    basis = np.zeros((*directions.shape[:-2], len(pairs), n, 3))
    q = np.arange(len(pairs))
    basis[..., q, pairs[:, 0], :] = directions
    basis[..., q, pairs[:, 1], :] = -directions
    return basis


def expert_optimum(
    grasp: Grasp, k_max_ratio: float, follows: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The certified minimax optimum of grasps in units of w: (k* / w, theta_lim - t*).

    t* is the solver's optimum max_i theta_i (attained by k*, certified within its gap of
    1e-9 rad). Where no grip in the box keeps every finger pushing (status NOT_PUSHING) the
    certified bound t* >= 90 deg is used: no action can earn more than theta_lim - 90 deg.
    """
    result = solve_minimax(grasp, k_max_ratio, follows=follows)
    optimum = np.where(result.status == Status.NOT_PUSHING, result.lower_bound, result.max_angle)
    if not (np.all(np.isfinite(result.k)) and np.all(np.isfinite(optimum))):
        raise RuntimeError("the minimax solver returned a non-finite optimum (a solver bug)")
    return result.k, grasp.friction_limit - optimum


def build_poses(
    scenes: SceneBatch,
    episode: np.ndarray,
    step: np.ndarray,
    k_max_ratio: float,
    known: Poses | None = None,
    known_rows: np.ndarray | None = None,
) -> Poses:
    """Grasp data, observations and the expert's optimum at poses of the batch's trajectories.

    ``episode`` (P,) says which scene each pose belongs to and ``step`` (P,) which pose t of
    its trajectory it is; the observation's phase is t / length. ``known`` holds the expert's
    optimum at rows ``known_rows`` of these poses where already solved.
    """
    n = scenes.contacts.shape[1]
    pairs = contact_pairs(n)
    count = len(episode)
    alphas, limit = np.empty(count), np.empty(count)
    rotations = np.empty((count, 3, 3))
    positions = np.empty((count, n, 3))
    forces, normals = np.empty((count, n, 3)), np.empty((count, n, 3))
    directions = np.empty((count, len(pairs), 3))
    observations = np.empty((count, ObservationLayout(n).size), np.float32)
    pose_geometry(
        scenes.contacts - scenes.cg_offset[:, None, :],
        scenes.normals,
        scenes.axis,
        scenes.alpha_start,
        scenes.alpha_step,
        scenes.length,
        scenes.weight,
        scenes.mu,
        scenes.extra_force,
        scenes.extra_torque,
        EDGE,
        episode,
        step,
        START_ROTATION,
        pairs,
        *_BOUNDS[n],
        alphas,
        rotations,
        positions,
        forces,
        directions,
        normals,
        observations,
        limit,
    )
    todo = np.ones(count, bool)
    expert_k = np.empty((count, len(pairs)))
    expert_reward = np.empty(count)
    if known is not None:
        todo[known_rows] = False
        expert_k[known_rows] = known.expert_k_w
        expert_reward[known_rows] = known.expert_reward
    # a pose whose predecessor on the trajectory is solved just before it starts from its
    # optimum (the solver's warm start)
    follows = np.zeros(count, bool)
    follows[1:] = todo[1:] & todo[:-1] & (episode[1:] == episode[:-1]) & (step[1:] == step[:-1] + 1)
    if todo.any():
        grasp = Grasp(
            positions[todo],
            normals[todo],
            forces[todo],
            interaction_basis(directions[todo], pairs, n),
            limit[todo],
        )
        expert_k[todo], expert_reward[todo] = expert_optimum(grasp, k_max_ratio, follows[todo])
    return Poses(
        rotations,
        forces,
        directions,
        normals,
        observations,
        alphas,
        limit,
        scenes.weight[episode],
        expert_k,
        expert_reward,
    )


@dataclass(frozen=True)
class EpisodeBatch:
    """E episodes: their scenes and the poses of all their trajectories, one after the other."""

    scenes: SceneBatch
    poses: Poses

    def __len__(self) -> int:
        return len(self.scenes)

    @property
    def starts(self) -> np.ndarray:
        """First pose row of every episode."""
        return np.cumsum(self.scenes.length) - self.scenes.length

    def worst_expert_reward(self) -> np.ndarray:
        """min over its trajectory of the expert's reward, per episode (E,)."""
        return np.minimum.reduceat(self.poses.expert_reward, self.starts)

    def take(self, index: Sequence[int] | np.ndarray) -> EpisodeBatch:
        index = np.asarray(index, dtype=np.intp)
        lengths = self.scenes.length[index]
        rows = np.repeat(self.starts[index] - np.cumsum(lengths) + lengths, lengths)
        return EpisodeBatch(self.scenes.take(index), self.poses.take(rows + np.arange(len(rows))))

    @staticmethod
    def concatenate(batches: Sequence[EpisodeBatch]) -> EpisodeBatch:
        return EpisodeBatch(
            SceneBatch(
                *(np.concatenate([getattr(b.scenes, f) for b in batches]) for f in SCENE_ARRAYS)
            ),
            Poses(
                *(
                    np.concatenate([getattr(b.poses, f.name) for b in batches])
                    for f in fields(Poses)
                )
            ),
        )

    def final_observations(self) -> np.ndarray:
        """The observation after each episode's last step: its last pose with phase 1 (E, size)."""
        final = self.poses.observations[self.starts + self.scenes.length - 1]
        final[:, ObservationLayout(self.scenes.contacts.shape[1]).phase] = 1.0
        return final

    def episode(self, index: int) -> Episode:
        """Episode ``index`` as read-only arrays of its own."""
        start, length = int(self.starts[index]), int(self.scenes.length[index])
        part = self.poses.take(np.arange(start, start + length))
        scene = self.scenes.take([index])
        observations = np.vstack([part.observations, self.final_observations()[index : index + 1]])
        weight = float(part.weight[0])
        episode = Episode(
            scene,
            part.rotations,
            part.forces_w,
            part.directions,
            part.normals,
            observations,
            part.alphas,
            part.expert_k_w,
            part.expert_reward,
            part.forces_w * weight,
            part.expert_k_w * weight,
            limit=float(part.limit[0]),
            weight=weight,
        )
        _read_only(*(getattr(scene, name) for name in SCENE_ARRAYS))
        _read_only(*(getattr(episode, f.name) for f in fields(Episode)[1:-2]))
        return episode


@dataclass(frozen=True)
class Episode:
    """One episode's precomputed arrays (read-only), T poses; forces in units of w.

    ``observations`` has T + 1 rows: row t is seen before step t, row T (the last pose with
    phase 1) after the last step.
    """

    scenes: SceneBatch  # a batch of one: the episode's scene and trajectory
    rotations: np.ndarray  # (T, 3, 3)
    forces_w: np.ndarray  # (T, n, 3) equilibrating forces F_i / w
    directions: np.ndarray  # (T, m, 3)
    normals: np.ndarray  # (T, n, 3)
    observations: np.ndarray  # (T + 1, size) float32
    alphas: np.ndarray  # (T,) degrees
    expert_k_w: np.ndarray  # (T, m) the optimal grip k* / w
    expert_reward: np.ndarray  # (T,) theta_lim - the certified optimum
    forces: np.ndarray  # (T, n, 3) the equilibrating forces F_i, newtons
    expert_k: np.ndarray  # (T, m) the optimal grips k*, newtons
    limit: float
    weight: float  # w, newtons

    def __len__(self) -> int:
        return self.rotations.shape[0]

    @property
    def scene(self) -> Scene:
        return self.scenes.scene(0)


def build_episodes(
    scenes: SceneBatch,
    k_max_ratio: float,
    known: Poses | None = None,
    known_rows: np.ndarray | None = None,
) -> EpisodeBatch:
    """The episodes of a batch of scenes, with every pose of every trajectory in one batch
    (``known``, ``known_rows``: the expert's optimum at some of these poses, see
    :func:`build_poses`)."""
    lengths = scenes.length
    episode = np.repeat(np.arange(len(scenes)), lengths)
    step = np.arange(len(episode)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return EpisodeBatch(scenes, build_poses(scenes, episode, step, k_max_ratio, known, known_rows))


_EPISODE_CACHE: dict[tuple, Episode] = {}
_EPISODE_CACHE_SIZE = 32


def cached_episode(scenes: SceneBatch, k_max_ratio: float) -> Episode:
    """The episode of one scene, remembered: environments made with the same scene (every
    ``gym.make("grasp_env/CubeGrasp-v0")``) share one read-only episode."""
    key = (k_max_ratio, *(getattr(scenes, name).tobytes() for name in SCENE_ARRAYS))
    if key not in _EPISODE_CACHE:
        if len(_EPISODE_CACHE) >= _EPISODE_CACHE_SIZE:
            _EPISODE_CACHE.pop(next(iter(_EPISODE_CACHE)))
        _EPISODE_CACHE[key] = build_episodes(scenes, k_max_ratio).episode(0)
    return _EPISODE_CACHE[key]


#: Candidate scenes drawn per environment and round of :func:`sample_episodes`.
DRAWS_PER_ROUND = 2
#: Give up (the ranges admit almost no holdable scene) when fewer than one candidate in this
#: many holds.
MAX_DRAWS = 2000
#: The most rounds of candidates a single environment draws ahead at once (EpisodeStream).
AHEAD_ROUNDS = 32


def draws_error(min_margin: float) -> ValueError:
    """The error of ranges that let fewer than 1 candidate in :data:`MAX_DRAWS` hold."""
    return ValueError(
        f"fewer than 1 in {MAX_DRAWS} random scenes lets the expert keep a margin of"
        f" {np.rad2deg(min_margin):g} deg along the whole trajectory; widen mu_range,"
        " lower min_expert_margin_deg or narrow the offset and trajectory ranges"
    )


def first_holders(
    drafts: SceneBatch, k_max_ratio: float, min_margin: float
) -> tuple[list[EpisodeBatch], list[np.ndarray]]:
    """The episode of each round of candidates that has one: ``drafts`` holds R rounds of
    :data:`DRAWS_PER_ROUND` candidates, round after round. A round's episode is its first
    candidate (in draw order) whose expert keeps every margin >= ``min_margin``.

    Candidates whose contacts are (nearly) collinear or coplanar (the rule of
    :class:`~grasp_env.mechanics.Scene`) or whose load nearly cancels the weight
    (:func:`~grasp_env.envs.cube_grasp.scenes.load_ok`) are dropped, a cheap screen solves the
    expert at the trajectory's two ends and middle, then candidates that pass are solved along
    the whole trajectory, draw position by draw position, all rounds at once. Returns the
    episodes as batches and, for each batch, the rounds its episodes come from.
    """
    rounds = len(drafts) // DRAWS_PER_ROUND
    usable = np.flatnonzero(
        layout_ok(drafts.contacts) & load_ok(drafts.weight, drafts.extra_force, drafts.extra_torque)
    )
    last = drafts.length - 1
    picks = np.stack([np.zeros_like(last), last // 2 + last % 2, last], axis=1)
    screen = build_poses(drafts, np.repeat(usable, 3), picks[usable].ravel(), k_max_ratio)
    worst = np.full(len(drafts), -np.inf)
    worst[usable] = screen.expert_reward.reshape(-1, 3).min(-1)
    passed = (worst >= min_margin).reshape(rounds, DRAWS_PER_ROUND)
    open_ = np.ones(rounds, bool)
    chosen: list[EpisodeBatch] = []
    held: list[np.ndarray] = []
    for d in range(DRAWS_PER_ROUND):  # candidates in their draw order
        slots = np.flatnonzero(open_ & passed[:, d])
        if len(slots) == 0:
            continue
        candidates = slots * DRAWS_PER_ROUND + d
        scenes = drafts.take(candidates)
        # The screened poses are solved already (the optimum ignores the phase).
        starts = np.cumsum(scenes.length) - scenes.length
        screened = np.searchsorted(usable, candidates)
        known = screen.take((screened[:, None] * 3 + np.arange(3)).ravel())
        rows = (starts[:, None] + picks[candidates]).ravel()
        full = build_episodes(scenes, k_max_ratio, known, rows)
        holds = full.worst_expert_reward() >= min_margin
        chosen.append(full if holds.all() else full.take(np.flatnonzero(holds)))
        held.append(slots[holds])
        open_[slots[holds]] = False
    return chosen, held


class EpisodeStream:
    """The random episodes of one generator, drawn ahead: what a single environment's resets
    read, so that a reset costs a pop, not a batch of solves of its own.

    The episodes are those :func:`sample_episodes` gives, in the same order: rounds of
    candidates are drawn from the generator one after the other as there, only several rounds
    at a time, their solves batched, and the episodes of the rounds that hold queued in round
    order. After a new generator (a reseed) the first batch is one round and batches double
    up to :data:`AHEAD_ROUNDS`: a seeded reset costs what it did, a long run a fraction. Past
    :data:`MAX_DRAWS` candidates without an episode, the next reset raises ValueError (as
    :func:`sample_episodes`), and the one after carries on drawing.
    """

    def __init__(self, sampler: SceneSampler, k_max_ratio: float, min_margin: float) -> None:
        self.sampler, self.k_max_ratio, self.min_margin = sampler, k_max_ratio, min_margin
        self._rng: np.random.Generator | None = None
        self._queue: deque[Episode | None] = deque()  # None: MAX_DRAWS failed, raise
        self._rounds = 1
        self._streak = 0  # candidates drawn since the last episode

    def next(self, rng: np.random.Generator) -> Episode:
        """The generator's next episode (a new generator restarts the stream)."""
        if rng is not self._rng:
            self._rng, self._rounds, self._streak = rng, 1, 0
            self._queue.clear()
        while not self._queue:
            self._draw(rng)
        episode = self._queue.popleft()
        if episode is None:
            raise draws_error(self.min_margin)
        return episode

    def _draw(self, rng: np.random.Generator) -> None:
        drafts = self.sampler.scenes(
            np.concatenate([self.sampler.raw(rng, DRAWS_PER_ROUND) for _ in range(self._rounds)])
        )
        batches, held = first_holders(drafts, self.k_max_ratio, self.min_margin)
        episodes = {
            int(r): b.episode(j)
            for b, rs in zip(batches, held, strict=True)
            for j, r in enumerate(rs)
        }
        for round_ in range(self._rounds):
            if round_ in episodes:
                self._queue.append(episodes[round_])
                self._streak = 0
                continue
            self._streak += DRAWS_PER_ROUND
            if self._streak >= MAX_DRAWS:
                self._queue.append(None)
                self._streak = 0
        self._rounds = min(2 * self._rounds, AHEAD_ROUNDS)


def sample_episodes(
    rngs: Sequence[np.random.Generator],
    sampler: SceneSampler,
    k_max_ratio: float,
    min_margin: float,
) -> EpisodeBatch:
    """One random episode per generator whose expert keeps every margin >= ``min_margin``.

    Each generator draws rounds of :data:`DRAWS_PER_ROUND` candidates until a round holds one
    (:func:`first_holders`). Which scene a generator yields depends on that generator alone,
    so a vector of environments gets the same episodes as single environments with the same
    seeds; all solves are batched. Raises ValueError once fewer than one candidate in
    :data:`MAX_DRAWS` has held.
    """
    chosen: list[EpisodeBatch] = []
    owners: list[np.ndarray] = []
    pending = np.arange(len(rngs))
    drawn = 0
    while len(pending):
        if drawn >= MAX_DRAWS * (len(rngs) - len(pending) + 1):
            raise draws_error(min_margin)
        drafts = sampler.scenes(
            np.concatenate([sampler.raw(rngs[e], DRAWS_PER_ROUND) for e in pending])
        )
        drawn += len(drafts)
        batches, held = first_holders(drafts, k_max_ratio, min_margin)
        chosen += batches
        owners += [pending[rounds] for rounds in held]
        open_ = np.ones(len(pending), bool)
        open_[np.concatenate(held or [np.zeros(0, np.intp)])] = False
        pending = pending[open_]
    batch = chosen[0] if len(chosen) == 1 else EpisodeBatch.concatenate(chosen)
    order = np.argsort(np.concatenate(owners))
    return batch if np.all(order == np.arange(len(order))) else batch.take(order)
