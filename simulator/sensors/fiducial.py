"""Fiducial finders (Stage 4 ``fiducial`` model; Player's fiducial interface).

Semantics of Stage's ``model_fiducial.cc``: a finder reports every other model whose
``fiducial_return`` is non-zero and whose ``fiducial_key`` equals the finder's ``key``, whose
centre is nearer than ``range_max`` and within ``fov / 2`` of the finder's heading, and that is in
line of sight. Each detection gives the range and bearing of the model's centre, its orientation
relative to the finder, its size, and its id: ``fiducial_return`` when nearer than
``range_max_id``, 0 beyond (Stage's convention). A detection nearer than ``range_min`` is
reported at ``range_min`` (Stage's documentation). Optional Gaussian noise on range and bearing
(``range_noise``, ``bearing_noise``; Stage has none) is drawn from the plug-in's own generator,
seeded from the world's seed.

All finders due in a step are computed together: candidates by vectorised masks over
finders x marked models, then one occlusion ray per remaining pair in a single batched
:func:`~simulator.raycast.cast_fans` call against the walls and the laser-visible bodies. A pair
is occluded when the ray hits something clearly before the target (more than 5 cm before its
bounding circle), as the blobfinder decides.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..raycast import cast_fans
from ..spec import FiducialSpec
from .base import Model, Sensor, mount, wrap

__all__ = ["Fiducial", "Fiducials"]

_OCCLUSION_MARGIN = 0.05  # m before the target's circle where a hit counts as occluding


@dataclass(frozen=True)
class Fiducial:
    """One detected fiducial (Player's ``player_fiducial_item_t``), in the finder's frame."""

    id: int  # the model's fiducial_return, or 0 when beyond range_max_id
    name: str  # the model seen (simulation only)
    range: float  # m, to the model's centre
    bearing: float  # rad, positive to the left
    yaw: float  # rad, the model's heading relative to the finder's
    size: tuple[float, float]  # m, the model's footprint
    time: float  # sim time, s

    @property
    def pose(self) -> tuple[float, float, float]:
        """``(x, y, yaw)`` of the model in the finder's frame (Player's ``pose``)."""
        return (self.range * float(np.cos(self.bearing)), self.range * float(np.sin(self.bearing)), self.yaw)


@dataclass
class _Finder:
    spec: FiducialSpec
    model: Model
    seen: list[Fiducial] = field(default_factory=list)
    time: float = -1.0  # sim time of the last update (-1 before the first)


class Fiducials(Sensor):
    kind = "fiducial"
    spec_field = "fiducials"
    describe_key = "fiducials"

    def __init__(self, world):
        super().__init__(world)
        self._rng = np.random.default_rng([int(world.seed) & 0xFFFFFFFF, 0xF1D])

    def make(self, model: Model, spec: FiducialSpec) -> _Finder:
        return _Finder(spec, model)

    def seen(self, name: str, index: int) -> list[Fiducial]:
        return list(self.device(name, index).seen)

    def updated(self, name: str, index: int) -> float:
        """Sim time of the last update of ``name``'s finder ``index`` (-1 before the first): a
        reader publishes at the finder's rate by comparing it with the time it last published."""
        return self.device(name, index).time

    def rebuild(self) -> None:
        self._marked = [m for m in self.world.models.values() if m.spec.fiducial_return]
        self._ids = np.array([m.spec.fiducial_return for m in self._marked], dtype=np.int64)
        self._keys = np.array([m.spec.fiducial_key for m in self._marked], dtype=np.int64)
        self._rad = np.array([m.radius for m in self._marked], dtype=float)

    def update(self, dt: float) -> None:
        w = self.world
        finders = [f for fs in self.devices.values() for f in fs if self.due(f.spec.interval)]
        if not finders:
            return
        for f in finders:
            f.seen = []
            f.time = w.time
        marked = self._marked
        if not marked:
            return
        tgt = np.array([(m.body.position.x, m.body.position.y, m.body.angle) for m in marked])
        org = np.array([mount(w.poses[f.model.row], f.spec.pose) for f in finders])  # (F, 3)
        d = tgt[None, :, :2] - org[:, None, :2]
        rng_ = np.hypot(d[..., 0], d[..., 1])
        bearing = wrap(np.arctan2(d[..., 1], d[..., 0]) - org[:, 2:3])
        col = np.array([(f.spec.key, f.spec.range_max, f.spec.fov) for f in finders])
        own = np.array([[m is f.model for m in marked] for f in finders], dtype=bool).reshape(len(finders), -1)
        ok = (self._keys[None, :] == col[:, 0:1]) & ~own & (rng_ < col[:, 1:2]) & (np.abs(bearing) <= col[:, 2:3] / 2)
        fi, cj = np.nonzero(ok)
        if fi.size == 0:
            return
        fans = {
            "x": org[fi, 0],
            "y": org[fi, 1],
            "th0": np.arctan2(d[fi, cj, 1], d[fi, cj, 0]),
            "dth": np.zeros(fi.size),
            "n": np.ones(fi.size, dtype=np.int64),
            "rmax": rng_[fi, cj],
            "owner": np.array([finders[k].model.uid for k in fi], dtype=np.int64),
        }
        hit = cast_fans(w.grid, fans, w.circles(), threads=w.spec.threads)
        visible = hit >= rng_[fi, cj] - self._rad[cj] - _OCCLUSION_MARGIN
        for k, j in zip(fi[visible], cj[visible], strict=True):
            f, m = finders[k], marked[j]
            spec = f.spec
            r, b = float(rng_[k, j]), float(bearing[k, j])
            if spec.range_noise > 0:
                r = max(0.0, r + spec.range_noise * float(self._rng.standard_normal()))
            if spec.bearing_noise > 0:
                b = float(wrap(b + spec.bearing_noise * float(self._rng.standard_normal())))
            f.seen.append(
                Fiducial(
                    id=int(self._ids[j]) if rng_[k, j] < spec.range_max_id else 0,
                    name=m.spec.name,
                    range=max(r, spec.range_min),
                    bearing=b,
                    yaw=float(wrap(tgt[j, 2] - org[k, 2])),
                    size=(float(m.spec.size[0]), float(m.spec.size[1])),
                    time=w.time,
                )
            )
        for f in finders:
            f.seen.sort(key=lambda x: x.range)
