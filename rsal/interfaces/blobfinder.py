"""The ``blobfinder`` interface: coloured blobs in a camera image (Player's ``blobfinder``).

Messages: :class:`BlobfinderData` (``data``) of :class:`BlobData`; proxy :class:`Blobfinder`.
Wire format: ``docs/protocol.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from ..data import BlobfinderBlob
from ..msgs import MessageError, _Msg, get_float, get_int, get_list
from .base import Device, Interface

__all__ = ["BlobData", "BlobfinderData", "Blobfinder", "INTERFACE"]


@dataclass(frozen=True)
class BlobData(_Msg):
    """One blob: colour 0xRRGGBB, image box and centre (pixels), area, range (m), bearing (rad)."""

    id: int
    color: int
    x: int
    y: int
    left: int
    right: int
    top: int
    bottom: int
    area: int
    range: float
    bearing: float

    @classmethod
    def from_dict(cls, m: dict) -> BlobData:
        if not isinstance(m, dict):
            raise MessageError("each blob must be a map")
        ints = {k: get_int(m, k, 0) for k in ("id", "x", "y", "left", "right", "top", "bottom", "area")}
        return cls(
            color=get_int(m, "color", lo=0, hi=0xFFFFFF),
            range=get_float(m, "range"),
            bearing=get_float(m, "bearing", 0.0),
            **ints,
        )


@dataclass(frozen=True)
class BlobfinderData(_Msg):
    t: float
    width: int
    height: int
    blobs: list[BlobData] = field(default_factory=list)

    @classmethod
    def from_dict(cls, m: dict) -> BlobfinderData:
        return cls(
            get_float(m, "t"),
            get_int(m, "width", lo=0),
            get_int(m, "height", lo=0),
            get_list(m, "blobs", BlobData.from_dict),
        )

    def to_dict(self) -> dict:
        return {"t": self.t, "width": self.width, "height": self.height, "blobs": [asdict(b) for b in self.blobs]}


class Blobfinder(Device):
    data_type = BlobfinderData

    @property
    def blobs(self) -> list[BlobfinderBlob]:
        m = self.latest
        if m is None:
            return []
        return [
            BlobfinderBlob(b.id, b.color, b.area, b.x, b.y, b.left, b.right, b.top, b.bottom, b.range, b.bearing)
            for b in m.blobs
        ]


INTERFACE = Interface(
    "blobfinder",
    proxy=Blobfinder,
    data=BlobfinderData,
    summary=lambda m: f"{len(m.blobs)} blob(s)" + "".join(f" #{b.color:06x}@{b.range:.2f}m" for b in m.blobs[:4]),
    doc="coloured blobs: image box, range and bearing",
)
