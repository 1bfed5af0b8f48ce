"""Occupancy grid of a floorplan bitmap, with its Euclidean distance field.

The grid follows Player's ``mapfile`` driver (thesis appendix A.2): a bitmap where dark pixels are
occupied, a resolution in metres per pixel and an ``origin``, the world position of the bitmap's
bottom-left corner. Row 0 of :attr:`GridMap.occupied` is the *bottom* row of the bitmap, so cell
``(iy, ix)`` covers ``origin + ([ix, ix+1), [iy, iy+1)) * resolution``.

The distance field (metres from each cell centre to the nearest occupied cell centre, computed with
``scipy.ndimage.distance_transform_edt``) lets the ray caster take long safe steps through free
space (sphere tracing) and only walk cell by cell near walls.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from .errors import WorldFileError

__all__ = ["GridMap", "image_size"]


def image_size(path: Path, what: str, file: str, line: int) -> tuple[int, int]:
    """Width and height in pixels of the bitmap ``path``, which a world file names as ``what``
    (e.g. ``"bitmap 'map.png'"``) at ``file:line``; an unreadable or empty image is a WorldFileError."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            w, h = im.size
    except Exception as e:  # Pillow raises many types for bad files; all mean "not an image"
        raise WorldFileError(
            f"{what} is not an image Pillow can read ({type(e).__name__}); use a PNG", file, line
        ) from None
    if w <= 0 or h <= 0:
        raise WorldFileError(f"{what} is empty ({w} x {h} pixels)", file, line)
    return int(w), int(h)


class GridMap:
    """A static occupancy grid in world coordinates."""

    def __init__(self, occupied: np.ndarray, resolution: float, origin: tuple[float, float]):
        occ = np.ascontiguousarray(np.asarray(occupied, dtype=bool))
        if occ.ndim != 2 or occ.size == 0:
            raise ValueError("occupancy grid must be a non-empty 2-D array")
        if not (resolution > 0 and np.isfinite(resolution)):
            raise ValueError(f"resolution must be a positive number of metres per cell, not {resolution!r}")
        self.occupied = occ
        self.resolution = float(resolution)
        self.origin = (float(origin[0]), float(origin[1]))
        self.height, self.width = occ.shape
        if occ.all():
            self.distance = np.zeros(occ.shape, dtype=np.float32)
        else:
            self.distance = (ndimage.distance_transform_edt(~occ) * self.resolution).astype(np.float32)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_image(
        cls,
        path: str | Path,
        resolution: float,
        origin: tuple[float, float],
        *,
        size: tuple[float, float] | None = None,
        threshold: float = 0.5,
    ) -> GridMap:
        """Load a bitmap: pixels darker than ``threshold`` (fraction of white) are occupied.

        With ``size`` (metres), the bitmap is stretched to that size as Stage does; cells stay
        square at ``size_x / width`` and rows are resampled if the vertical scale differs.
        Transparent pixels count as free.
        """
        from PIL import Image, UnidentifiedImageError

        p = Path(path)
        try:
            with Image.open(p) as im:
                im.load()
                if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
                    rgba = im.convert("RGBA")
                    alpha = np.asarray(rgba.getchannel("A"), dtype=np.float32) / 255.0
                    lum = np.asarray(rgba.convert("L"), dtype=np.float32) / 255.0
                    lum = lum * alpha + (1.0 - alpha)  # transparent = white = free
                else:
                    lum = np.asarray(im.convert("L"), dtype=np.float32) / 255.0
        except FileNotFoundError:
            raise WorldFileError(f"bitmap {str(p)!r} not found; check the path (relative to the world file)") from None
        except (UnidentifiedImageError, OSError, ValueError) as e:
            raise WorldFileError(f"bitmap {str(p)!r} is not a readable image ({e}); use a PNG") from None
        occ = lum[::-1, :] < threshold  # flip so row 0 is the bottom of the map
        h, w = occ.shape
        if size is not None:
            sx, sy = float(size[0]), float(size[1])
            if not (sx > 0 and sy > 0):
                raise WorldFileError(f"floorplan size {size!r} must be positive metres")
            resolution = sx / w
            rows = max(1, int(round(sy / resolution)))
            if rows != h:
                idx = np.minimum((np.arange(rows) * h / rows).astype(int), h - 1)
                occ = occ[idx, :]
        return cls(occ, resolution, origin)

    @classmethod
    def from_floorplan(cls, fp, cell: float = 0.0) -> GridMap:
        """The grid of a :class:`~simulator.spec.FloorplanSpec` as Stage rasterises it: a bitmap
        finer than ``cell`` metres (the world's ``resolution``) is coarsened to whole multiples of
        its pixels near ``cell`` (a coarse cell is occupied when any of its pixels is); with
        ``fp.boundary`` the outermost cells are walls (Stage's ``boundary 1``)."""
        g = cls.from_image(fp.bitmap, fp.resolution, fp.origin, size=fp.size, threshold=fp.threshold)
        k = int(cell / g.resolution + 1e-9) if cell > 0 else 1
        occ = g.occupied
        if k >= 2:
            h, w = occ.shape
            hk, wk = -(-h // k), -(-w // k)
            pad = np.zeros((hk * k, wk * k), dtype=bool)
            pad[:h, :w] = occ
            occ = pad.reshape(hk, k, wk, k).any(axis=(1, 3))
        if fp.boundary:
            occ = occ.copy()
            occ[0, :] = occ[-1, :] = True
            occ[:, 0] = occ[:, -1] = True
        if occ is g.occupied:
            return g
        return cls(occ, g.resolution * k if k >= 2 else g.resolution, g.origin)

    # ------------------------------------------------------------------ geometry
    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` of the map in world metres."""
        x0, y0 = self.origin
        return (x0, x0 + self.width * self.resolution, y0, y0 + self.height * self.resolution)

    def world_to_cell(self, x, y):
        """Cell indices ``(ix, iy)`` of world points (arrays or scalars); may be out of range."""
        ix = np.floor((np.asarray(x) - self.origin[0]) / self.resolution).astype(np.int64)
        iy = np.floor((np.asarray(y) - self.origin[1]) / self.resolution).astype(np.int64)
        return ix, iy

    def cell_to_world(self, ix, iy):
        """World coordinates of cell centres."""
        return (
            self.origin[0] + (np.asarray(ix) + 0.5) * self.resolution,
            self.origin[1] + (np.asarray(iy) + 0.5) * self.resolution,
        )

    def in_bounds(self, x, y):
        ix, iy = self.world_to_cell(x, y)
        return (ix >= 0) & (ix < self.width) & (iy >= 0) & (iy < self.height)

    def clearance(self, x, y):
        """Distance in metres from world points to the nearest occupied cell (0 outside the map)."""
        ix, iy = self.world_to_cell(x, y)
        inside = (ix >= 0) & (ix < self.width) & (iy >= 0) & (iy < self.height)
        if np.ndim(ix) == 0:
            return float(self.distance[iy, ix]) if inside else 0.0
        out = np.zeros(np.shape(ix), dtype=np.float32)
        out[inside] = self.distance[iy[inside], ix[inside]]
        return out

    def is_free(self, x, y, clearance: float = 0.0):
        """True where the point is on the map and at least ``clearance`` metres from obstacles."""
        c = self.clearance(x, y)
        return c > max(clearance, 0.0) if np.ndim(c) == 0 else c > max(clearance, 0.0)

    def rectangles(self) -> list[tuple[int, int, int, int]]:
        """Occupied cells merged into axis-aligned rectangles ``(ix0, iy0, ix1, iy1)`` (exclusive
        ends): runs along rows, then runs with equal ends stacked across rows. Used to build the
        static collision shapes; far fewer shapes than cells."""
        occ = self.occupied
        padded = np.zeros((self.height, self.width + 2), dtype=np.int8)
        padded[:, 1:-1] = occ
        d = np.diff(padded, axis=1)
        rows_s, cols_s = np.nonzero(d == 1)
        rows_e, cols_e = np.nonzero(d == -1)
        # np.nonzero is row-major, so starts and ends pair up in order.
        open_runs: dict[tuple[int, int], int] = {}  # (x0, x1) -> first row
        rects: list[tuple[int, int, int, int]] = []
        i = 0
        n = len(rows_s)
        for row in range(self.height + 1):
            current: set[tuple[int, int]] = set()
            while i < n and rows_s[i] == row:
                current.add((int(cols_s[i]), int(cols_e[i])))
                i += 1
            for key in list(open_runs):
                if key not in current:
                    rects.append((key[0], open_runs.pop(key), key[1], row))
            for key in current:
                if key not in open_runs:
                    open_runs[key] = row
        return rects
