"""The Swarm scenario's behaviour (thesis 3.6.2.4, 4.2.3): wall-following with a disperse layer.

:class:`Disperse` is the subsumption behaviour of 3.6.2.4 (escape, avoid, wall-follow) with one
more layer for a crowd in open space; :class:`SwarmPioneer` drives a Pioneer with it;
:func:`away_from` is the heading away from the neighbours (each pushing with 1/d), and
:func:`away_headings` the same for many robots at once (a k-d tree; the neighbourhood form's hub
computes every robot's heading this way before each re-watch).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from rsal.behaviours import Sectors, Subsumption
from rsal.data import Position, normalize_angle
from rsal.robot import Pioneer

__all__ = ["Disperse", "SwarmPioneer", "away_from", "away_headings"]


class Disperse(Subsumption):
    """The subsumption behaviour of thesis 3.6.2.4 with one more layer for a crowd in open space.

    Plain wall-following curves towards its side while no wall is in sight, which in an open arena
    keeps a robot circling where it started. Here, while wall-following sees no wall, the robot
    instead steers to :attr:`heading` (radians, world frame; set from the neighbours' broadcast
    positions) or, without one, drives straight on, so the crowd spreads out "towards a wall"
    (thesis fig. 4.7); once a wall is in sight wall-following takes over. Escape and avoid still
    override it. :attr:`yaw` is the robot's current heading, set every cycle by its robot. A robot
    that knows where its neighbours are sets :attr:`walls`: the echoes they explain are not walls,
    so a robot in a crowd disperses instead of following its neighbours round.
    """

    def __init__(self, params=None):
        super().__init__(params)
        self.heading: float | None = None
        self.yaw: float = 0.0
        #: the sectors without what is known to be another robot (set each cycle by a robot that
        #: knows its neighbours' positions); None: every echo may be a wall
        self.walls: Sectors | None = None

    def step(self, s: Sectors, now: float, stalled: bool = False) -> tuple[float, float]:
        v, w = super().step(s, now, stalled)
        if self.state != "wallfollow":
            return v, w
        p = self.p
        sign = 1.0 if p.side == "left" else -1.0
        ws = self.walls if self.walls is not None else s  # is a wall in sight, not only robots?
        side_d = ws.min_between(60, 120) if sign > 0 else ws.min_between(-120, -60)
        diag = ws.min_between(30, 60) if sign > 0 else ws.min_between(-60, -30)
        if min(side_d, diag) <= 2.5 * p.wall_dist:
            return v, w  # a wall to follow
        self.state = "disperse"
        if self.heading is None:
            return p.cruise_speed, 0.0
        err = normalize_angle(self.heading - self.yaw)
        w = max(-p.turn_rate, min(p.turn_rate, 1.5 * err))
        return self.guard_turn(s, p.cruise_speed * (1.0 if abs(err) < 0.8 else 0.4), w)


class SwarmPioneer(Pioneer):
    """A :class:`rsal.robot.Pioneer` whose behaviour is :class:`Disperse`: the same cycle, with the
    robot's heading handed to the behaviour before each step. A host's vectorised step
    (:class:`.vector.HostStep`) runs the cycle of many at once unless :attr:`vectorised` is false."""

    vectorised = True

    def __init__(self, devices, **kw):
        super().__init__(devices, **kw)
        self.behaviour = Disperse(self.behaviour.p)

    def update(self) -> None:
        m = self.position2d.latest
        if m is not None:
            self.behaviour.yaw = m.pose[2]
        super().update()


def away_from(me: Position, others: Sequence[Position] | np.ndarray, radius: float) -> float | None:
    """The heading (rad) away from the neighbours (poses, or an (n, 2) array of positions) within
    ``radius`` m, each pushing with 1/d; None when none is that close."""
    if len(others) == 0:
        return None
    if isinstance(others, np.ndarray):
        xy = others.reshape(-1, 2)
    else:
        xy = np.array([(o.x, o.y) for o in others], dtype=float)
    d = np.array([me.x, me.y]) - xy
    r2 = np.einsum("ij,ij->i", d, d)
    near = (r2 < radius * radius) & (r2 > 1e-6)
    if not near.any():
        return None
    v = (d[near] / r2[near, None]).sum(axis=0)
    if not np.any(v):
        return None
    return math.atan2(v[1], v[0])


def away_headings(me: np.ndarray, others: np.ndarray, radius: np.ndarray, own: np.ndarray) -> np.ndarray:
    """:func:`away_from` for many robots at once: row i of ``me`` (n, 2) pushed away from the rows
    of ``others`` (m, 2; NaN rows ignored) within ``radius[i]`` m, except row ``own[i]`` (its own
    broadcast; -1: none). NaN where no neighbour is that close."""
    from scipy.spatial import cKDTree

    out = np.full(len(me), np.nan)
    ok = ~np.isnan(others).any(axis=1)
    if not len(me) or not ok.any():
        return out
    rows = np.nonzero(ok)[0]
    pairs = cKDTree(me).sparse_distance_matrix(cKDTree(others[rows]), float(np.max(radius)), output_type="ndarray")
    i, j, dist = pairs["i"], rows[pairs["j"]], pairs["v"]
    keep = (dist < radius[i]) & (dist > 1e-3) & (j != own[i])
    i, j, dist = i[keep], j[keep], dist[keep]
    d = (me[i] - others[j]) / (dist * dist)[:, None]
    px = np.bincount(i, weights=d[:, 0], minlength=len(me))  # the push on each row, summed
    py = np.bincount(i, weights=d[:, 1], minlength=len(me))
    has = np.zeros(len(me), dtype=bool)
    has[i] = True
    has &= (px != 0.0) | (py != 0.0)
    out[has] = np.arctan2(py[has], px[has])
    return out
