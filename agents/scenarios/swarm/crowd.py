"""The swarm host's crowd path: all its robots read and commanded through the simulator's ``crowd`` device.

With ``crowd: true`` a swarm agent host does not build two device proxies per robot (two
subscriptions, a describe and a Python callback per sample: 20 samples per robot and second at
1000 robots). Its hub instead holds one :class:`CrowdLink` -- one ``rpc/describe`` of
``<simnode>:crowd:0`` (:mod:`rsal.interfaces.crowd`) and one subscription to its data, a
:class:`~rsal.interfaces.crowd.CrowdData` per simulation step -- and runs :class:`CrowdStep` as the
hub's batch step: the vectorised behaviour of :mod:`.vector` (:func:`.vector.fuse_rings`,
:class:`.vector.VectorState`) on the rows of the host's robots, and one
:class:`~rsal.interfaces.crowd.CrowdCmd` with all their commands per control cycle (each row passes
its robot's own base guard on the simulator, as a ``position2d`` command would). The commands are
sent when :meth:`rsal.robot.Pioneer.update` would send them: a changed command, or any moving one
-- every cycle, so the robots' command timeouts stay refreshed while the host runs, and the robots
stop when it stops.

:class:`CrowdRobot` stands in for the per-robot :class:`.behaviour.SwarmPioneer`: the same
:class:`.behaviour.Disperse` behaviour object and bookkeeping (distance, state listeners), its pose
read from the crowd's latest row. Broadcasts, the ledger, the monitor and delivery judging do not
change.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from rsal.data import Position
from rsal.interfaces.crowd import Crowd, CrowdLayout

from .behaviour import Disperse
from .vector import VectorState, _Pose, fuse_rings, read_state

__all__ = ["CrowdLink", "CrowdRobot", "CrowdStep", "link_of"]

_links: dict[int, CrowdLink] = {}
_links_lock = threading.Lock()


class CrowdLink:
    """A host's view of the simulator's crowd device: the layout (one describe) and the latest data."""

    def __init__(self, fabric, addr: str, timeout: float):
        self.device: Crowd = fabric.device(addr)  # subscribes to its data: one message per step
        self.layout: CrowdLayout = self.device.layout(timeout)
        self.rows = self.layout.index()
        self.beams: dict[int, tuple[np.ndarray, float]] = {}  # ranger geometry index -> (beams, range_max)
        for i, k in enumerate(self.layout.ranger_of):
            if k >= 0 and k not in self.beams:
                self.beams[k] = self.layout.beams(i)

    def row(self, name: str) -> int:
        i = self.rows.get(name)
        if i is None:
            raise LookupError(f"robot {name!r} is not in {self.device.addr} (it lists {len(self.rows)} robots)")
        return i

    def latest_pose(self, i: int) -> tuple[float, float, float] | None:
        m = self.device.latest
        if m is None or i >= m.count or math.isnan(m.pose[i, 0]):
            return None
        return tuple(m.pose[i].tolist())  # type: ignore[return-value]

    def close(self) -> None:
        self.device.undeclare()


def link_of(hub, timeout: float, node_template: str = "*:crowd:0") -> CrowdLink:
    """The :class:`CrowdLink` of ``hub`` (made by the first of its agents; the others wait for it)."""
    with _links_lock:
        link = _links.get(id(hub))
        if link is not None:
            return link
        node = hub.fabric.node(node_template)
        found = node.wait_for(node_template, 1, timeout)
        link = _links[id(hub)] = CrowdLink(hub.fabric, str(found[0]), timeout)
        return link


def drop_link(hub) -> None:
    with _links_lock:
        link = _links.pop(id(hub), None)
    if link is not None:
        try:
            link.close()
        except Exception:  # the hub's fabric (and session) may be closed already
            pass


class CrowdRobot:
    """A swarm robot driven through the crowd device (see the module docstring): row ``row`` of ``link``."""

    vectorised = True
    laser_enabled = False
    localize = None

    def __init__(self, link: CrowdLink, name: str, *, period: float = 0.1):
        self.link = link
        self.name = name
        self.row = link.row(name)
        self.period = float(period)
        self.behaviour = Disperse()
        vmax, wmax = link.layout.limits[self.row] if link.layout.limits else (math.inf, math.inf)
        bp = self.behaviour.p
        bp.cruise_speed = min(bp.cruise_speed, vmax)
        bp.turn_rate = min(bp.turn_rate, wmax)
        self._last_cmd: tuple[float, float] | None = None
        self._last_pose: _Pose | None = None
        self._state_listeners: list = []
        self.distance = 0.0
        self.updates = 0

    def xy(self) -> tuple[float, float] | None:
        """Its latest ``(x, y)`` (no :class:`Position` built: the hub asks this for every robot)."""
        m = self.link.device.latest
        i = self.row
        if m is None or i >= m.count:
            return None
        x, y = float(m.pose[i, 0]), float(m.pose[i, 1])
        return None if x != x else (x, y)

    @property
    def position(self) -> Position | None:
        p = self.link.latest_pose(self.row)
        return Position(*p) if p is not None else None

    @property
    def state(self) -> str:
        return self.behaviour.state

    def on_state(self, fn) -> None:
        self._state_listeners.append(fn)

    def set_wallfollow(self, on: bool = True, side: str | None = None) -> None:
        self.behaviour.set_wallfollow(on, side)

    def update(self) -> None:
        """Nothing of its own: the hub's :class:`CrowdStep` runs its cycle (no data yet: it waits)."""

    def stop(self) -> None:
        self.link.device.command([self.row], [0.0], [0.0])
        self._last_cmd = (0.0, 0.0)


class CrowdStep:
    """``hub.batch`` for :class:`CrowdRobot` rows: one vectorised step on the crowd's latest arrays,
    one crowd command; other robots are returned to run their own ``update()``."""

    def __init__(self, link: CrowdLink, clock_now):
        self.link = link
        self.now = clock_now
        self.stepped = 0
        self.step_s = 0.0
        self.send_s = 0.0
        self._params: tuple[tuple[int, ...], VectorState] | None = None  # the rows' parameters, by their ids

    def __call__(self, robots: list) -> list:
        rest = [r for r in robots if type(r) is not CrowdRobot]
        mine = [r for r in robots if type(r) is CrowdRobot and r.link is self.link]
        m = self.link.device.latest
        if not mine or m is None:
            return rest
        t0 = time.perf_counter()
        lay = self.link.layout
        rows = np.fromiter((r.row for r in mine), dtype=np.int64, count=len(mine))
        pose = m.pose[rows].astype(float)
        alive = ~np.isnan(pose[:, 0])
        behaviours = [r.behaviour for r in mine]
        st, self._params = read_state(behaviours, self._params)
        st.yaw = pose[:, 2].copy()
        sectors = np.full((len(mine), 36), np.inf)
        ranger_of = np.asarray(lay.ranger_of)[rows]
        for k, (beams, rmax) in self.link.beams.items():  # one group per ranger geometry (8 or 16 sonars ...)
            sel = np.nonzero((ranger_of == k) & alive)[0]
            if not len(sel):
                continue
            n_b = len(beams)
            starts = m.offsets[rows[sel]]
            ranges = m.ranges[starts[:, None] + np.arange(n_b)[None, :]].astype(float)
            sectors[sel] = fuse_rings(np.broadcast_to(beams, (len(sel), n_b, 4)), ranges, np.full(len(sel), rmax))
        out = st.step(sectors, self.now(), m.stall[rows] > 0.5)
        changed = set(st.write(behaviours))
        cmds = np.round(out, 3)
        last = np.array([(math.nan, math.nan) if r._last_pose is None else r._last_pose[:2] for r in mine], float)
        moved = np.hypot(*(pose[:, :2] - last).T)
        moved = np.where(np.isnan(moved), 0.0, moved).tolist()
        t1 = time.perf_counter()
        send_i, send_v, send_w = [], [], []
        for i, (r, p, c, d) in enumerate(zip(mine, pose.tolist(), cmds.tolist(), moved, strict=True)):
            if not alive[i]:
                continue
            r.behaviour.yaw = p[2]
            r.distance += d
            r._last_pose = _Pose(*p)
            if i in changed:
                for fn in r._state_listeners:
                    fn(r.behaviour.state)
            cmd = (c[0], c[1])
            if cmd != r._last_cmd or cmd != (0.0, 0.0):
                send_i.append(r.row)
                send_v.append(cmd[0])
                send_w.append(cmd[1])
                r._last_cmd = cmd
        if send_i:
            self.link.device.command(send_i, send_v, send_w)
        t2 = time.perf_counter()
        self.stepped += len(mine)
        self.step_s += t1 - t0
        self.send_s += t2 - t1
        return rest
