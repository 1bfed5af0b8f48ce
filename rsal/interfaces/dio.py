"""The ``dio`` interface: digital inputs and outputs (Player's ``dio``).

Messages :class:`DioData` (``data``) and :class:`DioCmd` (``cmd``); proxy :class:`Dio`.
Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..msgs import _Msg, get_float, get_int
from .base import Device, Interface

__all__ = ["DioData", "DioCmd", "Dio", "INTERFACE"]


@dataclass(frozen=True)
class DioData(_Msg):
    """dio ``data``: ``count`` digital inputs as the bit field ``bits`` (input i is bit i) and the
    current digital outputs ``outputs``. Player's ``player_dio_data``."""

    t: float
    count: int
    bits: int
    outputs: int = 0

    @classmethod
    def from_dict(cls, m: dict) -> DioData:
        count = get_int(m, "count", lo=0, hi=32)
        hi = (1 << count) - 1
        return cls(get_float(m, "t"), count, get_int(m, "bits", lo=0, hi=hi), get_int(m, "outputs", 0, lo=0, hi=0xFFFF))


@dataclass(frozen=True)
class DioCmd(_Msg):
    """dio ``cmd``: set the digital outputs selected by ``mask`` to the matching bits of ``bits``."""

    bits: int
    mask: int = 0xFF

    @classmethod
    def from_dict(cls, m: dict) -> DioCmd:
        return cls(get_int(m, "bits", lo=0, hi=0xFF), get_int(m, "mask", 0xFF, lo=0, hi=0xFF))


class Dio(Device):
    """Digital I/O: the inputs as bits, outputs set with a mask. Its ``latest`` stays the plain
    map of the :class:`DioData` fields (clients index it, ``latest["bits"]``), as before the
    interface had a proxy of its own."""

    def input(self, i: int) -> bool | None:
        """Input ``i`` (None before the first data)."""
        m = self.latest
        return bool(int(m.get("bits", 0)) >> i & 1) if isinstance(m, dict) else None

    def set_outputs(self, bits: int, mask: int = 0xFF) -> None:
        """Set the outputs selected by ``mask`` to the matching bits of ``bits``."""
        self.send(DioCmd(int(bits), int(mask)))


INTERFACE = Interface(
    "dio",
    proxy=Dio,
    data=DioData,
    cmds=(DioCmd,),
    summary=lambda m: f"in={m.bits:0{max(m.count, 1)}b} out={m.outputs:08b}",
    doc="digital inputs and outputs",
)
