"""``replay`` driver: a synthetic range sensor for tests and benchmarks (dora-rs ``MockNode`` replay).

Provides ``ranger`` and/or ``laser`` devices that publish :class:`~rsal.msgs.RangerData` scans at
``rate`` Hz without a simulator or hardware, the way Player test set-ups replayed a logged laser.
``rate = inf`` publishes as fast as it goes: back-to-back scans for 2 ms per scheduler call, so
commands and rpcs of the other devices still wait at most that long.

Parameters (Player-style names, degrees where a user types an angle)::

    [[driver]]
    name = "replay"
    provides = ["r0:ranger:0", "r0:laser:0"]
    rate = 10            # Hz; inf: as fast as it goes
    samples = 682        # beams per scan (default 682, a Hokuyo URG-04LX)
    fov = 240            # degrees, centred on the sensor's x axis (default 240)
    range_min = 0.02     # m (default 0.02)
    range_max = 5.6      # m (default 5.6)
    pattern = "constant" # "constant": every beam reads `value`;
                         # "sweep": a sine wave over the beams that turns once per `period` s
    value = 1.0          # m, the constant range (default 1.0; only used by "constant")
    period = 4.0         # s, one turn of the sweep (default 4)
    count = 1000         # optional: stop after this many scans (the devices stay alive)
    stamp = "monotonic"  # optional: t = time.monotonic() at publish ("elapsed", the default:
                         # seconds since the driver started)

``stamp = "monotonic"`` lets a process on the same machine measure latency as
``time.monotonic() - scan.t`` (``benchmarks/bench_fabric.py``). Every provided device carries the
same scan. ``rpc/get`` returns the latest scan; ``rpc/describe`` gives the geometry in the shape of
the ``sim`` driver's laser (``kind``, ``pose``, ``sensors[0]`` with ``fov`` in radians).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from rsal.msgs import ErrorCode, RangerData, RpcError

from ..driver import Driver, register
from ..params import param, parse_params

__all__ = ["ReplayDriver", "ReplayParams"]

BURST = 0.002  # s of back-to-back scans per scheduler call at rate = inf (commands and rpcs wait at most this)
_monotonic = time.monotonic


@dataclass(frozen=True)
class ReplayParams:
    """The ``replay`` driver's parameters (module docstring)."""

    samples: int = param(682, min=1, doc="beams per scan")
    fov: float = param(240.0, gt=0.0, max=360.0, expect="in (0, 360] degrees", doc="degrees")
    range_min: float = param(0.02, doc="m")
    range_max: float = param(5.6, doc="m")
    pattern: Literal["constant", "sweep"] = param("constant")
    value: float = param(1.0, doc="m, the constant range")
    period: float = param(4.0, doc="s, one turn of the sweep")
    count: int | None = param(None, min=1, doc="stop after this many scans")
    stamp: Literal["elapsed", "monotonic"] = param("elapsed")

    def __post_init__(self) -> None:
        if not 0.0 <= self.range_min < self.range_max:
            raise ValueError(
                f"range_min = {self.range_min:g} and range_max = {self.range_max:g} m must satisfy "
                "0 <= range_min < range_max"
            )
        if self.pattern == "constant" and not self.range_min <= self.value <= self.range_max:
            raise ValueError(
                f"value = {self.value:g} m must lie in [range_min, range_max] = "
                f"[{self.range_min:g}, {self.range_max:g}]"
            )
        if self.period <= 0:
            raise ValueError(f"period = {self.period:g} s must be positive")


@register("replay")
class ReplayDriver(Driver):
    interfaces = ("ranger", "laser")
    default_rate = 10.0
    data_types = {"ranger": "RangerData", "laser": "RangerData"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        p = self.settings = parse_params(ReplayParams, cfg)
        self.samples = p.samples
        self.fov = math.radians(p.fov)
        self.range_min, self.range_max = p.range_min, p.range_max
        self.pattern, self.value, self.period, self.count, self.stamp = p.pattern, p.value, p.period, p.count, p.stamp
        self.angle_step = self.fov / (self.samples - 1) if self.samples > 1 else 0.0
        self.angle_min = -self.fov / 2 if self.samples > 1 else 0.0
        self._constant = np.full(self.samples, self.value, dtype="<f4")
        self._constant.setflags(write=False)
        self._beam_phase = np.linspace(0.0, 2 * math.pi, self.samples, endpoint=False)
        self.configured_rate = self.rate
        self.sent = 0
        self.last: RangerData | None = None
        self._t0 = time.monotonic()

    # ------------------------------------------------------------------ the driver contract
    def setup(self) -> None:
        self._t0 = time.monotonic()
        self.sent = 0

    def ranges(self, elapsed: float) -> np.ndarray:
        """The scan ``elapsed`` seconds after start (float32, metres)."""
        if self.pattern == "constant":
            return self._constant
        lo, hi = self.range_min, self.range_max
        wave = np.sin(self._beam_phase + 2 * math.pi * elapsed / self.period)
        return (lo + (hi - lo) * 0.5 * (1.0 + wave)).astype("<f4")

    def update(self, now: float) -> None:
        if math.isinf(self.rate):  # as fast as it goes: a burst of scans, then back to the scheduler
            self._burst(now)
            return
        self._scan(now)

    def _burst(self, now: float) -> None:
        """Back-to-back scans for BURST seconds (the loop invariants read once)."""
        end = _monotonic() + BURST
        left = math.inf if self.count is None else self.count - self.sent
        ranges = self.ranges(now - self._t0)
        stamp = _monotonic if self.stamp == "monotonic" else (lambda t=now - self._t0: t)
        a0, da, lo, hi = self.angle_min, self.angle_step, self.range_min, self.range_max
        publish, provides = self.server.publish, self.cfg.provides
        n = 0
        scan = None
        while n < left:
            scan = RangerData(stamp(), ranges, a0, da, lo, hi)
            for a in provides:
                publish(a, scan)
            n += 1
            if not n & 7 and _monotonic() >= end:  # the clock read every 8 scans (~10 us)
                break
        if scan is not None:
            self.last = scan
        self.sent += n
        if self.count is not None and self.sent >= self.count:
            self._finished()

    def _scan(self, now: float) -> None:
        if self.count is not None and self.sent >= self.count:
            return
        elapsed = now - self._t0
        t = _monotonic() if self.stamp == "monotonic" else elapsed
        scan = RangerData(t, self.ranges(elapsed), self.angle_min, self.angle_step, self.range_min, self.range_max)
        for a in self.cfg.provides:
            self.publish(a, scan)
        self.last = scan
        self.sent += 1
        if self.count is not None and self.sent >= self.count:
            self._finished()

    def _finished(self) -> None:
        self.rate = 0.0  # the scheduler stops calling update(); the devices stay alive
        self.log.info("%s: replay finished after %d scan(s)", self.cfg.where, self.sent)

    def publish_rate(self, addr) -> float:
        # describe's rate must be finite (Describe.from_dict rejects inf): 0 means "not periodic".
        return self.configured_rate if math.isfinite(self.configured_rate) else 0.0

    def ops(self, addr) -> list[str]:
        return ["get"]

    def on_rpc(self, addr, op, args) -> dict:
        if op == "get":
            if self.last is None:
                raise RpcError(ErrorCode.UNAVAILABLE, "no scan yet")
            return self.last.to_dict()
        return super().on_rpc(addr, op, args)

    def geometry(self, addr) -> dict[str, Any]:
        return {
            "kind": "laser",
            "pose": [0.0, 0.0, 0.0],
            "sensors": [
                {
                    "pose": [0.0, 0.0, 0.0],
                    "fov": self.fov,
                    "samples": self.samples,
                    "range_min": self.range_min,
                    "range_max": self.range_max,
                }
            ],
            "pattern": self.pattern,
            "count": self.count or 0,
        }
