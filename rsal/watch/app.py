"""The logger of ``rsal watch``: :class:`Watcher` turns what the fabric says into a Rerun recording.

One thread ticks at ``--rate``: it drains the intake (:mod:`rsal.watch.subscriptions`), handles
device joins and rpc replies (``describe`` geometry, maps, ground-truth poses from the
simulation, planner waypoints, AMCL particles), hands the newest data message of each device to
its interface's drawing hook (:mod:`rsal.watch.draw`), moves the robots' footprints and logs
service messages and events as text, and draws the fleet dispatcher's tasks
(:mod:`rsal.watch.tasks`). Scans are downsampled (every k-th beam, at most
``--scan-rate`` per second per device), so a 100-robot fleet at full rate does not make it fall
behind. Entity paths: ``docs/watch.md``.
"""

from __future__ import annotations

import collections
import logging
import math
import threading
import time
from typing import Any

import numpy as np
import zenoh

from .. import interfaces
from ..geometry import compose_array
from ..keys import DeviceAddr
from ..msgs import MapData, MessageError, RpcError, decode_map
from . import draw
from .convert import (
    COV_AMBER,
    FLIP,
    GREEN,
    ORANGE,
    WHITE,
    cov_ellipse,
    ellipse_points,
    entity,
    footprint,
    map_image,
    map_transform,
    robot_color,
)
from .state import RobotView, WatchOptions
from .subscriptions import Subscriptions
from .tasks import TaskView, robot_link, task_log

__all__ = ["Watcher"]

log = logging.getLogger("rsal.watch")


class Watcher(Subscriptions):
    """Subscribes to the fabric and logs to a Rerun recording stream ``rec`` from one thread."""

    def __init__(self, session: zenoh.Session, rec, opts: WatchOptions):
        import rerun as rr

        super().__init__(session, opts)
        self.rr = rr
        self.rec = rec
        self._alive: set[DeviceAddr] = set()
        self._geometry: dict[DeviceAddr, dict] = {}
        self._typed: dict[DeviceAddr, Any] = {}  # typed form of _geometry per device (interface's geometry class)
        self._describing: dict[DeviceAddr, float] = {}
        self._layout: dict[DeviceAddr, tuple] = {}
        self._summaries: dict[DeviceAddr, str] = {}  # latest summary text logged per device
        self._drawn: dict[DeviceAddr, Any] = {}  # what a hook last drew per device (to skip repeats)
        self._last_scan: dict[DeviceAddr, float] = {}
        self._robots: dict[str, RobotView] = {}
        self._maps: dict[DeviceAddr, str] = {}
        self._planner: dict[str, tuple] = {}
        self._sim: DeviceAddr | None = None
        self._sim_models: tuple[list[str], list[str]] | None = None
        self._models_asked = -math.inf
        self._truth_queue: collections.deque = collections.deque()
        self._truth_inflight = 0
        self._truth_credit = 0.0
        self._particles_next = -math.inf
        self._sim_time: float | None = None
        self._scan_nodes: set[str] = set()  # nodes with a laser or sonar device
        self._tasks = TaskView(opts.task_hold)
        self._stop = threading.Event()
        self.t0 = time.monotonic()

    # ------------------------------------------------------------------ logger side
    def log(self, path: str, archetype, *, static: bool = False) -> None:
        self.rec.log(path, archetype, static=static)
        self.stats.logged += 1

    def setup(self) -> None:
        rr = self.rr
        for p in ("world/robots", "world/blobs", "world/tasks"):
            self.log(p, rr.Transform3D(scale=FLIP), static=True)
        self.log(
            "log/watch",
            rr.TextLog(
                f"rsal watch {self.opts.template!r}: logging at {self.opts.rate:g} Hz; scans downsampled to at most "
                f"{self.opts.max_beams} beams and {self.opts.scan_rate:g} scans/s per device; ground truth polled at "
                f"{self.opts.truth_rate:g} Hz per robot and carried forward by odometry",
                level="INFO",
            ),
        )

    def robot(self, name: str) -> RobotView:
        r = self._robots.get(name)
        if r is None:
            r = self._robots[name] = RobotView(name, robot_color(name))
        return r

    def run(self, stop: threading.Event, duration: float | None = None) -> None:
        """Tick at ``opts.rate`` until ``stop`` is set or ``duration`` seconds have passed."""
        period = 1.0 / self.opts.rate
        end = None if duration is None else time.monotonic() + duration
        next_tick = time.monotonic()
        next_report = time.monotonic() + self.opts.report_every
        last = (0, 0, 0, 0, time.monotonic())
        while not stop.is_set():
            now = time.monotonic()
            if end is not None and now >= end:
                break
            t = time.perf_counter()
            self.tick()
            dt = time.perf_counter() - t
            self.stats.tick_max = max(self.stats.tick_max, dt)
            if dt > period:
                self.stats.late += 1
            if now >= next_report:
                next_report = now + self.opts.report_every
                last = self.report(last)
            next_tick += period
            wait = next_tick - time.monotonic()
            if wait < -period:  # fell behind: do not try to catch up with a burst
                next_tick = time.monotonic()
                wait = 0.0
            if end is not None:
                wait = min(wait, end - time.monotonic())
            if wait > 0:
                stop.wait(wait)
        self.tick()

    def report(self, last: tuple) -> tuple:
        s = self.stats
        now = time.monotonic()
        span = max(now - last[4], 1e-9)
        with self._lock:
            n_in, n_text = s.n_in, s.n_text
        cur = (n_in + n_text, s.logged, n_in - s.taken, s.downsampled, now)
        truth = sum(1 for r in self._robots.values() if r.anchor is not None or r.gps is not None)
        print(
            f"[watch] {now - self.t0:6.1f} s  in {(cur[0] - last[0]) / span:7.1f} msg/s  logged "
            f"{(s.logged - last[1]) / span:7.1f}/s  robots {len(self._robots)} ({truth} with ground truth)  "
            f"maps {len(self._maps)}  superseded "
            f"{(cur[2] - last[2]) / span:.1f}/s (latest wins)  downsampled {(s.downsampled - last[3]) / span:.1f} "
            f"scans/s  text dropped {s.text_dropped}  text queue {len(self._text)}  largest drain "
            f"{s.drain_max} of {self.opts.ring}  "
            f"late ticks {s.late}  slowest tick {s.tick_max * 1000:.0f} ms",
            flush=True,
        )
        return cur

    def tick(self) -> None:
        rr = self.rr
        now_wall = time.time()
        self.rec.set_time("time", timestamp=now_wall)
        if self._sim_time is not None:
            self.rec.set_time("sim_time", duration=self._sim_time)
        self.drain()
        while self._tokens:
            self._on_join(*self._tokens.popleft())
        while self._replies:
            what, addr, r = self._replies.popleft()
            try:
                self._on_reply(what, addr, r)
            except Exception as e:  # an odd reply (geometry, map) must not stop the view
                self._bad(f"{what} reply of {addr}", e)
        with self._lock:
            batch, self._pending = self._pending, {}
            self.stats.taken += len(batch)
        now = time.monotonic()
        min_gap = 1.0 / self.opts.scan_rate
        for key, payload in batch.items():
            parsed = self._parse(key)
            if parsed is None or parsed[1] != "data":
                continue
            addr = parsed[0]
            if addr.interface in ("laser", "sonar", "ranger"):
                if addr.interface == "ranger" and addr.node in self._scan_nodes:
                    continue  # the node's laser/sonar already republishes this ranger
                if now - self._last_scan.get(addr, -math.inf) < min_gap:
                    self.stats.downsampled += 1
                    continue
            try:
                self._on_sample(addr, interfaces.decode_data(addr.interface, payload))
            except Exception as e:  # MessageError, or data that does not fit the device's geometry
                self._bad(key, e)
        self._emit_robots()
        self._poll(now_wall)
        self._drain_text(rr)
        for tid in self._tasks.unlink():
            self.log(entity("world", "tasks", tid, "link"), rr.Clear(recursive=False))
        for tid in self._tasks.expired(time.monotonic()):
            self.log(entity("world", "tasks", tid), rr.Clear(recursive=True))

    def _bad(self, where: str, e: Exception) -> None:
        """Count and log (rate-limited) a sample or reply that could not be used; carry on."""
        self.stats.malformed += 1
        if self.stats.malformed <= 5 or self.stats.malformed % 1000 == 0:
            log.warning("dropped %s: %s (%d dropped so far)", where, e, self.stats.malformed)

    # ------------------------------------------------------------------ devices
    def _on_join(self, addr: DeviceAddr, joined: bool) -> None:
        rr = self.rr
        if joined == (addr in self._alive):
            return
        if addr.interface in ("laser", "sonar"):
            self._scan_nodes = {a.node for a in self._alive | {addr} if a.interface in ("laser", "sonar")}
        if joined:
            self._alive.add(addr)
            self._describe(addr)
            if addr.interface == "simulation":
                self._sim = addr
                self._models_asked = -math.inf
        else:
            self._alive.discard(addr)
            self._scan_nodes = {a.node for a in self._alive if a.interface in ("laser", "sonar")}
            self._geometry.pop(addr, None)
            self._layout.pop(addr, None)
            self._typed.pop(addr, None)  # a device that comes back may describe another geometry
            self._drawn.pop(addr, None)
            if addr == self._sim:
                self._sim = None
                self._sim_models = None
        text = f"{addr} {'joined' if joined else 'lost'}"
        self.log(entity("log", "devices", addr.node), rr.TextLog(text, level="INFO"))

    def _describe(self, addr: DeviceAddr) -> None:
        self._describing[addr] = time.monotonic()
        self._rpc("describe", addr, "describe")

    def _on_reply(self, what: str, addr: DeviceAddr, r: Any) -> None:
        rr = self.rr
        if isinstance(r, RpcError):
            if what == "describe" and addr in self._alive:
                self._describing[addr] = time.monotonic() + 2.0  # retried by _poll
            elif what == "map" and addr in self._alive:
                self._describing[addr] = time.monotonic() + 1.0
                self._geometry.pop(addr, None)
            elif what.startswith("truth:"):
                self._truth_inflight -= 1
            log.debug("%s %s: %s", what, addr, r)
            return
        if what == "describe":
            self._describing.pop(addr, None)
            geo = r.get("geometry") if isinstance(r.get("geometry"), dict) else {}
            self._geometry[addr] = geo
            self._typed.pop(addr, None)
            if addr.interface == "position2d" and addr.index == 0 and isinstance(geo.get("size"), list):
                rb = self.robot(addr.node)
                rb.size = (float(geo["size"][0]), float(geo["size"][1]))
            if addr.interface == "gripper" and isinstance(geo.get("pose"), list):
                self.robot(addr.node).gripper_pose = tuple(float(v) for v in geo["pose"][:3])
            if addr.interface == "map":
                self._rpc("map", addr, "get", timeout=10.0)
        elif what == "map":
            try:
                m = MapData.from_dict(r)
            except MessageError as e:
                log.warning("map %s: %s", addr, e)
                return
            path = self._maps.setdefault(addr, "world/map" if not self._maps else f"world/map_{addr.node}_{addr.index}")
            tr, sc = map_transform(m.origin, m.resolution)
            self.log(path, rr.Transform3D(translation=tr, scale=sc), static=True)
            self.log(path, rr.Image(map_image(m.cells), color_model="L", draw_order=-10.0), static=True)
        elif what == "models":
            robots = [str(x) for x in r.get("robots", []) if isinstance(x, str)]
            objects = [str(x) for x in r.get("objects", []) if isinstance(x, str)]
            self._sim_models = (robots, objects)
        elif what.startswith("truth:"):
            self._truth_inflight -= 1
            kind, name = what.split(":", 2)[1:]
            pose = r.get("pose")
            if not (isinstance(pose, list) and len(pose) == 3):
                return
            if kind == "robot":
                rb = self.robot(name)
                rb.anchor = (np.asarray(pose, dtype=float), None if rb.odom is None else np.asarray(rb.odom))
                rb.dirty = True
            else:
                self.log(
                    entity("world", "blobs", name),
                    rr.Points2D([pose[:2]], radii=0.08, colors=GREEN, labels=[name]),
                )
        elif what == "waypoints":
            pts = r.get("waypoints") or []
            path = entity("world", "robots", addr.node, "path")
            if len(pts) >= 2:
                xy = np.asarray([p[:2] for p in pts], dtype=float)
                self.log(path, rr.LineStrips2D([xy], radii=0.02, colors=self.robot(addr.node).color))
                self.log(path + "/waypoints", rr.Points2D(xy, radii=0.05, colors=self.robot(addr.node).color))
        elif what == "particles":
            raw = r.get("particles")
            if isinstance(raw, (bytes, bytearray)) and len(raw) % 12 == 0 and raw:
                p = np.frombuffer(raw, dtype="<f4").reshape(-1, 3)
                if len(p) > 2000:
                    p = p[:: math.ceil(len(p) / 2000)]
                self.log(
                    entity("world", "robots", addr.node, "particles"),
                    rr.Points2D(p[:, :2], radii=0.015, colors=ORANGE),
                )

    # ------------------------------------------------------------------ samples
    def _on_sample(self, addr: DeviceAddr, msg: Any) -> None:
        """One decoded data message (the interface's type from :mod:`rsal.interfaces`), drawn by
        its interface's hook (:func:`rsal.watch.draw.hook`)."""
        draw.hook(addr.interface)(self, addr, msg)

    def _typed_geometry(self, addr: DeviceAddr, cls: type) -> Any:
        """The device's ``describe`` geometry as ``cls`` (e.g. ``BumperGeometry``), parsed once."""
        g = self._typed.get(addr)
        if not isinstance(g, cls):
            g = self._typed[addr] = cls.from_describe(self._geometry.get(addr, {}))
        return g

    def _emit_robots(self) -> None:
        rr = self.rr
        now = time.monotonic()
        for name, rb in self._robots.items():
            if not rb.dirty:
                continue
            rb.dirty = False
            base = entity("world", "robots", name)
            truth = rb.truth()
            if truth is not None:
                self._place(rb, "truth", truth, radius=0.015, color=rb.color, label=name)
            if rb.loc is not None:
                self._place(rb, "pose", rb.loc, radius=0.01, color=WHITE, label="")
                if rb.cov is not None and rb.cov_dirty:
                    rb.cov_dirty = False
                    a, b, ang = cov_ellipse(rb.cov)  # drawn in the pose's frame, like the footprint
                    ring = ellipse_points((0.0, 0.0), a, b, ang - rb.loc[2])
                    self.log(base + "/pose/covariance", rr.LineStrips2D([ring], radii=0.01, colors=COV_AMBER))
            if now - rb.last_plot >= 1.0 / self.opts.plot_rate:
                rb.last_plot = now
                if truth is not None and rb.loc is not None:
                    err = math.hypot(truth[0] - rb.loc[0], truth[1] - rb.loc[1])
                    self.log(entity("plots", name, "loc_error"), rr.Scalars(err))
                if rb.speed is not None:
                    self.log(entity("plots", name, "speed"), rr.Scalars(rb.speed))
            best = truth if truth is not None else rb.best()
            if rb.carrying and best is not None:
                g = compose_array(best, rb.gripper_pose)
                self.log(base + "/carried", rr.Points2D([g[:2]], radii=0.07, colors=GREEN, labels=[rb.carrying]))

    def _place(self, rb: RobotView, kind: str, pose, *, radius: float, color: int, label: str) -> None:
        """Move the footprint entity ``world/robots/<node>/<kind>`` to ``pose``: the outline is
        logged once (static, robot frame), then only a transform per move (a fraction of the cost
        of re-logging the outline), and nothing while the robot stands still."""
        rr = self.rr
        path = entity("world", "robots", rb.name, kind)
        if rb.shapes.get(kind) != rb.size:
            rb.shapes[kind] = rb.size
            labels = [label, ""] if label else None
            self.log(
                path,
                rr.LineStrips2D(footprint((0.0, 0.0, 0.0), rb.size), radii=radius, colors=color, labels=labels),
                static=True,
            )
        x, y, yaw = (float(v) for v in pose)
        last = rb.shown.get(kind)
        if last is not None and abs(last[0] - x) < 1e-3 and abs(last[1] - y) < 1e-3 and abs(last[2] - yaw) < 2e-3:
            return
        rb.shown[kind] = (x, y, yaw)
        q = rr.Quaternion(xyzw=[0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)])
        self.log(path, rr.Transform3D(translation=[x, y, 0.0], quaternion=q))

    def _poll(self, now_wall: float) -> None:
        now = time.monotonic()
        for addr, when in list(self._describing.items()):
            if addr not in self._alive:
                self._describing.pop(addr, None)
            elif now > when + 5.0:
                self._describe(addr)  # no answer (or an error): ask again
        if self._sim is not None and now - self._models_asked > 5.0:
            self._models_asked = now
            self._rpc("models", self._sim, "models")
        if self._sim is not None and self._sim_models is not None:
            robots = [r for r in self._sim_models[0] if r in self._robots]  # only the robots watched
            objects = self._sim_models[1]
            n = len(robots) + len(objects)
            self._truth_credit = min(self._truth_credit + n * self.opts.truth_rate / self.opts.rate, max(n, 1))
            while self._truth_credit >= 1.0 and self._truth_inflight < 32 and n:
                if not self._truth_queue:
                    self._truth_queue.extend([("robot", r) for r in robots] + [("object", o) for o in objects])
                kind, name = self._truth_queue.popleft()
                self._truth_credit -= 1.0
                self._truth_inflight += 1
                self._rpc(f"truth:{kind}:{name}", self._sim, "get_pose", {"name": name}, timeout=2.0)
        if self.opts.particles and now >= self._particles_next:
            self._particles_next = now + 1.0 / self.opts.particles_rate
            for a in self._alive:
                if a.interface == "localize":
                    self._rpc("particles", a, "get_particles", timeout=2.0)

    def _drain_text(self, rr) -> None:
        n = 0
        while self._text:
            if n >= self.opts.max_text:
                self.stats.text_dropped += len(self._text)
                self._text.clear()
                break
            kind, key, payload = self._text.popleft()
            n += 1
            if kind == "agent":
                agent = key.split("/", 1)[-1]
                self.log("log/agents", rr.TextLog(f"agent {agent} {'joined' if payload else 'left'}", level="INFO"))
                continue
            try:
                m = decode_map(payload)
            except MessageError:
                self.stats.malformed += 1
                continue
            if kind == "svc":
                parts = key.split("/")
                service = parts[1] if len(parts) > 1 else "?"
                sender = m.pop("sender", parts[2] if len(parts) > 2 else "?")
                conv = m.pop("conversation", "")
                m.pop("time", None)
                body = ", ".join(f"{k}={_short(v)}" for k, v in m.items())
                level = "WARN" if service == "outcome" and m.get("ok") is False else "INFO"
                self.log(entity("log", "services", service), rr.TextLog(f"{sender} [{conv}] {body}", level=level))
                if service == "task_state":
                    self._task_state(rr, m)
                elif service == "fleet":
                    self._fleet_link(rr, m)
            else:
                parsed = self._parse(key)
                if parsed is None:
                    continue
                addr = parsed[0]
                body = ", ".join(f"{k}={_short(v)}" for k, v in m.items())
                self.log(entity("log", "events", addr.node), rr.TextLog(f"{addr}: {body}", level="INFO"))

    # ------------------------------------------------------------------ dispatcher tasks
    def _task_state(self, rr, m: dict) -> None:
        """A ``task_state``: the task redrawn at ``world/tasks/<id>`` and a ``log/tasks`` entry."""
        text, level = task_log(m)
        self.log("log/tasks", rr.TextLog(text, level=level))
        d = self._tasks.state(m, time.monotonic())
        if d is None:
            return
        path = entity("world", "tasks", d.task_id)
        if len(d.points):
            labels = [d.label] + [""] * (len(d.points) - 1)
            self.log(path, rr.Points2D(d.points, radii=0.12, colors=d.color, labels=labels))
        if d.strip is not None:
            self.log(path + "/route", rr.LineStrips2D([d.strip], radii=0.03, colors=d.color))

    def _fleet_link(self, rr, m: dict) -> None:
        """A robot's ``fleet`` status: the line from the robot (its true pose where the view has
        it) to the next point of its active task."""
        rb = self._robots.get(str(m.get("robot", "")))
        truth = rb.truth() if rb is not None else None
        got = robot_link(m, None if truth is None else (float(truth[0]), float(truth[1])))
        if got is not None and self._tasks.link(got[0]):
            color = self.robot(str(m.get("robot"))).color if m.get("robot") else GREEN
            self.log(entity("world", "tasks", got[0], "link"), rr.LineStrips2D([got[1]], radii=0.02, colors=color))


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    if isinstance(v, (bytes, bytearray)):
        return f"<{len(v)} bytes>"
    if isinstance(v, list) and all(isinstance(x, float) for x in v):
        return "[" + ", ".join(f"{x:.3g}" for x in v) + "]"
    s = str(v)
    return s if len(s) <= 120 else s[:117] + "..."
