"""The ``ranger`` interface and its ``laser`` and ``sonar`` forms: range sensors (Player's
``ranger``, ``laser`` and ``sonar``).

Message :class:`RangerData` (``data`` and the ``rpc/get`` reply) with its packed fast path; typed
geometry :class:`RangerGeometry`, built from a ``rpc/describe`` answer, which lays out where every
beam starts and points (the one implementation the client proxies, the navigation drivers and the
live view use); proxies :class:`Ranger`, :class:`Laser`, :class:`Sonar`. Wire format and geometry
fields: ``docs/protocol.md`` (RangerData; "Drivers: devices, operations, geometry").
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..msgs import _F32, Describe, _frombuffer, _Msg, _pack_map, decode_map, f32_array, f32_bytes, get_float
from .base import Device, Interface

__all__ = ["RangerData", "RangerSensor", "RangerGeometry", "Ranger", "Laser", "Sonar", "INTERFACES"]


@dataclass(slots=True, eq=False)  # not frozen: a frozen init costs 4x on this hot path; treat as immutable
class RangerData(_Msg):
    """ranger, laser and sonar ``data``: ``ranges`` (float32 bytes on the wire, metres). For a
    laser, beam ``i`` points at ``angle_min + i * angle_step`` (rad, in the ranger's frame, whose
    pose on the robot is ``rpc/describe`` geometry ``pose``); a sonar's transducer poses are in
    ``rpc/describe`` geometry ``sensors``."""

    t: float
    ranges: np.ndarray
    angle_min: float = 0.0
    angle_step: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0

    @classmethod
    def from_dict(cls, m: dict) -> RangerData:
        try:
            t, r, a0, da = m["t"], m["ranges"], m["angle_min"], m["angle_step"]
            lo, hi = m["range_min"], m["range_max"]
        except KeyError:
            pass
        else:
            if (  # fast path: every field present and well-typed; x - x is NaN for inf and NaN
                type(t) is type(a0) is type(da) is type(lo) is type(hi) is float
                and (t - t) + (a0 - a0) + (da - da) + (lo - lo) + (hi - hi) == 0.0
                and type(r) is bytes
                and not len(r) & 3
            ):
                return cls(t, _frombuffer(r, _F32), a0, da, lo, hi)
        return cls(
            get_float(m, "t"),
            f32_array(m, "ranges"),
            get_float(m, "angle_min", 0.0),
            get_float(m, "angle_step", 0.0),
            get_float(m, "range_min", 0.0),
            get_float(m, "range_max", 0.0),
        )

    def to_dict(self) -> dict:  # explicit: the hottest message on the fabric
        r = self.ranges
        return {
            "t": self.t,
            "ranges": r.tobytes() if r.dtype is _F32 else f32_bytes(r),
            "angle_min": self.angle_min,
            "angle_step": self.angle_step,
            "range_min": self.range_min,
            "range_max": self.range_max,
        }

    # The wire fast path. Every scan a server sends has the same layout: this map's six keys in
    # field order, five float64 and one bin. Packing that layout with two precompiled structs and
    # reading it back the same way (the ranges a view into the payload, no copy) takes about half
    # the time of building and walking a generic map (docs/benchmarks.md). The bytes are exactly
    # msgpack's (a test compares them); any other layout -- another key order, float32 or integer
    # fields, extra keys, trailing bytes -- takes the generic path, with its checks and errors.
    def to_msgpack(self) -> bytes:
        t, r, a0, da, lo, hi = self.t, self.ranges, self.angle_min, self.angle_step, self.range_min, self.range_max
        if (
            type(t) is type(a0) is type(da) is type(lo) is type(hi) is float
            and type(r) is np.ndarray
            and r.dtype is _F32
        ):
            rb = r.tobytes()
            n = len(rb)
            if n < 0x10000:
                head = _RD_HEAD16.pack(_RD_T, t, _RD_R16, n) if n > 0xFF else _RD_HEAD8.pack(_RD_T, t, _RD_R8, n)
                return b"".join((head, rb, _RD_TAIL.pack(_RD_K0, a0, _RD_K1, da, _RD_K2, lo, _RD_K3, hi)))
        return _pack_map(self.to_dict())

    @classmethod
    def from_bytes(cls, data: bytes | bytearray | memoryview | None) -> RangerData:
        if type(data) is bytes and len(data) >= _RD_MIN:
            head, t, key, n = _RD_HEAD16.unpack_from(data)
            if head == _RD_T and key == _RD_R16 and len(data) == _RD_MIN + 1 + n and not n & 3:
                k0, a0, k1, da, k2, lo, k3, hi = _RD_TAIL.unpack_from(data, 22 + n)
                if (k0, k1, k2, k3) == _RD_KEYS and (t - t) + (a0 - a0) + (da - da) + (lo - lo) + (hi - hi) == 0.0:
                    return cls(t, _frombuffer(data, _F32, n >> 2, 22), a0, da, lo, hi)
        return cls.from_dict(decode_map(data))


# RangerData's wire layout: fixmap(6) "t" float64, "ranges" bin8/bin16 <n bytes>, then the four
# float64 fields. Only bin16 payloads (256 B to 64 kB of ranges: 64 to 16383 beams) are read by
# the fast path; shorter and longer scans are still written by it where they fit, and read generically.
_RD_T = 0x86A174CB  # fixmap(6), fixstr "t", float64 marker
_RD_R8, _RD_R16 = b"\xa6ranges\xc4", b"\xa6ranges\xc5"
_RD_HEAD8 = struct.Struct(">Id8sB")
_RD_HEAD16 = struct.Struct(">Id8sH")
_RD_K0, _RD_K1, _RD_K2, _RD_K3 = (
    b"\xa9angle_min\xcb",
    b"\xaaangle_step\xcb",
    b"\xa9range_min\xcb",
    b"\xa9range_max\xcb",
)
_RD_KEYS = (_RD_K0, _RD_K1, _RD_K2, _RD_K3)
_RD_TAIL = struct.Struct(">11sd12sd11sd11sd")
_RD_MIN = _RD_HEAD8.size + _RD_TAIL.size  # 98: the bin8 header is one byte shorter than bin16's


def _pose3(v: Any) -> tuple[float, float, float]:
    if isinstance(v, (list, tuple)) and len(v) >= 3:
        return (float(v[0]), float(v[1]), float(v[2]))
    return (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class RangerSensor:
    """One sensor of a ranger (a laser's scanner, one sonar transducer): ``pose`` in the ranger's
    frame, field of view ``fov`` (rad), ``samples`` per reading, range limits (m)."""

    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fov: float = 0.0
    samples: int = 1
    range_min: float = 0.0
    range_max: float = 0.0

    @classmethod
    def from_dict(cls, m: dict) -> RangerSensor:
        return cls(
            _pose3(m.get("pose")),
            float(m.get("fov", 0.0) or 0.0),
            int(m.get("samples", 1) or 1),
            float(m.get("range_min", 0.0) or 0.0),
            float(m.get("range_max", 0.0) or 0.0),
        )

    def to_dict(self) -> dict:
        return {
            "pose": list(self.pose),
            "fov": self.fov,
            "samples": self.samples,
            "range_min": self.range_min,
            "range_max": self.range_max,
        }


class RangerGeometry:
    """Where a range device's beams start and point, in the robot frame.

    Built from the device's ``rpc/describe`` geometry (:meth:`from_describe`, or the map itself):
    ``pose`` (the ranger's mount on the robot), ``sensors`` (each a :class:`RangerSensor`).
    ``override_pose`` replaces the mount (a driver configured with its own laser pose). The scan
    decides the layout (docs/protocol.md, RangerData):

    - as many readings as sensors (a sonar ring, ``angle_step`` 0): beam ``i`` is sensor ``i``;
    - several sensors whose ``samples`` add up to the readings: each fans over its own ``fov``;
    - otherwise a laser: beam ``i`` starts at the first sensor and points at
      ``angle_min + i * angle_step`` in the ranger's frame (a sonar with fewer described
      transducers than readings repeats the last one).

    The layout of one scan shape is computed once (numpy, no per-beam Python) and cached.
    """

    __slots__ = ("kind", "mount", "sensors", "_cache")

    def __init__(self, geometry: dict | None = None, override_pose=None):
        g = geometry if isinstance(geometry, dict) else {}
        self.kind: str = str(g.get("kind", "") or "")
        self.mount = _pose3(override_pose if override_pose is not None else g.get("pose"))
        self.sensors = tuple(RangerSensor.from_dict(s) for s in g.get("sensors") or [] if isinstance(s, dict))
        self._cache: tuple[tuple, np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_describe(cls, d: Describe | dict, override_pose=None) -> RangerGeometry:
        """From a ``describe`` reply (a :class:`~rsal.msgs.Describe` or its ``geometry`` map)."""
        return cls(d.geometry if isinstance(d, Describe) else d, override_pose)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "pose": list(self.mount), "sensors": [s.to_dict() for s in self.sensors]}

    def __repr__(self) -> str:
        return f"RangerGeometry(kind={self.kind!r}, pose={self.mount}, sensors={len(self.sensors)})"

    def _compose(self, poses: np.ndarray) -> np.ndarray:
        mx, my, ma = self.mount
        c, s = math.cos(ma), math.sin(ma)
        out = np.empty((len(poses), 3))
        out[:, 0] = mx + c * poses[:, 0] - s * poses[:, 1]
        out[:, 1] = my + s * poses[:, 0] + c * poses[:, 1]
        out[:, 2] = ma + poses[:, 2]
        return out

    def sensor_poses(self) -> np.ndarray:
        """``(k, 3)`` poses of the sensors in the robot frame (mount ⊕ sensor pose)."""
        return self._compose(np.array([s.pose for s in self.sensors], dtype=float).reshape(-1, 3))

    def beam_poses(self, n: int, angle_min: float = 0.0, angle_step: float = 0.0) -> np.ndarray:
        """``(n, 3)`` rows ``[x, y, bearing]``: where each of ``n`` beams starts and points, robot frame."""
        origins, bearings = self.layout(n, angle_min, angle_step)
        return np.column_stack([origins, bearings])

    def layout(self, n: int, angle_min: float = 0.0, angle_step: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Origins ``(n, 2)`` and bearings ``(n,)`` of ``n`` beams in the robot frame (cached)."""
        key = (n, angle_min, angle_step)
        hit = self._cache
        if hit is not None and hit[0] == key:
            return hit[1], hit[2]
        sens = self.sensors
        if sens and len(sens) == n and (n > 1 or angle_step == 0.0):
            t = self.sensor_poses()
        elif len(sens) > 1 and sum(s.samples for s in sens) == n:
            rows = []
            for s in sens:
                rel = np.linspace(-s.fov / 2, s.fov / 2, s.samples) if s.samples > 1 else np.zeros(1)
                p = np.zeros((s.samples, 3))
                p[:, 0], p[:, 1], p[:, 2] = s.pose[0], s.pose[1], s.pose[2] + rel
                rows.append(p)
            t = self._compose(np.vstack(rows))
        elif angle_step == 0.0 and 0 < len(sens) < n:  # more readings than described transducers
            t = self.sensor_poses()
            t = np.vstack([t, np.repeat(t[-1:], n - len(t), axis=0)])
        else:
            p = np.zeros((n, 3))
            if sens:
                p[:, 0], p[:, 1] = sens[0].pose[0], sens[0].pose[1]
            p[:, 2] = angle_min + angle_step * np.arange(n)
            t = self._compose(p)
        origins, bearings = np.ascontiguousarray(t[:, :2]), np.ascontiguousarray(t[:, 2])
        self._cache = (key, origins, bearings)
        return origins, bearings

    def beams(self, scan: RangerData) -> tuple[np.ndarray, np.ndarray]:
        """Origins ``(n, 2)`` and bearings ``(n,)`` of the beams of ``scan`` in the robot frame."""
        return self.layout(int(scan.ranges.shape[0]), scan.angle_min, scan.angle_step)

    def beam_width(self, scan: RangerData) -> float:
        """The cone width (rad) of one-reading-per-sensor devices (sonar), 0 for a laser's beams."""
        sens = self.sensors
        if sens and len(sens) == int(scan.ranges.shape[0]) and all(s.samples == 1 for s in sens):
            return float(np.mean([s.fov for s in sens]))
        return 0.0

    def points(self, scan: RangerData, *, max_range: float | None = None) -> np.ndarray:
        """Obstacle points ``(m, 2)`` in the robot frame; max-range and invalid readings dropped."""
        origins, bearings = self.beams(scan)
        r = np.asarray(scan.ranges, dtype=float)
        top = scan.range_max if scan.range_max > 0 else np.inf
        if max_range is not None:
            top = min(top, max_range)
        ok = np.isfinite(r) & (r < top - 1e-3) & (r > max(scan.range_min, 0.0))
        r = r[ok]
        return np.column_stack([origins[ok, 0] + r * np.cos(bearings[ok]), origins[ok, 1] + r * np.sin(bearings[ok])])


class Ranger(Device):
    """A range sensor (Player ranger): ``ranges`` in metres, beam angles when known."""

    data_type = RangerData

    @property
    def ranges(self) -> np.ndarray | None:
        return self.latest.ranges if self.latest is not None else None

    def geometry(self, timeout: float = 5.0) -> RangerGeometry:
        """The device's :class:`RangerGeometry` (one ``describe`` call, then cached)."""
        g = getattr(self, "_geometry", None)
        if g is None:
            g = self._geometry = RangerGeometry.from_describe(self.describe(timeout))
        return g

    def angles(self) -> np.ndarray | None:
        """Beam angles in the sensor frame: from the scan for a laser, from describe for a sonar."""
        m = self.latest
        if m is None:
            return None
        if m.angle_step != 0.0:
            return m.angle_min + np.arange(m.ranges.shape[0]) * m.angle_step
        return np.array([s.pose[2] for s in self.geometry().sensors], dtype=float)

    def sensor_poses(self) -> np.ndarray:
        """(n, 3) poses of the beams' origins in the robot frame (x, y, yaw): one per beam of the
        latest scan, or one per described sensor before the first scan."""
        g = self.geometry()
        m = self.latest
        if m is None:
            return g.sensor_poses()
        return g.beam_poses(int(m.ranges.shape[0]), m.angle_min, m.angle_step)


class Laser(Ranger):
    pass


class Sonar(Ranger):
    pass


def _summary(m: RangerData) -> str:
    r = np.asarray(m.ranges, dtype=float)
    ok = r[np.isfinite(r)]
    near = f"{ok.min():.2f}" if ok.size else "-"
    return f"{r.shape[0]} beams nearest={near} m"


def _record(name: str, proxy: type[Ranger], doc: str) -> Interface:
    return Interface(name, proxy=proxy, data=RangerData, geometry=RangerGeometry, summary=_summary, doc=doc)


INTERFACES = (
    _record("ranger", Ranger, "range readings of any kind of range sensor"),
    _record("laser", Laser, "a scanning laser: one sensor, many beams"),
    _record("sonar", Sonar, "a sonar ring: one reading per transducer"),
)
