"""The ``position2d`` interface: a mobile base (Player's ``position2d``; thesis 3.6.2.3).

Messages: :class:`Position2dData` (``data``), :class:`VelocityCmd` (``cmd``, Player's ``SetSpeed``)
and :class:`GoalCmd` (a local planner's ``cmd``, Player's ``GoTo``); proxy :class:`Position2d`.
Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..data import Position
from ..msgs import _Msg, get_bool, get_float, get_vec
from .base import Device, Interface

__all__ = ["VelocityCmd", "Position2dData", "GoalCmd", "Position2d", "INTERFACE"]


@dataclass(frozen=True)
class VelocityCmd(_Msg):
    """position2d ``cmd``: forward speed ``v`` (m/s), sideways ``vy`` (m/s, 0 for a diff drive),
    turn rate ``w`` (rad/s). Player's ``SetSpeed``."""

    v: float
    w: float
    vy: float = 0.0

    @classmethod
    def from_dict(cls, m: dict) -> VelocityCmd:
        return cls(get_float(m, "v"), get_float(m, "w"), get_float(m, "vy", 0.0))


@dataclass(slots=True)  # not frozen: a frozen init costs 4x on this hot path; treat as immutable
class Position2dData(_Msg):
    """position2d ``data``: pose (x, y, yaw) in the device's frame (odometry or map), velocity
    (vx, vy, w) in the robot frame, stall flag; ``timed_out``: the base stopped itself because its
    velocity command was not refreshed within its ``cmd_timeout``; ``estop``: its emergency stop is
    latched."""

    t: float
    pose: tuple[float, float, float]
    vel: tuple[float, float, float]
    stall: bool = False
    timed_out: bool = False
    estop: bool = False

    @classmethod
    def from_dict(cls, m: dict) -> Position2dData:
        return cls(
            get_float(m, "t"),
            get_vec(m, "pose", 3),
            get_vec(m, "vel", 3),
            get_bool(m, "stall", False),
            get_bool(m, "timed_out", False),
            get_bool(m, "estop", False),
        )


@dataclass(frozen=True)
class GoalCmd(_Msg):
    """position2d ``cmd`` of a local planner (vfh, nd, snd): drive to ``goal`` (x, y, yaw) in the
    device's frame. Player's ``GoTo``; a :class:`VelocityCmd` on the same key cancels the goal."""

    goal: tuple[float, float, float]

    @classmethod
    def from_dict(cls, m: dict) -> GoalCmd:
        return cls(get_vec(m, "goal", 3))


class Position2d(Device):
    """A mobile base (Player position2d): pose in its frame, velocity, stall; velocity commands."""

    data_type = Position2dData

    @property
    def position(self) -> Position | None:
        m = self.latest
        return Position(*m.pose) if m is not None else None

    @property
    def velocity(self) -> tuple[float, float]:
        m = self.latest
        return (m.vel[0], m.vel[2]) if m is not None else (0.0, 0.0)

    @property
    def stalled(self) -> bool:
        return bool(self.latest.stall) if self.latest is not None else False

    def set_velocity(self, v: float, w: float, *, hold: bool = True) -> None:
        """Forward speed m/s and turn rate rad/s (the server rejects values over the robot's limits).

        A base stops by itself when its velocity command is not refreshed within its ``cmd_timeout``
        (0.5 s by default). ``hold=True``: the fabric re-sends this command every 0.2 s until the
        next command or :meth:`stop`, for callers that set a velocity once. ``hold=False``: the
        caller refreshes it itself (a control cycle at 5 Hz or more), so a controller that hangs
        lets the robot stop."""
        cmd = VelocityCmd(float(v), float(w))
        if hold and (cmd.v != 0.0 or cmd.w != 0.0):
            self.fabric.hold(self.addr, cmd)
        else:
            self.fabric.release(self.addr)
            self.send(cmd)

    def stop(self) -> None:
        self.fabric.release(self.addr)
        self.send(VelocityCmd(0.0, 0.0))

    def goto(self, goal: Position) -> None:
        """Drive to ``goal`` in this device's frame: for a local planner's position2d (vfh, nd, snd),
        which reports ``{"event": "done"}`` on arrival; a plain base rejects it. A position goal is
        not a held velocity: the planner pursues it without refresh."""
        self.fabric.release(self.addr)
        self.send(GoalCmd(goal.as_tuple()))

    def set_motor_power(self, on: bool, timeout: float = 5.0) -> bool:
        """Switch the motors on or off (Player's ``MOTOR_POWER``, ``rpc/motor_power``); while off the
        base ignores velocity commands and stays stopped. Returns the state the base reports."""
        return bool(self.rpc("motor_power", timeout=timeout, on=bool(on))["on"])

    def estop(self, timeout: float = 5.0) -> dict:
        """Latch this base's emergency stop (``rpc/estop``): it stops and refuses velocity commands
        until :meth:`release_estop`."""
        self.fabric.release(self.addr)
        return self.rpc("estop", timeout=timeout)

    def release_estop(self, timeout: float = 5.0) -> dict:
        """Release the latched emergency stop (``rpc/release``)."""
        return self.rpc("release", timeout=timeout)

    @property
    def estopped(self) -> bool:
        """The base reports its emergency stop latched."""
        return bool(self.latest.estop) if self.latest is not None else False

    @property
    def timed_out(self) -> bool:
        """The base stopped itself because its velocity command was not refreshed in time."""
        return bool(self.latest.timed_out) if self.latest is not None else False

    def set_odometry(self, pose: Position) -> dict:
        return self.rpc("set_odom", pose=list(pose.as_tuple()))

    def limits(self) -> tuple[float, float]:
        g = self.describe().geometry
        v, w = g.get("max_speed", (0.5, 1.0))
        return float(v), float(w)


def _summary(m: Position2dData) -> str:
    x, y, a = m.pose
    flags = "".join(f" {f}" for f, on in (("stall", m.stall), ("timed_out", m.timed_out), ("estop", m.estop)) if on)
    return f"pose=({x:.2f}, {y:.2f}, {a:.2f}) v={m.vel[0]:.2f} w={m.vel[2]:.2f}{flags}"


INTERFACE = Interface(
    "position2d",
    proxy=Position2d,
    data=Position2dData,
    cmds=(VelocityCmd, GoalCmd),
    event="local planners: {event: done | aborted, goal}",
    summary=_summary,
    doc="a mobile base: odometry or map pose, velocity commands, goals of a local planner",
)
