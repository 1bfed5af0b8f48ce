"""Map files in the ROS ``map_server`` format: a YAML file that names an image, read and written.

The format (ROS ``map_server`` documentation, "Map format"; what ``map_saver`` writes and what
``slam_toolbox``, Cartographer's ``map_saver`` and Nav2's ``map_io`` exchange)::

    image: floor.png            # relative to the YAML file (or absolute)
    resolution: 0.05            # metres per pixel
    origin: [-31.475, -7.8, 0]  # pose (x, y, yaw) of the image's lower-left pixel in the world
    occupied_thresh: 0.65       # occupancy probability above which a pixel is occupied
    free_thresh: 0.196          # ... below which it is free (in between: unknown)
    negate: 0                   # 1: white is occupied, black free (thresholds unchanged)
    mode: trinary               # optional: trinary (default), scale or raw

A pixel of grey value ``x`` (the mean of its colour channels) has the occupancy probability
``p = (255 - x) / 255`` (``x / 255`` with ``negate``). ``trinary``: ``p > occupied_thresh`` is
occupied (1.0), ``p < free_thresh`` free (0.0), anything else unknown (-1). ``scale``: the same
ends, values in between mapped linearly to ``0.99 * (p - free) / (occupied - free)``, and a pixel
that is not fully opaque unknown. ``raw``: the grey value (truncated to an integer, after
``negate``) *is* the occupancy in percent, ``x <= 100`` gives ``x / 100`` and anything larger
unknown. Transparency counts only in ``scale`` mode.

:func:`write_map` writes what ``map_saver`` writes: an 8-bit greyscale PNG with occupied 0,
free 254, unknown 205, and the YAML with ``occupied_thresh 0.65``, ``free_thresh 0.196``,
``negate 0``, ``mode trinary`` (205 reads back as unknown: ``p = 50/255 = 0.19608 > 0.196``).
:func:`read_map` returns a :class:`MapImage`: ``occupancy`` as float32 with row 0 the *top* of the
image (as it is stored); :meth:`MapImage.cells` gives Player's map convention (rows from the bottom,
``-1`` free, ``0`` unknown, ``+1`` occupied) that the ``mapfile`` driver serves and
:class:`mrs_bridge.nav.grid.NavGrid` holds. Every problem is a :class:`MapFileError` whose message
is one line naming the file (and line) and a fix. Images go through Pillow, YAML through PyYAML.

The simulator imports nothing of ours (docs/concepts.md, "Layers") and reads the same format for a
floorplan itself (:func:`simulator.gridmap.read_map_yaml`); ``tests/mapping/test_mapyaml.py``
checks that both read a file alike.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rsal.errors import RsalError
from rsal.suggest import did_you_mean

__all__ = [
    "FREE_PIXEL",
    "MODES",
    "MapFileError",
    "MapImage",
    "OCCUPIED_PIXEL",
    "UNKNOWN_PIXEL",
    "is_map_yaml",
    "read_map",
    "write_map",
]

OCCUPIED_PIXEL, FREE_PIXEL, UNKNOWN_PIXEL = 0, 254, 205
"""The grey values ``map_saver`` writes."""
MODES = ("trinary", "scale", "raw")
KEYS = ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate", "mode")
REQUIRED = ("image", "resolution", "origin", "occupied_thresh", "free_thresh")
DEFAULT_OCCUPIED_THRESH, DEFAULT_FREE_THRESH = 0.65, 0.196
YAML_SUFFIXES = (".yaml", ".yml")


class MapFileError(RsalError, ValueError):
    """A map file that cannot be read or written; ``str()`` is one line with the file and a fix."""


def is_map_yaml(path: str | os.PathLike[str]) -> bool:
    """True for a path that names a map_server YAML (by its suffix) rather than a bare bitmap."""
    return Path(path).suffix.lower() in YAML_SUFFIXES


@dataclass(frozen=True)
class MapImage:
    """A map read from a map_server YAML (see the module docstring for the conventions)."""

    occupancy: np.ndarray  # float32 (H, W), row 0 = top of the image; -1 unknown, else 0..1
    resolution: float  # m per pixel
    origin: tuple[float, float, float]  # pose (x, y, yaw) of the lower-left pixel
    image: Path  # the image file
    yaml: Path  # the YAML file
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH
    free_thresh: float = DEFAULT_FREE_THRESH
    negate: bool = False
    mode: str = "trinary"

    @property
    def height(self) -> int:
        return int(self.occupancy.shape[0])

    @property
    def width(self) -> int:
        return int(self.occupancy.shape[1])

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` in world metres (for ``yaw == 0``)."""
        x0, y0 = self.origin[0], self.origin[1]
        return (x0, x0 + self.width * self.resolution, y0, y0 + self.height * self.resolution)

    @property
    def occupied(self) -> np.ndarray:
        """Boolean (H, W), row 0 = top: fully occupied cells (map_server's 100)."""
        return self.occupancy >= 0.995

    @property
    def free(self) -> np.ndarray:
        """Boolean (H, W), row 0 = top: fully free cells (map_server's 0)."""
        return (self.occupancy >= 0.0) & (self.occupancy < 0.005)

    def cells(self) -> np.ndarray:
        """Player's map convention: int8, row 0 = the *bottom* row, -1 free, 0 unknown, +1 occupied.
        Cells between free and occupied (``scale``/``raw`` gradations) are unknown, as a consumer
        of map_server's 0/100/-1 reads them."""
        c = np.zeros(self.occupancy.shape, dtype=np.int8)
        c[self.free] = -1
        c[self.occupied] = 1
        return np.ascontiguousarray(c[::-1])


# ---------------------------------------------------------------------------------------- write
def write_map(
    stem: str | os.PathLike[str],
    occupancy: np.ndarray,
    resolution: float,
    origin: tuple[float, ...],
    *,
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH,
    free_thresh: float = DEFAULT_FREE_THRESH,
) -> tuple[Path, Path]:
    """Write ``STEM.png`` and ``STEM.yaml`` as ``map_saver`` does; returns their paths.

    ``occupancy``: (H, W) floats, row 0 = the top of the image, negative = unknown, else the
    occupancy probability 0..1; a cell above ``occupied_thresh`` is written occupied, below
    ``free_thresh`` free, anything else unknown. ``origin``: ``(x, y)`` or ``(x, y, yaw)``, the
    pose of the lower-left pixel. A ``.yaml``/``.png`` suffix on ``stem`` is dropped."""
    from PIL import Image

    stem = Path(stem)
    if stem.suffix.lower() in (*YAML_SUFFIXES, ".png", ".pgm"):
        stem = stem.with_suffix("")
    if not stem.name:
        raise MapFileError(f"map output {str(stem)!r} has no file name; use e.g. -o maps/NAME")
    occ = np.asarray(occupancy, dtype=np.float64)
    if occ.ndim != 2 or occ.size == 0:
        raise MapFileError(f"{stem}: the occupancy grid must be a non-empty 2-D array, not shape {occ.shape}")
    if not np.isfinite(occ).all() or (occ > 1.0).any():
        raise MapFileError(f"{stem}: occupancy values must be finite, -1 (unknown) or 0..1 (probability)")
    if not (math.isfinite(resolution) and resolution > 0):
        raise MapFileError(f"{stem}: resolution must be a positive number of metres per pixel, not {resolution!r}")
    o = [float(v) for v in origin]
    if len(o) not in (2, 3) or not all(math.isfinite(v) for v in o):
        raise MapFileError(f"{stem}: origin must be [x, y] or [x, y, yaw] in metres and radians, not {origin!r}")
    if len(o) == 2:
        o.append(0.0)
    if not (0.0 <= free_thresh < occupied_thresh <= 1.0):
        raise MapFileError(
            f"{stem}: need 0 <= free_thresh < occupied_thresh <= 1, not {free_thresh}, {occupied_thresh}"
        )
    px = np.full(occ.shape, UNKNOWN_PIXEL, dtype=np.uint8)
    known = occ >= 0.0
    px[known & (occ > occupied_thresh)] = OCCUPIED_PIXEL
    px[known & (occ < free_thresh)] = FREE_PIXEL
    png, yml = stem.with_suffix(".png"), stem.with_suffix(".yaml")
    try:
        stem.parent.mkdir(parents=True, exist_ok=True)
        tmp = png.with_name(png.name + ".tmp")
        Image.fromarray(px, mode="L").save(tmp, format="PNG")
        os.replace(tmp, png)
        text = (
            f"image: {png.name}\n"
            f"resolution: {float(resolution)!r}\n"
            f"origin: [{o[0]!r}, {o[1]!r}, {o[2]!r}]\n"
            f"occupied_thresh: {float(occupied_thresh)!r}\n"
            f"free_thresh: {float(free_thresh)!r}\n"
            "negate: 0\n"
            "mode: trinary\n"
        )
        yml.write_text(text, encoding="utf-8")
    except OSError as e:
        raise MapFileError(
            f"{stem}: cannot write the map ({e.strerror or e}); check the folder exists and is writable"
        ) from None
    return png, yml


# ---------------------------------------------------------------------------------------- read
def read_map(yaml_path: str | os.PathLike[str]) -> MapImage:
    """Read a map_server YAML and its image (module docstring); :class:`MapFileError` if anything
    is wrong, naming the file, the line and a fix."""
    meta = read_map_meta(yaml_path)
    grey, alpha = _load_grey(meta["image"], meta["where_image"])
    if meta["negate"]:
        grey = 255.0 - grey
    mode, occ_t, free_t = meta["mode"], meta["occupied_thresh"], meta["free_thresh"]
    if mode == "raw":
        grey = np.floor(grey + 1e-9)  # map_server truncates the channel mean to an integer
        occ = np.where(grey <= 100.0, grey / 100.0, -1.0)
    else:
        p = (255.0 - grey) / 255.0
        if mode == "trinary":
            mid = np.full(p.shape, -1.0)
        else:
            mid = 0.99 * (p - free_t) / (occ_t - free_t)
        occ = np.where(p > occ_t, 1.0, np.where(p < free_t, 0.0, mid))
        if mode == "scale" and alpha is not None:
            occ[alpha < 255] = -1.0
    return MapImage(
        occupancy=occ.astype(np.float32),
        resolution=meta["resolution"],
        origin=meta["origin"],
        image=meta["image"],
        yaml=meta["yaml"],
        occupied_thresh=occ_t,
        free_thresh=free_t,
        negate=meta["negate"],
        mode=mode,
    )


def read_map_meta(yaml_path: str | os.PathLike[str]) -> dict:
    """The YAML's validated fields (``image`` resolved to an existing file), without the pixels."""
    import yaml

    path = Path(yaml_path)
    shown = os.fspath(yaml_path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MapFileError(f"{shown}: no such map file; check the path (a map_server .yaml)") from None
    except IsADirectoryError:
        raise MapFileError(f"{shown}: is a directory, not a map file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise MapFileError(f"{shown}: cannot read the map file ({e}); is it a map_server YAML?") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or "syntax error"
        raise MapFileError(f"{shown}{line}: not valid YAML ({problem}); see docs/mapping.md, 'Map files'") from None
    if not isinstance(doc, dict) or not isinstance(node, yaml.MappingNode):
        raise MapFileError(
            f"{shown}: a map_server YAML must be a mapping of keys (image: map.png, resolution: 0.05, ...)"
        )
    lines = {str(k.value): k.start_mark.line + 1 for k, _ in node.value if isinstance(k, yaml.ScalarNode)}

    def where(key: str) -> str:
        return f"{shown}:{lines[key]}" if key in lines else shown

    for k in doc:
        if str(k) not in KEYS and (near := did_you_mean(str(k), KEYS)) is not None and near not in doc:
            raise MapFileError(f"{where(str(k))}: unknown key {str(k)!r}; did you mean {near!r}?")
    for k in REQUIRED:
        if k not in doc:
            raise MapFileError(f"{shown}: missing key {k!r}; a map_server YAML needs {', '.join(REQUIRED)}")

    def number(key: str, lo: float | None = None, hi: float | None = None, what: str = "") -> float:
        v = doc[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise MapFileError(f"{where(key)}: {key} must be a number{what}, not {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise MapFileError(f"{where(key)}: {key} = {v!r} is out of range{what}")
        return float(v)

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise MapFileError(f"{where('image')}: image must name the map's image file, e.g. image: floor.png")
    img = Path(image.strip())
    img = img if img.is_absolute() else path.parent / img
    if not img.is_file():
        raise MapFileError(
            f"{where('image')}: image {image!r} not found (looked for {img}); the path is relative to the YAML file"
        )
    res = number("resolution", what=" of metres per pixel > 0")
    if res <= 0:
        raise MapFileError(f"{where('resolution')}: resolution must be metres per pixel > 0, not {res!r}")
    origin = doc["origin"]
    if (
        not isinstance(origin, list)
        or len(origin) not in (2, 3)
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in origin)
    ):
        raise MapFileError(f"{where('origin')}: origin must be [x, y, yaw] (metres, radians), not {origin!r}")
    o = (float(origin[0]), float(origin[1]), float(origin[2]) if len(origin) == 3 else 0.0)
    occ_t = number("occupied_thresh", 0.0, 1.0, " between 0 and 1")
    free_t = number("free_thresh", 0.0, 1.0, " between 0 and 1")
    if free_t >= occ_t:
        raise MapFileError(f"{where('free_thresh')}: free_thresh {free_t} must be below occupied_thresh {occ_t}")
    negate = doc.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise MapFileError(f"{where('negate')}: negate must be 0 or 1, not {negate!r}")
    mode = doc.get("mode", "trinary")
    if mode not in MODES:
        near = did_you_mean(str(mode), MODES)
        hint = f"; did you mean {near!r}?" if near else f"; use one of {', '.join(MODES)}"
        raise MapFileError(f"{where('mode')}: unknown mode {mode!r}{hint}")
    return {
        "yaml": path,
        "image": img,
        "where_image": where("image"),
        "resolution": res,
        "origin": o,
        "occupied_thresh": occ_t,
        "free_thresh": free_t,
        "negate": bool(negate),
        "mode": str(mode),
    }


def _load_grey(img: Path, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """The image's grey values (mean of the colour channels, float 0..255) and its alpha (or None)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(img) as im:
            im.load()
            if im.mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float64)
                top = 65535.0 if a.max(initial=0) > 255 else 255.0
                return a * (255.0 / top), None
            if im.mode not in ("L", "LA", "RGB", "RGBA"):
                im = im.convert("RGBA" if "A" in im.mode else "RGB")
            a = np.asarray(im, dtype=np.float64)
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise MapFileError(f"{where}: image {img.name!r} is not a readable image ({e}); use a PNG or PGM") from None
    if a.ndim == 2:
        return a, None
    if a.shape[2] in (2, 4):
        return a[..., :-1].mean(axis=2), a[..., -1]
    return a.mean(axis=2), None
