"""Pure conversions of ``rsal watch``: device data and geometry to points, outlines and images in
the world frame, entity paths and colours. No Rerun calls, no fabric: unit-tested alone
(``tests/rsal/test_watch.py``). Beam layouts come from :class:`~rsal.interfaces.ranger.RangerGeometry`,
pose algebra from :mod:`rsal.geometry`.
"""

from __future__ import annotations

import functools
import math
import zlib

import numpy as np

from ..geometry import compose_array
from ..interfaces.ranger import RangerGeometry

__all__ = [
    "FLIP",
    "beam_layout",
    "scan_to_world",
    "cov_ellipse",
    "ellipse_points",
    "footprint",
    "map_image",
    "map_transform",
    "entity",
    "rgba",
    "robot_color",
]

FLIP = (1.0, -1.0, 1.0)  # world y points up (north), a Rerun 2D view's y points down


# ---------------------------------------------------------------------------- pure conversions
def beam_layout(geometry: dict, n: int, angle_min: float, angle_step: float) -> tuple[np.ndarray, np.ndarray]:
    """Where each of ``n`` beams starts and points, in the robot frame: ``(origins (n, 2),
    angles (n,))``, from a ranger's describe geometry (:class:`~rsal.interfaces.ranger.RangerGeometry`
    lays them out: a laser fans its beams from its sensor, a sonar ring has one transducer per beam)."""
    origins, angles = RangerGeometry(geometry).layout(n, angle_min, angle_step)
    return origins.copy(), angles.copy()


def scan_to_world(
    ranges: np.ndarray,
    origins: np.ndarray,
    angles: np.ndarray,
    robot_pose,
    range_min: float = 0.0,
    range_max: float = 0.0,
    stride: int = 1,
) -> np.ndarray:
    """The end points ``(m, 2)`` in the world frame of the beams that hit something: every
    ``stride``-th beam whose range lies in ``(range_min, range_max)`` (a beam reading ``range_max``
    hit nothing; ``range_max`` 0 keeps every finite reading). Vectorised: no per-beam Python."""
    r = np.asarray(ranges, dtype=np.float64)[::stride]
    o = origins[::stride]
    a = angles[::stride]
    keep = np.isfinite(r) & (r > range_min)
    if range_max > 0.0:
        keep &= r < range_max - 1e-6
    r, o, a = r[keep], o[keep], a[keep]
    px = o[:, 0] + r * np.cos(a)
    py = o[:, 1] + r * np.sin(a)
    x, y, t = (float(v) for v in robot_pose)
    c, s = math.cos(t), math.sin(t)
    return np.column_stack([x + c * px - s * py, y + s * px + c * py])


def cov_ellipse(cov, sigma: float = 2.0) -> tuple[float, float, float]:
    """Half-axes ``(a, b)`` (m, ``a >= b``) and angle of the major axis (rad, from +x) of the
    ``sigma``-standard-deviation ellipse of the x-y block of a 3x3 (or 2x2, or 9 values row-major)
    pose covariance."""
    c = np.asarray(cov, dtype=float)
    c = c.reshape(3, 3) if c.size == 9 else c.reshape(2, 2)
    xy = 0.5 * (c[:2, :2] + c[:2, :2].T)
    w, v = np.linalg.eigh(xy)  # ascending
    w = np.clip(w, 0.0, None)
    a, b = sigma * math.sqrt(w[1]), sigma * math.sqrt(w[0])
    return a, b, math.atan2(v[1, 1], v[0, 1])


def ellipse_points(center, a: float, b: float, angle: float, n: int = 48) -> np.ndarray:
    """A closed polygon ``(n + 1, 2)`` tracing the ellipse."""
    t = np.linspace(0.0, 2.0 * math.pi, n + 1)
    ex, ey = a * np.cos(t), b * np.sin(t)
    c, s = math.cos(angle), math.sin(angle)
    return np.column_stack([center[0] + c * ex - s * ey, center[1] + s * ex + c * ey])


def footprint(pose, size) -> list[np.ndarray]:
    """The robot's outline at ``pose``: a closed rectangle ``size`` = [length, width] (m) centred on
    the pose, and a heading line from the centre to the front edge; world frame."""
    hl, hw = float(size[0]) / 2.0, float(size[1]) / 2.0
    corners = np.array([[hl, hw, 0], [-hl, hw, 0], [-hl, -hw, 0], [hl, -hw, 0], [hl, hw, 0]], dtype=float)
    head = np.array([[0.0, 0.0, 0.0], [hl, 0.0, 0.0]])
    return [compose_array(pose, corners)[:, :2], compose_array(pose, head)[:, :2]]


def map_image(cells: np.ndarray) -> np.ndarray:
    """A Player grid (-1 free, 0 unknown, +1 occupied; row 0 the bottom row) as a grey image of
    the same shape and row order: free 255, unknown 160, occupied 0."""
    img = np.full(cells.shape, 160, dtype=np.uint8)
    img[cells < 0] = 255
    img[cells > 0] = 0
    return img


def map_transform(origin, resolution: float) -> tuple[list[float], list[float]]:
    """Translation and scale placing the :func:`map_image` (pixel ``(col, row)``, row 0 the bottom
    row) in the view: world ``(origin + (col, row) * resolution)``, y flipped like every other
    entity under ``world/`` so north is up in a Rerun 2D view."""
    return [float(origin[0]), -float(origin[1]), 0.0], [float(resolution), -float(resolution), 1.0]


@functools.lru_cache(maxsize=16384)
def entity(*parts: str) -> str:
    """An entity path from name parts, each escaped (node names may contain '.')."""
    import rerun as rr

    return "/".join(rr.escape_entity_path_part(p) if i else p for i, p in enumerate(parts))


_PALETTE = np.array(
    [
        [230, 25, 75],
        [60, 180, 75],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
        [210, 245, 60],
        [0, 128, 128],
        [170, 110, 40],
        [128, 0, 0],
        [0, 0, 128],
    ],
    dtype=np.uint8,
)


def rgba(r: int, g: int, b: int, a: int = 255) -> int:
    """A colour packed as Rerun's 0xRRGGBBAA (the cheapest form to convert)."""
    return (r << 24) | (g << 16) | (b << 8) | a


def robot_color(name: str) -> int:
    return rgba(*(int(v) for v in _PALETTE[zlib.crc32(name.encode()) % len(_PALETTE)]))


WHITE, YELLOW, ORANGE, GREEN = rgba(255, 255, 255), rgba(255, 255, 0), rgba(250, 160, 0), rgba(40, 200, 40)
LASER_RED, SONAR_BLUE, COV_AMBER = rgba(255, 60, 60), rgba(60, 140, 255), rgba(255, 200, 0)
RED, BUMPER_GREEN, FIDUCIAL_MAGENTA = rgba(255, 30, 30), rgba(60, 200, 90, 160), rgba(230, 60, 230)
