"""Running motions in MuJoCo, many at once: ``mujoco.rollout`` steps them in C (it releases the
GIL), and the measurements are taken afterwards from the states of every step. A batch is split
into parts (:func:`in_parallel`: one contiguous part per thread, or, for trajectories, one run
at a time taken by the threads in turn), and each part is planned, stepped and measured by its
own thread: one part's Python then overlaps another's stepping, where a rollout thread pool
alone would leave the cores idle while the Python plans and measures.

A batch of runs steps in lockstep through chunks of steps. Chunks end where the settle ends (the
settle runs on a copy of the model with a high friction coefficient), where a finger is
placed or lifted in any run, and, on a curved object, where a contact starts or stops rolling
(:meth:`PhysicsModel.rolling`: each chunk runs on the model whose pairs roll as the run's
contacts do at its first step): between chunks those fingertips are moved (a placed one to its
contact, just inside the face; a lifted one to its parking place off the face). A touching
fingertip's motor pushes with its commanded force plus what its own mass needs to follow it
(:func:`~.batch._tip_inertia`), so that its contact pushes with the commanded force. The forces of
fingers that do not touch (released, see :mod:`~grasp_env.physics.motion`) act on the object
directly, at their contact points. Shorter runs are padded by holding their last step, and
measured over their own steps only.

A motion whose tips change their contact points (:attr:`~grasp_env.physics.motion.Motion.points`,
a gait with one tip per finger) runs on :meth:`PhysicsModel.following` it: the same MuJoCo
model (its tips are free bodies, placed by their joint positions), with the per-scene arrays the
controls and measurements read (contact points, normals, lever arms, where a tip is placed and
parked) given per step; such a run steps in a batch of its own.

The Python around the rollout is kept to whole-batch array work, since it does not run in
parallel: the controls of a batch are built in one pass, initial states are cached per finger
set, ``mujoco.rollout`` gets its inputs laid out as it wants them (its checks skipped), and the
measurements of the runs of one length are taken in one vectorised pass.
"""

from __future__ import annotations

import copy
import itertools
import threading
from collections.abc import Callable, Sequence

import mujoco
import mujoco.rollout
import numpy as np
from numpy.typing import ArrayLike

from grasp_env.mechanics import Scene
from grasp_env.mechanics.checks import is_integer
from grasp_env.mechanics.threads import available_cores, in_parts

from .batch import Trace, _controls, _measure, _move_fingers, _moves
from .model import (
    TIP_PENETRATION,
    build_mjcf,
    contact_shift,
    is_curved,
    model_cg,
    model_contacts,
    rolling_contacts,
    tip_centres,
    tip_positions,
    tip_radius,
    touches_faces,
)
from .motion import Motion, plan_motion

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
_CONTROL = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED
#: A batch steps at most this many (run x step) rows in one rollout call per chunk (to bound
#: memory: about 30 MB of controls and states). Fewer, larger calls: fewer points where the
#: threads wait for the Python between chunks.
_ROWS_PER_BATCH = 60_000


_local = threading.local()  # each thread's rollout runner and MjData (MuJoCo's are not shared)


def _runner() -> mujoco.rollout.Rollout:
    """This thread's rollout runner (no pool of its own: it steps on the calling thread)."""
    if not hasattr(_local, "runner"):
        _local.runner = mujoco.rollout.Rollout(nthread=0)
    return _local.runner


def in_parallel(
    work: Callable[[Sequence], list], items: Sequence, threads: int, size: int | None = None
) -> list:
    """``work`` of parts of ``items`` on ``threads`` threads, the results in order. Each part
    plans, simulates and measures its runs by itself: MuJoCo's stepping releases the GIL, so
    one part's Python overlaps another's stepping (a rollout thread pool alone leaves the cores
    idle while the Python plans and measures). ``size`` None: one contiguous part per thread
    (the most whole-batch array work per call); else the threads take parts of ``size`` items
    in turn, so that while one thread's Python holds the GIL the other steps (for runs whose
    own Python is a large share, such as planned trajectories). A run's result does not depend
    on its part (see :func:`simulate`)."""
    if size is None:
        parts = in_parts("grasp-physics", len(items), lambda lo, hi: work(items[lo:hi]), threads)
        return [result for part in parts for result in part]
    starts = range(0, len(items), size)
    results: list[list] = [[] for _ in starts]
    taken = itertools.count()  # next() on it is atomic under the GIL

    def take(_lo: int, _hi: int) -> None:
        while (p := next(taken)) < len(results):
            results[p] = work(items[starts[p] : starts[p] + size])

    # a pool of its own: the threads take the parts in turn, so in_parts' split (learnt per
    # pool name) means nothing here and must not be learnt from these calls
    in_parts("grasp-physics-queue", len(results), take, threads)
    return [result for part in results for result in part]


class PhysicsModel:
    """A scene's MuJoCo models (at the scene's mu, and the settle's) and their layout.

    Args:
        scene: the grasp.
        timestep: simulation step, seconds.
        settle_mu: friction coefficient while the contact forces build up.
    """

    def __init__(self, scene: Scene, timestep: float, settle_mu: float) -> None:
        self.scene = scene
        xml = build_mjcf(scene, timestep=timestep)
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.settle_model = mujoco.MjModel.from_xml_string(xml)
        self.settle_model.pair_friction[:, :2] = settle_mu
        # on a curved object, the models (and settle models) with some pairs at condim 3, per
        # pattern of rolling contacts (:meth:`rolling`), made when first needed
        self.curved = is_curved(scene)
        self._rolling_models: dict[bytes, tuple[mujoco.MjModel, mujoco.MjModel]] = {}
        n = scene.n_contacts
        self.n = n
        self.nq, self.nv = self.model.nq, self.model.nv
        self.nstate = mujoco.mj_stateSize(self.model, _STATE)
        self.ncontrol = mujoco.mj_stateSize(self.model, _CONTROL)
        self.object = self.model.body("object").id
        self.radius = tip_radius(scene)
        self.contacts = model_contacts(scene)
        self.cg = model_cg(scene)
        self.placed = tip_positions(scene, np.ones(n, dtype=bool))
        self.parked = tip_positions(scene, np.zeros(n, dtype=bool))
        # Models share rollout calls (and MjData) only with models of the same structure:
        # MuJoCo lays out its sparse matrices differently for a "simple" body (a centre of
        # gravity at the box centre) than for another.
        self.signature = (
            n,
            self.model.body_simple.tobytes(),
            self.model.dof_simplenum.tobytes(),
        )
        # Per-scene constants of the controls and the measurement, computed once.
        self.normals = scene.normals
        self.timestep = self.model.opt.timestep
        self.arms = self.contacts - self.cg  # about the centre of gravity, object at rest
        self.nu = 3 * n
        self.wrench_start = self.nu + 6 * self.object
        self._data: dict[int, mujoco.MjData] = {}
        self._initial: dict[bytes, np.ndarray] = {}
        self._response = self._contact_response()
        self.rest_depth = TIP_PENETRATION * self.radius  # of a placed tip
        # every shape's contact lever arms restored: MuJoCo's contact point lies d / 2 inside
        # the face, and the tangential forces' torque about it turns a flat object too
        # (a three-finger box grip 0.1 deg inside turned 0.118 deg over a 15-pose run)
        self.lever = contact_shift(scene, self._response[3])

    def _contact_response(self) -> tuple[float, float, float, float]:
        """A fingertip contact's stiffness K I, damping B, regulariser R and inverse inertia A
        as MuJoCo sets them (its soft constraint, read at the initial state)."""
        data = self.data()
        mujoco.mj_setState(self.model, data, self._initial_state(np.ones(self.n, bool)), _STATE)
        mujoco.mj_forward(self.model, data)
        row = data.contact[0].efc_address  # the normal row of a fingertip's contact
        stiffness, damping, impedance, _ = data.efc_KBIP[row]
        regulariser = data.efc_R[row]  # (1 - I) / I x A
        return (
            float(stiffness * impedance),
            float(damping),
            float(regulariser),
            float(regulariser * impedance / (1.0 - impedance)),
        )

    def rolling(self, motion: Motion) -> np.ndarray | None:
        """Which tips' contacts roll at each step of ``motion``, (N, n)
        (:func:`~grasp_env.physics.model.rolling_contacts`, from the commanded normal forces);
        None on a flat-faced object (condim 3 throughout)."""
        if not self.curved:
            return None
        normals = self.normals if motion.normals is None else motion.normals
        return rolling_contacts(np.sum(motion.forces * normals, axis=-1), motion.contact)

    def models(self, rolling: np.ndarray | None) -> tuple[mujoco.MjModel, mujoco.MjModel]:
        """The model and the settle model whose contact pairs roll (condim 6) where
        ``rolling`` (n,) says and are at condim 3 elsewhere (None: the scene's own, cached per
        pattern). MuJoCo reads ``pair_dim`` at every step, so a run switches between them at
        the steps where the pattern changes."""
        if rolling is None or rolling.all():
            return self.model, self.settle_model
        key = rolling.tobytes()
        pair = self._rolling_models.get(key)
        if pair is None:
            pair = (copy.copy(self.model), copy.copy(self.settle_model))
            for model in pair:
                model.pair_dim[~rolling] = 3
            self._rolling_models[key] = pair
        return pair

    def data(self) -> mujoco.MjData:
        """The calling thread's MjData of this model, kept for reuse."""
        data = self._data.get(threading.get_ident())
        if data is None:
            data = self._data[threading.get_ident()] = mujoco.MjData(self.model)
        return data

    def initial_state(self, contact: np.ndarray) -> np.ndarray:
        """The full physics state at rest: the object at the identity, centre of gravity at
        the origin, fingers in ``contact`` just inside their faces, the others parked (a new
        array; built once per finger set)."""
        return self._initial_state(contact).copy()

    def _initial_state(self, contact: np.ndarray) -> np.ndarray:
        """:meth:`initial_state`, cached per finger set (not to be written to)."""
        key = np.asarray(contact, dtype=bool).tobytes()
        state = self._initial.get(key)
        if state is None:
            state = self._initial[key] = self._build_initial_state(np.asarray(contact, bool))
        return state

    def following(self, motion: Motion) -> PhysicsModel:
        """This model for ``motion``: itself if the motion's tips keep the scene's contacts,
        else a copy whose contact points, normals, lever arms and tip places are the motion's
        per step, (N, n, 3) each (its runs step alone: a signature of their own)."""
        if motion.points is None:
            return self
        if touches_faces(self.scene) and not np.allclose(motion.normals, self.scene.normals):
            raise ValueError(
                "a tip on a box or a convex mesh touches its own face's half-space"
                " (model.face_geoms): its contact point may move along that face, not onto"
                " another face"
            )
        moving = copy.copy(self)
        moving.contacts, moving.normals = motion.points, motion.normals
        moving.arms = motion.points - self.cg
        moving.placed = tip_centres(motion.points, motion.normals, self.radius, True)
        moving.parked = tip_centres(motion.points, motion.normals, self.radius, False)
        moving.signature = (*self.signature, id(moving))
        moving._initial = {}
        return moving

    def at_step(self, step: int) -> PhysicsModel:
        """This model with the tips' places (``placed``, ``parked``, (n, 3)) of ``step``: itself
        unless it follows a motion (:meth:`following`)."""
        if self.placed.ndim == 2:
            return self
        here = copy.copy(self)
        here.placed, here.parked = self.placed[step], self.parked[step]
        return here

    def _build_initial_state(self, contact: np.ndarray) -> np.ndarray:
        data = self.data()
        mujoco.mj_resetData(self.model, data)
        data.qpos[:3] = -self.cg
        data.qpos[3] = 1.0
        start = self.at_step(0)
        data.qpos[7:] = (np.where(contact[:, None], start.placed, start.parked) - self.cg).ravel()
        state = np.empty(self.nstate)
        mujoco.mj_getState(self.model, data, state, _STATE)
        return state


def simulate(
    runs: list[tuple[PhysicsModel, Motion]],
    threads: int | None = None,
) -> list[Trace]:
    """Run each (model, motion) pair and measure it (see the module docstring).

    ``threads`` (default: every available core) is the number of parts run at once. Runs share
    rollout calls with runs of the same model structure (:attr:`PhysicsModel.signature`),
    settle and steps where fingers move, and nothing else: so a run's result is the same alone
    or in any batch, on any number of threads (a chunk boundary restarts MuJoCo's solver warm
    start).
    """
    return in_parallel(_simulate_serial, runs, check_threads(threads))


def check_threads(threads: int | None) -> int:
    """``threads`` (None: every available core): an integer >= 1 (not a boolean, a float or a
    string), or a ValueError."""
    if threads is None:
        return available_cores()
    if not is_integer(threads) or threads < 1:
        raise ValueError(
            f"threads must be >= 1, an integer (or None: every available core), got {threads!r}"
        )
    return int(threads)


def check_cases(cases: Sequence, item: str) -> list[tuple]:
    """``cases``, a sequence (list or tuple) of (scene, ``item``...) tuples whose scenes are
    :class:`~grasp_env.mechanics.Scene` s, as a list, or a ValueError naming what is wrong.
    Empty is fine (no case, no report)."""
    form = f"a list of (scene, {item}, contact_forces, in_contact) tuples"
    if isinstance(cases, str | bytes) or not isinstance(cases, Sequence):
        raise ValueError(f"cases must be {form}, got {type(cases).__name__}")
    for c, case in enumerate(cases):
        if not isinstance(case, tuple | list) or len(case) != 4:
            raise ValueError(
                f"case {c} must be a (scene, {item}, contact_forces, in_contact) tuple"
                f" (in_contact may be None), got {described(case)}"
            )
        if not isinstance(case[0], Scene):
            raise ValueError(
                f"case {c}'s scene must be a grasp_env.mechanics.Scene, got"
                f" {type(case[0]).__name__}"
            )
    return list(cases)


def described(value: object) -> str:
    """A short description of a value for a message: its type, and its length if it has one."""
    kind = type(value).__name__
    return f"a {kind} of length {len(value)}" if isinstance(value, tuple | list) else f"a {kind}"


def _simulate_serial(runs: Sequence[tuple[PhysicsModel, Motion]]) -> list[Trace]:
    """:func:`simulate` on the calling thread."""
    traces: list[Trace | None] = [None] * len(runs)
    groups: dict[tuple, list[int]] = {}
    runs = [(physics.following(motion), motion) for physics, motion in runs]
    moves = [_moves(motion) for _, motion in runs]
    rolls = [physics.rolling(motion) for physics, motion in runs]
    for r, (physics, motion) in enumerate(runs):
        place, lift = moves[r]
        steps = np.flatnonzero(np.any(place | lift, axis=-1)).tobytes()
        switches = b"" if rolls[r] is None else _switches(rolls[r]).tobytes()
        key = (physics.signature, motion.settle_steps, steps, switches)
        groups.setdefault(key, []).append(r)
    for which in groups.values():
        length = max(len(runs[r][1]) for r in which)
        per_batch = max(1, _ROWS_PER_BATCH // length)
        for start in range(0, len(which), per_batch):
            part = which[start : start + per_batch]
            batch = _simulate_batch(
                [runs[r] for r in part], [moves[r] for r in part], [rolls[r] for r in part]
            )
            for r, trace in zip(part, batch, strict=True):
                traces[r] = trace
    return traces  # type: ignore[return-value]


def simulate_cases(
    cases: Sequence[tuple[Scene, ArrayLike, ArrayLike, ArrayLike | None]],
    settings: dict[str, float],
    threads: int | None = None,
) -> list[tuple[Motion, Trace]]:
    """Plan and :func:`simulate` (scene, rotations (T, 3, 3), forces (T, n, 3), in_contact)
    cases over many scenes at once, one model per scene (``settings`` already checked)."""
    cases = check_cases(cases, "rotations")
    threads = check_threads(threads)
    physics: dict[int, PhysicsModel] = {}
    for scene, *_ in cases:
        if id(scene) not in physics:
            physics[id(scene)] = PhysicsModel(scene, settings["timestep"], settings["settle_mu"])

    def run(part: Sequence[tuple]) -> list[tuple[Motion, Trace]]:
        motions = [plan_motion(scene, *grip, settings) for scene, *grip in part]
        runs = [(physics[id(scene)], m) for (scene, *_), m in zip(part, motions, strict=True)]
        return list(zip(motions, _simulate_serial(runs), strict=True))

    return in_parallel(run, cases, threads, size=1)


def _switches(rolling: np.ndarray) -> np.ndarray:
    """The steps at which a run's pattern of rolling contacts (N, n) changes."""
    return np.flatnonzero(np.any(rolling[1:] != rolling[:-1], axis=-1)) + 1


def _simulate_batch(
    runs: list[tuple[PhysicsModel, Motion]],
    moves: list[tuple[np.ndarray, np.ndarray]],
    rolls: list[np.ndarray | None] | None = None,
) -> list[Trace]:
    """One batch of runs that share their model structure, settle, finger moves (their
    :func:`_moves`) and the steps where their rolling contacts change (``rolls``, each run's
    :meth:`PhysicsModel.rolling`; None: none changes)."""
    physics = [p for p, _ in runs]
    motions = [motion for _, motion in runs]
    physics0 = physics[0]
    count = len(runs)
    lengths = np.array([len(motion) for motion in motions])
    length = int(lengths.max())
    settle = motions[0].settle_steps
    if any(motion.settle_steps != settle for motion in motions):
        raise ValueError("the runs of one batch must share the settle")
    place, lift = moves[0]  # fingers move at the same steps in every run of the batch
    events = set(np.flatnonzero(np.any(place | lift, axis=-1)).tolist())
    if rolls is None:
        rolls = [None] * count
    switches = set() if rolls[0] is None else set(_switches(rolls[0]).tolist())
    bounds = sorted({0, settle, length, *events, *switches})
    if np.all(lengths == length):
        controls = _controls(
            physics,
            np.stack([motion.forces for motion in motions]),
            np.stack([motion.load for motion in motions]),
            np.stack([motion.contact for motion in motions]),
        )
    else:  # padded by holding each run's last step
        controls = np.empty((count, length, physics0.ncontrol))
        for r, (p, motion) in enumerate(runs):
            steps = len(motion)
            controls[r, :steps] = _controls(
                [p], motion.forces[None], motion.load[None], motion.contact[None]
            )[0]
            controls[r, steps:] = controls[r, steps - 1]
    state = np.stack([p._initial_state(motion.contact[0]) for p, motion in runs])
    runner, data = _runner(), [physics0.data()]
    chunks = []
    for a, b in itertools.pairwise(bounds):
        if a in events:
            for r, p in enumerate(physics):
                _move_fingers(p.at_step(a), state[r], moves[r][0][a], moves[r][1][a])
        # each run's models for this chunk: its contacts rolling as they do at its first step
        chunk_models = [
            p.models(None if roll is None else roll[min(a, len(roll) - 1)])
            for p, roll in zip(physics, rolls, strict=True)
        ]
        # Inputs are laid out as mujoco.rollout wants them (contiguous float64, one model and
        # initial state per run, the output allocated here), so its checks are skipped.
        states = np.empty((count, b - a, physics0.nstate))
        runner.rollout(
            [pair[0 if a >= settle else 1] for pair in chunk_models],
            data,
            state,
            np.ascontiguousarray(controls[:, a:b]),
            control_spec=_CONTROL,
            skip_checks=True,
            nstep=b - a,
            state=states,
        )
        chunks.append(states)
        state = states[:, -1].copy()  # fingers move in it: not a view of the output
    states = chunks[0] if len(chunks) == 1 else np.concatenate(chunks, axis=1)
    qpos = states[..., 1 : 1 + physics0.nq]
    dt = physics0.timestep
    # MuJoCo's rollout stops stepping (the clock stands still) on a warning.
    late = np.abs(states[..., 0] - dt * np.arange(1, length + 1))
    traces: list[Trace | None] = [None] * count
    for steps in sorted(set(lengths.tolist())):
        which = np.flatnonzero(lengths == steps)
        whole = len(which) == count
        diverged = ~np.all(late[which, :steps] <= dt / 4, axis=1)
        measured = _measure(
            [physics[r] for r in which],
            [motions[r] for r in which],
            np.stack([moves[r][0] for r in which]),
            qpos[:, :steps] if whole else qpos[which, :steps],
            diverged,
        )
        for r, trace in zip(which.tolist(), measured, strict=True):
            traces[r] = trace
    return traces  # type: ignore[return-value]


__all__ = ["PhysicsModel", "Trace", "available_cores", "in_parallel", "simulate"]
