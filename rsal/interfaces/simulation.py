"""The ``simulation`` interface: the simulator itself (Player's ``simulation``; the thesis's
``setPositionOf``).

Message :class:`SimulationData` (``data``); proxy :class:`Simulation` (model poses by name, pause,
step, reset). Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..data import Position
from ..msgs import _Msg, get_bool, get_float, get_int
from .base import Device, Interface

__all__ = ["SimulationData", "Simulation", "INTERFACE"]


@dataclass(frozen=True)
class SimulationData(_Msg):
    """simulation ``data``: simulated time, steps, paused flag, achieved real-time factor."""

    t: float
    steps: int
    paused: bool
    rtf: float = 0.0

    @classmethod
    def from_dict(cls, m: dict) -> SimulationData:
        return cls(get_float(m, "t"), get_int(m, "steps", lo=0), get_bool(m, "paused"), get_float(m, "rtf", 0.0))


class Simulation(Device):
    """The simulation interface (thesis ``setPositionOf``): poses of models by name."""

    data_type = SimulationData

    def get_pose(self, name: str) -> Position:
        return Position(*self.rpc("get_pose", name=name)["pose"])

    def set_pose(self, name: str, pose: Position) -> None:
        self.rpc("set_pose", name=name, pose=list(pose.as_tuple()))

    def models(self) -> dict:
        return self.rpc("models")

    def batteries(self) -> dict[str, dict]:
        """Every robot's true battery: ``{name: {battery, capacity, fraction, charging, charger, empty, lowest,
        flat, charged}}`` (``docs/protocol.md``; the record since the world was built)."""
        return dict(self.rpc("batteries")["robots"])

    def pause(self, paused: bool = True) -> bool:
        return bool(self.rpc("pause", paused=paused)["paused"])

    def step(self, n: int = 1) -> dict:
        return self.rpc("step", n=n)

    def reset(self) -> dict:
        return self.rpc("reset")


INTERFACE = Interface(
    "simulation",
    proxy=Simulation,
    data=SimulationData,
    summary=lambda m: f"t={m.t:.2f} s steps={m.steps}{' paused' if m.paused else ''} rtf={m.rtf:.1f}",
    doc="the simulator: clock, ground truth poses, pause/step/reset",
)
