"""The occupancy grid the navigation algorithms share, built from a ``map`` device's data.

A :class:`NavGrid` holds Player's map convention (thesis appendix A.2, ``mapfile``): cells row-major
from the *bottom* row, ``-1`` free, ``0`` unknown, ``+1`` occupied, square cells of ``resolution``
metres, ``origin`` the world position of the bottom-left corner, so cell ``(iy, ix)`` covers
``origin + ([ix, ix+1), [iy, iy+1)) * resolution``.

It precomputes the Euclidean distance (metres) from every cell centre to the nearest occupied
cell centre with ``scipy.ndimage.distance_transform_edt``: AMCL's likelihood field and Wavefront's
configuration space (obstacles inflated by the robot radius plus ``safety_dist``) both read it.
Unknown cells count as obstacles for planning (``unknown_is_occupied``) but not for the
distance field of the sensor model, where only occupied cells reflect.

:meth:`NavGrid.shared` returns one grid per distinct map within a process, and :meth:`NavGrid.derived`
keeps what is computed from it once (AMCL's cone-casting grids, its surface distance): a server that
runs 100 navigation stacks on one 1280 x 1280 floorplan otherwise built 200 grids and 100 cone maps,
each with its own distance transform (about 0.5 s and 10 MB apiece). A grid is read-only once built.
"""

from __future__ import annotations

import hashlib
import threading
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import ndimage

__all__ = ["NavGrid", "FREE", "UNKNOWN", "OCCUPIED"]

FREE, UNKNOWN, OCCUPIED = -1, 0, 1

_shared_lock = threading.Lock()
_shared: weakref.WeakValueDictionary = weakref.WeakValueDictionary()  # map digest -> NavGrid


class NavGrid:
    """A static map in world coordinates with a distance field."""

    def __init__(self, cells: np.ndarray, resolution: float, origin: tuple[float, float]):
        c = np.ascontiguousarray(np.asarray(cells, dtype=np.int8))
        if c.ndim != 2 or c.size == 0:
            raise ValueError("map cells must be a non-empty 2-D array")
        if not (np.isfinite(resolution) and resolution > 0):
            raise ValueError(f"map resolution must be a positive number of metres per cell, not {resolution!r}")
        self.cells = c
        self.resolution = float(resolution)
        self.origin = (float(origin[0]), float(origin[1]))
        self.height, self.width = c.shape
        self.occupied = c > 0
        self.free = c < 0
        #: metres from each cell centre to the nearest occupied cell centre (large where none)
        if self.occupied.any():
            self.distance = (ndimage.distance_transform_edt(~self.occupied) * self.resolution).astype(np.float32)
        else:
            self.distance = np.full(c.shape, np.float32(1e6), dtype=np.float32)
        self._derived: dict[Any, Any] = {}
        self._derived_lock = threading.Lock()

    @classmethod
    def from_map(cls, m) -> NavGrid:
        """From an :class:`rsal.msgs.MapData` (``cells``, ``resolution``, ``origin``)."""
        return cls(m.cells, m.resolution, m.origin)

    @classmethod
    def shared(cls, m) -> NavGrid:
        """:meth:`from_map`, but one grid per distinct map in this process (same cells, resolution
        and origin: the same object), kept while any user holds it."""
        c = np.ascontiguousarray(np.asarray(m.cells, dtype=np.int8))
        key = (
            hashlib.blake2b(c.tobytes(), digest_size=16).digest(),
            c.shape,
            float(m.resolution),
            tuple(map(float, m.origin)),
        )
        with _shared_lock:
            g = _shared.get(key)
            if g is None:
                g = cls(c, m.resolution, m.origin)
                _shared[key] = g
            return g

    def derived(self, key, build: Callable[[], Any]) -> Any:
        """What ``build()`` computes from this grid, computed once per ``key`` and kept with the grid
        (every user of a :meth:`shared` grid gets the same object; treat it as read-only)."""
        with self._derived_lock:
            if key not in self._derived:
                self._derived[key] = build()
            return self._derived[key]

    @classmethod
    def from_occupancy(cls, occupied: np.ndarray, resolution: float, origin: tuple[float, float]) -> NavGrid:
        """From a boolean grid (row 0 at the bottom): True occupied, False free."""
        return cls(np.where(np.asarray(occupied, dtype=bool), OCCUPIED, FREE).astype(np.int8), resolution, origin)

    # ------------------------------------------------------------------ geometry
    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` in world metres."""
        x0, y0 = self.origin
        return (x0, x0 + self.width * self.resolution, y0, y0 + self.height * self.resolution)

    def world_to_cell(self, x, y):
        """Integer cell indices ``(ix, iy)`` of world points (arrays or scalars); may be out of range."""
        ix = np.floor((np.asarray(x, dtype=np.float64) - self.origin[0]) / self.resolution).astype(np.int64)
        iy = np.floor((np.asarray(y, dtype=np.float64) - self.origin[1]) / self.resolution).astype(np.int64)
        return ix, iy

    def cell_to_world(self, ix, iy):
        """World coordinates of cell centres."""
        return (
            self.origin[0] + (np.asarray(ix) + 0.5) * self.resolution,
            self.origin[1] + (np.asarray(iy) + 0.5) * self.resolution,
        )

    def in_bounds_cell(self, ix, iy):
        return (ix >= 0) & (ix < self.width) & (iy >= 0) & (iy < self.height)

    def in_bounds(self, x, y):
        ix, iy = self.world_to_cell(x, y)
        return self.in_bounds_cell(ix, iy)

    def clearance(self, x, y, outside: float = 0.0):
        """Metres from world points to the nearest occupied cell; ``outside`` off the map."""
        ix, iy = self.world_to_cell(x, y)
        inside = self.in_bounds_cell(ix, iy)
        d = self.distance[np.clip(iy, 0, self.height - 1), np.clip(ix, 0, self.width - 1)]
        out = np.where(inside, d, np.float32(outside))
        return out if np.ndim(out) else float(out)

    def free_cells(self, clearance: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """``(ix, iy)`` of free cells at least ``clearance`` metres from any obstacle."""
        iy, ix = np.nonzero(self.free & (self.distance >= clearance))
        return ix, iy
