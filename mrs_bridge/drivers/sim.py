"""Simulation drivers: bind the in-process simulator to devices (Stage's Player plugin, A.4).

- ``simulation`` provides ``simulation:0`` (default node ``sim``): it loads the world file
  (``worldfile``), steps it at ``speedup`` times real time and answers the simulation interface
  (``get_pose``, ``set_pose`` -- the thesis's ``setPositionOf`` for mixed-reality proxies --
  ``models``, ``pause``, ``step``, ``reset``, ``remove_model``). After every step it hands over to
  the ``sim`` drivers, which publish what changed. When the world's ``quit_time`` (Stage) is
  reached it logs so and stops the server cleanly.
- ``sim`` (alias ``stage``) binds one robot model (``model``) and provides its ``position2d``
  (odometry pose, or ground truth with ``localization = "gps"``), ``ranger:i`` (the model's i-th
  ranger), ``sonar`` and ``laser`` (its first sonar / laser ranger), ``blobfinder``, ``gripper``,
  ``bumper``, ``fiducial`` and ``power`` (the robot's battery in the simulator's energy model,
  :mod:`simulator.energy`: voltage, charge, charging, and the low-battery event of
  :mod:`mrs_bridge.battery` below ``low_battery`` percent); which of them a robot has comes
  from its world model (:func:`robot_devices`, from the simulator's sensor plug-ins). Its
  ``position2d`` stops the robot when velocity commands stop for ``cmd_timeout`` s and latches an
  emergency stop (:mod:`mrs_bridge.baseguard`).
  It also serves ``crowd:0`` (:mod:`mrs_bridge.drivers.simcrowd`): every robot of the world read
  and commanded as arrays, one message per step.
- ``mapfile`` (:mod:`mrs_bridge.drivers.mapfile`) serves the floorplan as a map.

The readings' and device specs' conversions to wire messages are :mod:`mrs_bridge.drivers.simmsgs`
(the simulator imports nothing of ours).

A simulator server calls every robot's ``sim`` driver after each step (1000 robots: 1000 calls
every 100 ms), so :meth:`SimDriver.on_step` stays lean: its publications are planned once
(:meth:`SimDriver._plan`), a ranger's scan is converted and encoded once for all the devices that
show it (``ranger:0`` and its alias ``sonar:0``, ``DeviceServer.publish_each``), a device nobody
subscribes to gets no message built (``Driver.listened``), a robot none of whose data devices is
listened to is passed over with one flag (``Driver.listen_group``), and the battery
state is built only when a power report is due or the low-battery latch changes
(docs/benchmarks.md, "Simulator server CPU at 1000 sonar robots"). The module is a little over
500 lines because both drivers share the one world binding and its error handling.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from rsal.keys import DeviceAddr
from rsal.msgs import (
    ErrorCode,
    GripperCmd,
    MessageError,
    Position2dData,
    RpcError,
    SimulationData,
    VelocityCmd,
    get_bool,
    get_int,
    get_str,
    get_vec,
)

from ..baseguard import ESTOP_OPS, BaseGuard
from ..battery import DEFAULT_LOW_BATTERY, LowBattery
from ..config import ConfigError
from ..driver import Deferred, Driver, OutOfRange, register
from ..params import param, parse_params
from . import simmsgs

log = logging.getLogger(__name__)

__all__ = ["SimulationDriver", "SimDriver", "robot_devices"]

WORLD_KEY = "simulator.world"
STEP_SLICE = 0.01  # s of stepping per scheduler pass for rpc/step
ODOM_LIMIT = 1e5  # m (and rad): the largest odometry value set_odom accepts


@dataclass(frozen=True)
class SimulationParams:
    """The ``simulation`` driver's parameters."""

    worldfile: Path | None = param(None, doc="the world to simulate (relative to the config file)")
    seed: int | None = param(None, doc="random seed of the world's noise")
    speedup: float | None = param(
        None, min=0.0, finite=False, expect="a number (0 or inf: as fast as possible)", doc="default: the world's"
    )


@dataclass(frozen=True)
class SimParams:
    """The ``sim`` driver's parameters."""

    model: str | None = param(None, doc="the world's model (default: the provided devices' node)")
    localization: str | None = param(None, doc='"gps": ground-truth poses; default: the world\'s')
    battery_percent: float | None = param(None, min=0.0, max=100.0, doc="% at start; default: the world's")
    low_battery: float = param(DEFAULT_LOW_BATTERY, min=0.0, max=100.0, doc="% below which power:0 reports low")
    cmd_timeout: Any = param(None, doc="s, read by the base guard (mrs_bridge.baseguard)")


@register("simulation")
class SimulationDriver(Driver):
    interfaces = ("simulation", "crowd")
    data_types = {"simulation": "SimulationData", "crowd": "CrowdData"}
    cmd_types = {"crowd": "CrowdCmd"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        from simulator import SimulatorError
        from simulator.loader import load_world
        from simulator.world import World

        p = self.settings = parse_params(SimulationParams, cfg)
        world = server.shared.get(WORLD_KEY)
        if world is None:
            path = p.worldfile
            if path is None:
                raise ConfigError(f"{cfg.where}: needs 'worldfile', the world to simulate")
            try:
                spec = load_world(path, seed=p.seed)
                world = World(spec)
            except SimulatorError as e:
                raise ConfigError(f"{cfg.where}: {e}") from None
            server.shared[WORLD_KEY] = world
        self.world = world
        from ..kernels import prepare

        prepare("simulator", label="sim")  # before any device of this server is announced
        sp = world.spec.speedup if p.speedup is None else p.speedup
        self.speedup = math.inf if sp <= 0 or math.isinf(sp) else sp
        self.rate = self.speedup / world.spec.interval_sim
        self._last_pub = -math.inf
        self._wall0 = time.monotonic()
        self._sim0 = world.time
        self._quit = False
        from .simcrowd import CrowdView

        self.crowds = [CrowdView(self, a) for a in cfg.provides if a.interface == "crowd"]
        self._sim_addrs = [a for a in cfg.provides if a.interface == "simulation"]

    def setup(self) -> None:
        # The sim drivers of this world cannot work without it: they fail when this driver fails.
        for d in self.server.hosted(SimDriver):
            if d.world is self.world and self not in d.depends_on:
                d.depends_on.append(self)

    def publish_rate(self, addr) -> float:
        return 10.0

    def update(self, now: float) -> None:
        w = self.world
        self._check_timeouts()
        q = w.spec.quit_time
        if q > 0 and w.time >= q - 1e-9:  # Stage: a run stops once sim time reaches quit_time > 0
            if not self._quit:
                self._quit = True
                log.warning("simulation: quit_time %g s reached at t=%.1f s; stopping the server", q, w.time)
                self.server.stop()
            return
        if w.advance():
            for d in self.server.drivers_of(SimDriver):
                self.server.call_driver(d, d.on_step, w)
            for c in self.crowds:
                c.on_step(w)
        if now - self._last_pub >= 0.1:
            self._last_pub = now
            wall = now - self._wall0
            rtf = (w.time - self._sim0) / wall if wall > 0 else 0.0
            for a in self._sim_addrs:
                self.publish(a, SimulationData(w.time, w.steps, w.paused, rtf))

    def _check_timeouts(self) -> None:
        """The robots' command timeouts, before the next step moves anyone (cheap: a clock read per robot)."""
        for d in self.server.drivers_of(SimDriver):
            d.check_timeout()

    def on_cmd(self, addr, msg):
        """A crowd ``cmd`` (:class:`~rsal.interfaces.crowd.CrowdCmd`, decoded by the server)."""
        crowd = next((c for c in self.crowds if c.addr == addr), None)
        if crowd is None:
            raise MessageError(f"{addr} takes no commands")
        crowd.command(msg)

    def ops(self, addr):
        if addr.interface == "crowd":
            return []
        return [
            "get_pose",
            "get_poses",
            "set_pose",
            "models",
            "contacts",
            "batteries",
            "pause",
            "step",
            "reset",
            "remove_model",
        ]

    def geometry(self, addr):
        crowd = next((c for c in self.crowds if c.addr == addr), None)
        if crowd is not None:
            return crowd.geometry()
        return {
            "interval_sim": self.world.spec.interval_sim,
            "speedup": self.speedup if math.isfinite(self.speedup) else 0,
            "chargers": [simmsgs.charger_geometry(c) for c in self.world.spec.chargers],
        }

    def on_rpc(self, addr, op, args):
        from simulator import ModelError, OutOfWorld

        if addr.interface == "crowd":
            return super().on_rpc(addr, op, args)
        w = self.world
        try:
            if op == "get_pose":
                return {"name": get_str(args, "name"), "pose": list(w.get_pose(get_str(args, "name")))}
            if op == "get_poses":  # many true poses at one simulated instant (a crowd's ground truth)
                names = args.get("names")
                if names is None:
                    names = list(w.robot_names)
                if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                    raise RpcError(ErrorCode.BAD_REQUEST, "get_poses: 'names' must be a list of model names")
                return {"t": w.time, "names": names, "poses": [list(w.get_pose(n)) for n in names]}
            if op == "set_pose":
                name = get_str(args, "name")
                x, y, a = get_vec(args, "pose", 3)
                w.set_pose(name, x, y, a)
                return {"name": name, "pose": [x, y, a]}
            if op == "models":
                return {"robots": w.robot_names, "objects": [n for n in w.model_names if n not in w.robot_names]}
            if op == "contacts":
                return w.contacts()
            if op == "batteries":  # every robot's true battery and its record (the energy verdicts)
                return {"t": w.time, "robots": {n: simmsgs.battery_truth(w.battery(n)) for n in w.robot_names}}
            if op == "pause":
                w.pause(get_bool(args, "paused", True))
                return {"paused": w.paused}
            if op == "step":
                return self._step(get_int(args, "n", 1, lo=1, hi=10000))
            if op == "reset":
                w.reset()
                for d in self.server.hosted(SimDriver):  # removed robots come back with the reset
                    if d.world is w and d.model in w.model_names:
                        self.server.reinstate(d)
                return {"t": w.time}
            if op == "remove_model":
                name = get_str(args, "name")
                w.remove_model(name)
                for d in self.server.hosted(SimDriver):  # its devices go with it
                    if d.world is w and d.model == name:
                        self.server.withdraw(d, f"model {name!r} was removed from the simulation")
                return {}
        except OutOfWorld as e:
            raise OutOfRange(str(e)) from None
        except ModelError as e:
            raise RpcError(ErrorCode.NOT_FOUND, str(e)) from None
        return super().on_rpc(addr, op, args)

    def _step(self, n: int) -> Deferred:
        """``n`` steps in slices of at most STEP_SLICE seconds, between the server's other work."""
        left = [n]

        def work():
            w = self.world
            t_end = time.perf_counter() + STEP_SLICE
            self._check_timeouts()  # commands that stopped arriving stop their robots, slice by slice
            while left[0] > 0:
                w.step()
                left[0] -= 1
                for d in self.server.drivers_of(SimDriver):
                    self.server.call_driver(d, d.on_step, w)
                for c in self.crowds:
                    c.on_step(w)
                if time.perf_counter() >= t_end:
                    break
            return None if left[0] else {"t": w.time, "steps": w.steps}

        return Deferred(work)


def robot_devices(spec) -> list[tuple[str, int]]:
    """The devices ``(interface, index)`` a ``sim`` driver serves for a robot of model ``spec``
    (a :class:`simulator.spec.ModelSpec`): its ``position2d:0``, what its sensors serve (each
    sensor plug-in declares its devices) and its simulated battery ``power:0``."""
    from simulator.sensors import player_devices

    return [("position2d", 0), *player_devices(spec), ("power", 0)]


#: Interfaces whose data :meth:`SimDriver.on_step` builds only while someone listens; the others
#: (gripper, fiducial, power) carry events or latches and run every step.
_HEARD_ONLY = frozenset({"position2d", "ranger", "blobfinder", "bumper"})


@register("sim", "stage")
class SimDriver(Driver):
    interfaces = ("position2d", "ranger", "sonar", "laser", "blobfinder", "gripper", "bumper", "fiducial", "power")
    default_rate = 0.0  # publishes after each simulation step
    data_types = {
        "position2d": "Position2dData",
        "ranger": "RangerData",
        "sonar": "RangerData",
        "laser": "RangerData",
        "blobfinder": "BlobfinderData",
        "gripper": "GripperData",
        "bumper": "BumperData",
        "fiducial": "FiducialData",
        "power": "PowerData",
    }
    cmd_types = {"position2d": "VelocityCmd", "gripper": "GripperCmd"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        from simulator import ModelError

        world = server.shared.get(WORLD_KEY)
        if world is None:
            raise ConfigError(f"{cfg.where}: a 'simulation' driver block must come before the sim drivers")
        self.world = world
        p = self.settings = parse_params(SimParams, cfg)
        self.model = p.model or cfg.provides[0].node
        try:
            self.spec = world.model_spec(self.model)
        except ModelError as e:
            raise ConfigError(f"{cfg.where}: {e}") from None
        if not self.spec.position:
            raise ConfigError(f"{cfg.where}: model {self.model!r} is not a robot")
        # The config's localization, else the world's (Stage's position ``localization`` keyword).
        self.gps = str(p.localization or self.spec.localization).lower() == "gps"
        rangers = world.rangers(self.model)
        self.sonar_idx = next((i for i, r in enumerate(rangers) if r.kind == "sonar"), None)
        self.laser_idx = next((i for i, r in enumerate(rangers) if r.kind != "sonar"), None)
        self._src: dict[DeviceAddr, int] = {}
        for a in cfg.provides:
            i = a.index
            if a.interface == "ranger":
                if i >= len(rangers):
                    raise ConfigError(
                        f"{cfg.where}: model {self.model!r} has {len(rangers)} ranger(s); ranger:{i} does not exist"
                    )
                self._src[a] = i
            elif a.interface in ("sonar", "laser"):
                idx = self.sonar_idx if a.interface == "sonar" else self.laser_idx
                if idx is None or i != 0:
                    raise ConfigError(f"{cfg.where}: model {self.model!r} has no {a.interface}:{i}")
                self._src[a] = idx
            elif a.interface == "blobfinder" and i >= len(self.spec.blobfinders):
                raise ConfigError(f"{cfg.where}: model {self.model!r} has no blobfinder:{i}")
            elif a.interface == "gripper" and i >= len(self.spec.grippers):
                raise ConfigError(f"{cfg.where}: model {self.model!r} has no gripper:{i}")
            elif a.interface in ("bumper", "fiducial") and (a.interface, i) not in robot_devices(self.spec):
                raise ConfigError(f"{cfg.where}: model {self.model!r} has no {a.interface}:{i}; add one in the world")
        self._last_scan: dict[int, float] = {}  # ranger index -> sim time of the scan last sent
        self._publish_plan: list[tuple[str, Any]] | None = None  # built on the first step (_plan)
        self._always_plan: list[tuple[str, Any]] = []  # what is sent even unheard (events ride on it)
        self._heard = None  # ListenGroup of the devices only sent while someone listens (_plan)
        self._last_grip: dict[DeviceAddr, tuple] = {}
        self._last_contact: dict[DeviceAddr, float] = {}  # sim time of the bumper/fiducial data last sent
        if p.battery_percent is not None:
            world.set_battery(self.model, p.battery_percent / 100.0)
        self.low = LowBattery(p.low_battery)
        self._last_power = -math.inf
        self.motors = True
        self.guard = BaseGuard.for_driver(self, self.cfg.provides[0].node)
        self.guard.clock = lambda: self.world.time  # the timeout counts simulated seconds (one clock)

    def check_timeout(self) -> None:
        """Stop the robot if its velocity command was not refreshed within ``cmd_timeout``."""
        if self.guard.expired() and self.model in self.world.model_names:
            self.world.halt(self.model)

    def publish_rate(self, addr) -> float:
        if addr.interface == "power":
            return 1.0
        if addr.interface in ("ranger", "sonar", "laser"):
            return 1.0 / self.world.rangers(self.model)[self._src[addr]].interval
        if addr.interface in ("bumper", "fiducial"):  # spec lists "bumpers", "fiducials"
            return 1.0 / getattr(self.spec, addr.interface + "s")[addr.index].interval
        return 1.0 / self.world.spec.interval_sim

    # ------------------------------------------------------------------ publishing
    def _plan(self) -> list[tuple[str, Any]]:
        """What :meth:`on_step` publishes, in the order of ``provides``: each device once, except
        that the devices showing one ranger (``ranger:0`` and its alias ``sonar:0``) form one entry
        ``("ranger", (index, [addrs]))``, whose scan is converted and encoded once for all of them."""
        plan: list[tuple[str, Any]] = []
        groups: dict[int, list[DeviceAddr]] = {}
        for a in self.cfg.provides:
            if a.interface in ("ranger", "sonar", "laser"):
                src = self._src[a]
                if src not in groups:
                    groups[src] = []
                    plan.append(("ranger", (src, groups[src])))
                groups[src].append(a)
            else:
                plan.append((a.interface, a))
        return plan

    def on_step(self, w) -> None:
        if self.model not in w.models:  # removed at run time (a dict: no list built per robot and step)
            return
        if self.guard.estop or not self.motors:  # also over the world's own ctrl controllers (Stage wander)
            w.halt(self.model)
        t = w.time
        plan = self._publish_plan
        if plan is None:
            full = self._plan()
            plan = self._publish_plan = [e for e in full if e[0] in _HEARD_ONLY]
            self._always_plan = [e for e in full if e[0] not in _HEARD_ONLY]
            self._heard = self.listen_group([a for i, e in plan for a in (e[1] if i == "ranger" else [e])])
        if self._heard.any:  # one flag for the robot: a crowd nobody reads robot by robot costs nothing here
            self._publish_heard(w, t, plan)
        for iface, a in self._always_plan:
            if iface == "gripper":
                self._publish_gripper(w, a, t)
            elif iface == "fiducial":
                self._publish_fiducial(w, a)
            elif iface == "power":
                self._publish_power(w, a, t)

    def _publish_heard(self, w, t: float, plan) -> None:
        """The devices whose data is only built while someone listens, each asked on its own."""
        heard = self.server.listened
        for iface, a in plan:
            if iface == "position2d":
                if not heard(a):  # nobody subscribes: no message built (a crowd reader may read all robots)
                    continue
                pose = w.get_pose(self.model) if self.gps else w.odometry(self.model)
                v, om = w.velocity(self.model)
                g = self.guard
                self.publish(a, Position2dData(t, pose, (v, 0.0, om), w.stalled(self.model), g.timed_out, g.estop))
            elif iface == "ranger":
                src, addrs = a
                if not any(heard(x) for x in addrs):
                    continue
                r = w.ranger(self.model, src)
                if r is None or self._last_scan.get(src) == r.time:
                    continue
                self._last_scan[src] = r.time
                self.publish_each(addrs, simmsgs.ranger_data(r))
            elif iface == "blobfinder":
                if not heard(a):
                    continue
                blobs = w.blobfinder(self.model, a.index)
                self.publish(a, simmsgs.blobfinder_data(t, self.spec.blobfinders[a.index], blobs))
            elif iface == "bumper":
                if not heard(a):
                    continue
                b = w.bumper(self.model, a.index)
                if b is None or self._last_contact.get(a) == b.time:
                    continue
                self._last_contact[a] = b.time
                self.publish(a, simmsgs.bumper_data(b))

    def _publish_gripper(self, w, a: DeviceAddr, t: float) -> None:
        """The gripper's state every step, and an event when it changes (heard or not)."""
        st = w.gripper(self.model, a.index)
        self.publish(a, simmsgs.gripper_data(t, st))
        prev = self._last_grip.get(a)
        now_state = (st.paddles, st.lift, st.carrying)
        if prev is not None and prev != now_state:
            self.event(a, {"t": t, "event": "state", "paddles": st.paddles, "lift": st.lift, "carrying": st.carrying})
        self._last_grip[a] = now_state

    def _publish_power(self, w, a: DeviceAddr, t: float) -> None:
        """The battery once per simulated second (and at once when it turns low or recovers)."""
        due = t - self._last_power >= 1.0
        pct = 100.0 * w.battery_fraction(self.model)  # every step, cheaply: the low-battery latch
        if not due and not self.low.changes(pct):
            return  # neither due nor an event: no message built
        b = w.battery(self.model)
        msg = simmsgs.power_data(t, pct, b.charging, self.low.low)
        ev = self.low.update(t, pct, msg.volts)
        if ev is not None or due:
            self._last_power = t
            self.publish(a, replace(msg, low=self.low.low))
        if ev is not None:
            self.event(a, ev)

    def _publish_fiducial(self, w, a: DeviceAddr) -> None:
        """The finder's detections when it updated this step (:func:`simmsgs.fiducial_data`)."""
        t = w.sensors["fiducial"].updated(self.model, a.index)
        if t < 0 or self._last_contact.get(a) == t:
            return
        self._last_contact[a] = t
        self.publish(a, simmsgs.fiducial_data(t, w.fiducial(self.model, a.index)))

    # ------------------------------------------------------------------ commands
    def on_cmd(self, addr, msg: VelocityCmd | GripperCmd):
        """``msg`` arrives typed (``cmd_types``), decoded and validated by the server."""
        if addr.interface == "position2d":
            self._velocity(msg)
        elif addr.interface == "gripper":
            self.world.gripper_command(self.model, msg.action, addr.index)
        else:
            raise MessageError(f"{addr} takes no commands")

    def _velocity(self, c: VelocityCmd, *, rpc: bool = False) -> None:
        vmax, wmax = self.spec.max_speed
        if abs(c.v) > vmax + 1e-9 or abs(c.w) > wmax + 1e-9:
            raise OutOfRange(f"v={c.v:g} m/s, w={c.w:g} rad/s exceeds the limits |v| <= {vmax:g}, |w| <= {wmax:.3g}")
        if c.vy != 0.0:
            raise OutOfRange(f"vy={c.vy:g}: a differential drive cannot move sideways")
        self.guard.check(rpc=rpc)
        if self.motors:
            self.guard.command(c.v, c.w)
            self.world.set_velocity(self.model, c.v, c.w)

    def ops(self, addr):
        if addr.interface == "position2d":
            return ["set_odom", "motor_power", "stop", *ESTOP_OPS]
        if addr.interface == "gripper":
            return ["open", "close", "up", "down", "stop"]
        if addr.interface in ("ranger", "sonar", "laser"):
            return ["get"]
        return []

    def on_rpc(self, addr, op, args):
        w = self.world
        if self.model not in w.model_names:  # removed with simulation rpc/remove_model
            raise RpcError(ErrorCode.UNAVAILABLE, f"model {self.model!r} was removed from the simulation")
        if addr.interface == "position2d":
            if op == "set_odom":
                x, y, a = get_vec(args, "pose", 3)
                if max(abs(x), abs(y), abs(a)) > ODOM_LIMIT:
                    raise OutOfRange(f"set_odom pose ({x:g}, {y:g}, {a:g}): each value must be within +-{ODOM_LIMIT:g}")
                w.set_odometry(self.model, x, y, a)
                return {"pose": [x, y, a]}
            if op == "motor_power":
                self.motors = get_bool(args, "on")
                if not self.motors:
                    w.set_velocity(self.model, 0.0, 0.0)
                    self.guard.stopped()
                return {"on": self.motors}
            if op == "stop":
                w.set_velocity(self.model, 0.0, 0.0)
                self.guard.stopped()
                return {}
            if op == "set_velocity":
                self._velocity(VelocityCmd.from_dict(args), rpc=True)
                return {}
            if op == "estop":
                self.guard.press()
                w.halt(self.model)
                return {"estop": True}
            if op == "release":
                self.guard.release()
                return {"estop": False}
        if addr.interface == "gripper":
            w.gripper_command(self.model, op, addr.index)
            st = w.gripper(self.model, addr.index)
            return {"paddles": st.paddles, "lift": st.lift}
        if op == "get" and addr.interface in ("ranger", "sonar", "laser"):
            r = w.ranger(self.model, self._src[addr])
            if r is None:
                raise RpcError(ErrorCode.UNAVAILABLE, "no scan yet")
            return simmsgs.ranger_data(r).to_dict()
        return super().on_rpc(addr, op, args)

    def geometry(self, addr) -> dict[str, Any]:
        s = self.spec
        if addr.interface == "position2d":
            return {
                "size": list(s.size[:2]),
                "max_speed": list(s.max_speed),
                "max_accel": list(s.max_accel),
                "frame": "gps" if self.gps else "odom",
                "model": self.model,
            }
        if addr.interface in ("ranger", "sonar", "laser"):
            return simmsgs.ranger_geometry(self.world.rangers(self.model)[self._src[addr]])
        if addr.interface == "blobfinder":
            return simmsgs.blobfinder_geometry(s.blobfinders[addr.index])
        if addr.interface == "gripper":
            return simmsgs.gripper_geometry(s.grippers[addr.index])
        if addr.interface == "bumper":
            return simmsgs.bumper_geometry(s.bumpers[addr.index])
        if addr.interface == "fiducial":
            return simmsgs.fiducial_geometry(s.fiducials[addr.index])
        if addr.interface == "power":
            b = s.battery
            return {
                "battery": b is not None,  # false: no battery model, the robot never runs flat
                "capacity": b.capacity if b is not None else 0.0,  # J
                "low_battery": self.low.threshold,  # %
            }
        return {}

    def shutdown(self) -> None:
        if self.model in self.world.model_names:
            self.world.set_velocity(self.model, 0.0, 0.0)
