"""Pictures of the can gait environments: the can, the fingertips on its side, their pushes
and friction cones (:class:`~grasp_env.physics.GraspView` on the can with one contact per
finger). The turn is about the can's axis, so the grasp in the world frame depends only on
the fingers' ages: the view draws the can in the world frame (a plain cylinder looks the same
at every alpha; the caption gives alpha) with a model per set of contact points, the last few
kept. Imported only when a frame is drawn: environments that never render load no MuJoCo."""

from __future__ import annotations

import importlib.util
from collections import OrderedDict

import numpy as np

from ...mechanics import Scene
from ...physics import GraspView
from .env import CanGaitTask

#: Views (MuJoCo models with their renderers) kept, one per set of contact points.
_KEPT = 4


def resting_frame(task: CanGaitTask, x: int, t: int) -> tuple:
    """What a frame shows before the first step: the state's ages and the forces of the
    certified grip of the fingers it keeps loaded (eq. 2, 4)."""
    table = task.table
    t = min(t, task.n_poses - 1)
    ages = table.states[x].copy()
    forces = np.zeros((task.n_fingers, 3))
    lo = int(table.ptr[x])
    if table.ptr[x + 1] > lo:
        config = int(table.config[lo])
        fingers = [f for f, _ in task.solution.values.configs[config]]
        _, _, _, net = task.score(fingers, ages, task.optimal_grip(config))
        forces[fingers] = net
    return t, ages, forces, None


class CanView:
    """Draws a can gait task's frames (see the module docstring); 480 x 480 pixels."""

    def __init__(self, task: CanGaitTask, width: int = 480, height: int = 480) -> None:
        self.task = task
        self.size = (width, height)
        self._views: OrderedDict[tuple[int, ...], GraspView] = OrderedDict()
        self._caption = importlib.util.find_spec("PIL") is not None

    def caption(self, t: int, ages: np.ndarray, margin: float | None) -> list[str]:
        """The overlay's lines: alpha (and the step's margin), the touching fingers' ages."""
        first = f"alpha {self.task.solution.turn.alphas_deg[t]:.0f} deg"
        if margin is not None:
            first += f"   margin {np.degrees(margin):+.2f} deg"
        names = self.task.solution.hand.names
        on = [f"{names[f]} {int(a)}" for f, a in enumerate(ages) if a >= 0]
        lines = [first, ("ages: " + "  ".join(on)) if on else "no finger touches"]
        if len(on) < 3:
            lines.append("the can drops")
        return lines

    def _view(self, ages: np.ndarray) -> GraspView:
        key = tuple(int(a) for a in ages)
        if key in self._views:
            self._views.move_to_end(key)
            return self._views[key]
        task = self.task
        rows = np.arange(task.n_fingers)
        where = np.clip(ages, 0, task.max_age + 1)  # a lifted finger waits at its patch's edge
        solution = task.solution
        scene = Scene(
            contacts=task.points[rows, where],
            weight=solution.weight,
            mu=solution.mu,
            shape=solution.can,
        )
        view = GraspView(scene, "rgb_array", *self.size)
        view.camera.elevation = -25.0
        self._views[key] = view
        if len(self._views) > _KEPT:
            self._views.popitem(last=False)[1].close()
        return view

    def render(
        self, t: int, ages: np.ndarray, forces: np.ndarray, margin: float | None = None
    ) -> np.ndarray:
        """Pose ``t`` with the fingers at ``ages`` (F,) (-1: lifted) pushing ``forces`` (F, 3),
        newtons, world frame; ``margin`` (radians) goes into the caption."""
        ages = np.asarray(ages, np.int64)
        touching = ages >= 0
        forces = np.array(forces, float)
        tiny = touching & (np.linalg.norm(forces, axis=1) <= 1e-6 * self.task.solution.weight)
        rows = np.flatnonzero(tiny)  # a push too small to draw: along the normal, green
        forces[rows] = 1e-12 * self.task.normals[rows, np.clip(ages[rows], 0, None)]
        text = self.caption(t, ages, margin) if self._caption else ()
        return self._view(ages).render(np.eye(3), forces, touching, text)

    def close(self) -> None:
        """Free every view's renderer."""
        for view in self._views.values():
            view.close()
        self._views.clear()
