"""Bumpers: rings of binary touch sensors (Stage 4 ``bumper`` model; Player's bumper interface).

Semantics of Stage's ``model_bumper.cc``: a bumper is a set of straight segments, each centred at
its pose and lying across the direction the pose faces, ``length`` metres long; a segment reads 1
while something other than its own robot crosses it. Here that is judged on the simulator's
ground truth, batched over every segment of every robot due this step:

* walls: one ray along each segment through the compiled caster
  (:func:`simulator.raycast.cast_fans`, static map only; the walls pymunk collides with are the
  same grid cells), pressed when it hits before the segment's end (or starts inside a wall);
* bodies with ``obstacle_return``: their exact pymunk boxes; segment/body pairs near enough to
  touch come from a k-d tree (:class:`scipy.spatial.cKDTree`), then one vectorised slab test
  (segment against the box in the box's frame) decides each pair.

Bumpers usually sit a centimetre or two outside the body, as real bumper skirts do: the robot's
box stops at a wall (within pymunk's collision slop of 2 mm), so a segment on the hull itself
would flicker.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..raycast import cast_fans
from ..spec import BumperSpec
from .base import ReadingSensor

__all__ = ["BumperReading", "Bumpers"]


@dataclass(frozen=True)
class BumperReading:
    """One reading of a bumper ring (Player's ``player_bumper_data_t``): ``pressed[i]`` is 1 while
    segment ``i`` touches an obstacle."""

    pressed: np.ndarray  # uint8, read-only
    time: float  # sim time, s
    spec: BumperSpec


class Bumpers(ReadingSensor):
    kind = "bumper"
    spec_field = "bumpers"
    describe_key = "bumpers"

    def __init__(self, world):
        super().__init__(world)
        self._solid_for: object = None  # the world's body list the solid table below was made from

    def describe(self, name: str) -> list[tuple[str, int]]:
        return [(b.name, len(b.segments)) for b in self.devices.get(name, [])]

    def rebuild(self) -> None:
        """One row per segment: robot row, both ends in the robot frame, length; one entry per
        bumper: its robot, index, first segment and segment count."""
        rows, ends, lengths, slices = [], [], [], []
        for m in self.world.robots:
            for bi, b in enumerate(self.devices.get(m.spec.name, [])):
                slices.append((m.spec.name, bi, len(rows), len(b.segments)))
                px, py, pa = b.pose
                for seg in b.segments:
                    sx, sy, sa = seg.pose
                    cx = px + math.cos(pa) * sx - math.sin(pa) * sy
                    cy = py + math.sin(pa) * sx + math.cos(pa) * sy
                    along = pa + sa + math.pi / 2  # the segment lies across the way it faces
                    hx, hy = 0.5 * seg.length * math.cos(along), 0.5 * seg.length * math.sin(along)
                    rows.append(m.row)
                    ends.append((cx - hx, cy - hy, cx + hx, cy + hy))
                    lengths.append(seg.length)
        self._rows = np.asarray(rows, dtype=np.int64)
        self._ends = np.asarray(ends, dtype=float).reshape(-1, 4)
        self._len = np.asarray(lengths, dtype=float)
        self._slices = slices
        self._uids = np.array([m.uid for m in self.world.robots], dtype=np.int64)

    def update(self, dt: float) -> None:
        w = self.world
        due = [s for s in self._slices if self.due(self.devices[s[0]][s[1]].interval)]
        if not due or self._rows.size == 0:
            return
        seg = np.concatenate([np.arange(first, first + n) for _, _, first, n in due])
        pose = w.poses[self._rows[seg]]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        e = self._ends[seg]
        p0 = np.stack([pose[:, 0] + c * e[:, 0] - s * e[:, 1], pose[:, 1] + s * e[:, 0] + c * e[:, 1]], 1)
        p1 = np.stack([pose[:, 0] + c * e[:, 2] - s * e[:, 3], pose[:, 1] + s * e[:, 2] + c * e[:, 3]], 1)
        owner = self._uids[self._rows[seg]]
        length = self._len[seg]
        pressed = np.zeros(seg.size, dtype=bool)
        if w.grid is not None:
            d = p1 - p0
            fans = {
                "x": p0[:, 0],
                "y": p0[:, 1],
                "th0": np.arctan2(d[:, 1], d[:, 0]),
                "dth": np.zeros(seg.size),
                "n": np.ones(seg.size, dtype=np.int64),
                "rmax": length,
                "owner": owner,
            }
            pressed |= cast_fans(w.grid, fans, threads=w.spec.threads) < length
        pressed |= self._touch_bodies(p0, p1, owner, length)
        out = pressed.astype(np.uint8)
        out.flags.writeable = False
        k = 0
        for name, bi, _, n in due:
            self.readings[name][bi] = BumperReading(out[k : k + n], w.time, self.devices[name][bi])
            k += n

    def _solid_table(self):
        """The bodies bumpers feel (``obstacle_return``), cached while the world's body list lasts."""
        models, xy = self.world.space_poses()
        if self._solid_for is not models:
            solid = np.array([bool(m and m.spec.obstacle_return) for m in models], dtype=bool)
            half = np.array([(0.5 * m.spec.size[0], 0.5 * m.spec.size[1]) if m else (0.0, 0.0) for m in models])
            uid = np.array([m.uid if m else -1 for m in models], dtype=np.int64)
            self._solid = (np.nonzero(solid)[0], half.reshape(-1, 2), uid)
            self._solid_for = models
        idx, half, uid = self._solid
        return xy[idx], half[idx], uid[idx]

    def _touch_bodies(self, p0, p1, owner, length) -> np.ndarray:
        pressed = np.zeros(len(p0), dtype=bool)
        xya, half, uid = self._solid_table()
        if len(uid) == 0:
            return pressed
        mid = 0.5 * (p0 + p1)
        reach = 0.5 * float(length.max()) + float(np.hypot(half[:, 0], half[:, 1]).max())
        pairs = cKDTree(mid).sparse_distance_matrix(cKDTree(xya[:, :2]), reach, output_type="ndarray")
        i, j = pairs["i"], pairs["j"]
        keep = uid[j] != owner[i]
        i, j = i[keep], j[keep]
        if i.size == 0:
            return pressed
        # Both ends in the body's frame, then the slab test of the segment against its box.
        ca, sa = np.cos(xya[j, 2]), np.sin(xya[j, 2])
        hit = np.ones(i.size, dtype=bool)
        t0, t1 = np.zeros(i.size), np.ones(i.size)
        for axis in range(2):
            a0 = _to_frame(p0[i], xya[j], ca, sa, axis)
            a1 = _to_frame(p1[i], xya[j], ca, sa, axis)
            h = half[j, axis]
            d = a1 - a0
            flat = np.abs(d) < 1e-12
            hit &= ~flat | (np.abs(a0) <= h)
            safe = np.where(flat, 1.0, d)
            lo, hi = (-h - a0) / safe, (h - a0) / safe
            t0 = np.where(flat, t0, np.maximum(t0, np.minimum(lo, hi)))
            t1 = np.where(flat, t1, np.minimum(t1, np.maximum(lo, hi)))
        hit &= t0 <= t1
        np.logical_or.at(pressed, i[hit], True)
        return pressed


def _to_frame(p, pose, ca, sa, axis):
    """Coordinate ``axis`` (0: x, 1: y) of world points ``p`` in the frames of bodies at ``pose``."""
    dx, dy = p[:, 0] - pose[:, 0], p[:, 1] - pose[:, 1]
    return ca * dx + sa * dy if axis == 0 else -sa * dx + ca * dy
