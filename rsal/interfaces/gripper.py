"""The ``gripper`` interface: a Pioneer paddle gripper with a lift (Player's ``gripper``).

Messages: :class:`GripperData` (``data``), :class:`GripperCmd` (``cmd``); proxy :class:`Gripper`,
whose actions return futures resolved by the reported state. Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass

from ..msgs import _Msg, get_float, get_int, get_str
from .base import Device, Interface

__all__ = ["GRIPPER_ACTIONS", "GripperCmd", "GripperData", "Gripper", "INTERFACE"]


GRIPPER_ACTIONS = ("open", "close", "stop", "up", "down")


@dataclass(frozen=True)
class GripperCmd(_Msg):
    """gripper ``cmd``: one of open, close, stop (paddles), up, down (lift)."""

    action: str

    @classmethod
    def from_dict(cls, m: dict) -> GripperCmd:
        return cls(get_str(m, "action", choices=GRIPPER_ACTIONS))


@dataclass(frozen=True)
class GripperData(_Msg):
    """gripper ``data``: paddles open/closed/opening/closing, lift down/up/raising/lowering,
    beams bit 0 inner and bit 1 outer, ``stored`` objects held (0 or 1) and what is carried."""

    t: float
    paddles: str
    lift: str
    beams: int
    stored: int
    carrying: str | None = None

    @classmethod
    def from_dict(cls, m: dict) -> GripperData:
        return cls(
            get_float(m, "t"),
            get_str(m, "paddles", choices=("open", "closed", "opening", "closing", "error")),
            get_str(m, "lift", "down", choices=("down", "up", "raising", "lowering", "error")),
            get_int(m, "beams", 0, lo=0, hi=3),
            get_int(m, "stored", 0, lo=0),
            get_str(m, "carrying", optional=True),
        )


class Gripper(Device):
    """A gripper: ``open()``/``close()``/``lift_up()``/``lift_down()`` return futures that resolve
    with the gripper state when the paddles or lift reach the requested position."""

    data_type = GripperData

    def __init__(self, fabric, addr):
        self._waiters: list[tuple[Callable[[GripperData], bool], Future, float]] = []
        self._wlock = threading.Lock()
        super().__init__(fabric, addr)

    @property
    def state(self) -> GripperData | None:
        return self.latest

    @property
    def carrying(self) -> bool:
        return bool(self.latest and self.latest.stored)

    @property
    def beams(self) -> int:
        return self.latest.beams if self.latest else 0

    def _after_data(self, msg) -> None:
        now = time.monotonic()
        with self._wlock:
            keep = []
            for cond, fut, deadline in self._waiters:
                if fut.done():
                    continue
                if cond(msg):
                    fut.set_result(msg)
                elif now > deadline:
                    fut.set_exception(TimeoutError(f"{self.addr}: gripper did not get there in time"))
                else:
                    keep.append((cond, fut, deadline))
            self._waiters = keep

    def _command(self, action: str, cond, timeout: float) -> Future:
        fut: Future = Future()
        with self._wlock:
            self._waiters.append((cond, fut, time.monotonic() + timeout))
        self.send(GripperCmd(action))
        return fut

    def open(self, timeout: float = 10.0) -> Future:
        return self._command("open", lambda m: m.paddles == "open", timeout)

    def close(self, timeout: float = 10.0) -> Future:
        return self._command("close", lambda m: m.paddles == "closed", timeout)

    def lift_up(self, timeout: float = 10.0) -> Future:
        return self._command("up", lambda m: m.lift == "up", timeout)

    def lift_down(self, timeout: float = 10.0) -> Future:
        return self._command("down", lambda m: m.lift == "down", timeout)

    def stop(self) -> None:
        self.send(GripperCmd("stop"))


INTERFACE = Interface(
    "gripper",
    proxy=Gripper,
    data=GripperData,
    cmds=(GripperCmd,),
    event="{event: state, paddles, lift}",
    summary=lambda m: f"paddles={m.paddles} lift={m.lift} beams={m.beams} carrying={m.carrying or '-'}",
    doc="paddles and lift; actions resolve on the reported state",
)
