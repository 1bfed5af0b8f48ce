"""Blobfinders: colour-blob cameras (Stage 4 ``blobfinder`` model; Player's blobfinder interface).

A blobfinder sees every other model with ``blob_return`` whose colour it looks for, inside its
range and horizontal field of view. Occlusion is one ray from the camera to each candidate's
centre, all candidates of a camera in one batched :func:`~simulator.raycast.cast_fans` call: the
candidate is hidden when something is hit well before it (unless what is hit is the candidate
itself). A blob's image box comes from a pinhole camera 0.3 m above the floor (thesis A.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..raycast import cast_fans
from ..spec import BlobfinderSpec
from .base import Model, Sensor, mount, wrap

__all__ = ["Blob", "Blobfinders"]

CAMERA_HEIGHT = 0.3  # m above the floor


@dataclass(frozen=True)
class Blob:
    """A coloured blob seen by a blobfinder (Player's ``player_blobfinder_blob``)."""

    name: str  # the model seen (simulation only; a real camera does not know it)
    color: tuple[int, int, int]
    x: int  # image centre column, pixels
    y: int  # image centre row, pixels
    left: int
    right: int
    top: int
    bottom: int
    area: int  # pixels
    range: float  # m
    bearing: float  # rad, positive to the left


@dataclass
class _Finder:
    spec: BlobfinderSpec
    model: Model
    blobs: list[Blob] = field(default_factory=list)
    stamp: float = 0.0


class Blobfinders(Sensor):
    kind = "blobfinder"
    spec_field = "blobfinders"
    describe_key = "blobfinders"

    def make(self, model: Model, spec: BlobfinderSpec) -> _Finder:
        return _Finder(spec, model)

    def blobs(self, name: str, index: int) -> list[Blob]:
        return list(self.device(name, index).blobs)

    def rebuild(self) -> None:
        self._cands = [m for m in self.world.models.values() if m.spec.blob_return]
        self._crad = np.array([m.radius for m in self._cands])
        self._ccol = np.array([m.spec.color for m in self._cands], dtype=np.int64).reshape(-1, 3)

    def update(self, dt: float) -> None:
        cands = self._cands
        finders = [f for fs in self.devices.values() for f in fs]
        if not cands:
            for f in finders:
                f.blobs, f.stamp = [], self.world.time
            return
        cxy = np.array([(m.body.position.x, m.body.position.y) for m in cands])
        circles = None
        for f in finders:
            if not self.due(f.spec.interval):
                continue
            if circles is None:
                circles = self.world.circles()
            f.blobs = self._see(f, cxy, circles)
            f.stamp = self.world.time

    def _see(self, f: _Finder, cxy, circles) -> list[Blob]:
        spec, m, cands, crad, ccol = f.spec, f.model, self._cands, self._crad, self._ccol
        ox, oy, oa = mount(self.world.poses[m.row], spec.pose)
        d = cxy - (ox, oy)
        rng_ = np.hypot(d[:, 0], d[:, 1])
        bearing = wrap(np.arctan2(d[:, 1], d[:, 0]) - oa)
        half_w = np.arctan2(crad, np.maximum(rng_, 1e-6))
        self_mask = np.array([c is m for c in cands])
        if spec.colors:
            want = np.array(spec.colors, dtype=np.int64)
            colour_ok = (ccol[:, None, :] == want[None, :, :]).all(axis=2).any(axis=1)
        else:
            colour_ok = np.ones(len(cands), dtype=bool)
        ok = (
            colour_ok
            & ~self_mask
            & (rng_ <= spec.range_max)
            & (np.abs(bearing) - half_w <= spec.fov / 2)
            & (rng_ > 1e-6)
        )
        idx = np.nonzero(ok)[0]
        if idx.size == 0:
            return []
        # Occlusion: one ray to each candidate's centre; blocked if something is hit well before it.
        fans = {
            "x": np.full(idx.size, ox),
            "y": np.full(idx.size, oy),
            "th0": np.arctan2(d[idx, 1], d[idx, 0]),
            "dth": np.zeros(idx.size),
            "n": np.ones(idx.size, dtype=np.int64),
            "rmax": rng_[idx],
            "owner": np.full(idx.size, m.uid, dtype=np.int64),
        }
        hit = cast_fans(self.world.grid, fans, circles, threads=self.world.spec.threads)
        w_px, h_px = spec.image
        fov = spec.fov
        vfov = fov * h_px / w_px
        blobs = []
        for j, t in zip(idx, hit, strict=True):
            visible_to = rng_[j] - crad[j] - 0.05
            if t < visible_to and not _hit_is_target(cands[j], t, rng_[j], crad[j]):
                continue
            bx = w_px / 2 - bearing[j] / (fov / 2) * (w_px / 2)
            hw = half_w[j] / (fov / 2) * (w_px / 2)
            left, right = int(max(0, math.floor(bx - hw))), int(min(w_px - 1, math.ceil(bx + hw)))
            height = float(cands[j].spec.size[2]) or 2 * crad[j]
            top_ang = math.atan2(CAMERA_HEIGHT, rng_[j])  # angle below the horizon to the floor
            bot_ang = math.atan2(CAMERA_HEIGHT - height, rng_[j])
            ty = h_px / 2 + bot_ang / (vfov / 2) * (h_px / 2)
            by = h_px / 2 + top_ang / (vfov / 2) * (h_px / 2)
            top, bottom = int(max(0, math.floor(ty))), int(min(h_px - 1, math.ceil(by)))
            if right < left or bottom < top:
                continue
            blobs.append(
                Blob(
                    name=cands[j].spec.name,
                    color=tuple(int(v) for v in ccol[j]),  # type: ignore[arg-type]
                    x=int(round(min(max(bx, 0), w_px - 1))),
                    y=int(round((top + bottom) / 2)),
                    left=left,
                    right=right,
                    top=top,
                    bottom=bottom,
                    area=int((right - left + 1) * (bottom - top + 1)),
                    range=float(rng_[j]),
                    bearing=float(bearing[j]),
                )
            )
        blobs.sort(key=lambda b: b.range)
        return blobs


def _hit_is_target(model: Model, t: float, rng_: float, rad: float) -> bool:
    # A laser-visible target is itself hit at about range - radius.
    return bool(model.spec.laser_return) and t >= rng_ - rad - 0.05
