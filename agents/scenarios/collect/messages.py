"""The services of Find and Collect (thesis 4.2.2), beyond the shared ones of :mod:`agents.services`.

Bodies without a schema in :mod:`agents.services`; fields validated here and by the agents:

``blob``       explorer → all: ``robot`` str, ``color`` int 0xRRGGBB, ``x``, ``y`` m (map frame). The
               thesis's ReceiveNewGoalService report of a new blob (:class:`BlobReport`). Explorers
               repeat their blobs every ``repeat_every`` seconds, so a master that starts late still
               learns them.
``collect``    master → collector: ``to``, ``blob`` id, ``x``, ``y`` m: fetch that blob home.
``collected``  collector → master: ``to``, ``blob``, ``ok`` bool, ``x``, ``y`` (where it was put
               down, or where the collector gave up), ``reason`` str (empty when ok).

When a blob is home the master publishes ``Outcome("delivered", subject=<blob id>, ...)``. Also the
checks of the agents' keyword arguments that the scenario's agents share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rsal.data import Position
from rsal.msgs import get_float, get_int, get_str

__all__ = ["ALLOCATIONS", "BLOB", "COLLECT", "COLLECTED", "BlobReport", "check_number", "check_point"]

BLOB = "blob"
COLLECT = "collect"
COLLECTED = "collected"
ALLOCATIONS = ("direct", "contract_net", "dispatch")


def check_number(agent_id: str, name: str, value, lo: float = 0.0, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not lo < value <= hi or math.isnan(value):
        raise ValueError(f"agent {agent_id}: {name} {value!r} must be a number in ({lo:g}, {hi:g}]")
    return float(value)


def check_point(agent_id: str, name: str, value) -> Position | None:
    if value is None:
        return None
    try:
        vals = list(value)
        if len(vals) not in (2, 3):
            raise ValueError
        return Position.from_degrees(*vals) if len(vals) == 3 else Position(*vals)
    except (TypeError, ValueError):
        raise ValueError(f"agent {agent_id}: {name} {value!r} must be [x, y] or [x, y, degrees]") from None


@dataclass(frozen=True)
class BlobReport:
    """A ``blob`` message body: robot ``robot`` saw a blob of ``color`` at (``x``, ``y``), map frame."""

    robot: str
    color: int
    x: float
    y: float

    @classmethod
    def from_dict(cls, m: dict) -> BlobReport:
        return cls(get_str(m, "robot"), get_int(m, "color", 0, lo=0, hi=0xFFFFFF), get_float(m, "x"), get_float(m, "y"))

    def to_dict(self) -> dict:
        return {"robot": self.robot, "color": self.color, "x": self.x, "y": self.y}
