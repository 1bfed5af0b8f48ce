"""``p2os`` driver: Pioneer 2/3 robots over a serial line (Player's p2os driver, thesis 3.3.2, A.2).

The robot's microcontroller (P2OS, later ARCOS) speaks a packet protocol on its serial port; its
codec (framing, checksum, commands, SIP parsing, robot models, odometry) is :mod:`mrs_bridge.hw.p2os`
(the names are re-exported here), the port's thread :class:`mrs_bridge.hw.serial_link.SerialLink`.
This module is the glue: the session on the link, and the devices on the server.

Connecting: SYNC0, SYNC1, SYNC2 are each echoed by the robot; the SYNC2 echo carries the robot's
name, class and subclass as NUL-terminated strings. Then OPEN, SONAR 1, ENABLE 1, and PULSE at
least every ``pulse`` seconds (the robot stops its motors when it hears nothing for about 2 s).

Threads: the serial link's thread owns the port: it connects (the sync handshake of
:meth:`P2osDriver._session`, with retries), writes the commands the scheduler queued, sends the
keep-alive pulse, reads and parses packets and hands them over through its inbox, drained in
``update()``. The scheduler thread never touches the port. When no SIP arrives for ``timeout``
seconds the robot counts as lost: its devices' tokens are withdrawn and the link reconnects with a
growing back-off; tokens return with the first SIP. Bytes that are no packet (noise, bad checksums,
truncated packets) are skipped by re-synchronising on 0xFA 0xFB, counted (``stats``) and reported at
most every 5 s.

Provides ``position2d`` (odometry, VelocityCmd), ``sonar`` or ``ranger`` (the sonar ring),
``power``, ``gripper`` (GripperCmd), ``dio`` (digital in/out, DioCmd) and ``actarray`` (the gripper
lift as a one-joint array, Player's ``lift::actarray:0``).

The module is over 500 lines because one Pioneer serves seven interfaces: their publication,
commands and rpcs are the bulk, each short; the protocol itself is in :mod:`mrs_bridge.hw.p2os`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from rsal.interfaces.power import lead_acid_fraction
from rsal.msgs import (
    ActArrayData,
    DioCmd,
    DioData,
    ErrorCode,
    GripperCmd,
    GripperData,
    MessageError,
    Position2dData,
    PowerData,
    RangerData,
    RpcError,
    VelocityCmd,
    get_bool,
    get_float,
    get_int,
    get_vec,
)

from ..baseguard import ESTOP_OPS, BaseGuard
from ..battery import DEFAULT_LOW_BATTERY, LowBattery
from ..config import ConfigError
from ..driver import Driver, OutOfRange, register
from ..hw.p2os import (
    CLOSE,
    DIGOUT,
    ENABLE,
    GRIP_CLOSE,
    GRIP_OPEN,
    GRIP_STOP,
    GRIPPER,
    GRIPPER_ARGS,
    LIFT_DOWN,
    LIFT_STOP,
    LIFT_UP,
    MODELS,
    OPEN,
    PULSE,
    RVEL,
    SONAR,
    SYNC0,
    SYNC1,
    SYNC2,
    VEL,
    Odometry,
    PacketReader,
    RobotModel,
    Sip,
    checksum,
    command,
    decode_sip,
    gripper_state,
    is_sip,
    model_for,
    packet,
)
from ..hw.serial_link import SerialLink
from ..params import param, parse_params

__all__ = [
    "P2osDriver",
    "RobotModel",
    "MODELS",
    "Sip",
    "PacketReader",
    "checksum",
    "packet",
    "command",
    "decode_sip",
    "Odometry",
    # command numbers and arguments, re-exported from mrs_bridge.hw.p2os with the codec
    "GRIP_CLOSE",
    "GRIP_OPEN",
    "GRIP_STOP",
    "LIFT_DOWN",
    "LIFT_STOP",
    "LIFT_UP",
]


# ---------------------------------------------------------------------------- the driver
@dataclass(frozen=True)
class P2osParams:
    """The ``p2os`` driver's parameters (module docstring)."""

    port: str = param(doc="the robot's serial device", example="/dev/ttyS0")
    baud: Literal[9600, 19200, 38400, 57600, 115200] = param(9600)
    model: str | None = param(None, choices=tuple(MODELS))
    pulse: float = param(0.5, min=0.05, max=1.5, unit="seconds")
    reconnect: float = param(1.0, min=0.05, max=60.0, unit="seconds")
    timeout: float = param(1.0, min=0.2, max=30.0, unit="seconds")
    sonars: Literal[8, 16] | None = param(None, expect="8 or 16 (transducers fitted)")
    cmd_timeout: Any = param(None, doc="s, read by the base guard (mrs_bridge.baseguard)")
    low_battery: float = param(DEFAULT_LOW_BATTERY, min=0.0, max=100.0, doc="% below which power:0 reports low")


WARN_INTERVAL = 5.0


@register("p2os")
class P2osDriver(Driver):
    interfaces = ("position2d", "sonar", "ranger", "power", "gripper", "dio", "actarray")
    default_rate = 20.0  # Hz: how often the SIPs received are drained and published
    data_types = {
        "position2d": "Position2dData",
        "sonar": "RangerData",
        "ranger": "RangerData",
        "power": "PowerData",
        "gripper": "GripperData",
        "dio": "DioData",
        "actarray": "ActArrayData",
    }
    cmd_types = {"position2d": "VelocityCmd", "gripper": "GripperCmd", "dio": "DioCmd"}

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        p = self.settings = parse_params(P2osParams, cfg)
        try:
            import serial  # noqa: F401
        except ImportError:
            raise ConfigError(
                f"{cfg.where}: the p2os driver needs pyserial; install it with: pip install pyserial"
            ) from None
        self.port, self.baud = p.port, p.baud
        self.pulse, self.reconnect, self.timeout = p.pulse, p.reconnect, p.timeout
        self.forced_model = MODELS[p.model] if p.model is not None else None
        self.sonar_override = p.sonars
        self.low = LowBattery(p.low_battery)
        for a in cfg.provides:
            if a.index != 0:
                raise ConfigError(
                    f"{cfg.where}: a Pioneer has one {a.interface}; provide {a.interface}:0, not :{a.index}"
                )
        self.online = False  # tokens come with the robot's first SIP
        self.model: RobotModel | None = self.forced_model
        self.odom: Odometry | None = None
        self.ident: tuple[str, str, str] | None = None
        self.link: SerialLink | None = None
        self.reader = PacketReader()  # the link thread's; its counters survive reconnections
        self.sync_retries = 3
        self.sync_wait = 0.5  # s to wait for each echo
        self.last_sip: Sip | None = None
        self.sonar_ranges: np.ndarray | None = None
        self._sonar_fresh = False  # readings arrived since the last sonar publication
        self.stats = {"sips": 0, "skipped_bytes": 0, "bad_packets": 0, "bad_sips": 0, "reconnects": 0}
        self._reported = (0, 0)
        self._last_warn = -math.inf
        self._motors = True
        self._last_grip_cmd = ""
        self._last_lift = 0.0  # the lift's last known or commanded position (0 down, 1 up)
        self._lost_reason = ""
        self._t0 = time.monotonic()
        self.guard = BaseGuard.for_driver(self, cfg.provides[0].node)

    # ------------------------------------------------------------------ lifecycle
    def setup(self) -> None:
        self.online = False
        self.link = SerialLink(
            self.port,
            self.baud,
            self._session,
            name=f"p2os {self.port}",
            reconnect=self.reconnect,
            max_backoff=8 * self.reconnect,
            read_timeout=0.02,
            write_timeout=0.5,
        )
        self.link.start()
        self.log.info("%s: connecting to the robot on %s at %d baud", self.cfg.where, self.port, self.baud)

    def shutdown(self) -> None:
        link = self.link
        if link is None:
            return
        link.stop([command(VEL, 0), command(RVEL, 0), command(ENABLE, 0), command(CLOSE)])
        self.link = None

    def update(self, now: float) -> None:
        link = self.link
        if link is None:
            return
        newest: Sip | None = None
        stamp = 0.0
        while link.inbox:
            item = link.inbox.popleft()
            kind = item[0]
            if kind == "sip":
                sip = self._on_sip(item[2])
                if sip is not None:
                    newest, stamp = sip, item[1]
            elif kind == "connected":
                self._on_connected(item[1], item[2], item[3])
            elif kind == "lost":
                self._on_lost(item[1])
        if self.guard.expired():  # the commander went silent: ARCOS would drive on while we pulse
            try:
                self._velocity(0.0, 0.0)
            except RpcError:
                pass  # not answering: ARCOS stops by itself without our pulse
        if newest is not None:
            self._publish(newest, stamp - self._t0)
        self._report_noise(now)

    def _on_connected(self, name: str, cls: str, sub: str) -> None:
        model = self.forced_model or model_for(sub)
        if model is None:
            raise ConfigError(
                f"{self.cfg.where}: the robot on {self.port} calls itself {cls!r} {sub!r}, a model this driver does "
                f"not know; set model = one of {', '.join(MODELS)}"
            )
        if self.model is not model or self.odom is None:
            self.model = model
            self.odom = Odometry(model)
            n = self.sonar_override or model.sonars
            self.sonar_ranges = np.full(n, model.sonar_range[1], dtype="<f4")
        self.odom.reset_reference()
        if self.ident is not None:
            self.stats["reconnects"] += 1
        self.ident = (name, cls, sub)
        self._motors = True
        self.log.info("%s: connected to %s (%s %s) on %s", self.cfg.where, name or "?", cls, sub, self.port)

    def _on_lost(self, why: str) -> None:
        if self.online:
            self.log.warning("%s: robot lost (%s); devices withdrawn, reconnecting", self.cfg.where, why)
            self.set_online(False)
        elif why != self._lost_reason:
            self.log.warning("%s: %s; retrying every %g s or more", self.cfg.where, why, self.reconnect)
        self._lost_reason = why

    def _on_sip(self, payload: bytes) -> Sip | None:
        if self.odom is None:
            return None
        try:
            sip = decode_sip(payload)
        except ValueError:
            self.stats["bad_sips"] += 1
            return None
        self.stats["sips"] += 1
        self.odom.update(sip)
        rng = self.sonar_ranges
        if sip.sonars and rng is not None:
            idx = np.array([s[0] for s in sip.sonars])
            val = np.array([s[1] for s in sip.sonars], dtype=np.float64) * (self.model.range_conv / 1000.0)
            ok = idx < len(rng)
            rng[idx[ok]] = np.clip(val[ok], 0.0, self.model.sonar_range[1])
            self._sonar_fresh = True
        self.last_sip = sip
        if not self.online:
            self.set_online(True)
            self._lost_reason = ""
            self.log.info("%s: robot answering; devices online", self.cfg.where)
        return sip

    def _report_noise(self, now: float) -> None:
        if self.link is None:
            return
        r = self.reader
        self.stats["skipped_bytes"] = r.skipped
        self.stats["bad_packets"] = r.bad
        cur = (self.stats["skipped_bytes"], self.stats["bad_packets"])
        if cur != self._reported and now - self._last_warn >= WARN_INTERVAL:
            self.log.warning(
                "%s: skipped %d byte(s) of line noise and %d bad packet(s) from %s (check cable and baud rate)",
                self.cfg.where,
                cur[0] - self._reported[0],
                cur[1] - self._reported[1],
                self.port,
            )
            self._reported = cur
            self._last_warn = now

    # ------------------------------------------------------------------ the session (on the link's thread)
    def _session(self, link: SerialLink) -> str:
        """Connect and serve until the robot is lost; return why. Runs on the link's thread and
        touches only the link and the packet reader."""
        self.reader.buf.clear()  # counters survive reconnections
        ident = self._sync(link)
        if ident is None:
            return f"no answer to the sync handshake on {self.port} at {self.baud} baud"
        link.up("connected", *ident)
        for c in (command(OPEN), command(SONAR, 1), command(ENABLE, 1), command(PULSE)):
            link.write(c)
        last_sip = time.monotonic()
        last_pulse = last_sip
        while not link.stopping:
            link.write_pending()
            now = time.monotonic()
            if now - last_pulse >= self.pulse:
                link.write(command(PULSE))
                last_pulse = now
            data = link.read()
            now = time.monotonic()
            for p in self.reader.feed(data) if data else ():
                if is_sip(p):
                    last_sip = now
                    link.post("sip", now, p)
            if now - last_sip > self.timeout:
                return f"no data from the robot for {self.timeout:g} s"
        return "stopped"

    def _expect(self, link: SerialLink, want: int) -> bytes | None:
        """Read packets for up to ``sync_wait`` s; the payload starting with ``want`` or None."""
        deadline = time.monotonic() + self.sync_wait
        sips = False
        while link.wait_until(deadline):
            data = link.read()
            for p in self.reader.feed(data) if data else ():
                if p[0] == want and (want != SYNC0 or len(p) == 1):
                    return p
                sips = sips or is_sip(p)
        if sips:  # still open from an earlier client: close it before syncing again
            link.write(command(CLOSE))
        return None

    def _sync(self, link: SerialLink) -> tuple[str, str, str] | None:
        for step in (SYNC0, SYNC1, SYNC2):
            for _ in range(self.sync_retries):
                link.write(command(step))
                p = self._expect(link, step)
                if p is not None:
                    break
            else:
                return None
        strings = p[1:].split(b"\0")
        name, cls, sub = (
            (s.decode("ascii", "replace").strip() for s in strings[:3]) if len(strings) >= 3 else ("", "", "")
        )
        return name, cls, sub

    # ------------------------------------------------------------------ publishing
    def _t(self) -> float:
        return time.monotonic() - self._t0

    def _publish(self, sip: Sip, t: float) -> None:
        """Publish the newest SIP, stamped with its arrival (s since the driver started)."""
        m = self.model
        assert m is not None and self.odom is not None
        lv, rv = sip.l_vel * m.vel_conv, sip.r_vel * m.vel_conv  # mm/s
        v = (lv + rv) / 2000.0
        w = (rv - lv) * m.diff_conv / 2.0
        for a in self.cfg.provides:
            iface = a.interface
            if iface == "position2d":
                p = self.odom.pose
                g = self.guard
                self.publish(a, Position2dData(t, (p[0], p[1], p[2]), (v, 0.0, w), sip.stalled, g.timed_out, g.estop))
            elif iface in ("sonar", "ranger"):
                if self._sonar_fresh and self.sonar_ranges is not None:
                    self.publish(a, RangerData(t, self.sonar_ranges.copy(), 0.0, 0.0, *m.sonar_range))
            elif iface == "power":
                volts = sip.volts
                pct = 100.0 * lead_acid_fraction(volts)  # the charge from the voltage, as the simulator's curve
                ev = self.low.update(t, pct, volts)
                self.publish(a, PowerData(t, volts, pct, bool(sip.charge_state), self.low.low))
                if ev is not None:
                    self.event(a, ev)
            elif iface == "gripper" and sip.gripper is not None:
                self.publish(a, self._gripper_msg(t, sip))
            elif iface == "dio" and sip.digin is not None:
                self.publish(a, DioData(t, 8, sip.digin, sip.digout or 0))
            elif iface == "actarray" and sip.gripper is not None:
                self.publish(a, self._lift_msg(t, sip))
        self._sonar_fresh = False

    def _gripper_msg(self, t: float, sip: Sip) -> GripperData:
        """GripperData from the gripper state byte and DIGIN (tables in :mod:`mrs_bridge.hw.p2os`)."""
        st = gripper_state(sip.gripper or 0, sip.digin or 0)
        paddles = st.paddles
        if paddles in ("moving", "between"):  # no direction reported: the last command's
            paddles = "closing" if self._last_grip_cmd == "close" else "opening"
        lift = st.lift
        if lift == "moving":  # no direction reported: the last command's
            lift = "lowering" if self._last_grip_cmd == "down" else "raising"
        elif lift == "between":  # stopped at a carry position: the nearer end
            lift = "up" if self._last_lift >= 0.5 else "down"
        elif lift == "stalled":  # neither at an end nor moving
            lift = "error"
        stored = 1 if (paddles == "closed" and st.beams) else 0
        return GripperData(t, paddles, lift, st.beams, stored, None)

    def _lift_msg(self, t: float, sip: Sip) -> ActArrayData:
        """The lift as a one-joint actuator array (Player's ``lift::actarray``): 1 up, 0 down;
        between its ends the last commanded position."""
        st = gripper_state(sip.gripper or 0, 0)
        if st.lift == "up":
            pos, state = 1.0, "idle"
        elif st.lift == "down":
            pos, state = 0.0, "idle"
        elif st.lift in ("raising", "lowering", "moving"):
            pos, state = self._last_lift, "moving"
        elif st.lift == "between":
            pos, state = self._last_lift, "idle"
        else:
            pos, state = self._last_lift, "stalled"
        self._last_lift = pos
        return ActArrayData(t, (pos,), (0.0,), (state,))

    def publish_rate(self, addr) -> float:
        return 10.0  # the robot's SIP rate

    # ------------------------------------------------------------------ commands
    def _need_robot(self) -> SerialLink:
        if self.link is None or not self.link.connected or self.model is None:
            raise RpcError(ErrorCode.UNAVAILABLE, f"the robot on {self.port} is not answering")
        return self.link

    def _velocity(self, v: float, w: float) -> None:
        link = self._need_robot()
        link.send(command(VEL, int(round(v * 1000.0))))
        link.send(command(RVEL, int(round(math.degrees(w)))))

    def on_cmd(self, addr, msg):
        iface = addr.interface
        if iface == "position2d":
            try:
                self._command(VelocityCmd.from_dict(msg))
            except RpcError as e:
                raise MessageError(e.message) from None
        elif iface == "gripper":
            self._gripper(GripperCmd.from_dict(msg).action)
        elif iface == "dio":
            c = DioCmd.from_dict(msg)
            self._digout(c.bits, c.mask)
        else:
            raise MessageError(f"{addr} takes no commands")

    def _command(self, c: VelocityCmd, *, rpc: bool = False) -> None:
        m = self.model or self.forced_model
        if m is not None:
            vmax, wmax = m.max_speed
            if abs(c.v) > vmax + 1e-9 or abs(c.w) > wmax + 1e-9:
                raise OutOfRange(
                    f"v={c.v:g} m/s, w={c.w:g} rad/s exceeds the {m.name} limits |v| <= {vmax:g}, |w| <= {wmax:.3g}"
                )
        if c.vy != 0.0:
            raise OutOfRange(f"vy={c.vy:g}: a differential drive cannot move sideways")
        self.guard.check(rpc=rpc)
        if not self._motors:
            return
        self._velocity(c.v, c.w)
        self.guard.command(c.v, c.w)

    def _gripper(self, action: str) -> None:
        try:
            link = self._need_robot()
        except RpcError as e:
            raise MessageError(e.message) from None
        link.send(command(GRIPPER, GRIPPER_ARGS[action]))
        self._last_grip_cmd = action
        if action in ("up", "down"):
            self._last_lift = 1.0 if action == "up" else 0.0

    def _digout(self, bits: int, mask: int) -> None:
        self._need_robot().send(command(DIGOUT, (mask << 8) | bits))

    def ops(self, addr):
        i = addr.interface
        if i == "position2d":
            return ["set_odom", "motor_power", "stop", "status", *ESTOP_OPS]
        if i == "gripper":
            return ["open", "close", "up", "down", "stop"]
        if i in ("sonar", "ranger"):
            return ["get"]
        if i == "dio":
            return ["set"]
        if i == "actarray":
            return ["set_position", "home"]
        return []

    def on_rpc(self, addr, op, args):
        i = addr.interface
        if i == "position2d":
            if op == "set_odom":
                x, y, a = get_vec(args, "pose", 3)
                if self.odom is None:
                    raise RpcError(ErrorCode.UNAVAILABLE, f"the robot on {self.port} has not answered yet")
                self.odom.set_pose(x, y, a)
                return {"pose": [x, y, a]}
            if op == "motor_power":
                on = get_bool(args, "on")
                link = self._need_robot()
                if not on:
                    self._velocity(0.0, 0.0)
                link.send(command(ENABLE, 1 if on else 0))
                self._motors = on
                if not on:
                    self.guard.stopped()
                return {"on": on}
            if op == "stop":
                self._velocity(0.0, 0.0)
                self.guard.stopped()
                return {}
            if op == "set_velocity":
                self._command(VelocityCmd.from_dict(args), rpc=True)
                return {}
            if op == "estop":
                self.guard.press()  # latched even while the robot does not answer (ARCOS stops then)
                try:
                    self._velocity(0.0, 0.0)
                except RpcError:
                    pass
                return {"estop": True}
            if op == "release":
                self.guard.release()
                return {"estop": False}
            if op == "status":
                connected = self.link is not None and self.link.connected
                return {"connected": connected, "robot": list(self.ident or ()), **self.stats}
        if i == "gripper" and op in GRIPPER_ARGS:
            self._need_robot()
            self._gripper(op)
            return {"action": op}
        if i in ("sonar", "ranger") and op == "get":
            if self.sonar_ranges is None or self.model is None:
                raise RpcError(ErrorCode.UNAVAILABLE, "no sonar reading yet")
            return RangerData(self._t(), self.sonar_ranges.copy(), 0.0, 0.0, *self.model.sonar_range).to_dict()
        if i == "dio" and op == "set":
            self._digout(get_int(args, "bits", lo=0, hi=0xFF), get_int(args, "mask", 0xFF, lo=0, hi=0xFF))
            return {}
        if i == "actarray" and op in ("set_position", "home"):
            self._need_robot()
            if get_int(args, "joint", 0, lo=0, hi=0) != 0:
                raise OutOfRange("the lift has one joint, 0")
            pos = 0.0 if op == "home" else get_float(args, "position", lo=0.0, hi=1.0)
            self._gripper("up" if pos >= 0.5 else "down")
            return {"position": 1.0 if pos >= 0.5 else 0.0}
        return super().on_rpc(addr, op, args)

    def geometry(self, addr) -> dict[str, Any]:
        m = self.model or self.forced_model
        i = addr.interface
        base: dict[str, Any] = {"port": self.port, "model": m.name if m else ""}
        if self.ident:
            base["robot"] = {"name": self.ident[0], "class": self.ident[1], "subclass": self.ident[2]}
        if m is None:
            return base
        if i == "position2d":
            return {**base, "size": list(m.size), "max_speed": list(m.max_speed), "frame": "odom"}
        if i in ("sonar", "ranger"):
            n = self.sonar_override or m.sonars
            lo, hi = m.sonar_range
            fov = math.radians(15)
            return {
                **base,
                "kind": "sonar",
                "pose": [0.0, 0.0, 0.0],
                "sensors": [
                    {"pose": list(p), "fov": fov, "samples": 1, "range_min": lo, "range_max": hi}
                    for p in m.sonar_poses[:n]
                ],
            }
        if i == "actarray":
            return {**base, "actuators": [{"type": "linear", "min": 0.0, "max": 1.0, "name": "lift"}]}
        if i == "dio":
            return {**base, "inputs": 8, "outputs": 8}
        return base
