"""The simulator's ``crowd`` device: all robots of a world read and commanded as arrays.

Served by the ``simulation`` driver (:mod:`mrs_bridge.drivers.sim`) as ``<simnode>:crowd:0``; the
interface and its messages are :mod:`rsal.interfaces.crowd` (docs/protocol.md, "crowd"). It is
the in-process swarm simulators' loop-function view (ARGoS) put on the fabric: a host that drives
many simulated robots reads one :class:`~rsal.interfaces.crowd.CrowdData` per step instead of two
samples per robot, and sends one :class:`~rsal.interfaces.crowd.CrowdCmd` per control cycle.

- The robots are the world's ``sim`` drivers that serve a ``position2d:0``, in the server's order,
  fixed when first asked (``describe`` or the first step someone listens).
- Each row of the data is what that robot's own driver publishes in the same step: its
  position2d pose (odometry or ground truth, as configured), velocity and stall flag, and the
  latest scan of its ``sonar:0`` (else ``ranger:0``) with that scan's time.
- Each row of a command goes through the robot's own :meth:`SimDriver._velocity`: speed limits,
  the latched emergency stop (:class:`mrs_bridge.baseguard.BaseGuard`), the command timeout's
  refresh, motor power. A refused row is skipped with a rate-limited warning; the others apply.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rsal.interfaces.crowd import CrowdCmd, CrowdData, CrowdLayout
from rsal.interfaces.position2d import VelocityCmd
from rsal.msgs import MessageError
from simulator.sensors.base import wrap

from . import simmsgs

if TYPE_CHECKING:
    from rsal.keys import DeviceAddr

    from .sim import SimDriver, SimulationDriver

__all__ = ["CrowdView"]


class CrowdView:
    """The crowd device of one ``simulation`` driver (see the module docstring)."""

    def __init__(self, driver: SimulationDriver, addr: DeviceAddr):
        self.driver = driver
        self.addr = addr
        self._robots: list[SimDriver] | None = None
        self._src: list[int | None] = []
        self._layout: CrowdLayout | None = None
        self._offsets = np.zeros(1, np.int32)
        self._gps: list[int] = []  # rows whose position2d reports ground truth

    # ------------------------------------------------------------------ the robots and their order
    def robots(self) -> list[SimDriver]:
        if self._robots is None:
            from .sim import SimDriver

            w = self.driver.world
            robots = [
                d
                for d in self.driver.server.drivers_of(SimDriver)
                if d.world is w and any(a.interface == "position2d" and a.index == 0 for a in d.cfg.provides)
            ]
            geoms: list[dict] = []
            ranger_of: list[int] = []
            offsets = [0]
            self._src = []
            for d in robots:
                rs = w.rangers(d.model)
                src = d.sonar_idx if d.sonar_idx is not None else (0 if rs else None)
                self._src.append(src)
                if src is None:
                    ranger_of.append(-1)
                    offsets.append(offsets[-1])
                    continue
                g = simmsgs.ranger_geometry(rs[src])
                if g not in geoms:
                    geoms.append(g)
                ranger_of.append(geoms.index(g))
                offsets.append(offsets[-1] + sum(s.samples for s in rs[src].sensors))
            self._robots = robots
            self._gps = [i for i, d in enumerate(robots) if d.gps]
            self._offsets = np.asarray(offsets, np.int32)
            self._layout = CrowdLayout(
                [d.model for d in robots],
                ["gps" if d.gps else "odom" for d in robots],
                geoms,
                ranger_of,
                offsets,
                [list(d.spec.max_speed[:2]) for d in robots],
            )
        return self._robots

    def geometry(self) -> dict:
        self.robots()
        assert self._layout is not None
        return self._layout.to_dict()

    # ------------------------------------------------------------------ data
    def on_step(self, w) -> None:
        """Publish this step's rows, if anyone listens (nothing is built otherwise)."""
        if not self.driver.listened(self.addr):
            return
        self.driver.publish(self.addr, self.data(w))

    def data(self, w) -> CrowdData:
        """This step's rows, read from the world's arrays (odometry, velocities, stall flags) by the
        robots' rows; ground-truth poses and scans per robot. The values (and their float
        arithmetic) are those of ``World.odometry``/``get_pose``/``velocity``/``stalled``/``ranger``."""
        robots = self.robots()
        n = len(robots)
        models = w.models
        rows = np.fromiter((m.row if (m := models.get(d.model)) is not None else -1 for d in robots), np.int64, n)
        gone = rows < 0
        r = np.where(gone, 0, rows)
        dr = w.drives
        pose = np.array(dr.odom[r], dtype=np.float64)
        pose[:, 2] = wrap(pose[:, 2])
        if self._gps:  # ground truth: the world's poses after its last step, by row (World.get_pose's values)
            g = np.asarray(self._gps, dtype=np.int64)
            g = g[~gone[g]]
            truth = np.asarray(w.poses, dtype=np.float64)[r[g]]
            pose[g, :2] = truth[:, :2]
            pose[g, 2] = wrap(truth[:, 2])
        vel = np.array(dr.vel[r], dtype=np.float64)
        stall = np.asarray(dr.stall[r], dtype=np.float32)
        pose[gone] = np.nan  # removed at run time: its row says so
        scan_t = np.full(n, -1.0)
        offs = self._offsets
        readings = w.sensors["ranger"].readings
        parts = []
        for i, d in enumerate(robots):
            src = self._src[i]
            if src is None:
                continue
            rec = readings.get(d.model) if not gone[i] else None
            rec = rec[src] if rec is not None else None
            if rec is None:
                parts.append(np.full(int(offs[i + 1] - offs[i]), np.nan, np.float32))
            else:
                parts.append(rec.ranges)
                scan_t[i] = rec.time
        ranges = np.concatenate(parts).astype(np.float32, copy=False) if parts else np.zeros(0, np.float32)
        return CrowdData(w.time, pose, vel, stall, scan_t, ranges, offs)

    # ------------------------------------------------------------------ commands
    def command(self, c: CrowdCmd) -> None:
        """Each row through its robot's own velocity path; refused rows are warned about and skipped."""
        robots = self.robots()
        n = len(robots)
        bad = (c.idx < 0) | (c.idx >= n)
        if bad.any():
            raise MessageError(
                f"crowd cmd: index {int(c.idx[bad][0])} is outside the {n} robots of {self.addr} "
                "(indices follow the order of its rpc/describe)"
            )
        for i, v, om in zip(c.idx.tolist(), c.v.tolist(), c.w.tolist(), strict=True):
            d = robots[i]
            try:
                if d.model not in d.world.models:
                    raise MessageError(f"model {d.model!r} was removed from the simulation")
                d._velocity(VelocityCmd(v, om))
            except MessageError as e:
                self.driver.warn("crowd-row", f"{self.addr} cmd: refused the row of {d.model}: {e}")
