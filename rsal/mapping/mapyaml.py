"""Map files in the ROS ``map_server`` format (YAML naming an image), written and read.

A minimal version: :func:`write_map` writes what ``map_saver`` writes (8-bit greyscale PNG,
occupied 0, free 254, unknown 205; YAML with ``image``, ``resolution``, ``origin``,
``occupied_thresh`` 0.65, ``free_thresh`` 0.196, ``negate`` 0, ``mode`` trinary) and
:func:`read_map` reads it back (trinary). Occupancy arrays: float, row 0 = the top of the image,
-1 unknown, else the occupied probability 0..1.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RsalError

__all__ = ["MapFileError", "MapImage", "write_map", "read_map"]

DEFAULT_OCCUPIED_THRESH = 0.65
DEFAULT_FREE_THRESH = 0.196


class MapFileError(RsalError, ValueError):
    """A map file that cannot be written or read; one line naming the file and a fix."""


@dataclass
class MapImage:
    occupancy: np.ndarray  # (H, W), row 0 = top; -1 unknown, else 0..1
    resolution: float
    origin: tuple[float, float, float]
    image: Path
    yaml: Path


def write_map(
    stem: str | os.PathLike[str],
    occupancy: np.ndarray,
    resolution: float,
    origin: tuple[float, ...],
    *,
    occupied_thresh: float = DEFAULT_OCCUPIED_THRESH,
    free_thresh: float = DEFAULT_FREE_THRESH,
) -> tuple[Path, Path]:
    """Write ``STEM.png`` and ``STEM.yaml``; returns their paths."""
    from PIL import Image

    stem = Path(stem)
    png, yml = stem.with_name(stem.name + ".png"), stem.with_name(stem.name + ".yaml")
    occ = np.asarray(occupancy, dtype=float)
    img = np.full(occ.shape, 205, np.uint8)
    img[(occ >= 0) & (occ > occupied_thresh)] = 0
    img[(occ >= 0) & (occ < free_thresh)] = 254
    o = [float(v) for v in (*origin, 0.0, 0.0)][:3]
    try:
        stem.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(img, mode="L").save(png)
        yml.write_text(
            f"image: {png.name}\nresolution: {float(resolution)!r}\norigin: [{o[0]!r}, {o[1]!r}, {o[2]!r}]\n"
            f"occupied_thresh: {float(occupied_thresh)!r}\nfree_thresh: {float(free_thresh)!r}\nnegate: 0\n"
            "mode: trinary\n",
            encoding="utf-8",
        )
    except OSError as e:
        raise MapFileError(f"{stem}: cannot write the map ({e.strerror or e}); check the folder is writable") from None
    return png, yml


def read_map(yaml_path: str | os.PathLike[str]) -> MapImage:
    """Read a map_server YAML and its image (trinary)."""
    import yaml
    from PIL import Image

    p = Path(yaml_path)
    try:
        meta = yaml.safe_load(p.read_text(encoding="utf-8"))
        img = p.parent / meta["image"]
        grey = np.asarray(Image.open(img).convert("L"), dtype=float)
        res = float(meta["resolution"])
        origin = tuple(float(v) for v in meta["origin"][:3])
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as e:
        raise MapFileError(f"{p}: not a readable map_server map ({type(e).__name__}: {e})") from None
    if int(meta.get("negate", 0)):
        grey = 255.0 - grey
    prob = (255.0 - grey) / 255.0
    occ = np.full(grey.shape, -1.0, np.float32)
    occ[prob > float(meta.get("occupied_thresh", DEFAULT_OCCUPIED_THRESH))] = 1.0
    occ[prob < float(meta.get("free_thresh", DEFAULT_FREE_THRESH))] = 0.0
    return MapImage(occ, res, origin, img, p)
