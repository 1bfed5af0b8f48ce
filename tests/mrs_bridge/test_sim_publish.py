"""The ``sim`` driver's cheaper publishing path publishes exactly what the per-device path did.

The driver encodes a ranger's scan once for all the devices that show it (``ranger:0`` and its
alias ``sonar:0`` or ``laser:0``, :meth:`DeviceServer.publish_each`) and reads only the battery's
charge between power reports. Here a reference -- the per-device loop as it was: every provided
device in turn, its own message, a battery state and a low-battery check every step -- runs beside
the driver on the same world, step by step, and both must give the same keys with the same bytes
(in one step, the scan's devices now follow each other: the order across keys is no contract),
and the same low-battery events; and the server's ``publish_each`` must put the bytes ``publish``
puts on each device.
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import mrs_bridge.drivers  # noqa: F401  (registers the built-in drivers)
from mrs_bridge.battery import LowBattery
from mrs_bridge.cli import sim_config
from mrs_bridge.drivers import simmsgs
from mrs_bridge.drivers.sim import SimDriver
from mrs_bridge.server.devices import _Devices
from rsal.interfaces.position2d import Position2dData
from rsal.keys import DeviceAddr
from rsal.msgs import encode
from rsal.testing import FakeServer
from simulator.presets import pioneer2dx, urg04lx
from simulator.spec import BatterySpec, WorldSpec
from simulator.world import World


def _world() -> World:
    """Two Pioneers with their sonar ring, one also with a laser, on small batteries that cross
    the 20 % low-battery threshold after about a second."""
    batt = BatterySpec(capacity=100.0, charge=0.22, watts=2.0)
    r0 = replace(pioneer2dx("r0", (0.0, 0.0, 0.0)), battery=batt)
    r1 = replace(pioneer2dx("r1", (2.0, 1.0, 1.0)), battery=batt)
    r1.rangers = [*r1.rangers, urg04lx()]
    return World(WorldSpec(models=[r0, r1], interval_sim=0.1), seed=3)


class _Reference:
    """The per-device publishing loop as it was before the shared-scan path (the oracle)."""

    def __init__(self, drv: SimDriver):
        self.d = drv
        self.last_scan: dict[DeviceAddr, float] = {}
        self.low = LowBattery(drv.low.threshold)
        self.last_power = -math.inf

    def step(self, w) -> tuple[list[tuple[str, bytes]], list[dict]]:
        d, out, events = self.d, [], []
        t = w.time
        v, om = w.velocity(d.model)
        for a in d.cfg.provides:
            if a.interface == "position2d":
                pose = w.get_pose(d.model) if d.gps else w.odometry(d.model)
                g = d.guard
                out.append(
                    (str(a), encode(Position2dData(t, pose, (v, 0.0, om), w.stalled(d.model), g.timed_out, g.estop)))
                )
            elif a.interface in ("ranger", "sonar", "laser"):
                r = w.ranger(d.model, d._src[a])
                if r is None or self.last_scan.get(a) == r.time:
                    continue
                self.last_scan[a] = r.time
                out.append((str(a), encode(simmsgs.ranger_data(r))))
            elif a.interface == "power":
                b = w.battery(d.model)
                pct = 100.0 * b.fraction
                msg = simmsgs.power_data(t, pct, b.charging, self.low.low)
                ev = self.low.update(t, pct, msg.volts)
                if ev is not None or t - self.last_power >= 1.0:
                    self.last_power = t
                    out.append((str(a), encode(replace(msg, low=self.low.low))))
                if ev is not None:
                    events.append(ev)
        return out, events


def test_the_sim_driver_publishes_what_the_per_device_loop_did():
    w = _world()
    w.set_velocity("r0", 0.3, 0.2)
    w.set_velocity("r1", 0.2, -0.4)
    cfg = sim_config(w, map_device=False)
    pairs = []
    for dc in cfg.drivers[1:]:
        srv = FakeServer(shared={"simulator.world": w})
        drv = SimDriver(dc, srv)
        pairs.append((drv, srv, _Reference(drv)))
    assert {str(a) for a in cfg.drivers[2].provides} >= {"r1:ranger:0", "r1:sonar:0", "r1:ranger:1", "r1:laser:0"}
    seen = set()
    events = 0
    for _ in range(40):
        w.step()
        for drv, srv, ref in pairs:
            srv.published.clear()
            srv.events.clear()
            drv.on_step(w)
            got = [(a, encode(m)) for a, m in srv.published]
            want, want_events = ref.step(w)
            # one put per key and step: the order across keys is no contract (Zenoh orders per key)
            assert sorted(got) == sorted(want) and len({a for a, _ in got}) == len(got), f"t={w.time:.1f} {drv.model}"
            assert srv.events == want_events
            seen.update(a for a, _ in got)
            events += len(want_events)
    assert {"r0:sonar:0", "r0:ranger:0", "r1:laser:0", "r1:ranger:1", "r0:power:0", "r1:position2d:0"} <= seen
    assert events == 2  # each battery turned low once, reported at once by both paths


def test_publish_each_puts_the_bytes_publish_puts_on_every_device():
    puts: dict[str, list[bytes]] = {}
    addrs = [DeviceAddr("r0", "ranger", 0), DeviceAddr("r0", "sonar", 0), DeviceAddr("r0", "laser", 0)]
    devices = {
        a: SimpleNamespace(pub=SimpleNamespace(put=puts.setdefault(str(a), []).append), listened=True)
        for a in addrs[:2]
    }
    srv = SimpleNamespace(devices=devices, _pub_cache={}, stats={"published": 0})
    w = _world()
    w.step()
    msg = simmsgs.ranger_data(w.ranger("r0", 0))
    for a in addrs:
        _Devices.publish(srv, a, msg)  # laser:0 is not declared: nothing is put
    _Devices.publish_each(srv, addrs, msg)
    assert puts == {"r0:ranger:0": [encode(msg)] * 2, "r0:sonar:0": [encode(msg)] * 2}
    assert srv.stats["published"] == 4


def test_low_battery_changes_tells_what_update_would_do():
    for low0 in (False, True):
        for pct in (0.0, 10.0, 19.99, 20.0, 22.0, 24.99, 25.0, 60.0, 100.0):
            lb = LowBattery(20.0)
            lb.low = low0
            predicted = lb.changes(pct)
            assert predicted == (lb.update(0.0, pct, 12.0) is not None), (low0, pct)
