"""Episodes of any object, padded to a fixed number of contacts, with everything that does not
depend on the agent computed when they start; and the random episodes drawn ahead.

An environment pads every scene to its ``max_contacts`` N (the observation and the action have
one shape across draws): contact i < n is real, the others are zeros with mask 0, and the
interaction scalars are those of the N (N - 1) / 2 pairs of :func:`contact_pairs(N)
<grasp_env.mechanics.contact_pairs>`, of which the pairs of two real contacts are used. The
world-frame geometry is the cube family's kernel (:func:`~grasp_env.envs.kernels.pose_geometry`
on contacts in units of L), the expert's optimum one batched
:func:`~grasp_env.mechanics.solve_minimax` per contact count.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np

from ...mechanics import START_ROTATION, Grasp, Status, contact_pairs, solve_minimax
from ..cube_grasp.episodes import interaction_basis
from ..kernels import evaluate_grips, pose_geometry
from ..observation import ObservationLayout
from .scenes import ObjectSampler, ObjectScene

#: The largest certificate gap of the expert accepted in a random scene, radians (5.7e-4 deg):
#: the conic solver (five or more contacts) returns UNCERTIFIED results with gaps of 1e-9 to
#: 1e-5 rad on about one pose in twelve; below it a result is the optimum to that accuracy.
MAX_EXPERT_GAP = 1e-5
#: Give up when fewer than one candidate in this many holds (as the cube's random env).
MAX_DRAWS = 2000
#: The most candidates a generator draws ahead at once (:class:`EpisodeStream`).
AHEAD = 32


@dataclass(frozen=True)
class ObjectLayout:
    """The padded observation of ``max_contacts`` N contacts (14 + 7 N floats):

    ==================  =====  ==========================================  ===============
    slice               size   content                                     bounds
    ==================  =====  ==========================================  ===============
    ``rotation``        6      first two columns of R                      [-1, 1]
    ``positions``       3N     p_i / L = R (c_i - g) / L (0 for padding)   [-√3, √3]
    ``normals``         3N     inward normals n_i = R nu_i (0 for padding) [-1, 1]
    ``mask``            N      1 for a real contact, 0 for padding         [0, 1]
    ``force``           3      f / w = (0, 0, -1) + f_d / w                x, y [-1, 1];
                                                                           z [-2, 0]
    ``torque``          3      tau_d / (w L)                               [-1, 1]
    ``friction_limit``  1      theta_lim = atan(mu), radians               [0, pi/2]
    ``phase``           1      steps taken / trajectory length             [0, 1]
    ==================  =====  ==========================================  ===============

    L is the largest edge of the shape's bounding box; the real contacts come first.
    """

    max_contacts: int

    @property
    def size(self) -> int:
        return 14 + 7 * self.max_contacts

    @property
    def positions(self) -> slice:
        return slice(6, 6 + 3 * self.max_contacts)

    @property
    def normals(self) -> slice:
        return slice(6 + 3 * self.max_contacts, 6 + 6 * self.max_contacts)

    @property
    def mask(self) -> slice:
        return slice(6 + 6 * self.max_contacts, 6 + 7 * self.max_contacts)

    @property
    def tail(self) -> slice:
        """force, torque, friction limit and phase: the cube layout's last 8 entries."""
        return slice(6 + 7 * self.max_contacts, 14 + 7 * self.max_contacts)

    @property
    def phase(self) -> int:
        return 13 + 7 * self.max_contacts

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) float32 arrays of the observation space."""
        low, high = ObservationLayout(self.max_contacts).bounds()
        n = self.max_contacts
        pad = np.zeros(n, np.float32), np.ones(n, np.float32)
        return (
            np.concatenate([low[: 6 + 6 * n], pad[0], low[6 + 6 * n :]]),
            np.concatenate([high[: 6 + 6 * n], pad[1], high[6 + 6 * n :]]),
        )


@cache
def pair_slots(n: int, max_contacts: int) -> np.ndarray:
    """Where each pair of :func:`contact_pairs(n)` sits in :func:`contact_pairs(max_contacts)`."""
    padded = {tuple(p): q for q, p in enumerate(contact_pairs(max_contacts).tolist())}
    return np.array([padded[tuple(p)] for p in contact_pairs(n).tolist()], dtype=np.int64)


def projection(scene: ObjectScene, max_contacts: int) -> np.ndarray:
    """E^+ E (M, M), padded: the map from a grip k to the minimum-norm k of its interaction
    force E k (eq. 4), which the expert's box bounds with five or more contacts (docs/solver.md,
    "Any number of contacts"). It does not depend on the pose (E turns with the object,
    E^T E does not). For n <= 4 the e_ij are independent and it is the identity on the pairs."""
    n = scene.n_contacts
    slots = pair_slots(n, max_contacts)
    m_max = len(contact_pairs(max_contacts))
    out = np.zeros((m_max, m_max))
    if n <= 4:
        out[slots, slots] = 1.0
        return out
    pairs = contact_pairs(n)
    c = scene.contacts
    u = c[pairs[:, 1]] - c[pairs[:, 0]]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    e = interaction_basis(u, pairs, n).reshape(len(pairs), 3 * n).T
    out[np.ix_(slots, slots)] = np.linalg.pinv(e) @ e
    return out


_EXPERT = ("expert_k_w", "expert_reward", "expert_gap", "solved")


@dataclass(frozen=True)
class ObjectEpisode:
    """One episode's arrays, padded to N contacts and M pairs (forces in units of w); T poses,
    ``observations`` T + 1 rows (row T: the last pose with phase 1)."""

    scene: ObjectScene
    rotations: np.ndarray  # (T, 3, 3)
    forces_w: np.ndarray  # (T, N, 3)
    directions: np.ndarray  # (T, M, 3)
    normals: np.ndarray  # (T, N, 3)
    observations: np.ndarray  # (T + 1, 14 + 7 N) float32
    alphas: np.ndarray  # (T,) degrees
    expert_k_w: np.ndarray  # (T, M) the optimal grip k* / w
    expert_reward: np.ndarray  # (T,) theta_lim - the optimum
    expert_gap: np.ndarray  # (T,) the optimum's certificate gap, radians
    projection: np.ndarray  # (M, M)
    solved: np.ndarray  # (T,) bool: the expert's optimum is known (else solve_pending)
    limit: float
    weight: float

    def __len__(self) -> int:
        return self.rotations.shape[0]

    @property
    def n_contacts(self) -> int:
        return self.scene.n_contacts


def _geometry(scenes: Sequence[ObjectScene], episode: np.ndarray, step: np.ndarray) -> dict:
    """The world-frame arrays at poses (episode[P], step[P]) of scenes of one contact count n,
    in units of w and L (the cube family's kernel on contacts divided by L)."""
    n = scenes[0].n_contacts
    pairs = contact_pairs(n)
    length = np.array([s.length for s in scenes])
    relative = np.stack([s.relative_contacts() for s in scenes]) / length[:, None, None]
    torque = np.stack([s.extra_torque for s in scenes]) / length[:, None]
    traj = [s.trajectory for s in scenes]
    count = len(episode)
    out = {
        "alphas": np.empty(count),
        "rotations": np.empty((count, 3, 3)),
        "positions": np.empty((count, n, 3)),
        "forces": np.empty((count, n, 3)),
        "directions": np.empty((count, len(pairs), 3)),
        "normals": np.empty((count, n, 3)),
        "observations": np.empty((count, ObservationLayout(n).size), np.float32),
        "limit": np.empty(count),
    }
    pose_geometry(
        relative,
        np.stack([s.normals for s in scenes]),
        np.array([t.axis for t in traj]),
        np.array([t.alpha_start_deg for t in traj]),
        np.array([t.alpha_step_deg for t in traj]),
        np.array([len(t) for t in traj], dtype=np.int64),
        np.array([s.weight for s in scenes]),
        np.array([s.mu for s in scenes]),
        np.stack([s.extra_force for s in scenes]),
        torque,
        1.0,
        episode,
        step,
        START_ROTATION,
        pairs,
        *ObservationLayout(n).bounds(),
        *out.values(),
    )
    return out


def _solve(geometry: dict, rows: np.ndarray, k_max_ratio: float, follows: np.ndarray | None):
    """The expert at ``rows`` of ``geometry``: (k* / w, theta_lim - optimum, gap, not pushing)."""
    n = geometry["forces"].shape[1]
    pairs = contact_pairs(n)
    grasp = Grasp(
        geometry["positions"][rows],
        geometry["normals"][rows],
        geometry["forces"][rows],
        interaction_basis(geometry["directions"][rows], pairs, n),
        geometry["limit"][rows],
    )
    result = solve_minimax(grasp, k_max_ratio, follows=follows)
    pushing = result.status != Status.NOT_PUSHING
    optimum = np.where(pushing, result.max_angle, result.lower_bound)
    gap = np.where(pushing, result.max_angle - result.lower_bound, 0.0)
    return result.k, geometry["limit"][rows] - optimum, gap, ~pushing


def _chains(episode: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """follows for solving ``rows`` (sorted) in one batch: a row follows the previous one
    when it is the next pose of the same episode (the solver's warm start)."""
    follows = np.zeros(len(rows), bool)
    follows[1:] = (rows[1:] == rows[:-1] + 1) & (episode[rows[1:]] == episode[rows[:-1]])
    return follows


def build_episodes(
    scenes: Sequence[ObjectScene],
    k_max_ratio: float,
    max_contacts: int,
    min_margin: float | None = None,
) -> list[ObjectEpisode | None]:
    """The episodes of ``scenes`` (any contact counts up to ``max_contacts``), the poses of
    each contact count in one batch. Each scene's result depends on that scene alone.

    Without ``min_margin`` (explicit scenes) the expert is solved at every pose (each from the
    previous pose's optimum). With it (random scenes) a scene is kept (else None) when the
    expert's optimum keeps every margin >= min_margin at every pose, and only what decides
    that is solved: the first pose (where a certificate gap above :data:`MAX_EXPERT_GAP` or
    a finger not pushing also rejects the scene), then the first pose's optimal grip k*_0 is
    evaluated at every pose (it lies in the box there too: the box is the same at every
    pose, docs/solver.md), and the poses where it keeps a margin below min_margin are solved
    (the optimum is at least as good as any grip, so where k*_0 holds the optimum does). The
    other poses are solved when an episode reaches them (:func:`solve_pending`).
    """
    out: list[ObjectEpisode | None] = [None] * len(scenes)
    for n in sorted({s.n_contacts for s in scenes}):
        index = [i for i, s in enumerate(scenes) if s.n_contacts == n]
        built = _build_group([scenes[i] for i in index], k_max_ratio, max_contacts, min_margin)
        for i, episode in zip(index, built, strict=True):
            out[i] = episode
    return out


def _build_group(
    group: Sequence[ObjectScene], k_max_ratio: float, max_contacts: int, min_margin: float | None
) -> list[ObjectEpisode | None]:
    """:func:`build_episodes` of scenes of one contact count."""
    n = group[0].n_contacts
    out: list[ObjectEpisode | None] = [None] * len(group)
    lengths = np.array([len(s.trajectory) for s in group], dtype=np.int64)
    starts = np.cumsum(lengths) - lengths
    episode = np.repeat(np.arange(len(group), dtype=np.int64), lengths)
    step = np.arange(len(episode)) - np.repeat(starts, lengths)
    geometry = _geometry(group, episode, step)
    m = len(contact_pairs(n))
    count = len(episode)
    expert_k, reward, gap = np.zeros((count, m)), np.zeros(count), np.zeros(count)
    solved = np.zeros(count, bool)
    keep = np.ones(len(group), bool)

    def solve(rows: np.ndarray) -> np.ndarray:
        """Solve ``rows``; whether each is good (margin, gap, pushing)."""
        k, r, g, stuck = _solve(geometry, rows, k_max_ratio, _chains(episode, rows))
        expert_k[rows], reward[rows], gap[rows] = k, r, g
        solved[rows] = True
        return (
            (r >= (-np.inf if min_margin is None else min_margin)) & (g <= MAX_EXPERT_GAP) & ~stuck
        )

    if min_margin is None:
        solve(np.arange(count))
    else:
        keep &= solve(starts)
        rows = np.flatnonzero(keep[episode])
        if len(rows):
            _, _, _, _, _, held = evaluate_grips(
                geometry["forces"], geometry["directions"], geometry["normals"],
                contact_pairs(n), rows, expert_k[starts[episode[rows]]] / k_max_ratio,
                k_max_ratio, np.array([group[e].weight for e in episode[rows]]),
                geometry["limit"][rows],
            )  # fmt: skip
            hard = rows[(held < min_margin) & ~solved[rows]]
            if len(hard):
                good = solve(hard)
                keep[episode[hard[~good]]] = False
    for e in np.flatnonzero(keep):
        rows = slice(int(starts[e]), int(starts[e] + lengths[e]))
        out[e] = _episode(group[e], geometry, rows, expert_k, reward, gap, solved, max_contacts)
    return out


#: A pose not solved yet is solved with up to this many poses after it, in one batch (each
#: from the previous optimum), when an episode reaches it.
PENDING_CHUNK = 8


def solve_pending(items: Sequence[tuple[ObjectEpisode, int]], k_max_ratio: float) -> list[slice]:
    """Solve, for each (episode, pose t) whose pose t is not solved, the poses from t up to
    :data:`PENDING_CHUNK` on (up to the next solved pose), all in one batch per contact
    count, and write the optimum into the episode. Returns each item's solved poses (an
    empty slice where t was solved). The chunks depend on the episode and t alone, so a
    single env and a vector env solve the same batches' poses."""
    spans = []
    for episode, t in items:
        if episode.solved[t]:
            spans.append(slice(t, t))
            continue
        end = t + 1
        while end < min(len(episode), t + PENDING_CHUNK) and not episode.solved[end]:
            end += 1
        spans.append(slice(t, end))
    for n in sorted(
        {e.n_contacts for (e, _), s in zip(items, spans, strict=True) if s.stop > s.start}
    ):
        members = [
            (e, s) for (e, _), s in zip(items, spans, strict=True)
            if e.n_contacts == n and s.stop > s.start
        ]  # fmt: skip
        big = members[0][0].forces_w.shape[1]
        slots = pair_slots(n, big)
        pairs = contact_pairs(n)
        forces = np.concatenate([e.forces_w[s, :n] for e, s in members])
        normals = np.concatenate([e.normals[s, :n] for e, s in members])
        directions = np.concatenate([e.directions[s][:, slots] for e, s in members])
        limit = np.concatenate([np.full(s.stop - s.start, e.limit) for e, s in members])
        follows = np.concatenate([np.arange(s.stop - s.start) > 0 for _, s in members])
        grasp = Grasp(
            np.zeros_like(forces), normals, forces, interaction_basis(directions, pairs, n), limit
        )
        result = solve_minimax(grasp, k_max_ratio, follows=follows)
        pushing = result.status != Status.NOT_PUSHING
        optimum = np.where(pushing, result.max_angle, result.lower_bound)
        gap = np.where(pushing, result.max_angle - result.lower_bound, 0.0)
        first = 0
        for e, s in members:
            rows = slice(first, first + s.stop - s.start)
            e.expert_k_w[s.start : s.stop, slots] = result.k[rows]
            e.expert_reward[s] = limit[rows] - optimum[rows]
            e.expert_gap[s] = gap[rows]
            e.solved[s] = True
            first = rows.stop
    return spans


def _episode(
    scene: ObjectScene,
    geometry: dict,
    rows: slice,
    expert_k: np.ndarray,
    reward: np.ndarray,
    gap: np.ndarray,
    solved: np.ndarray,
    max_contacts: int,
) -> ObjectEpisode:
    """One episode's padded arrays from the rows of its poses: read-only but for the expert's
    (``expert_k_w``, ``expert_reward``, ``expert_gap``, ``solved``) where poses are pending."""
    n, big = scene.n_contacts, max_contacts
    slots = pair_slots(n, big)
    count = rows.stop - rows.start
    m_max = len(contact_pairs(big))
    forces = np.zeros((count, big, 3))
    forces[:, :n] = geometry["forces"][rows]
    normals = np.zeros((count, big, 3))
    normals[:, :n] = geometry["normals"][rows]
    directions = np.zeros((count, m_max, 3))
    directions[:, slots] = geometry["directions"][rows]
    k = np.zeros((count, m_max))
    k[:, slots] = expert_k[rows]
    layout = ObjectLayout(big)
    cube = geometry["observations"][rows]
    observations = np.zeros((count + 1, layout.size), np.float32)
    obs = observations[:count]
    obs[:, :6] = cube[:, :6]
    obs[:, 6 : 6 + 3 * n] = cube[:, 6 : 6 + 3 * n]
    obs[:, layout.normals.start : layout.normals.start + 3 * n] = cube[:, 6 + 3 * n : 6 + 6 * n]
    obs[:, layout.mask.start : layout.mask.start + n] = 1.0
    obs[:, layout.tail] = cube[:, 6 + 6 * n :]
    observations[count] = observations[count - 1]
    observations[count, layout.phase] = 1.0
    episode = ObjectEpisode(
        scene,
        geometry["rotations"][rows].copy(),
        forces,
        directions,
        normals,
        observations,
        geometry["alphas"][rows].copy(),
        k,
        reward[rows].copy(),
        gap[rows].copy(),
        projection(scene, big),
        solved[rows].copy(),
        limit=float(geometry["limit"][rows.start]),
        weight=float(scene.weight),
    )
    pending = not episode.solved.all()
    for name in ObjectEpisode.__dataclass_fields__:
        value = getattr(episode, name)
        if isinstance(value, np.ndarray) and not (pending and name in _EXPERT):
            value.flags.writeable = False
    return episode


def draws_error(min_margin: float) -> ValueError:
    """The error of ranges that let fewer than 1 candidate in :data:`MAX_DRAWS` hold."""
    return ValueError(
        f"fewer than 1 in {MAX_DRAWS} random scenes lets the expert keep a margin of"
        f" {np.rad2deg(min_margin):g} deg along the whole trajectory; widen mu_range, lower"
        " min_expert_margin_deg, or narrow contact_offset, cg_offset_max and the extra load"
    )


class EpisodeStream:
    """The random episodes of one generator, drawn ahead: the candidates it draws one after
    the other, those that hold kept in order (so they do not depend on how many are drawn at
    a time). After a new generator (a reseed) the first draw is one candidate and draws
    double up to :data:`AHEAD`; :func:`fill` draws for many streams in one batch of solves."""

    def __init__(self, sampler: ObjectSampler, k_max_ratio: float, min_margin: float, big: int):
        self.sampler, self.k_max_ratio, self.min_margin, self.big = (
            sampler, k_max_ratio, min_margin, big,
        )  # fmt: skip
        self.rng: np.random.Generator | None = None
        self.queue: deque[ObjectEpisode | None] = deque()  # None: MAX_DRAWS failed, raise
        self.batch = 1
        self.streak = 0  # candidates drawn since the last episode
        self.drawn = 0  # candidates drawn (for the benchmark's counts)

    def restart(self, rng: np.random.Generator) -> None:
        self.rng, self.batch, self.streak = rng, 1, 0
        self.queue.clear()

    def next(self, rng: np.random.Generator) -> ObjectEpisode:
        """The generator's next episode (a new generator restarts the stream)."""
        if rng is not self.rng:
            self.restart(rng)
        while not self.queue:
            fill([self])
        episode = self.queue.popleft()
        if episode is None:
            raise draws_error(self.min_margin)
        return episode


def fill(streams: Sequence[EpisodeStream]) -> None:
    """Draw each stream's next batch of candidates from its generator and build them all in
    one :func:`build_episodes` call; queue each stream's episodes in draw order."""
    drafts, owners = [], []
    for s, stream in enumerate(streams):
        assert stream.rng is not None
        raw = stream.sampler.raw(stream.rng, stream.batch)
        stream.drawn += stream.batch
        for row in raw:
            drafts.append(stream.sampler.scene(row))
            owners.append(s)
        stream.batch = min(2 * stream.batch, AHEAD)
    valid = [i for i, d in enumerate(drafts) if d is not None]
    first = streams[0]
    built = build_episodes(
        [drafts[i] for i in valid], first.k_max_ratio, first.big, first.min_margin
    )
    episodes: list[ObjectEpisode | None] = [None] * len(drafts)
    for i, episode in zip(valid, built, strict=True):
        episodes[i] = episode
    for owner, episode in zip(owners, episodes, strict=True):
        stream = streams[owner]
        if episode is not None:
            stream.queue.append(episode)
            stream.streak = 0
            continue
        stream.streak += 1
        if stream.streak >= MAX_DRAWS:
            stream.queue.append(None)
            stream.streak = 0


__all__ = [
    "AHEAD",
    "MAX_EXPERT_GAP",
    "EpisodeStream",
    "ObjectEpisode",
    "ObjectLayout",
    "build_episodes",
    "fill",
    "pair_slots",
    "projection",
    "solve_pending",
]
