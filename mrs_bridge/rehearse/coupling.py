"""The rehearsal's coupling: a robot of a simulated world as the body of an emulated Pioneer, and
the world's geometry as the scene of an emulated Hokuyo laser (issue "hardware rehearsal").

:class:`WorldRobot` is the :class:`mrs_bridge.emulators.p2os.Body` of one robot model: the speeds
the emulated microcontroller drives become the model's velocity command (acceleration-limited by
the world, as motors are), GRIPPER commands the world's gripper model, and every SIP reports the
model's wheel odometry (the world's drifting odometry, Stage's ``odom_error``), its wheel speeds,
stall, bumper ring (segments ahead of the axle as the front bumpers, the others as the rear),
sonar ring, gripper with break beams (the paddles touch what they carry) and a battery that drains
with time and motion. :class:`WorldLaser` is the ``scene`` of a
:class:`mrs_bridge.emulators.urg.HokuyoEmulator`: every reading ray-cast in the world
(:func:`simulator.raycast.cast_fans`, walls and bodies that return lasers) from the sensor's
mount pose on the robot's true pose, with the data sheet's 10 mm noise; no echo within ``DMAX``
reads the SCIP error code 1.

Threads: the world is stepped by the server's scheduler (:class:`RehearsalDriver`, the
``simulation`` driver with this coupling's two hooks); the emulators run on their own threads. They
meet only in the couplings' snapshots and pending commands, under one lock each: the stepping
thread applies the pending commands before a step and takes the snapshot after it; an emulator
thread never touches the world.
"""

from __future__ import annotations

import math
import threading
from collections import deque

import numpy as np

from ..driver import register
from ..drivers.sim import SimulationDriver
from ..emulators.p2os import Sensed
from ..emulators.urg import Sensor

__all__ = ["WorldRobot", "WorldLaser", "RehearsalDriver", "COUPLINGS_KEY", "BATTERY_FULL"]

COUPLINGS_KEY = "rehearse.couplings"  # server.shared: the couplings the stepping thread serves
BATTERY_FULL = 12.8  # V of a charged 12 V lead-acid pack
BATTERY_DRAIN = (2e-4, 1e-3)  # V per second at rest, and per metre driven
URG_NOISE = 0.01  # m, the URG-04LX data sheet's accuracy (+-10 mm up to 1 m)


class WorldRobot:
    """The body of robot ``name`` in ``world`` for an emulated Pioneer (module docstring)."""

    def __init__(self, world, name: str, *, battery: float = BATTERY_FULL):
        self.name = name
        self.spec = world.model_spec(name)
        self.battery = float(battery)
        rangers = world.rangers(name)
        self.sonar_idx = next((i for i, r in enumerate(rangers) if r.kind == "sonar"), None)
        self._lock = threading.Lock()
        self._drive: tuple[float, float] | None = None
        self._grip: deque[str] = deque(maxlen=16)
        self._sensed = self._read(world)

    # -- the emulator's side (its thread)
    def drive(self, v: float, w: float) -> None:
        with self._lock:
            self._drive = (float(v), float(w))

    def gripper(self, action: str) -> None:
        if self.spec.grippers:
            with self._lock:
                self._grip.append("stop" if action == "lift_stop" else action)

    def sense(self) -> Sensed:
        with self._lock:
            return self._sensed

    # -- the world's side (the stepping thread)
    def before_step(self, world) -> None:
        with self._lock:
            drive, self._drive = self._drive, None
            grips = list(self._grip)
            self._grip.clear()
        if drive is not None:
            world.set_velocity(self.name, *drive)
        for g in grips:
            world.gripper_command(self.name, g)

    def after_step(self, world, dt: float) -> None:
        v, _ = world.velocity(self.name)
        self.battery = max(0.0, self.battery - (BATTERY_DRAIN[0] + BATTERY_DRAIN[1] * abs(v)) * dt)
        s = self._read(world)
        with self._lock:
            self._sensed = s

    def _read(self, world) -> Sensed:
        name, spec = self.name, self.spec
        front = rear = 0
        if spec.bumpers:
            b = world.bumper(name, 0)
            if b is not None:
                segs = spec.bumpers[0].segments
                fi = ri = 0
                for seg, pressed in zip(segs, b.pressed, strict=False):
                    ahead = seg.pose[0] >= 0.0
                    if ahead and fi < 7:
                        front |= (1 << fi) if pressed else 0
                        fi += 1
                    elif not ahead and ri < 7:
                        rear |= (1 << ri) if pressed else 0
                        ri += 1
        grip = {}
        if spec.grippers:
            g = world.gripper(name, 0)
            held = g.carrying is not None
            grip = dict(
                paddles=g.paddles,
                lift=g.lift,
                inner_beam=g.inner_beam,
                outer_beam=g.outer_beam,
                contacts=(held, held),
            )
        sonars = None
        if self.sonar_idx is not None:
            r = world.ranger(name, self.sonar_idx)
            if r is not None:
                sonars = tuple(float(x) for x in r.ranges)
        stall = world.stalled(name)
        return Sensed(
            odom=world.odometry(name),
            vel=world.velocity(name),
            stall=(stall, stall),
            front_bumpers=front,
            rear_bumpers=rear,
            battery=self.battery,
            sonars=sonars,
            **grip,
        )


class WorldLaser:
    """The scene of an emulated Hokuyo ``sensor`` mounted at ``pose`` (x, y, yaw in m, rad) on
    robot ``name`` (module docstring)."""

    def __init__(self, world, name: str, sensor: Sensor, pose=(0.13, 0.0, 0.0), *, noise: float = URG_NOISE):
        self.name, self.sensor, self.pose, self.noise = name, sensor, tuple(float(p) for p in pose), noise
        self.uid = world.models[name].uid
        self._steps = np.arange(sensor.amin, sensor.amax + 1)
        self._lock = threading.Lock()
        self._mm = self._cast(world)

    def __call__(self, steps) -> np.ndarray:
        with self._lock:
            mm = self._mm
        return mm[np.asarray(steps, dtype=np.int64) - self.sensor.amin]

    def before_step(self, world) -> None:
        pass

    def after_step(self, world, dt: float) -> None:
        mm = self._cast(world)
        with self._lock:
            self._mm = mm

    def _cast(self, world) -> np.ndarray:
        from simulator.raycast import cast_fans

        x, y, a = world.get_pose(self.name)
        lx, ly, la = self.pose
        c, s = math.cos(a), math.sin(a)
        pp = self.sensor
        rmax = pp.dmax / 1000.0
        fans = {
            "x": [x + c * lx - s * ly],
            "y": [y + s * lx + c * ly],
            "th0": [a + la + float(pp.angle(pp.amin))],
            "dth": [2.0 * math.pi / pp.ares],
            "n": [self._steps.size],
            "rmax": [rmax],
            "owner": [self.uid],
            "noise": [self.noise],
            "rmin": [pp.dmin / 1000.0],
        }
        r = cast_fans(world.grid, fans, world.circles(), seed=world.seed + 1, step=world.steps)
        mm = np.round(r * 1000.0).astype(np.int64)
        mm[r >= rmax - 1e-9] = 1  # no echo: the SCIP error code 1
        mm.flags.writeable = False
        return mm


@register("rehearsal")
class RehearsalDriver(SimulationDriver):
    """The ``simulation`` driver of a rehearsal: it steps the world in real time and, around every
    step, serves the couplings in ``server.shared[COUPLINGS_KEY]`` (module docstring)."""

    _seen = -1  # the world's step count the couplings last saw

    def update(self, now: float) -> None:
        w = self.world
        couplings = self.server.shared.get(COUPLINGS_KEY, ())
        for c in couplings:
            c.before_step(w)
        super().update(now)
        if w.steps != self._seen:  # stepped here, by rpc/step, or reset
            dt = max(0, w.steps - self._seen) * w.spec.interval_sim if self._seen >= 0 else 0.0
            self._seen = w.steps
            for c in couplings:
                c.after_step(w, dt)
