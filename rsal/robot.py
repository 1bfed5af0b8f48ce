"""Robots of the RSAL layer (thesis 3.6.2.2): ``Robot``, ``Pioneer``, ``ExploreRobot``, ``NavRobot``.

A :class:`Robot` is made from a list of device proxies, anywhere on the fabric; it needs a
``position2d`` and at least one ranger (laser or sonar), and uses what else it is given
(``localize``, ``simulation``, ``blobfinder``, ``gripper``...). Like the thesis's robots, which
were devices with a thread, it runs its :meth:`Robot.update` every ``period`` seconds (100 ms by
default, the thesis's sleep time) on its own thread until :meth:`Robot.shutdown`.

:class:`Pioneer` adds the subsumption behaviour of :mod:`rsal.behaviours` (sonar+laser fusion,
avoid, escape when stuck, wall-follow) with ``set_command`` and ``set_wallfollow``; the laser can
be switched off per robot (the thesis's "Laser" flag, 3.5), leaving sonar only.
:class:`ExploreRobot` also watches a blobfinder and reports each newly seen blob with its world
position.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import Future

import numpy as np

from .behaviours import SECTOR_COUNT, BehaviourParams, ListSectors, Sectors, Subsumption, beam_points, fuse, fuse_beams
from .client import HOLD_REFRESH
from .clock import clock
from .data import BlobfinderBlob, Position
from .devices import Blobfinder, Device, Gripper, Laser, Planner, Position2d, Ranger, Simulation, Sonar
from .errors import RsalError

__all__ = ["Robot", "Pioneer", "ExploreRobot", "NavRobot", "RobotError"]

log = logging.getLogger(__name__)


class RobotError(RsalError, ValueError):
    """A robot cannot be made from the given devices."""


class Robot:
    def __init__(self, devices: Iterable[Device], *, name: str | None = None, period: float = 0.1, laser: bool = True):
        devs = list(devices)
        pos = [d for d in devs if isinstance(d, Position2d)]
        if not pos:
            raise RobotError(f"a robot needs a position2d device; got {', '.join(str(d.addr) for d in devs) or 'none'}")
        self.position2d: Position2d = pos[0]
        self.lasers: list[Ranger] = [d for d in devs if isinstance(d, Laser)]
        self.sonars: list[Ranger] = [d for d in devs if isinstance(d, Sonar)]
        # a generic ranger counts as a laser unless a dedicated laser/sonar of the same node exists
        if not self.lasers and not self.sonars:
            self.lasers = [d for d in devs if type(d) is Ranger]
        if not self.lasers and not self.sonars:
            raise RobotError(f"robot {name or self.position2d.node!r} needs a ranger (laser or sonar)")
        self.laser_enabled = bool(laser)
        if not self.laser_enabled and not self.sonars:
            raise RobotError(
                f"robot {name or self.position2d.node!r} has its laser disabled and no sonar; "
                "enable the laser or give it a sonar"
            )
        self.simulation: Simulation | None = next((d for d in devs if isinstance(d, Simulation)), None)
        self.blobfinder: Blobfinder | None = next((d for d in devs if isinstance(d, Blobfinder)), None)
        self.gripper: Gripper | None = next((d for d in devs if isinstance(d, Gripper)), None)
        self.localize = next((d for d in devs if d.interface == "localize"), None)
        self.devices = devs
        self.name = name or self.position2d.node
        self.period = float(period)
        self.goal: Position | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.updates = 0

    # ------------------------------------------------------------------ pose
    @property
    def position(self) -> Position | None:
        """The best pose known: localized if a localize device is given, else odometry."""
        if self.localize is not None and getattr(self.localize, "position", None) is not None:
            return self.localize.position
        return self.position2d.position

    def set_position(self, pose: Position) -> None:
        """Set the robot's pose belief (odometry/localization) and, in a simulation, move its
        simulated body there (thesis 3.6.2.2)."""
        if self.localize is not None and hasattr(self.localize, "set_position"):
            self.localize.set_position(pose)
        else:
            self.position2d.set_odometry(pose)
        if self.simulation is not None:
            self.simulation.set_pose(self.name, pose)

    # ------------------------------------------------------------------ sensing
    def obstacle_points(self) -> list[np.ndarray]:
        """Obstacle points in the robot frame from the enabled rangers."""
        out = []
        rangers = (self.lasers if self.laser_enabled else []) + self.sonars
        for r in rangers:
            m = r.latest
            if m is None or not r.alive:
                continue
            try:
                poses = r.sensor_poses()
            except Exception as e:  # describe not answered yet
                log.debug("%s: no geometry yet: %s", r.addr, e)
                continue
            out.append(beam_points(poses, m.ranges, m.range_max or float(np.max(m.ranges))))
        return out

    # ------------------------------------------------------------------ run loop
    def start(self) -> Robot:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=f"robot-{self.name}", daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        clk = clock()  # the period counts seconds of the process's clock (simulated under use_sim_time)
        next_t = clk.now()
        while not self._stop.is_set():
            try:
                self.update()
                self.updates += 1
            except Exception:
                log.exception("%s: update failed", self.name)
            next_t += self.period
            now = clk.now()
            if next_t < now - self.period:
                next_t = now
            clk.sleep_until(next_t, self._stop)

    def update(self) -> None:
        """One cycle of the robot's own behaviour (override)."""

    def stop(self) -> None:
        self.position2d.stop()

    def shutdown(self) -> None:
        """Stop the run loop and the motors."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        try:
            self.stop()
        except Exception:
            pass


class Pioneer(Robot):
    """A Pioneer with the subsumption behaviour of thesis 3.6.2.4.

    Its cycle fuses the enabled rangers into sectors (:meth:`sectors`): with numpy while a ranger
    has more than :attr:`fast_beams` beams (a laser), else in plain Python with each ranger's beam
    geometry computed once (a sonar ring: :func:`~rsal.behaviours.fuse_beams`); both give the same
    sectors."""

    fast_beams = 32

    def __init__(self, devices: Iterable[Device], *, params: BehaviourParams | None = None, **kw):
        super().__init__(devices, **kw)
        self.behaviour = Subsumption(params)
        self._last_cmd: tuple[float, float] | None = None
        self._state_listeners: list[Callable[[str], None]] = []
        self.distance = 0.0  # metres travelled according to odometry
        self._last_pose: Position | None = None
        self._beams: dict = {}  # ranger address -> [(x, y, cos, sin)] of its beams, for fuse_beams
        try:
            vmax, wmax = self.position2d.limits()
            bp = self.behaviour.p
            bp.cruise_speed = min(bp.cruise_speed, vmax)
            bp.turn_rate = min(bp.turn_rate, wmax)
        except Exception:  # limits are a nicety; describe may not be reachable yet
            pass

    @property
    def state(self) -> str:
        return self.behaviour.state

    def on_state(self, fn: Callable[[str], None]) -> None:
        self._state_listeners.append(fn)

    def set_command(self, v: float, w: float) -> None:
        """Manual speed and turn rate; obstacle avoidance and escape still apply."""
        self.behaviour.set_command(v, w)

    def set_wallfollow(self, on: bool = True, side: str | None = None) -> None:
        self.behaviour.set_wallfollow(on, side)

    def sectors(self) -> Sectors:
        """The enabled rangers fused into sectors around the robot (nearest obstacle per direction)."""
        rangers = (self.lasers if self.laser_enabled else []) + self.sonars
        if any(r.latest is not None and len(r.latest.ranges) > self.fast_beams for r in rangers):
            return fuse(self.obstacle_points())
        d: list[float] | None = None
        for r in rangers:
            m = r.latest
            if m is None or not r.alive:
                continue
            beams = self._beams.get(r.addr)
            if beams is None or len(beams) != len(m.ranges):
                try:
                    poses = r.sensor_poses()
                except Exception as e:  # describe not answered yet
                    log.debug("%s: no geometry yet: %s", r.addr, e)
                    continue
                beams = self._beams[r.addr] = [(x, y, math.cos(a), math.sin(a)) for x, y, a in poses.tolist()]
            f = fuse_beams(beams, m.ranges, m.range_max or float(np.max(m.ranges)))
            d = f if d is None else [min(a, b) for a, b in zip(d, f, strict=True)]
        return ListSectors(d if d is not None else [math.inf] * SECTOR_COUNT)

    def update(self) -> None:
        pos = self.position2d
        if pos.latest is None or not pos.alive:
            return
        cur = pos.position
        if self._last_pose is not None and cur is not None:
            self.distance += cur.distance_to(self._last_pose)
        self._last_pose = cur
        sectors = self.sectors()
        before = self.behaviour.state
        v, w = self.behaviour.step(sectors, clock().now(), pos.stalled)
        if self.behaviour.state != before:
            for fn in self._state_listeners:
                fn(self.behaviour.state)
        cmd = (round(v, 3), round(w, 3))
        # Re-send every cycle while moving (a lost command must not leave the robot stuck);
        # send a stop once.
        if cmd != self._last_cmd or cmd != (0.0, 0.0):
            # A cycle faster than the fabric's refresh refreshes the base itself, so a hung cycle lets
            # the base's command timeout stop the robot; a slower one lets the fabric re-send it.
            pos.set_velocity(*cmd, hold=self.period > HOLD_REFRESH)
            self._last_cmd = cmd


class ExploreRobot(Pioneer):
    """A Pioneer that wall-follows and reports blobs its blobfinder sees (thesis 4.2.2)."""

    def __init__(self, devices: Iterable[Device], *, merge_dist: float = 0.5, **kw):
        super().__init__(devices, **kw)
        if self.blobfinder is None:
            raise RobotError(f"an ExploreRobot needs a blobfinder; {self.name} has none")
        self.merge_dist = merge_dist
        self.found: list[BlobfinderBlob] = []
        self._blob_listeners: list[Callable[[BlobfinderBlob], None]] = []

    def on_blob(self, fn: Callable[[BlobfinderBlob], None]) -> None:
        self._blob_listeners.append(fn)

    def update(self) -> None:
        super().update()
        pose = self.position
        if pose is None:
            return
        for b in self.blobfinder.blobs:
            wp = b.world_position(pose)
            if any(f.discovered is not None and f.discovered.distance_to(wp) < self.merge_dist for f in self.found):
                continue
            found = BlobfinderBlob(
                b.id, b.color, b.area, b.x, b.y, b.left, b.right, b.top, b.bottom, b.range, b.bearing, discovered=wp
            )
            self.found.append(found)
            for fn in self._blob_listeners:
                fn(found)


class NavRobot(Robot):
    """A robot that moves by goals on the map (thesis 3.6.2.2): a ``planner`` (wavefront) plans and
    drives through the local planner, a ``localize`` (amcl) says where it is.

    :meth:`goto` returns a future that resolves to ``"done"`` or raises
    :class:`~rsal.msgs.RpcError` (``not_found``: invalid goal; ``unavailable``: aborted or superseded).
    """

    def __init__(self, devices: Iterable[Device], **kw):
        devs = list(devices)
        super().__init__(devs, **kw)
        self.planner: Planner | None = next((d for d in devs if isinstance(d, Planner)), None)
        if self.planner is None:
            raise RobotError(
                f"robot {self.name!r} needs a planner device to move by goals (e.g. 'rsal sim WORLD --nav vfh')"
            )
        base = [d for d in devs if isinstance(d, Position2d)]
        self.position2d = min(base, key=lambda d: d.index)  # the base itself, for stop()
        #: the localizer's position2d (amcl: map frame, at the odometry's rate), if given
        self.localized: Position2d | None = None
        for d in base:
            try:
                if d.describe(timeout=5.0).geometry.get("frame") == "map":
                    self.localized = d
                    break
            except Exception as e:  # a silent device is simply not used
                log.debug("%s: no describe: %s", d.addr, e)

    @property
    def position(self) -> Position | None:
        """The localized pose at the odometry's rate (amcl's position2d), else the localize device's."""
        if self.localized is not None and self.localized.latest is not None:
            return self.localized.position
        return super().position

    def goto(self, goal: Position, timeout: float = 5.0) -> Future:
        self.goal = goal
        return self.planner.set_goal(goal, timeout=timeout)

    def add_is_done_listener(self, fn: Callable[[str], None]) -> None:
        self.planner.add_is_done_listener(fn)

    @property
    def is_done(self) -> bool:
        return self.planner.status == "done"

    def stop(self) -> None:
        try:
            self.planner.stop()
        finally:
            self.position2d.stop()


def robot_devices(node, name: str, *, timeout: float = 10.0) -> list[Device]:
    """Proxies of every device of node ``name`` that a DeviceNode sees (waits for position2d)."""
    node.wait_for(f"{name}:position2d:*", 1, timeout)
    return [node.device(a) for a in node.search(node=name)]
