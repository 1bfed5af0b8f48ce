"""The ``bumper`` interface: contact switches around a robot (Player's ``bumper``; a Pioneer's
bumper rings, Stage's ``bumper`` model).

Message :class:`BumperData` (``data``, Player's ``player_bumper_data_t``: one 0/1 per segment);
typed geometry :class:`BumperGeometry` (Player's ``player_bumper_geom_t``: the mount ``pose`` and
per segment its ``pose`` and ``length``); proxy :class:`Bumper`. Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..msgs import Describe, MessageError, _Msg, _need, get_float, get_vec
from .base import Device, Interface

__all__ = ["BumperData", "BumperSegment", "BumperGeometry", "Bumper", "INTERFACE"]


@dataclass(frozen=True)
class BumperData(_Msg):
    """bumper ``data``: ``bumpers[i]`` is 1 while segment ``i`` is pressed, else 0."""

    t: float
    bumpers: tuple[int, ...] = ()

    @classmethod
    def from_dict(cls, m: dict) -> BumperData:
        raw = _need(m, "bumpers", True)
        if not isinstance(raw, (list, tuple)) or any(type(b) is not int or b not in (0, 1) for b in raw):
            raise MessageError("field 'bumpers' must be a list of 0 or 1, one per segment")
        return cls(get_float(m, "t"), tuple(raw))

    @property
    def pressed(self) -> tuple[int, ...]:
        """Indices of the pressed segments."""
        return tuple(i for i, b in enumerate(self.bumpers) if b)


@dataclass(frozen=True)
class BumperSegment:
    """One bumper segment: ``pose`` (x, y, yaw) of its centre in the bumper's frame, the segment
    lying across the yaw direction; ``length`` (m); ``radius`` of its arc (m, 0 for a straight one)."""

    pose: tuple[float, float, float]
    length: float
    radius: float = 0.0

    @classmethod
    def from_dict(cls, m: Any) -> BumperSegment:
        if not isinstance(m, dict):
            raise MessageError("each bumper segment must be a map")
        return cls(get_vec(m, "pose", 3), get_float(m, "length", lo=0.0), get_float(m, "radius", 0.0, lo=0.0))

    def to_dict(self) -> dict:
        return {"pose": list(self.pose), "length": self.length, "radius": self.radius}


@dataclass(frozen=True)
class BumperGeometry:
    """bumper ``rpc/describe`` geometry: ``pose`` of the bumper array on the robot and its ``segments``."""

    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    segments: tuple[BumperSegment, ...] = ()

    @classmethod
    def from_describe(cls, d: Describe | dict) -> BumperGeometry:
        """From a ``describe`` reply (a :class:`~rsal.msgs.Describe` or its ``geometry`` map);
        raises :class:`~rsal.msgs.MessageError` naming the field that does not fit."""
        g = d.geometry if isinstance(d, Describe) else d
        raw = g.get("segments", [])
        if not isinstance(raw, list):
            raise MessageError("bumper geometry: 'segments' must be a list")
        return cls(get_vec(g, "pose", 3, (0.0, 0.0, 0.0)), tuple(BumperSegment.from_dict(s) for s in raw))

    def to_dict(self) -> dict:
        return {"pose": list(self.pose), "segments": [s.to_dict() for s in self.segments]}

    def segment_poses(self) -> np.ndarray:
        """``(k, 3)`` segment centre poses in the robot frame."""
        mx, my, ma = self.pose
        p = np.array([s.pose for s in self.segments], dtype=float).reshape(-1, 3)
        c, s = math.cos(ma), math.sin(ma)
        return np.column_stack([mx + c * p[:, 0] - s * p[:, 1], my + s * p[:, 0] + c * p[:, 1], ma + p[:, 2]])

    def segment_ends(self) -> np.ndarray:
        """``(k, 2, 2)`` end points of each (straight) segment in the robot frame."""
        t = self.segment_poses()
        half = np.array([s.length / 2 for s in self.segments], dtype=float)
        dx, dy = -np.sin(t[:, 2]) * half, np.cos(t[:, 2]) * half  # across the segment's facing
        return np.stack(
            [np.column_stack([t[:, 0] - dx, t[:, 1] - dy]), np.column_stack([t[:, 0] + dx, t[:, 1] + dy])], 1
        )


class Bumper(Device):
    """A bumper array: which segments are pressed."""

    data_type = BumperData

    @property
    def bumpers(self) -> tuple[int, ...]:
        return self.latest.bumpers if self.latest is not None else ()

    @property
    def pressed(self) -> tuple[int, ...]:
        """Indices of the pressed segments (empty before the first data)."""
        return self.latest.pressed if self.latest is not None else ()

    @property
    def any_pressed(self) -> bool:
        return bool(self.pressed)

    def geometry(self, timeout: float = 5.0) -> BumperGeometry:
        """The device's :class:`BumperGeometry` (one ``describe`` call, then cached)."""
        g = getattr(self, "_geometry", None)
        if g is None:
            g = self._geometry = BumperGeometry.from_describe(self.describe(timeout))
        return g


def _summary(m: BumperData) -> str:
    p = m.pressed
    return f"pressed {', '.join(map(str, p))} of {len(m.bumpers)}" if p else f"none of {len(m.bumpers)} pressed"


INTERFACE = Interface(
    "bumper",
    proxy=Bumper,
    data=BumperData,
    geometry=BumperGeometry,
    summary=_summary,
    doc="contact switches: one 0/1 per segment",
)
