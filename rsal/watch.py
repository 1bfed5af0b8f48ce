"""``rsal watch``: a live view of the fleet in Rerun (thesis 5.2.3 *User Interface*).

The thesis watched robot localizations and planned paths with Player's *Playernav* and the Stage
window (5.2.3), asked for a graphical interface to follow scenarios (3.4.2) and mixed simulated and
real robots on one map (4.3). This module is that view for the fabric: it subscribes to every
device matching a template, and to the agents' services, and logs to a Rerun recording (a native
viewer, the bundled web viewer, or an ``.rrd`` file):

- the map (any ``map`` device, ``rpc/get``) as an image placed in world coordinates;
- each robot's ground-truth pose when a simulation is present (``sim:simulation:0`` ``get_pose``,
  polled at ``--truth-rate`` and carried forward by odometry between polls, or a ``gps`` position2d),
  and its localized pose (``amcl``'s map-frame position2d and ``localize`` data) with the
  covariance ellipse; both drawn as the footprint from ``rpc/describe`` geometry;
- laser and sonar scans as points in the world frame, blobs seen and carried, planner paths with
  the current waypoint and goal, optionally AMCL particles (``get_particles``);
- agent service messages (``svc/**``), device events and joins as text logs, and per-robot time
  series: speed, localization error (where ground truth exists), battery.

Samples wait in Zenoh's ring buffers (no Python runs per sample on Zenoh's threads); one logger
thread ticks at a fixed rate, drains them into a latest-wins dict (one sample per device), decodes
only the newest, converts scans with numpy and downsamples them (every k-th beam, at most
``--scan-rate`` scans per second per device), so a 100-robot fleet at full rate does not make it
fall behind. Entity paths are documented in ``docs/watch.md`` and stay stable.

This module imports nothing above the RSAL layer: service messages are read as plain msgpack maps.
"""

from __future__ import annotations

import argparse
import collections
import functools
import logging
import math
import os
import sys
import threading
import time
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from . import interfaces, keys
from .cliutil import stop_on_signals
from .geometry import compose_array, invert_array
from .interfaces.ranger import RangerGeometry
from .keys import DeviceAddr
from .msgs import (
    BlobfinderData,
    MapData,
    MessageError,
    PlannerData,
    RangerData,
    RpcError,
    decode_map,
)
from .transport import TransportArgs, add_transport_args, open_session

__all__ = [
    "register",
    "run_watch",
    "Watcher",
    "WatchOptions",
    "beam_layout",
    "scan_to_world",
    "cov_ellipse",
    "ellipse_points",
    "footprint",
    "map_image",
    "map_transform",
    "entity",
]

log = logging.getLogger(__name__)

FLIP = (1.0, -1.0, 1.0)  # world y points up (north), a Rerun 2D view's y points down


# ---------------------------------------------------------------------------- pure conversions
def beam_layout(geometry: dict, n: int, angle_min: float, angle_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Where each of ``n`` beams starts and points, in the robot frame: ``(origins (n, 2),
    angles (n,))``, from a ranger's describe geometry (:class:`~rsal.interfaces.ranger.RangerGeometry`
    lays them out: a laser fans its beams from its sensor, a sonar ring has one transducer per beam)."""
    origins, angles = RangerGeometry(geometry).layout(n, angle_min, angle_step)
    return origins.copy(), angles.copy()


def scan_to_world(
    ranges: np.ndarray,
    origins: np.ndarray,
    angles: np.ndarray,
    robot_pose,
    range_min: float = 0.0,
    range_max: float = 0.0,
    stride: int = 1,
) -> np.ndarray:
    """The end points ``(m, 2)`` in the world frame of the beams that hit something: every
    ``stride``-th beam whose range lies in ``(range_min, range_max)`` (a beam reading ``range_max``
    hit nothing; ``range_max`` 0 keeps every finite reading). Vectorised: no per-beam Python."""
    r = np.asarray(ranges, dtype=np.float64)[::stride]
    o = origins[::stride]
    a = angles[::stride]
    keep = np.isfinite(r) & (r > range_min)
    if range_max > 0.0:
        keep &= r < range_max - 1e-6
    r, o, a = r[keep], o[keep], a[keep]
    px = o[:, 0] + r * np.cos(a)
    py = o[:, 1] + r * np.sin(a)
    x, y, t = (float(v) for v in robot_pose)
    c, s = math.cos(t), math.sin(t)
    return np.column_stack([x + c * px - s * py, y + s * px + c * py])


def cov_ellipse(cov, sigma: float = 2.0) -> tuple[float, float, float]:
    """Half-axes ``(a, b)`` (m, ``a >= b``) and angle of the major axis (rad, from +x) of the
    ``sigma``-standard-deviation ellipse of the x-y block of a 3x3 (or 2x2, or 9 values row-major)
    pose covariance."""
    c = np.asarray(cov, dtype=float)
    c = c.reshape(3, 3) if c.size == 9 else c.reshape(2, 2)
    xy = 0.5 * (c[:2, :2] + c[:2, :2].T)
    w, v = np.linalg.eigh(xy)  # ascending
    w = np.clip(w, 0.0, None)
    a, b = sigma * math.sqrt(w[1]), sigma * math.sqrt(w[0])
    return a, b, math.atan2(v[1, 1], v[0, 1])


def ellipse_points(center, a: float, b: float, angle: float, n: int = 48) -> np.ndarray:
    """A closed polygon ``(n + 1, 2)`` tracing the ellipse."""
    t = np.linspace(0.0, 2.0 * math.pi, n + 1)
    ex, ey = a * np.cos(t), b * np.sin(t)
    c, s = math.cos(angle), math.sin(angle)
    return np.column_stack([center[0] + c * ex - s * ey, center[1] + s * ex + c * ey])


def footprint(pose, size) -> list[np.ndarray]:
    """The robot's outline at ``pose``: a closed rectangle ``size`` = [length, width] (m) centred on
    the pose, and a heading line from the centre to the front edge; world frame."""
    hl, hw = float(size[0]) / 2.0, float(size[1]) / 2.0
    corners = np.array([[hl, hw, 0], [-hl, hw, 0], [-hl, -hw, 0], [hl, -hw, 0], [hl, hw, 0]], dtype=float)
    head = np.array([[0.0, 0.0, 0.0], [hl, 0.0, 0.0]])
    return [compose_array(pose, corners)[:, :2], compose_array(pose, head)[:, :2]]


def map_image(cells: np.ndarray) -> np.ndarray:
    """A Player grid (-1 free, 0 unknown, +1 occupied; row 0 the bottom row) as a grey image of
    the same shape and row order: free 255, unknown 160, occupied 0."""
    img = np.full(cells.shape, 160, dtype=np.uint8)
    img[cells < 0] = 255
    img[cells > 0] = 0
    return img


def map_transform(origin, resolution: float) -> tuple[list[float], list[float]]:
    """Translation and scale placing the :func:`map_image` (pixel ``(col, row)``, row 0 the bottom
    row) in the view: world ``(origin + (col, row) * resolution)``, y flipped like every other
    entity under ``world/`` so north is up in a Rerun 2D view."""
    return [float(origin[0]), -float(origin[1]), 0.0], [float(resolution), -float(resolution), 1.0]


@functools.lru_cache(maxsize=16384)
def entity(*parts: str) -> str:
    """An entity path from name parts, each escaped (node names may contain '.')."""
    import rerun as rr

    return "/".join(rr.escape_entity_path_part(p) if i else p for i, p in enumerate(parts))


_PALETTE = np.array(
    [
        [230, 25, 75],
        [60, 180, 75],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
        [210, 245, 60],
        [0, 128, 128],
        [170, 110, 40],
        [128, 0, 0],
        [0, 0, 128],
    ],
    dtype=np.uint8,
)


def rgba(r: int, g: int, b: int, a: int = 255) -> int:
    """A colour packed as Rerun's 0xRRGGBBAA (the cheapest form to convert)."""
    return (r << 24) | (g << 16) | (b << 8) | a


def robot_color(name: str) -> int:
    return rgba(*(int(v) for v in _PALETTE[zlib.crc32(name.encode()) % len(_PALETTE)]))


WHITE, YELLOW, ORANGE, GREEN = rgba(255, 255, 255), rgba(255, 255, 0), rgba(250, 160, 0), rgba(40, 200, 40)
LASER_RED, SONAR_BLUE, COV_AMBER = rgba(255, 60, 60), rgba(60, 140, 255), rgba(255, 200, 0)


# ---------------------------------------------------------------------------- options and state
@dataclass
class WatchOptions:
    template: str = "**"
    rate: float = 10.0  # logger ticks per second
    scan_rate: float = 5.0  # scans logged per second per device, at most
    max_beams: int = 180  # beams per logged scan, at most (every k-th)
    truth_rate: float = 1.0  # ground-truth polls per robot per second
    plot_rate: float = 2.0  # time-series points per robot per second, at most
    particles: bool = False
    particles_rate: float = 1.0
    services: bool = True
    max_text: int = 200  # text log entries per tick, at most
    ring: int = 8192  # samples a Zenoh ring buffer holds between two ticks
    report_every: float = 5.0

    def check(self) -> None:
        for name in ("rate", "scan_rate", "truth_rate", "plot_rate", "particles_rate", "report_every"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"--{name.replace('_', '-')} {v!r} must be a positive number")
        if self.max_beams < 1:
            raise ValueError(f"--max-beams {self.max_beams} must be at least 1")
        keys.template_to_keyexpr(self.template)  # raises ValueError with the template in it


@dataclass
class _Robot:
    name: str
    color: int
    size: tuple[float, float] = (0.44, 0.38)
    odom: tuple[float, float, float] | None = None  # latest odometry pose
    speed: float | None = None
    anchor: tuple[np.ndarray, np.ndarray | None] | None = None  # (truth, odometry) at the last truth poll
    gps: tuple[float, float, float] | None = None  # a ground-truth position2d
    loc: tuple[float, float, float] | None = None
    cov: tuple[float, ...] | None = None
    battery: float | None = None
    carrying: str | None = None
    gripper_pose: tuple[float, float, float] = (0.2, 0.0, 0.0)
    dirty: bool = False
    cov_dirty: bool = False
    last_plot: float = -math.inf
    shapes: dict = field(default_factory=dict)  # footprint size logged per entity kind
    shown: dict = field(default_factory=dict)  # pose last logged per entity kind

    def truth(self) -> np.ndarray | None:
        if self.gps is not None:
            return np.asarray(self.gps)
        if self.anchor is None:
            return None
        t, o = self.anchor
        if self.odom is None or o is None:
            return t
        return compose_array(t, compose_array(invert_array(o), self.odom))

    def best(self) -> np.ndarray | None:
        """The pose sensors are drawn from: ground truth, else the localized pose."""
        t = self.truth()
        if t is not None:
            return t
        return np.asarray(self.loc) if self.loc is not None else None


@dataclass
class _Stats:
    n_in: int = 0  # data samples received
    taken: int = 0  # data samples the logger took (the rest were overwritten: latest wins)
    n_text: int = 0  # service messages and events received
    logged: int = 0  # rr.log calls
    downsampled: int = 0  # scans skipped by the per-device rate limit
    text_dropped: int = 0
    malformed: int = 0
    late: int = 0  # ticks that took longer than their period
    tick_max: float = 0.0
    drain_max: int = 0  # most samples taken from the ring buffers in one tick


# ---------------------------------------------------------------------------- the watcher
class Watcher:
    """Subscribes to the fabric and logs to a Rerun recording stream ``rec`` from one thread."""

    def __init__(self, session: zenoh.Session, rec, opts: WatchOptions):
        import rerun as rr

        self.rr = rr
        self.session = session
        self.rec = rec
        self.opts = opts
        self.ke = keys.template_to_keyexpr(opts.template)
        self.stats = _Stats()
        self._lock = threading.Lock()
        self._pending: dict[str, bytes] = {}
        self._text: collections.deque = collections.deque(maxlen=20000)  # (kind, key, payload)
        self._replies: collections.deque = collections.deque()  # (what, addr, reply or RpcError)
        self._tokens: collections.deque = collections.deque()  # (addr, joined)
        self._alive: set[DeviceAddr] = set()
        self._geometry: dict[DeviceAddr, dict] = {}
        self._describing: dict[DeviceAddr, float] = {}
        self._layout: dict[DeviceAddr, tuple] = {}
        self._summaries: dict[DeviceAddr, str] = {}  # latest summary text logged per device
        self._last_scan: dict[DeviceAddr, float] = {}
        self._robots: dict[str, _Robot] = {}
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
        self._addr_cache: dict[str, tuple | None] = {}
        self._scan_nodes: set[str] = set()  # nodes with a laser or sonar device
        self._stop = threading.Event()
        self._subs: list = []
        self._channels: list = []
        self.t0 = time.monotonic()

    # ------------------------------------------------------------------ zenoh side (never blocks)
    def _on_data(self, sample) -> None:
        payload = sample.payload.to_bytes()
        with self._lock:
            self._pending[str(sample.key_expr)] = payload
            self.stats.n_in += 1

    def _on_text(self, sample) -> None:
        self._text.append(("svc", str(sample.key_expr), sample.payload.to_bytes()))
        with self._lock:
            self.stats.n_text += 1

    def _on_event(self, sample) -> None:
        self._text.append(("event", str(sample.key_expr), sample.payload.to_bytes()))
        with self._lock:
            self.stats.n_text += 1

    def _on_agent(self, sample) -> None:
        self._text.append(("agent", str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

    def _on_token(self, sample) -> None:
        parsed = keys.parse_key(str(sample.key_expr))
        if parsed is not None and parsed[1] == "":
            self._tokens.append((parsed[0], sample.kind == zenoh.SampleKind.PUT))

    def _rpc(self, what: str, addr: DeviceAddr, op: str, args: dict | None = None, timeout: float = 5.0) -> None:
        from .client import query_rpc

        query_rpc(self.session, addr, op, args, timeout, lambda r: self._replies.append((what, addr, r)))

    def start(self) -> None:
        s = self.session
        base = self.ke
        ring = zenoh.handlers.RingChannel
        # Samples wait in Zenoh's own ring buffers (no Python runs on Zenoh's threads for them, so
        # the logger never waits for the GIL behind thousands of callbacks a second); each tick
        # drains them into the latest-wins dict. A ring that overflows drops its oldest samples.
        self._channels = [
            (s.declare_subscriber(f"{base}/data", ring(self.opts.ring)), self._on_data),
            (s.declare_subscriber(f"{base}/event", ring(1024)), self._on_event),
        ]
        self._subs = [s.liveliness().declare_subscriber(base, self._on_token, history=True)]
        if self.opts.services:
            self._channels.append((s.declare_subscriber("svc/**", ring(self.opts.ring)), self._on_text))
            self._subs.append(s.liveliness().declare_subscriber("agents/*", self._on_agent, history=True))
        self._subs.extend(sub for sub, _ in self._channels)

    def drain(self) -> None:
        """Move what the Zenoh ring buffers hold into the latest-wins dict and the text queue
        (at most one ring's worth each, so a flood cannot keep a tick from ending)."""
        n = 0
        for sub, take in self._channels:
            for _ in range(self.opts.ring):
                smp = sub.try_recv()
                if smp is None:
                    break
                take(smp)
                n += 1
        self.stats.drain_max = max(self.stats.drain_max, n)

    def close(self) -> None:
        self._channels = []
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        self._subs.clear()

    def wait_for_devices(self, timeout: float, stop: threading.Event | None = None) -> bool:
        """True once a device matching the template is alive (tokens arrive on a Zenoh thread);
        False after ``timeout`` seconds or when ``stop`` is set."""
        stop = stop or threading.Event()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not stop.is_set():
            if self._tokens:
                return True
            stop.wait(0.05)
        return bool(self._tokens) and not stop.is_set()

    # ------------------------------------------------------------------ logger side
    def log(self, path: str, archetype, *, static: bool = False) -> None:
        self.rec.log(path, archetype, static=static)
        self.stats.logged += 1

    def setup(self) -> None:
        rr = self.rr
        for p in ("world/robots", "world/blobs"):
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

    def robot(self, name: str) -> _Robot:
        r = self._robots.get(name)
        if r is None:
            r = self._robots[name] = _Robot(name, robot_color(name))
        return r

    def _parse(self, key: str) -> tuple | None:
        p = self._addr_cache.get(key, False)
        if p is False:
            p = keys.parse_key(key)
            self._addr_cache[key] = p
        return p

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
        """One decoded data message (the interface's type from :mod:`rsal.interfaces`)."""
        iface = addr.interface
        node = addr.node
        if iface == "position2d":
            frame = self._geometry.get(addr, {}).get("frame")
            if frame is None:
                frame = {0: "odom", 2: "map"}.get(addr.index)
            if addr.index == 1 and frame == "odom":
                return  # a local planner republishing its base's odometry
            rb = self.robot(node)
            if frame == "odom":
                rb.odom = msg.pose
                if rb.anchor is not None and rb.anchor[1] is None:  # truth came first: anchor it here
                    rb.anchor = (rb.anchor[0], np.asarray(msg.pose))
                rb.speed = msg.vel[0]
            elif frame == "gps":
                rb.gps = msg.pose
                rb.speed = msg.vel[0]
            elif frame == "map":
                rb.loc = msg.pose
            else:
                return
            rb.dirty = True
        elif iface == "localize":
            rb = self.robot(node)
            rb.loc, rb.cov = msg.pose, msg.cov
            rb.dirty = rb.cov_dirty = True
        elif iface in ("laser", "sonar", "ranger"):
            self._on_scan(addr, msg)
        elif iface == "planner":
            self._on_planner(addr, msg)
        elif iface == "blobfinder":
            self._on_blobs(addr, msg)
        elif iface == "gripper":
            g = msg
            rb = self.robot(node)
            if g.carrying != rb.carrying:
                rb.carrying = g.carrying
                rb.dirty = True
                if g.carrying is None:
                    self.log(entity("world", "robots", node, "carried"), self.rr.Clear(recursive=False))
        elif iface == "power":
            p = msg
            self.robot(node).battery = p.percent
            self.log(entity("plots", node, "battery"), self.rr.Scalars(p.percent))
        elif iface == "simulation":
            self._sim_time = msg.t
        else:
            self._on_summary(addr, msg)

    def _on_summary(self, addr: DeviceAddr, msg: Any) -> None:
        """An interface the view does not draw (bumper, fiducial, dio, ...): its registry summary as
        a text log under ``log/devices/<node>``, each time the text changes."""
        rec = interfaces.get(addr.interface)
        if rec is None:
            return
        text = rec.summary(msg)
        if not text or self._summaries.get(addr) == text:
            return
        self._summaries[addr] = text
        self.log(entity("log", "devices", addr.node), self.rr.TextLog(f"{addr}: {text}", level="INFO"))

    def _on_scan(self, addr: DeviceAddr, scan: RangerData) -> None:
        now = time.monotonic()
        geo = self._geometry.get(addr)
        rb = self._robots.get(addr.node)
        pose = rb.best() if rb is not None else None
        if geo is None or pose is None:
            return
        n = len(scan.ranges)
        if n == 0:
            return
        key = (n, scan.angle_min, scan.angle_step)
        lay = self._layout.get(addr)
        if lay is None or lay[0] != key:
            lay = (key, *beam_layout(geo, n, scan.angle_min, scan.angle_step))
            self._layout[addr] = lay
        stride = max(1, math.ceil(n / self.opts.max_beams))
        pts = scan_to_world(scan.ranges, lay[1], lay[2], pose, scan.range_min, scan.range_max, stride)
        self._last_scan[addr] = now
        name = addr.interface if addr.index == 0 else f"{addr.interface}{addr.index}"
        color = SONAR_BLUE if addr.interface == "sonar" else LASER_RED
        self.log(entity("world", "robots", addr.node, name), self.rr.Points2D(pts, radii=0.03, colors=color))

    def _on_planner(self, addr: DeviceAddr, p: PlannerData) -> None:
        rr = self.rr
        node = addr.node
        color = self.robot(node).color
        base = entity("world", "robots", node)
        state = (p.status, p.goal, p.waypoint_count)
        old = self._planner.get(node)
        if old is None or old[0] != state:
            if p.status == "driving" and p.waypoint_count >= 2:
                self._rpc("waypoints", addr, "waypoints")
            elif p.status != "driving":
                self.log(base + "/path", rr.Clear(recursive=True))
                self.log(base + "/waypoint", rr.Clear(recursive=False))
            if p.goal:
                self.log(base + "/goal", rr.Points2D([p.goal[:2]], radii=0.1, colors=color, labels=[f"goal {node}"]))
                self.log(
                    base + "/goal",
                    rr.Arrows2D(origins=[p.goal[:2]], vectors=[[0.4 * math.cos(p.goal[2]), 0.4 * math.sin(p.goal[2])]]),
                )
            if old is None or old[0][0] != p.status:
                msg = f"{node}: {p.status}" + (f" ({p.message})" if p.message else "")
                level = "WARN" if p.status in ("aborted", "invalid") else "INFO"
                self.log(entity("log", "planner", node), rr.TextLog(msg, level=level))
        if p.status == "driving" and p.waypoint and (old is None or old[1] != p.waypoint):
            self.log(base + "/waypoint", rr.Points2D([p.waypoint[:2]], radii=0.07, colors=YELLOW))
        self._planner[node] = (state, p.waypoint)

    def _on_blobs(self, addr: DeviceAddr, b: BlobfinderData) -> None:
        rr = self.rr
        rb = self._robots.get(addr.node)
        pose = rb.best() if rb is not None else None
        path = entity("world", "robots", addr.node, "blobs" if addr.index == 0 else f"blobs{addr.index}")
        if pose is None:
            return
        if not b.blobs:
            if self._last_scan.get(addr) != 0.0:
                self.log(path, rr.Clear(recursive=False))
                self._last_scan[addr] = 0.0
            return
        now = time.monotonic()
        if now - self._last_scan.get(addr, -math.inf) < 1.0 / self.opts.scan_rate:
            return
        self._last_scan[addr] = now
        cam = np.asarray(self._geometry.get(addr, {}).get("pose") or (0.0, 0.0, 0.0), dtype=float)
        rng = np.array([x.range for x in b.blobs])
        brg = np.array([x.bearing for x in b.blobs])
        local = np.column_stack([rng * np.cos(brg), rng * np.sin(brg), np.zeros_like(rng)])
        w = compose_array(compose_array(pose, cam), local)[:, :2]
        colors = np.array([(x.color << 8) | 255 for x in b.blobs], dtype=np.uint32)
        self.log(path, rr.Points2D(w, radii=0.06, colors=colors))
        self._last_scan[addr] = now

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

    def _place(self, rb: _Robot, kind: str, pose, *, radius: float, color: int, label: str) -> None:
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
            else:
                parsed = self._parse(key)
                if parsed is None:
                    continue
                addr = parsed[0]
                body = ", ".join(f"{k}={_short(v)}" for k, v in m.items())
                self.log(entity("log", "events", addr.node), rr.TextLog(f"{addr}: {body}", level="INFO"))


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3g}"
    if isinstance(v, (bytes, bytearray)):
        return f"<{len(v)} bytes>"
    if isinstance(v, list) and all(isinstance(x, float) for x in v):
        return "[" + ", ".join(f"{x:.3g}" for x in v) + "]"
    s = str(v)
    return s if len(s) <= 120 else s[:117] + "..."


# ---------------------------------------------------------------------------- command line
def _blueprint():
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="world", name="fleet"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="plots", name="plots"),
                rrb.TextLogView(origin="log", name="log"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=False,
    )


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def run_watch(args: argparse.Namespace) -> int:
    opts = WatchOptions(
        template=args.template,
        rate=args.rate,
        scan_rate=args.scan_rate,
        max_beams=args.max_beams,
        truth_rate=args.truth_rate,
        plot_rate=args.plot_rate,
        particles=args.particles,
        particles_rate=args.particles_rate,
        services=not args.no_services,
        report_every=args.report_every,
    )
    try:
        opts.check()
    except ValueError as e:
        print(f"rsal watch: {e}", file=sys.stderr)
        return 1
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        print(f"rsal watch: --duration {args.duration:g} must be a positive number of seconds", file=sys.stderr)
        return 1
    if not (args.save or args.serve or _has_display()):
        print(
            "rsal watch: no display ($DISPLAY and $WAYLAND_DISPLAY are unset): record with --save FILE.rrd or "
            "open the web viewer with --serve",
            file=sys.stderr,
        )
        return 1
    if args.save and not str(args.save).endswith(".rrd"):
        print(f"rsal watch: --save {args.save!r} must name an .rrd file", file=sys.stderr)
        return 1
    if args.save and not os.path.isdir(os.path.dirname(os.path.abspath(args.save))):
        print(f"rsal watch: --save {args.save!r}: the directory does not exist", file=sys.stderr)
        return 1
    stop, got = stop_on_signals()
    try:
        session = open_session(TransportArgs.from_namespace(args))
    except ValueError as e:
        print(f"rsal watch: {e}", file=sys.stderr)
        return 1
    watcher = None
    rec = None
    try:
        import rerun as rr

        rec = rr.RecordingStream("rsal_watch")
        watcher = Watcher(session, rec, opts)
        watcher.start()
        if not watcher.wait_for_devices(args.wait, stop):
            if stop.is_set():
                return 0
            print(
                f"rsal watch: no devices match {opts.template!r} within {args.wait:g} s (is a device server running? "
                f"try 'rsal sim maps/testroom.world', or check --connect)",
                file=sys.stderr,
            )
            return 1
        sinks = []
        if args.save:
            sinks.append(rr.FileSink(args.save))
        if args.serve:
            try:
                server = rr.GrpcServerSink("127.0.0.1", args.grpc_port)
            except Exception as e:
                print(f"rsal watch: cannot serve gRPC on port {args.grpc_port}: {e} (try --grpc-port)", file=sys.stderr)
                return 1
            sinks.append(server)
        if sinks:
            rec.set_sinks(*sinks, default_blueprint=_blueprint())
        else:
            try:
                rec.spawn(default_blueprint=_blueprint())
            except Exception as e:
                print(f"rsal watch: cannot start the Rerun viewer: {e} (record with --save FILE.rrd)", file=sys.stderr)
                return 1
        if args.serve:
            uri = server.uri
            try:
                rr.serve_web_viewer(web_port=args.web_port, open_browser=False, connect_to=uri)
            except Exception as e:
                print(
                    f"rsal watch: cannot serve the web viewer on port {args.web_port}: {e} (try --web-port)",
                    file=sys.stderr,
                )
                return 1
            print(f"[watch] web viewer: http://127.0.0.1:{args.web_port}/?url={uri}", flush=True)
        if args.save:
            print(f"[watch] recording to {args.save}", flush=True)
        watcher.setup()
        watcher.run(stop, args.duration)
    finally:
        if watcher is not None:
            watcher.close()
        if rec is not None:
            try:
                rec.flush(timeout_sec=10.0)
                rec.disconnect()
            except Exception as e:
                print(f"rsal watch: could not finish the recording: {e}", file=sys.stderr)
        session.close()
    s = watcher.stats
    print(
        f"[watch] stopped ({got[0] if got else 'done'}): {s.n_in} samples and {s.n_text} messages in, {s.taken} "
        f"samples taken, {s.logged} logged, "
        f"{s.downsampled} scans downsampled, {s.text_dropped} text entries dropped, {s.malformed} malformed, "
        f"{s.late} late ticks",
        flush=True,
    )
    return 0


def register(sub) -> None:
    p = sub.add_parser("watch", help="live view of the fleet in Rerun (viewer, web viewer or .rrd file)")
    p.add_argument("template", nargs="?", default="**", help="devices to watch, e.g. 'r0:*:*' (default: all)")
    p.add_argument("--save", metavar="FILE.rrd", help="record to this file instead of spawning a viewer")
    p.add_argument("--serve", action="store_true", help="serve the web viewer on loopback and print its URL")
    p.add_argument("--web-port", type=int, default=9090, help="web viewer HTTP port with --serve (default 9090)")
    p.add_argument("--grpc-port", type=int, default=9876, help="gRPC port with --serve (default 9876)")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--wait", type=float, default=10.0, help="seconds to wait for the first device (default 10)")
    p.add_argument("--rate", type=float, default=10.0, help="logger ticks per second (default 10)")
    p.add_argument("--scan-rate", type=float, default=5.0, help="scans logged per second per device (default 5)")
    p.add_argument("--max-beams", type=int, default=180, help="beams per logged scan, every k-th (default 180)")
    p.add_argument("--truth-rate", type=float, default=1.0, help="ground-truth polls per robot per second (default 1)")
    p.add_argument("--plot-rate", type=float, default=2.0, help="time-series points per robot per second (default 2)")
    p.add_argument("--particles", action="store_true", help="also log AMCL particles (rpc get_particles)")
    p.add_argument("--particles-rate", type=float, default=1.0, help="particle polls per second (default 1)")
    p.add_argument("--no-services", action="store_true", help="do not log agent service messages")
    p.add_argument("--report-every", type=float, default=5.0, help="seconds between progress lines (default 5)")
    add_transport_args(p)
    p.set_defaults(func=run_watch)
