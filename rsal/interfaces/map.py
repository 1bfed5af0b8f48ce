"""The ``map`` interface: an occupancy grid (Player's ``map``).

Message :class:`MapData` (the ``rpc/get`` reply; ``data`` carries the MapInfo map, untyped);
proxy :class:`MapDevice`. Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..msgs import MessageError, _Msg, _need, get_float, get_int, get_vec
from .base import Device, Interface

__all__ = ["MapData", "MapDevice", "INTERFACE"]


@dataclass(frozen=True, eq=False)
class MapData(_Msg):
    """map ``rpc/get`` reply: ``cells`` int8 row-major from the *bottom* row, Player's values
    (-1 free, 0 unknown, +1 occupied), ``origin`` the world position of the bottom-left corner."""

    width: int
    height: int
    resolution: float
    origin: tuple[float, float]
    cells: np.ndarray  # int8, shape (height, width)

    def to_dict(self) -> dict:
        return {
            "width": self.width,
            "height": self.height,
            "resolution": self.resolution,
            "origin": list(self.origin),
            "cells": np.ascontiguousarray(self.cells, dtype=np.int8).tobytes(),
        }

    @classmethod
    def from_dict(cls, m: dict) -> MapData:
        w = get_int(m, "width", lo=1)
        h = get_int(m, "height", lo=1)
        raw = _need(m, "cells", True)
        if not isinstance(raw, (bytes, bytearray)) or len(raw) != w * h:
            raise MessageError(f"field 'cells' must be {w * h} bytes (width x height int8)")
        return cls(
            w,
            h,
            get_float(m, "resolution", lo=1e-6),
            get_vec(m, "origin", 2),
            np.frombuffer(raw, dtype=np.int8).reshape(h, w),
        )


class MapDevice(Device):
    """A grid map (Player map): :meth:`get_map` fetches the whole grid once."""

    def get_map(self, timeout: float = 5.0) -> MapData:
        return MapData.from_dict(self.rpc("get", timeout=timeout))


INTERFACE = Interface(
    "map",
    proxy=MapDevice,
    summary=lambda m: (
        f"{m.get('width')}x{m.get('height')} cells of {m.get('resolution')} m" if isinstance(m, dict) else ""
    ),
    doc="an occupancy grid: MapInfo as data, the grid by rpc/get",
)
