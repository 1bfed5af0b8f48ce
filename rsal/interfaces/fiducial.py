"""The ``fiducial`` interface: markers a fiducial finder sees, with their ids and poses (Player's
``fiducial``; Stage's ``fiducial`` finder, which sees models whose ``fiducial_return`` is set).

Message :class:`FiducialData` (``data``, Player's ``player_fiducial_data_t``) of
:class:`FiducialItem` (``id``, ``pose`` in the sensor frame, ``range``/``bearing`` for
convenience); typed geometry :class:`FiducialGeometry` (sensor ``pose``, ``fov``, range limits,
as Stage's fiducial model has them); proxy :class:`Fiducial`. Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..msgs import Describe, MessageError, _Msg, get_float, get_int, get_list, get_vec
from .base import Device, Interface

__all__ = ["FiducialItem", "FiducialData", "FiducialGeometry", "Fiducial", "INTERFACE"]


@dataclass(frozen=True)
class FiducialItem(_Msg):
    """One fiducial seen: ``id`` (-1 when it is seen but cannot be identified, e.g. beyond
    ``range_max_id``), ``pose`` (x, y, yaw) of the marker in the sensor frame (m, rad), and its
    ``range`` (m) and ``bearing`` (rad) from the sensor; on the wire ``range`` and ``bearing`` are
    optional and computed from ``pose`` when absent."""

    id: int
    pose: tuple[float, float, float]
    range: float = 0.0
    bearing: float = 0.0

    @classmethod
    def at(cls, id: int, pose) -> FiducialItem:
        """An item at ``pose`` with its range and bearing filled in."""
        x, y, a = (float(v) for v in pose)
        return cls(int(id), (x, y, a), math.hypot(x, y), math.atan2(y, x))

    @classmethod
    def from_dict(cls, m: Any) -> FiducialItem:
        if not isinstance(m, dict):
            raise MessageError("each fiducial must be a map")
        pose = get_vec(m, "pose", 3)
        return cls(
            get_int(m, "id", lo=-1),
            pose,
            get_float(m, "range", math.hypot(pose[0], pose[1]), lo=0.0),
            get_float(m, "bearing", math.atan2(pose[1], pose[0])),
        )


@dataclass(frozen=True)
class FiducialData(_Msg):
    """fiducial ``data``: every fiducial in view, nearest first by convention (not required)."""

    t: float
    fiducials: list[FiducialItem] = field(default_factory=list)

    @classmethod
    def from_dict(cls, m: dict) -> FiducialData:
        return cls(get_float(m, "t"), get_list(m, "fiducials", FiducialItem.from_dict))


@dataclass(frozen=True)
class FiducialGeometry:
    """fiducial ``rpc/describe`` geometry: the sensor's ``pose`` on the robot, its field of view
    ``fov`` (rad), ``range_min``/``range_max`` (m) within which it sees markers and
    ``range_max_id`` (m) within which it can read their ids (Stage's fiducial model)."""

    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fov: float = math.pi
    range_min: float = 0.0
    range_max: float = 8.0
    range_max_id: float = 5.0

    @classmethod
    def from_describe(cls, d: Describe | dict) -> FiducialGeometry:
        """From a ``describe`` reply (a :class:`~rsal.msgs.Describe` or its ``geometry`` map);
        missing fields take Stage's defaults; raises :class:`~rsal.msgs.MessageError` for a bad one."""
        g = d.geometry if isinstance(d, Describe) else d
        dflt = cls()
        rmax = get_float(g, "range_max", dflt.range_max, lo=0.0)
        return cls(
            get_vec(g, "pose", 3, dflt.pose),
            get_float(g, "fov", dflt.fov, lo=0.0, hi=2 * math.pi),
            get_float(g, "range_min", dflt.range_min, lo=0.0),
            rmax,
            get_float(g, "range_max_id", min(dflt.range_max_id, rmax), lo=0.0),
        )

    def to_dict(self) -> dict:
        return {
            "pose": list(self.pose),
            "fov": self.fov,
            "range_min": self.range_min,
            "range_max": self.range_max,
            "range_max_id": self.range_max_id,
        }

    def to_robot(self, item: FiducialItem) -> tuple[float, float, float]:
        """The pose of a seen fiducial in the robot frame (sensor pose ⊕ item pose)."""
        mx, my, ma = self.pose
        x, y, a = item.pose
        c, s = math.cos(ma), math.sin(ma)
        return (mx + c * x - s * y, my + s * x + c * y, ma + a)


class Fiducial(Device):
    """A fiducial finder: the markers in view with their ids and poses."""

    data_type = FiducialData

    @property
    def fiducials(self) -> list[FiducialItem]:
        return list(self.latest.fiducials) if self.latest is not None else []

    def find(self, fid: int) -> FiducialItem | None:
        """The nearest item with id ``fid`` in the latest data, or None."""
        seen = [f for f in self.fiducials if f.id == fid]
        return min(seen, key=lambda f: f.range) if seen else None

    def nearest(self) -> FiducialItem | None:
        f = self.fiducials
        return min(f, key=lambda i: i.range) if f else None

    def geometry(self, timeout: float = 5.0) -> FiducialGeometry:
        """The device's :class:`FiducialGeometry` (one ``describe`` call, then cached)."""
        g = getattr(self, "_geometry", None)
        if g is None:
            g = self._geometry = FiducialGeometry.from_describe(self.describe(timeout))
        return g


def _summary(m: FiducialData) -> str:
    if not m.fiducials:
        return "no fiducial in view"
    items = sorted(m.fiducials, key=lambda f: f.range)
    return f"{len(items)} in view: " + ", ".join(
        f"#{f.id} {f.range:.2f} m {math.degrees(f.bearing):+.0f} deg" for f in items[:5]
    )


INTERFACE = Interface(
    "fiducial",
    proxy=Fiducial,
    data=FiducialData,
    geometry=FiducialGeometry,
    summary=_summary,
    doc="markers in view: id, pose in the sensor frame, range and bearing",
)
