"""The swarm's vectorised host step: one behaviour step for all robots of an agent host.

The subsumption behaviour of thesis 3.6.2.4 (escape, avoid, wall-follow; :class:`rsal.behaviours.Subsumption`)
with the swarm's disperse layer (:class:`.behaviour.Disperse`), and the sector fusion before it
(:func:`rsal.behaviours.fuse_beams`: the nearest beam end point per 10-degree sector), computed on
arrays for N robots at once instead of once per robot in Python. Its semantics are the per-robot
code's, row by row (the equivalence is a unit test, ``tests/agents/test_swarm_vector.py``):

- :func:`fuse_rings`: (N, k) ranges of N rings of k beams (with their (N, k, 4) beam geometry) ->
  (N, 36) sectors;
- :class:`VectorState`: the behaviours' state as arrays (command, wall-following, side, heading,
  yaw, the escape timers) with :meth:`VectorState.step`: sectors, time and stall flags in, (N, 2)
  velocity commands and each row's layer out; with the body-aware checks of
  :class:`rsal.behaviours.BehaviourParams` per row (``corridor``: :func:`lane_distances`; ``sweep``:
  the turn guard) and the sectors without known robots (``walls``, :attr:`.behaviour.Disperse.walls`);
- :class:`HostStep`: the hook of an agent host's :class:`agents.hub.RobotHub` (``hub.batch``) that
  runs one step for every plain :class:`.behaviour.SwarmPioneer` of the host per control cycle:
  it gathers the robots' latest sonar scans and poses, reads their behaviours' state, steps, writes
  the state back (the per-robot objects stay the truth, so a robot may take either path in any
  cycle) and sends the commands. Robots it cannot take (another class, a laser, no data or beam
  geometry yet) run their own ``update()``. Its hooks (:meth:`HostStep.row`, :meth:`HostStep.adjust`)
  let a robot class with more to its cycle run on the same step (:mod:`.thesisstep`).
"""

from __future__ import annotations

import math
import time
from operator import attrgetter
from typing import NamedTuple

import numpy as np

from rsal.behaviours import _AHEAD, _BEHIND, SECTOR_COUNT  # the lane's sectors, defined once there
from rsal.client import HOLD_REFRESH
from rsal.geometry import wrap

from .behaviour import Disperse, SwarmPioneer

__all__ = ["STATES", "HostStep", "VectorState", "fuse_rings", "read_state", "sector_span"]

#: the layer names, in the order of :attr:`VectorState.state`'s codes
STATES = ("idle", "command", "escape", "avoid", "wallfollow", "disperse")
IDLE, COMMAND, ESCAPE, AVOID, WALLFOLLOW, DISPERSE = range(len(STATES))
_CODE = {s: i for i, s in enumerate(STATES)}
_SECTOR = 360.0 / SECTOR_COUNT
_SIN65 = math.sin(math.radians(65))


class _Pose(NamedTuple):
    """A robot's pose at its last cycle (``Pioneer._last_pose``: only ``x`` and ``y`` are read, for
    the distance travelled); a tuple, since a validated :class:`rsal.data.Position` per robot and
    cycle cost a third of the step."""

    x: float
    y: float
    yaw: float


def sector_span(a0_deg: float, a1_deg: float) -> np.ndarray:
    """The sector indices :meth:`rsal.behaviours.Sectors.min_between` reads from ``a0`` to ``a1`` degrees."""
    i0 = math.floor((a0_deg + _SECTOR / 2) / _SECTOR)
    i1 = math.floor((a1_deg + _SECTOR / 2) / _SECTOR)
    return np.arange(i0, i1 + 1) % SECTOR_COUNT


_FRONT, _LEFT, _RIGHT = sector_span(-30, 30), sector_span(30, 100), sector_span(-100, -30)
_SIDE_L, _DIAG_L = sector_span(60, 120), sector_span(30, 60)
_SIDE_R, _DIAG_R = sector_span(-120, -60), sector_span(-60, -30)
# the sectors a turn's corners swing through (Subsumption.guard_turn): turning left, turning right
_SWING_L = np.unique(np.concatenate([sector_span(-30, 90), sector_span(-180, -90), sector_span(150, 180)]))
_SWING_R = np.unique(np.concatenate([sector_span(-90, 30), sector_span(90, 180), sector_span(-180, -150)]))
# the lane's sectors (rsal.behaviours.lane_distance), in its order: (index, cos, sin) ahead and behind
_LANE_AHEAD = [(int(i), c, sn) for i, c, sn in _AHEAD]
_LANE_BEHIND = [(int(i), c, sn) for i, c, sn in _BEHIND]


def fuse_rings(beams: np.ndarray, ranges: np.ndarray, range_max: np.ndarray) -> np.ndarray:
    """:func:`rsal.behaviours.fuse_beams` for N rings at once: ``beams`` (N, k, 4) rows (x, y, cos
    yaw, sin yaw) of each beam's origin in its robot's frame, ``ranges`` (N, k), ``range_max`` (N,);
    a beam counts when its range is below 0.999 of its ring's ``range_max`` (NaN never). (N, 36)
    nearest distances per sector, inf where none."""
    r = np.asarray(ranges, dtype=float)
    hit = r < (np.asarray(range_max, dtype=float) * 0.999)[:, None]
    r = np.where(hit, r, 0.0)  # no inf * 0 in the misses' (unused) end points
    x = beams[..., 0] + r * beams[..., 2]
    y = beams[..., 1] + r * beams[..., 3]
    idx = np.floor((np.degrees(np.arctan2(y, x)) + _SECTOR / 2) / _SECTOR).astype(np.int64) % SECTOR_COUNT
    dist = np.where(hit, np.hypot(x, y), np.inf)
    out = np.full((r.shape[0], SECTOR_COUNT), np.inf)
    rows = np.arange(r.shape[0])
    for j in range(r.shape[1]):  # k beams (8 or 16): a few array operations each, no per-robot loop
        col = idx[:, j]
        np.minimum(out[rows, col], dist[:, j], out=dist[:, j])
        out[rows, col] = dist[:, j]
    return out


def _min(sectors: np.ndarray, span: np.ndarray) -> np.ndarray:
    return sectors[:, span].min(axis=1)


def lane_distances(sectors: np.ndarray, half_width: np.ndarray, behind: bool = False) -> np.ndarray:
    """:func:`rsal.behaviours.lane_distance` for N rows: (N, 36) sectors and (N,) lane half-widths
    in, (N,) distances along the heading (backwards: ``behind``) out. Its sectors in its order, with
    its early skip of a sector no nearer than the best so far (its result, not a plain minimum)."""
    best = np.full(len(sectors), np.inf)
    with np.errstate(invalid="ignore"):
        for i, c, sn in _LANE_BEHIND if behind else _LANE_AHEAD:
            d = sectors[:, i]
            if c <= 0.0:
                continue
            x = d * c
            take = (d < best) & (np.abs(d * sn) < half_width) & (x < best)
            best = np.where(take, x, best)
    return best


class VectorState:
    """The :class:`.behaviour.Disperse` state of N robots as arrays; :meth:`step` is its ``step``
    row by row. Parameters (:class:`rsal.behaviours.BehaviourParams`) are per row too."""

    _PARAMS = (
        "cruise_speed",
        "turn_rate",
        "stop_dist",
        "avoid_dist",
        "wall_dist",
        "stuck_time",
        "escape_time",
        "escape_speed",
        "corridor",
        "sweep",
    )

    def __init__(self, n: int):
        self.n = n
        self.cmd = np.zeros((n, 2))
        self.wallfollow = np.zeros(n, dtype=bool)
        self.left_side = np.ones(n, dtype=bool)  # the wall followed: left (else right)
        self.heading = np.full(n, np.nan)  # NaN: none
        self.yaw = np.zeros(n)
        self.blocked_since = np.full(n, np.nan)  # NaN: not blocked
        self.escape_until = np.full(n, -np.inf)
        self.escape_turn = np.ones(n)
        self.escapes = np.zeros(n, dtype=np.int64)
        self.state = np.zeros(n, dtype=np.int64)
        for name in self._PARAMS:
            setattr(self, name, np.zeros(n))

    # ------------------------------------------------------------------ objects <-> arrays
    @classmethod
    def of(cls, behaviours: list[Disperse]) -> VectorState:
        """The state of ``behaviours`` (parameters included) as arrays."""
        s = cls(len(behaviours))
        s.read_params(behaviours)
        s.read(behaviours)
        return s

    def read_params(self, behaviours: list[Disperse]) -> None:
        for name in self._PARAMS:
            setattr(self, name, np.array(list(map(attrgetter(f"p.{name}"), behaviours)), dtype=float))

    def read(self, behaviours: list[Disperse]) -> None:
        """Take the state the robots' behaviour objects hold now (what their agents set included)."""
        self.cmd = np.array(list(map(attrgetter("command"), behaviours)), dtype=float).reshape(-1, 2)
        self.wallfollow = np.array(list(map(attrgetter("wallfollow"), behaviours)), dtype=bool)
        self.left_side = np.array([p == "left" for p in map(attrgetter("p.side"), behaviours)], dtype=bool)
        self.heading = np.array([math.nan if h is None else h for h in map(attrgetter("heading"), behaviours)])
        self.yaw = np.array(list(map(attrgetter("yaw"), behaviours)), dtype=float)
        self.blocked_since = np.array(
            [math.nan if b is None else b for b in map(attrgetter("_blocked_since"), behaviours)]
        )
        self.escape_until = np.array(list(map(attrgetter("_escape_until"), behaviours)), dtype=float)
        self.escape_turn = np.array(list(map(attrgetter("_escape_turn"), behaviours)), dtype=float)
        self.escapes = np.array(list(map(attrgetter("escapes"), behaviours)), dtype=np.int64)
        self.state = np.array([_CODE.get(s, IDLE) for s in map(attrgetter("state"), behaviours)], dtype=np.int64)

    def write(self, behaviours: list[Disperse]) -> list[int]:
        """Put the stepped state back on the behaviour objects; returns the rows whose layer changed."""
        changed = []
        blocked = [None if math.isnan(b) else b for b in self.blocked_since.tolist()]
        rows = zip(
            behaviours,
            blocked,
            self.escape_until.tolist(),
            self.escape_turn.tolist(),
            self.escapes.tolist(),
            self.state.tolist(),
            strict=True,
        )
        for i, (b, bs, eu, et, ne, st) in enumerate(rows):
            b._blocked_since, b._escape_until, b._escape_turn, b.escapes = bs, eu, et, ne
            name = STATES[st]
            if b.state != name:
                b.state = name
                changed.append(i)
        return changed

    # ------------------------------------------------------------------ the step
    def step(self, sectors: np.ndarray, now: float, stalled: np.ndarray, walls: np.ndarray | None = None) -> np.ndarray:
        """One cycle of every row's behaviour: (N, 36) sectors, the time (s) and (N,) stall flags in;
        (N, 2) ``(v, w)`` out (:attr:`state`: each row's layer). ``walls``: (N, 36) sectors without
        the echoes known to be other robots (:attr:`.behaviour.Disperse.walls`; None: the sectors).
        Rows with ``corridor`` > 0 read the front in their lane and back up only into a clear one,
        rows with ``sweep`` > 0 drop a turn that would swing a corner into something
        (:meth:`rsal.behaviours.Subsumption.guard_turn`)."""
        n = self.n
        front, left, right = _min(sectors, _FRONT), _min(sectors, _LEFT), _min(sectors, _RIGHT)
        lane = self.corridor > 0
        if lane.any():
            front = np.where(lane, lane_distances(sectors, self.corridor), front)
        moving = self.wallfollow | (np.abs(self.cmd[:, 0]) > 1e-3)
        out = np.zeros((n, 2))
        done = np.zeros(n, dtype=bool)
        state = self.state

        # 1. escape: running, or blocked for stuck_time
        escaping = now < self.escape_until
        blocked = moving & (stalled | (front < self.stop_dist)) & ~escaping
        fresh = blocked & np.isnan(self.blocked_since)
        self.blocked_since[fresh] = now
        trigger = blocked & ~fresh & (now - self.blocked_since >= self.stuck_time)
        self.blocked_since[trigger] = np.nan
        self.escape_until[trigger] = now + self.escape_time[trigger]
        self.escape_turn[trigger] = np.where(left[trigger] > right[trigger], 1.0, -1.0)
        self.escapes[trigger] += 1
        self.blocked_since[~blocked & ~escaping] = np.nan
        esc = escaping | trigger
        out[esc, 0] = self.escape_speed[esc]
        out[esc, 1] = self.turn_rate[esc] * self.escape_turn[esc]
        back = esc & lane
        if back.any():  # back up only into a clear lane behind
            behind = lane_distances(sectors[back], self.corridor[back], behind=True)
            rows = np.flatnonzero(back)[behind < self.stop_dist[back]]
            out[rows, 0] = 0.0
        state[esc] = ESCAPE
        done |= esc

        # 2. avoid
        av = ~done & moving & (front < self.avoid_dist)
        turn = np.where(left >= right, 1.0, -1.0)
        turn = np.where(self.wallfollow, np.where(self.left_side, -1.0, 1.0), turn)
        with np.errstate(invalid="ignore"):
            slow = self.cruise_speed * (front - self.stop_dist) / (self.avoid_dist - self.stop_dist) * 0.5
        out[av, 0] = np.where(front < self.stop_dist, 0.0, slow)[av]
        out[av, 1] = (self.turn_rate * turn)[av]
        state[av] = AVOID
        done |= av

        # 3. wall-follow, and the disperse layer where no wall is in sight
        wf = ~done & self.wallfollow
        sign = np.where(self.left_side, 1.0, -1.0)
        side_d = np.where(self.left_side, _min(sectors, _SIDE_L), _min(sectors, _SIDE_R))
        diag = np.where(self.left_side, _min(sectors, _DIAG_L), _min(sectors, _DIAG_R))
        ws = sectors if walls is None else walls  # a wall in sight, not only robots? (Disperse.step)
        if walls is None:
            ws_side, ws_diag = side_d, diag
        else:
            ws_side = np.where(self.left_side, _min(ws, _SIDE_L), _min(ws, _SIDE_R))
            ws_diag = np.where(self.left_side, _min(ws, _DIAG_L), _min(ws, _DIAG_R))
        nowall = np.minimum(ws_side, ws_diag) > 2.5 * self.wall_dist
        follow = wf & ~nowall
        with np.errstate(invalid="ignore"):
            diag_d = diag * _SIN65
            err = np.minimum(side_d, diag_d) - self.wall_dist
            w = sign * np.clip(1.5 * err + 4.0 * (diag_d - side_d), -self.turn_rate, self.turn_rate)
        out[follow, 0] = (self.cruise_speed * np.where(np.abs(err) > 0.3, 0.6, 1.0))[follow]
        out[follow, 1] = w[follow]
        state[follow] = WALLFOLLOW
        disp = wf & nowall
        has = disp & ~np.isnan(self.heading)
        straight = disp & ~has
        out[straight, 0] = self.cruise_speed[straight]
        out[straight, 1] = 0.0
        if has.any():
            herr = wrap(self.heading[has] - self.yaw[has])
            tr = self.turn_rate[has]
            out[has, 1] = np.maximum(-tr, np.minimum(tr, 1.5 * herr))
            out[has, 0] = self.cruise_speed[has] * np.where(np.abs(herr) < 0.8, 1.0, 0.4)
        state[disp] = DISPERSE
        done |= wf

        # the turn guard of every layer that turns: escape, avoid, wall-following, a heading
        guard = (esc | av | follow | has) & (self.sweep > 0) & (out[:, 1] != 0.0)
        if guard.any():
            near = np.where(out[:, 1] > 0, _min(sectors, _SWING_L), _min(sectors, _SWING_R))
            out[guard & (near < self.sweep), 1] = 0.0

        # 4. command
        rest = ~done
        out[rest] = self.cmd[rest]
        state[rest] = np.where(moving[rest] | (self.cmd[rest, 1] != 0.0), COMMAND, IDLE)
        return out


def read_state(behaviours: list, cached: tuple | None) -> tuple[VectorState, tuple]:
    """A :class:`VectorState` of ``behaviours`` (their state read now) and the parameter cache to
    keep: the parameters are read again only when the rows' parameter objects change."""
    st = VectorState(len(behaviours))
    key = tuple(map(id, map(attrgetter("p"), behaviours)))
    if cached is None or cached[0] != key:
        st.read_params(behaviours)
        cached = (key, st)
    else:
        for name in VectorState._PARAMS:
            setattr(st, name, getattr(cached[1], name))
    st.read(behaviours)
    return st, cached


class HostStep:
    """``hub.batch`` of an agent host's :class:`agents.hub.RobotHub`: one vectorised behaviour step
    (:func:`fuse_rings`, :meth:`VectorState.step`) for every plain sonar :class:`.behaviour.SwarmPioneer`
    of the host per control cycle; returns the robots it did not step (they run their own ``update()``).

    Per cycle it reads each robot's latest pose and scan and its behaviour's state (one pass of
    attribute reads), and after the step writes the state back, tells state listeners, and sends the
    rounded commands exactly when :meth:`rsal.robot.Pioneer.update` would (a changed command, or any
    non-zero one). :attr:`stepped`, :attr:`step_s` and :attr:`send_s` tell what it did and its cost."""

    def __init__(self, clock_now):
        self.now = clock_now
        self.stepped = 0
        self.step_s = 0.0
        self.send_s = 0.0
        self._beams: dict[int, np.ndarray] = {}  # id(robot) -> (k, 4) geometry
        self._params: tuple[tuple[int, ...], VectorState] | None = None  # the rows' parameters, by their ids

    @staticmethod
    def takes(r) -> bool:
        return type(r) is SwarmPioneer and r.vectorised and not r.laser_enabled and len(r.sonars) == 1

    def row(self, r):
        """What else a row needs beyond its odometry and scan (a subclass's hook, called once the
        robot is known to be stepped, so it may act for the robot's cycle); None: its own update()."""
        return ()

    def adjust(self, rows: list, extra: list, pose: np.ndarray, sectors: np.ndarray):
        """A subclass's hook before the step: (sectors, walls or None, (N,) yaw) from the rows, their
        :meth:`row` data, their odometry poses and their sonar sectors."""
        return sectors, None, pose[:, 2].copy()

    def __call__(self, robots: list) -> list:
        rest, rows, poses, scans, rmax, beams, stall, last, extra = [], [], [], [], [], [], [], [], []
        k = None
        for r in robots:
            if not self.takes(r):
                rest.append(r)
                continue
            pos, sonar = r.position2d, r.sonars[0]
            m, sm = pos.latest, sonar.latest
            geo = r._beams.get(sonar.addr)
            if m is None or not pos.alive or sm is None or not sonar.alive or geo is None or len(geo) != len(sm.ranges):
                rest.append(r)  # its own update() (which also learns the beam geometry)
                continue
            if k is None:
                k = len(geo)
            elif len(geo) != k:
                rest.append(r)
                continue
            x = self.row(r)
            if x is None:
                rest.append(r)
                continue
            b = self._beams.get(id(r))
            if b is None or len(b) != k:
                b = self._beams[id(r)] = np.array(geo, dtype=float)
            rows.append(r)
            poses.append(m.pose)
            scans.append(sm.ranges)
            rmax.append(sm.range_max)
            beams.append(b)
            stall.append(bool(m.stall))
            extra.append(x)
            lp = r._last_pose
            last.append((math.nan, math.nan) if lp is None else (lp.x, lp.y))
        if not rows:
            return rest
        t0 = time.perf_counter()
        n = len(rows)
        pose = np.array(poses, dtype=float)
        ranges = np.array(scans, dtype=float)
        rm = np.array(rmax, dtype=float)
        # fuse_beams's default range_max: the scan's own maximum when the message gives none
        zero = rm == 0.0
        if zero.any():
            rm[zero] = ranges[zero].max(axis=1)
        sectors, walls, yaw = self.adjust(rows, extra, pose, fuse_rings(np.stack(beams), ranges, rm))
        behaviours = [r.behaviour for r in rows]
        st, self._params = read_state(behaviours, self._params)
        st.yaw = yaw
        out = st.step(sectors, self.now(), np.array(stall, dtype=bool), walls)
        changed = set(st.write(behaviours))
        cmds = np.round(out, 3).tolist()
        moved = np.hypot(*(pose[:, :2] - np.array(last, dtype=float)).T)
        moved = np.where(np.isnan(moved), 0.0, moved).tolist()  # 0 for a robot's first cycle
        t1 = time.perf_counter()
        rows_out = zip(rows, poses, behaviours, yaw.tolist(), cmds, moved, strict=True)
        for i, (r, p, b, y, c, d) in enumerate(rows_out):
            b.yaw = y
            r.distance += d
            r._last_pose = _Pose(*p)
            if i in changed:
                for fn in r._state_listeners:
                    fn(b.state)
            cmd = (c[0], c[1])
            if cmd != r._last_cmd or cmd != (0.0, 0.0):
                r.position2d.set_velocity(*cmd, hold=r.period > HOLD_REFRESH)
                r._last_cmd = cmd
        t2 = time.perf_counter()
        self.stepped += n
        self.step_s += t1 - t0
        self.send_s += t2 - t1
        return rest
