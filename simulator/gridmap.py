"""Occupancy grid of a floorplan bitmap, with its Euclidean distance field.

The grid follows Player's ``mapfile`` driver (thesis appendix A.2): a bitmap where dark pixels are
occupied, a resolution in metres per pixel and an ``origin``, the world position of the bitmap's
bottom-left corner. Row 0 of :attr:`GridMap.occupied` is the *bottom* row of the bitmap, so cell
``(iy, ix)`` covers ``origin + ([ix, ix+1), [iy, iy+1)) * resolution``.

A floorplan may also be a ROS ``map_server`` map: a YAML file naming the image with its
``resolution``, ``origin`` (x, y, yaw of the lower-left pixel), ``occupied_thresh``, ``free_thresh``,
``negate`` and ``mode`` (ROS map_server documentation, "Map format"). :func:`read_map_yaml` reads
it into a :class:`~simulator.spec.FloorplanSpec`; the simulator only needs walls, so a pixel is
occupied where map_server would say occupied, and unknown pixels are free space. The platform's
own reader and writer of the format is :mod:`rsal.mapping.mapyaml`; the simulator imports nothing
of ours, so this is its own short reading of the same rules (a test checks both agree).

The distance field (metres from each cell centre to the nearest occupied cell centre, computed with
``scipy.ndimage.distance_transform_edt``) lets the ray caster take long safe steps through free
space (sphere tracing) and only walk cell by cell near walls.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import ndimage

from .errors import WorldFileError, did_you_mean
from .spec import FloorplanSpec

__all__ = ["GridMap", "MAP_YAML_SUFFIXES", "image_size", "read_map_yaml"]

MAP_YAML_SUFFIXES = (".yaml", ".yml")
"""A floorplan ``bitmap`` with one of these suffixes is a map_server YAML."""
_MAP_KEYS = ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate", "mode")
_MAP_MODES = ("trinary", "scale", "raw")


def read_map_yaml(path: Path, what: str, file: str, line: int, name: str = "floorplan") -> FloorplanSpec:
    """The floorplan of the map_server YAML ``path``, which a world file names as ``what`` at
    ``file:line``; a missing key, a bad value or a missing image is a WorldFileError naming both."""
    import yaml

    def fail(msg: str) -> WorldFileError:
        return WorldFileError(f"{what}: {msg}; see docs/mapping.md, 'Map files'", file, line)

    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise fail(f"cannot read the map file ({e})") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise fail(f"is not valid YAML{at}") from None
    if not isinstance(doc, dict):
        raise fail("is not a map_server YAML (image: map.png, resolution: 0.05, origin: [x, y, yaw], ...)")
    for k in ("image", "resolution", "origin", "occupied_thresh", "free_thresh"):
        if k not in doc:
            near = did_you_mean(k, [str(x) for x in doc if x not in _MAP_KEYS])
            raise fail(f"missing key {k!r}" + (f" (is {near!r} a misspelling?)" if near else ""))

    def number(key: str, lo: float, hi: float) -> float:
        v = doc[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= v <= hi):
            raise fail(f"{key} must be a number in [{lo:g}, {hi:g}], not {v!r}")
        return float(v)

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise fail("image must name the map's image file, e.g. image: floor.png")
    img = Path(image.strip())
    img = img if img.is_absolute() else path.parent / img
    if not img.is_file():
        raise fail(f"image {image!r} not found (looked for {img}); it is relative to the YAML file")
    res = number("resolution", 0.0, math.inf)
    if res <= 0:
        raise fail(f"resolution must be metres per pixel > 0, not {res!r}")
    o = doc["origin"]
    if not (isinstance(o, list) and len(o) in (2, 3) and all(isinstance(v, (int, float)) for v in o)):
        raise fail(f"origin must be [x, y, yaw] in metres and radians, not {o!r}")
    if len(o) == 3 and abs(float(o[2])) > 1e-9:
        raise fail(f"origin yaw {o[2]!r} is not 0: a floorplan is axis-aligned; rotate the map first")
    occ_t, free_t = number("occupied_thresh", 0.0, 1.0), number("free_thresh", 0.0, 1.0)
    negate = doc.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise fail(f"negate must be 0 or 1, not {negate!r}")
    mode = doc.get("mode", "trinary")
    if mode not in _MAP_MODES:
        near = did_you_mean(str(mode), _MAP_MODES)
        raise fail(f"unknown mode {mode!r}" + (f"; did you mean {near!r}?" if near else f"; use {_MAP_MODES}"))
    del free_t  # only walls matter to the simulator: unknown space is free
    image_size(img, f"{what}: image {image!r}", file, line)
    return FloorplanSpec(
        bitmap=img.absolute(),
        resolution=res,
        origin=(float(o[0]), float(o[1])),
        size=None,
        name=name,
        threshold=1.0 - occ_t,
        negate=bool(negate),
        mode=str(mode),
        mapfile=path.absolute(),
    )


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
        negate: bool = False,
        mode: str | None = None,
    ) -> GridMap:
        """Load a bitmap: pixels darker than ``threshold`` (fraction of white) are occupied.

        With ``size`` (metres), the bitmap is stretched to that size as Stage does; cells stay
        square at ``size_x / width`` and rows are resampled if the vertical scale differs.
        Transparent pixels count as free. ``mode`` (a map_server map's ``trinary``, ``scale`` or
        ``raw``) reads grey as map_server does, the mean of the colour channels, and transparency
        only in ``scale`` mode (a translucent pixel is unknown, so free here); ``negate``:
        pixels *brighter* than ``1 - threshold`` are occupied; ``raw``: grey values are percent
        occupancy and only 100 is a wall (as a consumer of map_server's 0..100 reads it).
        """
        from PIL import Image, UnidentifiedImageError

        p = Path(path)
        try:
            with Image.open(p) as im:
                im.load()
                grey = "RGB" if mode is not None and im.mode not in ("L", "LA", "I", "I;16") else "L"
                if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
                    rgba = im.convert("RGBA")
                    alpha = np.asarray(rgba.getchannel("A"), dtype=np.float32) / 255.0
                    lum = _grey(rgba.convert(grey))
                    if mode is None:
                        lum = lum * alpha + (1.0 - alpha)  # transparent = white = free
                    elif mode == "scale":  # map_server: translucent = unknown (free here)
                        lum[alpha < 1.0] = 0.0 if negate else 1.0
                else:
                    lum = _grey(im.convert(grey))
        except FileNotFoundError:
            raise WorldFileError(f"bitmap {str(p)!r} not found; check the path (relative to the world file)") from None
        except (UnidentifiedImageError, OSError, ValueError) as e:
            raise WorldFileError(f"bitmap {str(p)!r} is not a readable image ({e}); use a PNG") from None
        lum = lum[::-1, :]  # flip so row 0 is the bottom of the map
        if mode == "raw":
            v = np.floor(lum * 255.0 + 1e-3)  # map_server truncates the channel mean to an integer
            v = 255.0 - v if negate else v
            occ = v == 100.0  # map_server's "occupied" (100); other values are grades or unknown
        elif negate:
            occ = lum > 1.0 - threshold
        else:
            occ = lum < threshold
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
        mode = fp.mode if fp.mapfile is not None else None
        g = cls.from_image(
            fp.bitmap, fp.resolution, fp.origin, size=fp.size, threshold=fp.threshold, negate=fp.negate, mode=mode
        )
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


def _grey(im) -> np.ndarray:
    """Grey values 0..1 of a Pillow image in mode ``L`` (luminance) or ``RGB`` (channel mean)."""
    a = np.asarray(im, dtype=np.float32)
    return (a.mean(axis=2) if a.ndim == 3 else a) / 255.0
