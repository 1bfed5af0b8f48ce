"""Checks of a dispatcher task against the floor map: outside the map, unreachable, through walls.

A point is *reachable* when it lies in the drivable space of the map (free cells, Player's -1,
farther than ``robot_radius`` from any other cell, by ``scipy.ndimage.distance_transform_edt``) and
in a connected part of it (8-neighbourhood) that holds one of the ``starts`` (the robots), as in
:func:`agents.scenarios.distribution.target_points`. A patrol route leg goes *through a wall* when
a cell on the straight segment between two route points (sampled every half cell) is not free:
patrol routes are driven leg by leg in straight lines. Each failure raises :class:`TaskRefused`
with the reason and one line naming the point and a fix.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from rsal.msgs import MapData

from .core import Charger
from .tasks import Refusal, Task, TaskRefused, task_places

__all__ = ["MapCheck"]


class MapCheck:
    """Callable ``check(task)`` for :class:`agents.dispatch.Dispatcher` on ``grid``."""

    def __init__(self, grid: MapData, starts: Sequence[Sequence[float]] = (), *, robot_radius: float = 0.25):
        from scipy import ndimage

        cells = np.asarray(grid.cells)
        self.res = float(grid.resolution)
        self.ox, self.oy = float(grid.origin[0]), float(grid.origin[1])
        self.h, self.w = cells.shape
        self.free = cells < 0
        dist = ndimage.distance_transform_edt(self.free) * self.res
        self.drivable = dist >= robot_radius
        self.labels, _ = ndimage.label(self.drivable, structure=np.ones((3, 3), dtype=bool))
        self.keep: set[int] = set()
        for s in starts:
            self.add_start(float(s[0]), float(s[1]))

    def bounds(self) -> tuple[float, float, float, float]:
        return self.ox, self.oy, self.ox + self.w * self.res, self.oy + self.h * self.res

    def cell(self, x: float, y: float) -> tuple[int, int] | None:
        r, c = int(math.floor((y - self.oy) / self.res)), int(math.floor((x - self.ox) / self.res))
        return (r, c) if 0 <= r < self.h and 0 <= c < self.w else None

    def add_start(self, x: float, y: float) -> None:
        """A robot stands at (x, y): its part of the drivable space is reachable (the nearest
        drivable cell within 1 m, for a robot close to a wall)."""
        rc = self.cell(x, y)
        if rc is None:
            return
        k = int(math.ceil(1.0 / self.res))
        r, c = rc
        win = self.labels[max(0, r - k) : r + k + 1, max(0, c - k) : c + k + 1]
        if win.any():
            rr, cc = np.nonzero(win)
            i = int(np.argmin((rr + max(0, r - k) - r) ** 2 + (cc + max(0, c - k) - c) ** 2))
            self.keep.add(int(win[rr[i], cc[i]]))

    def _where(self, x: float, y: float, what: str) -> str:
        x0, y0, x1, y1 = self.bounds()
        return f"{what} ({x:g}, {y:g}) is outside the map; use x in [{x0:g}, {x1:g}] and y in [{y0:g}, {y1:g}] m"

    def point(self, task_id: str, x: float, y: float, what: str = "goal") -> None:
        rc = self.cell(x, y)
        if rc is None:
            raise TaskRefused(Refusal.OUTSIDE_MAP, f"task {task_id}: {self._where(x, y, what)}")
        lab = int(self.labels[rc])
        if not self.drivable[rc] or (self.keep and lab not in self.keep):
            why = "in or next to a wall" if not self.drivable[rc] else "in a part of the map no robot can reach"
            raise TaskRefused(
                Refusal.UNREACHABLE, f"task {task_id}: {what} ({x:g}, {y:g}) is {why}; pick a point in open floor space"
            )

    def leg(self, task_id: str, a: Sequence[float], b: Sequence[float]) -> None:
        n = max(2, int(math.ceil(math.hypot(b[0] - a[0], b[1] - a[1]) / (self.res / 2))) + 1)
        xs, ys = np.linspace(a[0], b[0], n), np.linspace(a[1], b[1], n)
        r = np.floor((ys - self.oy) / self.res).astype(int).clip(0, self.h - 1)
        c = np.floor((xs - self.ox) / self.res).astype(int).clip(0, self.w - 1)
        blocked = ~self.free[r, c]
        if blocked.any():
            i = int(np.argmax(blocked))
            raise TaskRefused(
                Refusal.THROUGH_WALL,
                f"task {task_id}: route leg ({a[0]:g}, {a[1]:g}) -> ({b[0]:g}, {b[1]:g}) crosses a wall near "
                f"({xs[i]:.2f}, {ys[i]:.2f}); add a route point that goes around it",
            )

    def __call__(self, task: Task) -> None:
        pts = task_places(task)
        for i, (x, y) in enumerate(pts):
            self.point(task.id, x, y, "goal" if len(pts) == 1 else f"point {i}")
        if task.kind == "patrol":
            route = task.args["route"]
            for a, b in zip(route, route[1:] + route[:1], strict=True):
                self.leg(task.id, a, b)

    def check_chargers(self, chargers: Sequence[Charger], where: str = "chargers") -> None:
        """Raise ValueError (one line) for a charger outside the map."""
        for c in chargers:
            if self.cell(c.x, c.y) is None:
                raise ValueError(f"{where}: {self._where(c.x, c.y, f'charger {c.name!r}')}")
