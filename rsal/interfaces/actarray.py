"""The ``actarray`` interface: an array of actuators (Player's ``actarray``).

Message :class:`ActArrayData` (``data``); proxy :class:`ActArray`. Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..msgs import MessageError, _Msg, _need, get_float, get_str, get_vec
from .base import Device, Interface

__all__ = ["ACTUATOR_STATES", "ActArrayData", "ActArray", "INTERFACE"]


ACTUATOR_STATES = ("idle", "moving", "braked", "stalled")


@dataclass(frozen=True)
class ActArrayData(_Msg):
    """actarray ``data``: per actuator its position (m for a linear joint, rad for a rotary one),
    speed and state (idle, moving, braked, stalled). Player's ``player_actarray_data``."""

    t: float
    positions: tuple[float, ...]
    speeds: tuple[float, ...]
    states: tuple[str, ...]

    @classmethod
    def from_dict(cls, m: dict) -> ActArrayData:
        pos, spd, st = (_need(m, k, True) for k in ("positions", "speeds", "states"))
        if not all(isinstance(v, (list, tuple)) for v in (pos, spd, st)) or not len(pos) == len(spd) == len(st):
            raise MessageError("fields 'positions', 'speeds' and 'states' must be lists of the same length")
        n = len(pos)
        return cls(
            get_float(m, "t"),
            get_vec(m, "positions", n),
            get_vec(m, "speeds", n),
            tuple(get_str({"state": s}, "state", choices=ACTUATOR_STATES) for s in st),
        )


class ActArray(Device):
    """Actuators' positions, speeds and states. Its ``latest`` stays the plain map of the
    :class:`ActArrayData` fields (clients index it), as before the interface had a proxy of its own."""

    @property
    def positions(self) -> tuple[float, ...]:
        m = self.latest
        return tuple(m.get("positions", ())) if isinstance(m, dict) else ()


INTERFACE = Interface(
    "actarray",
    proxy=ActArray,
    data=ActArrayData,
    summary=lambda m: " ".join(f"{p:.2f}:{s}" for p, s in zip(m.positions, m.states, strict=False)),
    doc="per actuator: position, speed, state",
)
