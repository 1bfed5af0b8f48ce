"""The ``crowd`` interface: every robot of a simulator as arrays, in one message per step.

A host that drives hundreds of simulated robots cannot afford one sample per robot and device
(1000 robots: 20,000 samples per second, one Python callback each). Like the in-process swarm
simulators (ARGoS's loop functions read and write all robots' state as arrays), the simulator
serves a ``crowd`` device (``rsal/<simnode>/crowd/0``) that reads and commands all its robots at
once:

- ``rpc/describe`` geometry (:class:`CrowdLayout`): the robots in a fixed order, each one's frame
  and the index of its ranger geometry (the ranger's own ``describe`` geometry, listed once per
  distinct geometry) and the offsets of its ranges in the flat range array;
- ``data`` (:class:`CrowdData`), once per simulation step while someone listens: the values of
  every robot's ``position2d:0`` and ``sonar:0``/``ranger:0`` samples of that step, as packed
  little-endian float32 arrays;
- ``cmd`` (:class:`CrowdCmd`): velocities for a set of robots (indices into the order), each of
  which passes that robot's own safety path as a ``position2d`` command would.

Wire format: ``docs/protocol.md``, "crowd".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..msgs import MessageError, _Msg, get_float, get_list
from .base import Device, Interface

__all__ = ["CrowdData", "CrowdCmd", "CrowdLayout", "Crowd", "INTERFACE"]

_F32 = np.dtype("<f4")
_F64 = np.dtype("<f8")
_I32 = np.dtype("<i4")


def _array(m: dict, name: str, dtype: np.dtype, n: int | None = None) -> np.ndarray:
    v = m.get(name)
    if not isinstance(v, (bytes, bytearray)):
        raise MessageError(f"field {name!r} must be packed {dtype.name} bytes, not {type(v).__name__}")
    if len(v) % dtype.itemsize:
        raise MessageError(f"field {name!r} has {len(v)} bytes, not a whole number of {dtype.name}")
    a = np.frombuffer(bytes(v), dtype=dtype)
    if n is not None and len(a) != n:
        raise MessageError(f"field {name!r} has {len(a)} values, expected {n}")
    return a


@dataclass(eq=False)  # arrays: compare field by field
class CrowdData(_Msg):
    """crowd ``data``: sim time ``t``; for N robots in the layout's order: ``pose`` (N, 3) x, y,
    yaw as each robot's ``position2d:0`` reports it (odometry, or ground truth with
    ``localization = "gps"``); ``vel`` (N, 2) forward speed and turn rate; ``stall`` (N,) 1.0 where
    stalled; ``scan_t`` (N,) the time of each robot's latest scan (-1: none yet); ``ranges`` every
    robot's latest scan, flat, robot ``i``'s at ``offsets[i]:offsets[i + 1]`` (int32, N + 1)."""

    t: float
    pose: np.ndarray
    vel: np.ndarray
    stall: np.ndarray
    scan_t: np.ndarray
    ranges: np.ndarray
    offsets: np.ndarray

    @property
    def count(self) -> int:
        return len(self.stall)

    def scan(self, i: int) -> np.ndarray:
        """Robot ``i``'s ranges."""
        return self.ranges[self.offsets[i] : self.offsets[i + 1]]

    def to_dict(self) -> dict:
        return {
            "t": float(self.t),
            "pose": np.ascontiguousarray(self.pose, _F32).tobytes(),
            "vel": np.ascontiguousarray(self.vel, _F32).tobytes(),
            "stall": np.ascontiguousarray(self.stall, _F32).tobytes(),
            "scan_t": np.ascontiguousarray(self.scan_t, _F32).tobytes(),
            "ranges": np.ascontiguousarray(self.ranges, _F32).tobytes(),
            "offsets": np.ascontiguousarray(self.offsets, _I32).tobytes(),
        }

    @classmethod
    def from_dict(cls, m: dict) -> CrowdData:
        offsets = _array(m, "offsets", _I32)
        n = len(offsets) - 1
        if n < 0:
            raise MessageError("field 'offsets' is empty: it has one value more than there are robots")
        ranges = _array(m, "ranges", _F32)
        if offsets[0] != 0 or offsets[-1] != len(ranges) or np.any(np.diff(offsets) < 0):
            raise MessageError(f"field 'offsets' does not index the {len(ranges)} ranges (0, ascending, to the end)")
        return cls(
            get_float(m, "t"),
            _array(m, "pose", _F32, 3 * n).reshape(n, 3),
            _array(m, "vel", _F32, 2 * n).reshape(n, 2),
            _array(m, "stall", _F32, n),
            _array(m, "scan_t", _F32, n),
            ranges,
            offsets,
        )


@dataclass(eq=False)
class CrowdCmd(_Msg):
    """crowd ``cmd``: forward speed ``v`` (m/s) and turn rate ``w`` (rad/s) for the robots at
    ``idx`` (int32 indices into the layout's order); velocities travel as float64, so a command at
    a robot's exact speed limit stays within it."""

    idx: np.ndarray
    v: np.ndarray
    w: np.ndarray

    def to_dict(self) -> dict:
        return {
            "idx": np.ascontiguousarray(self.idx, _I32).tobytes(),
            "v": np.ascontiguousarray(self.v, _F64).tobytes(),
            "w": np.ascontiguousarray(self.w, _F64).tobytes(),
        }

    @classmethod
    def from_dict(cls, m: dict) -> CrowdCmd:
        idx = _array(m, "idx", _I32)
        v = _array(m, "v", _F64, len(idx))
        w = _array(m, "w", _F64, len(idx))
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise MessageError("fields 'v' and 'w' must be finite numbers")
        return cls(idx, v, w)


@dataclass
class CrowdLayout:
    """The crowd device's ``describe`` geometry, typed: ``robots`` (names, the order of every array),
    ``frames`` (each robot's position2d frame, ``odom`` or ``gps``), ``rangers`` (the distinct ranger
    geometries, as each ranger's own ``describe`` reports it), ``ranger_of`` (each robot's index
    into ``rangers``, -1: no ranger), ``offsets`` (N + 1: where each robot's ranges sit) and
    ``limits`` (each robot's ``[max speed m/s, max turn rate rad/s]``, as its position2d reports)."""

    robots: list[str]
    frames: list[str]
    rangers: list[dict]
    ranger_of: list[int]
    offsets: list[int] = field(default_factory=list)
    limits: list[list[float]] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "robots": list(self.robots),
            "frames": list(self.frames),
            "rangers": list(self.rangers),
            "ranger_of": list(self.ranger_of),
            "offsets": list(self.offsets),
            "limits": [list(x) for x in self.limits],
        }

    @classmethod
    def from_dict(cls, m: dict) -> CrowdLayout:
        robots = get_list(m, "robots", str)
        n = len(robots)
        out = cls(
            robots,
            get_list(m, "frames", str),
            get_list(m, "rangers", dict),
            get_list(m, "ranger_of", int),
            get_list(m, "offsets", int),
            get_list(m, "limits", lambda x: [float(v) for v in x], required=False),
        )
        if len(out.frames) != n or len(out.ranger_of) != n or len(out.offsets) != n + 1:
            raise MessageError(f"crowd layout: {n} robots, but frames, ranger_of or offsets do not match")
        if out.limits and (len(out.limits) != n or any(len(x) != 2 for x in out.limits)):
            raise MessageError(f"crowd layout: {n} robots, but limits does not list [v, w] for each")
        if any(not -1 <= k < len(out.rangers) for k in out.ranger_of):
            raise MessageError("crowd layout: a ranger_of index names no ranger geometry")
        return out

    def index(self) -> dict[str, int]:
        """Robot name -> its row."""
        return {r: i for i, r in enumerate(self.robots)}

    def beams(self, i: int) -> tuple[np.ndarray, float] | None:
        """Robot ``i``'s beams as (k, 4) rows (x, y, cos yaw, sin yaw) of each transducer in the
        robot's frame, and the ring's largest range; None without a ranger."""
        k = self.ranger_of[i]
        if k < 0:
            return None
        g = self.rangers[k]
        px, py, pa = g.get("pose", (0.0, 0.0, 0.0))[:3]
        rows = []
        for s in g.get("sensors", ()):
            sx, sy, sa = s["pose"][:3]
            x = px + sx * math.cos(pa) - sy * math.sin(pa)
            y = py + sx * math.sin(pa) + sy * math.cos(pa)
            rows.append((x, y, math.cos(pa + sa), math.sin(pa + sa)))
        rmax = max((float(s["range_max"]) for s in g.get("sensors", ())), default=0.0)
        return np.asarray(rows, dtype=float).reshape(-1, 4), rmax


class Crowd(Device):
    """All robots of a simulator as arrays: :meth:`layout` once, then ``latest`` (a :class:`CrowdData`
    per step) and :meth:`command` for many robots in one message."""

    data_type = CrowdData

    def layout(self, timeout: float = 10.0) -> CrowdLayout:
        return CrowdLayout.from_dict(self.describe(timeout).geometry)

    def command(self, idx: Any, v: Any, w: Any) -> None:
        """Velocities for the robots at ``idx`` (fire and forget; each robot's command timeout
        applies, so the caller refreshes them every control cycle)."""
        self.send(CrowdCmd(np.asarray(idx, _I32), np.asarray(v, _F64), np.asarray(w, _F64)))


INTERFACE = Interface(
    "crowd",
    proxy=Crowd,
    data=CrowdData,
    cmds=(CrowdCmd,),
    summary=lambda m: f"t={m.t:.2f} s robots={m.count} beams={len(m.ranges)}",
    doc="every robot of a simulator as arrays: poses, velocities, stalls, scans; velocities in one message",
)
