"""The thesis swarm's robots on the vectorised host step: one cycle of every :class:`.thesis.ThesisPioneer`
of an agent host on arrays.

The per-robot cycle (:meth:`.thesis.ThesisPioneer.update`, thesis 3.6.2.4 and 4.2.3) is the
specification, row by row (the equivalence on recorded inputs is a unit test,
``tests/agents/test_swarm_thesisstep.py``):

- the localize guard (:meth:`.thesis.ThesisPioneer.guard`) of each robot, as its own cycle calls it;
- the sonar ring fused into sectors (:func:`.vector.fuse_rings`), the neighbours' bodies filled in
  where the host's latest broadcasts put them round each robot's localize pose
  (:func:`neighbour_bodies`, the arrays of :func:`.thesis._bodies` for every robot at once) and the
  sectors without them (:attr:`.behaviour.Disperse.walls`);
- the behaviour with the body-aware checks of :func:`.thesis.params_for_size` (the lane ahead and
  behind, the turn guard) and the heading from the localize pose (:meth:`.vector.VectorState.step`);
- the commands sent as :meth:`rsal.robot.Pioneer.update` sends them (:class:`.vector.HostStep`).

A robot without a localize pose yet, without neighbours' positions to read, or without its scan,
odometry or beam geometry runs its own ``update()`` that cycle.
"""

from __future__ import annotations

import numpy as np

from rsal.behaviours import SECTOR_COUNT

from .vector import HostStep

__all__ = ["ThesisStep", "neighbour_bodies"]

_SECTOR = 360.0 / SECTOR_COUNT
_HALF_SECTOR = _SECTOR / 2
_COLS = np.arange(SECTOR_COUNT)


def neighbour_bodies(
    est: np.ndarray, xy: np.ndarray, own: np.ndarray, reach: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """Per robot and sector, the nearest surface of its neighbours' bodies: row i of ``est`` (N, 3)
    is a robot's (x, y, yaw) and ``own[i]`` its own row of ``xy`` (-1: none); the rows of ``xy``
    (M, 2; NaN: unknown) within ``reach[i]`` m of it (the hub's :meth:`~agents.hub.RobotHub.near`)
    are discs of ``radius[i]`` m, each filling the sectors its width spans (:func:`.thesis._bodies`).
    (N, 36), inf where none."""
    n = len(est)
    out = np.full((n, SECTOR_COUNT), np.inf)
    if not n or not len(xy):
        return out
    d = xy[None, :, :] - est[:, None, :2]
    with np.errstate(invalid="ignore"):
        ok = np.einsum("nmk,nmk->nm", d, d) <= (reach * reach)[:, None]
    has = own >= 0
    ok[np.flatnonzero(has), own[has]] = False
    i, j = np.nonzero(ok)
    if not len(i):
        return out
    dx, dy = d[i, j, 0], d[i, j, 1]
    dist = np.hypot(dx, dy)
    keep = dist >= 1e-6
    i, dx, dy, dist = i[keep], dx[keep], dy[keep], dist[keep]
    r = radius[i]
    surface = np.maximum(0.0, dist - r)
    bearing = np.degrees(np.arctan2(dy, dx) - est[i, 2])
    half = np.degrees(np.arcsin(np.minimum(1.0, r / dist)))
    i0 = np.floor((bearing - half + _HALF_SECTOR) / _SECTOR)
    i1 = np.minimum(np.floor((bearing + half + _HALF_SECTOR) / _SECTOR), i0 + SECTOR_COUNT - 1)
    cols = (i0.astype(np.int64)[:, None] + _COLS) % SECTOR_COUNT
    vals = np.where(_COLS <= (i1 - i0)[:, None], surface[:, None], np.inf)
    np.minimum.at(out, (np.broadcast_to(i[:, None], cols.shape), cols), vals)
    return out


class ThesisStep(HostStep):
    """``hub.batch`` of a thesis swarm's agent host: the :class:`.vector.HostStep` for the rows of
    ``robot_class`` (:class:`.thesis.ThesisPioneer`), their neighbours read from ``hub``'s latest
    broadcasts (:meth:`agents.hub.RobotHub.received_positions`) once per cycle for all of them."""

    def __init__(self, hub, clock_now, robot_class: type):
        super().__init__(clock_now)
        self.hub = hub
        self.robot_class = robot_class

    def takes(self, r) -> bool:
        return type(r) is self.robot_class and r.vectorised and not r.laser_enabled and len(r.sonars) == 1

    def row(self, r):
        """The robot's localize pose, after its guard has seen it (its own cycle's first act); None
        without one or without a neighbour source (its own ``update()`` then)."""
        m = r.localize.latest if r.localize is not None else None
        if m is None or r.neighbours is None:
            return None
        r.guard(m.pose)
        return m.pose

    def adjust(self, rows: list, extra: list, pose: np.ndarray, sectors: np.ndarray):
        est = np.array(extra, dtype=float)
        xy, index = self.hub.received_positions()
        own = np.array([index.get(r.name, -1) for r in rows], dtype=np.int64)
        reach = np.array([r.neighbour_range for r in rows], dtype=float)
        radius = np.array([r.neighbour_radius for r in rows], dtype=float)
        tol = np.array([r.explained_within for r in rows], dtype=float)
        bodies = neighbour_bodies(est, np.asarray(xy, dtype=float), own, reach, radius)
        # an echo no farther than a neighbour's body (give or take the poses' errors) is that robot
        walls = np.where(sectors < bodies - tol[:, None], sectors, np.inf)
        return np.minimum(sectors, bodies), walls, est[:, 2].copy()
