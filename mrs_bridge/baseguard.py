"""Command timeout (deadman) and latched emergency stop of a mobile base.

Every driver that moves a robot -- ``sim``'s and ``p2os``'s ``position2d`` and a local planner's
output -- keeps one :class:`BaseGuard` and asks it before it moves the motors:

- **deadman**: a velocity command holds for ``cmd_timeout`` seconds (driver parameter, default
  :data:`DEFAULT_CMD_TIMEOUT`; ``0`` disables the timeout, which is unsafe: a robot whose commander
  dies drives on). When a moving command is not refreshed in time, :meth:`BaseGuard.expired`
  answers ``True`` once, the driver stops the motors, the data says ``timed_out`` until the next
  command, and one line is logged per timeout (not per cycle; the timeouts of many bases within a second, one
  line for all). The time is the base's own clock:
  simulated seconds for a simulated base (so a run at any speed-up behaves alike), the server's
  monotonic wall clock for hardware and local planners: see docs/protocol.md, "Command timeout".
  A position goal (a local planner's ``goto``) is not a held velocity: the planner pursues it
  without refresh and refreshes its base itself.
- **emergency stop**: ``rpc/estop`` latches the stop; while latched the base stays stopped,
  refuses velocity commands (``cmd`` puts are dropped with the server's rate-limited warning,
  ``rpc/set_velocity`` answers error code ``estop``) and its data says ``estop``; only
  ``rpc/release`` clears it. Pressing and releasing are separate operations so that an access
  control list can allow one and not the other (docs/deployment.md).

The same concept as ROS ``diff_drive_controller``'s ``cmd_vel_timeout`` and Open-RMF's emergency
alarm.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections.abc import Callable

from rsal.cliutil import brief
from rsal.msgs import ErrorCode, MessageError, RpcError

from .config import ConfigError

__all__ = ["BaseGuard", "DEFAULT_CMD_TIMEOUT", "ESTOP_OPS", "Latched"]

DEFAULT_CMD_TIMEOUT = 0.5  # s (the base's clock): a velocity command not refreshed this long stops the base
ESTOP_OPS = ("set_velocity", "estop", "release")  # the operations every base answers besides its own


class Latched(MessageError):
    """A velocity ``cmd`` arrived while the emergency stop is latched (dropped, warned rate-limited)."""


class _TimeoutLines:
    """The timeout warnings of a process's bases: the first in a second as its own line, the
    others of that second (a server of a thousand robots whose commander stalled) gathered in one
    line, written by a timer at the second's end -- not a thousand lines."""

    window = 1.0  # s of wall time

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._open_until = -math.inf
        self._held: dict[logging.Logger, list[str]] = {}

    def add(self, guard: BaseGuard, age: float) -> None:
        now = time.monotonic()
        with self._lock:
            if now >= self._open_until:
                self._open_until = now + self.window
                held = False
            else:
                self._held.setdefault(guard.log, []).append(guard.name)
                held = True
        if not held:
            guard.log.warning(
                "%s: no velocity command for %.2f s (cmd_timeout %g s): motors stopped until the next command",
                guard.where,
                age,
                guard.cmd_timeout,
            )
            timer = threading.Timer(self.window, self.flush)
            timer.name = "base-timeouts"
            timer.start()  # not a daemon: the held names are written before the process ends

    def flush(self) -> None:
        with self._lock:
            held, self._held = self._held, {}
        for log, names in held.items():
            bases = sorted(set(names), key=_natural)
            log.warning(
                "%d more base(s) without a velocity command within their cmd_timeout%s: %s; motors stopped "
                "until the next command",
                len(bases),
                "" if len(bases) == len(names) else f" ({len(names)} timeouts, some bases twice)",
                brief(bases),
            )


_TIMEOUTS = _TimeoutLines()


def _natural(name: str) -> tuple:
    """Sort key: ``r2`` before ``r10``."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name))


class BaseGuard:
    """Deadman and emergency-stop state of one base (see the module docstring).

    ``clock`` is the base's clock: the server's monotonic wall clock by default, the world's
    simulated time for ``sim`` bases; tests pass their own.
    """

    def __init__(
        self,
        where: str,
        name: str,
        cmd_timeout: float = DEFAULT_CMD_TIMEOUT,
        *,
        log: logging.Logger | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.where = where
        self.name = name  # the base, as a user names it in `rsal estop` (the node)
        self.cmd_timeout = float(cmd_timeout)
        self.log = log or logging.getLogger(__name__)
        self.clock = clock
        self.timed_out = False
        self.estop = False
        self._last_cmd = -math.inf
        self._moving = False  # the command held now is not a stop
        if self.cmd_timeout == 0:
            self.log.warning(
                "%s: cmd_timeout = 0: the command timeout is off; the robot drives on if its commander dies",
                where,
            )

    @staticmethod
    def timeout_param(cfg) -> float:
        """The driver parameter ``cmd_timeout`` (s), checked: a number >= 0."""
        v = cfg.param("cmd_timeout", DEFAULT_CMD_TIMEOUT)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (v >= 0 and math.isfinite(v)):
            raise ConfigError(
                f"{cfg.where}: cmd_timeout = {v!r} must be a number of seconds >= 0 "
                f"(default {DEFAULT_CMD_TIMEOUT:g}; 0 turns the command timeout off, which is unsafe)"
            )
        return float(v)

    @classmethod
    def for_driver(cls, driver, name: str) -> BaseGuard:
        return cls(driver.cfg.where, name, cls.timeout_param(driver.cfg), log=driver.log)

    # ------------------------------------------------------------------ commands
    def check(self, *, rpc: bool = False) -> None:
        """Refuse a velocity command while latched: :class:`Latched` for a ``cmd`` (the server
        drops it with a rate-limited warning), :class:`RpcError` ``estop`` for an rpc."""
        if self.estop:
            text = f"emergency stop of {self.name} is latched; release it with: rsal estop {self.name} --release"
            if rpc:
                raise RpcError(ErrorCode.ESTOP, text)
            raise Latched(text)

    def command(self, v: float, w: float) -> None:
        """A velocity command was accepted (after :meth:`check`): restart the timeout."""
        self._last_cmd = self.clock()
        self._moving = v != 0.0 or w != 0.0
        self.timed_out = False

    def stopped(self) -> None:
        """The base was stopped by other means (``rpc/stop``, motor power off): nothing is held."""
        self._moving = False

    def expired(self) -> bool:
        """True once when a moving command has not been refreshed within ``cmd_timeout``: the
        caller stops the motors."""
        if not self._moving or self.cmd_timeout <= 0:
            return False
        age = self.clock() - self._last_cmd
        if age <= self.cmd_timeout:
            return False
        self._moving = False
        self.timed_out = True
        _TIMEOUTS.add(self, age)
        return True

    # ------------------------------------------------------------------ emergency stop
    def press(self) -> None:
        """Latch the emergency stop (the caller stops the motors)."""
        if not self.estop:
            self.log.warning("%s: EMERGENCY STOP latched; motors stopped until rpc/release", self.where)
        self.estop = True
        self._moving = False

    def release(self) -> None:
        if self.estop:
            self.log.warning("%s: emergency stop released", self.where)
        self.estop = False
