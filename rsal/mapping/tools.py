"""Map tools: a world file's static geometry as a map, and aligning a built map to a floor plan.

:func:`from_world` rasterises what a world's robots would map -- the floorplan as the simulator
places it (:meth:`simulator.gridmap.GridMap.from_floorplan`) and the non-robot models that lasers
see (their outlines at their initial poses) -- into an occupancy grid of the requested resolution,
free everywhere else inside the world's extent. Written with :func:`rsal.mapping.mapyaml.write_map`
it is the same map_server format ``rsal map`` builds, so shipped maps and built maps are one kind.
A coarser cell is occupied if any part of it is (walls thinner than a cell survive); a finer or
equal one takes the floorplan cell under its centre, so at the bitmap's own resolution the map is
the bitmap.

:func:`align` is step (b) of the thesis's fig. 3.24: the rigid transform ``(x, y, yaw)`` that maps
a built map onto a floor plan, ``plan = R(yaw) @ built + (x, y)``. Occupied cells of both become
point sets. A global search scores every heading (``yaw_step``) by the likelihood field of the
plan (``exp(-d^2 / 2 sigma^2)`` of the plan's distance transform, ``scipy.ndimage``), the
translation of each heading found at once by an FFT cross-correlation (``scipy.fft``) at a coarse
cell; the best few headings are refined by ICP (Besl and McKay 1992), ranked on an even thinning
of 2000 cells and the winner refined on all (up to ``max_points``), on the occupied cells with
nearest neighbours from ``scipy.spatial.cKDTree`` and the closed-form 2-D rigid fit (Arun et al.
1987), trimming pairs farther than a shrinking gate. The answer carries the residual: the mean
distance of the built map's walls to the plan's walls, and the share of them within 0.10 m.

The simulator is imported only inside :func:`from_world` (the one place ``rsal`` reads a world
file), so the rest of ``rsal`` stays free of it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import fft, ndimage
from scipy.spatial import cKDTree

from .mapyaml import MapFileError

__all__ = ["Alignment", "Grid", "align", "from_world", "resample", "world_spec"]

log = logging.getLogger(__name__)

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Grid:
    """An occupancy grid in the map_server sense: ``occupancy`` (H, W) float, row 0 = the *top*
    row, -1 unknown, else 0..1; ``origin`` = world (x, y) of the lower-left corner, the grid
    turned by ``yaw`` about it (map_server's origin yaw)."""

    occupancy: np.ndarray
    resolution: float
    origin: tuple[float, float]
    yaw: float = 0.0

    @property
    def occupied(self) -> np.ndarray:
        return self.occupancy >= 0.5

    def to_world(self, uv: np.ndarray) -> np.ndarray:
        """Grid-frame metres (from the lower-left corner, along the rows and columns) to world."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return uv @ np.array([[c, s], [-s, c]]) + self.origin

    def to_grid(self, xy: np.ndarray) -> np.ndarray:
        """World to grid-frame metres (the inverse of :meth:`to_world`)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return (xy - self.origin) @ np.array([[c, -s], [s, c]])

    def wall_points(self) -> np.ndarray:
        """World (x, y) of the centres of the occupied cells, (N, 2)."""
        r, c = np.nonzero(self.occupied)
        h = self.occupancy.shape[0]
        uv = np.column_stack([(c + 0.5) * self.resolution, (h - r - 0.5) * self.resolution])
        return self.to_world(uv)


# ---------------------------------------------------------------------------------- from a world
def world_spec(world_path):
    """The parsed world file (``simulator.spec.WorldSpec``); ``simulator.SimulatorError`` if bad."""
    from simulator.loader import load_world

    return load_world(world_path)


def from_world(world_path, resolution: float | None = None, *, models: bool = True, progress: Progress | None = None):
    """``(Grid, spec)``: the static geometry of the world file ``world_path`` (or an already
    loaded ``WorldSpec``) at ``resolution`` m/cell (default: the floorplan's, else 0.05). Raises
    ``simulator.SimulatorError`` for a bad world file, :class:`MapFileError` for nothing to map."""
    from simulator.gridmap import GridMap
    from simulator.shapes import outline
    from simulator.spec import WorldSpec

    say = progress or (lambda s: None)
    spec = world_path if isinstance(world_path, WorldSpec) else world_spec(world_path)
    world_path = spec.source or "the world" if isinstance(world_path, WorldSpec) else world_path
    fp_grid = GridMap.from_floorplan(spec.floorplan, spec.resolution) if spec.floorplan is not None else None
    solid = [m for m in spec.models if models and not m.position and m.laser_return and m.obstacle_return]
    polys = []
    for m in solid:
        x, y, a = m.pose
        c, s = math.cos(a), math.sin(a)
        for poly in outline(m):
            polys.append([(x + c * u - s * v, y + s * u + c * v) for u, v in poly])
    if fp_grid is None and not polys:
        raise MapFileError(
            f"{world_path}: nothing to map: no floorplan and no static model that lasers see; "
            "give a world with a floorplan bitmap"
        )
    if resolution is None:
        resolution = fp_grid.resolution if fp_grid is not None else 0.05
    if not (math.isfinite(resolution) and resolution > 0):
        raise MapFileError(f"--resolution {resolution!r} must be a positive number of metres per cell")
    if fp_grid is not None:
        x0, x1, y0, y1 = fp_grid.extent
    else:
        pts = np.array([p for poly in polys for p in poly])
        x0, y0 = pts.min(axis=0) - 1.0
        x1, y1 = pts.max(axis=0) + 1.0
    w = max(1, int(math.ceil((x1 - x0) / resolution - 1e-9)))
    h = max(1, int(math.ceil((y1 - y0) / resolution - 1e-9)))
    if w * h > 40_000_000:
        raise MapFileError(f"--resolution {resolution} gives a {w} x {h} map; choose a coarser resolution")
    say(f"world {world_path}: {w} x {h} cells at {resolution:g} m, {len(solid)} static model(s)")
    occ = np.zeros((h, w), dtype=bool)  # row 0 = bottom while building
    if fp_grid is not None:
        occ |= _pool(fp_grid.occupied, fp_grid.resolution, fp_grid.origin, (w, h), resolution, (x0, y0))
    if polys:
        occ |= _polygons(polys, (w, h), resolution, (x0, y0))
    grid = Grid(np.where(occ[::-1], 1.0, 0.0), float(resolution), (float(x0), float(y0)))
    return grid, spec


def _pool(src: np.ndarray, src_res: float, src_origin, size, res: float, origin) -> np.ndarray:
    """``src`` (bool, row 0 bottom) on a grid of ``size`` = (w, h) cells of ``res`` from
    ``origin``: a cell is occupied if any of n x n sample points in it falls on an occupied
    source cell, n = ceil(res / src_res) (n = 1: the cell centre)."""
    w, h = size
    n = max(1, int(math.ceil(res / src_res - 1e-9)))
    sub = (np.arange(n) + 0.5) / n
    xs = origin[0] + (np.arange(w)[:, None] + sub[None, :]).ravel() * res
    ys = origin[1] + (np.arange(h)[:, None] + sub[None, :]).ravel() * res
    ix = np.floor((xs - src_origin[0]) / src_res + 1e-9).astype(np.int64)
    iy = np.floor((ys - src_origin[1]) / src_res + 1e-9).astype(np.int64)
    okx = (ix >= 0) & (ix < src.shape[1])
    oky = (iy >= 0) & (iy < src.shape[0])
    sample = src[np.clip(iy, 0, src.shape[0] - 1)][:, np.clip(ix, 0, src.shape[1] - 1)]
    sample &= oky[:, None] & okx[None, :]
    return sample.reshape(h, n, w, n).any(axis=(1, 3))


def _polygons(polys, size, res: float, origin, n: int = 3) -> np.ndarray:
    """Polygons (world metres) on a bool grid of ``size`` = (w, h) (row 0 bottom): a cell is
    occupied if any of its n x n sample points is inside one (even-odd rule, vectorised)."""
    w, h = size
    occ = np.zeros((h, w), dtype=bool)
    sub = (np.arange(n) + 0.5) / n
    for poly in polys:
        pts = np.asarray(poly, dtype=np.float64)
        lo = np.floor((pts.min(axis=0) - origin) / res).astype(int)
        hi = np.ceil((pts.max(axis=0) - origin) / res).astype(int)
        i0, j0 = max(lo[0], 0), max(lo[1], 0)
        i1, j1 = min(hi[0], w), min(hi[1], h)
        if i0 >= i1 or j0 >= j1:
            continue
        xs = origin[0] + (np.arange(i0, i1)[:, None] + sub).ravel() * res
        ys = origin[1] + (np.arange(j0, j1)[:, None] + sub).ravel() * res
        X, Y = np.meshgrid(xs, ys)
        inside = np.zeros(X.shape, dtype=bool)
        for (xa, ya), (xb, yb) in zip(pts, np.roll(pts, -1, axis=0), strict=True):
            if ya == yb:
                continue
            cross = ((ya > Y) != (yb > Y)) & (X < xa + (Y - ya) * (xb - xa) / (yb - ya))
            inside ^= cross
        occ[j0:j1, i0:i1] |= inside.reshape(j1 - j0, n, i1 - i0, n).any(axis=(1, 3))
    return occ


# ---------------------------------------------------------------------------------------- align
@dataclass(frozen=True)
class Alignment:
    """``plan = R(yaw) @ built + (x, y)``; ``residual`` = mean distance (m) of the built map's
    walls to the plan's walls after alignment, ``inliers`` = the share of them within 0.10 m."""

    x: float
    y: float
    yaw: float  # rad
    residual: float
    inliers: float
    points: int  # built wall cells used
    iterations: int

    def apply(self, pts: np.ndarray) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return pts @ np.array([[c, s], [-s, c]]) + (self.x, self.y)


def align(
    built: Grid,
    plan: Grid,
    *,
    yaw_step: float = math.radians(2.0),
    candidates: int = 3,
    max_points: int = 20000,
    progress: Progress | None = None,
) -> Alignment:
    """The rigid transform that lays ``built`` onto ``plan`` (module docstring)."""
    say = progress or (lambda s: None)
    src, dst = built.wall_points(), plan.wall_points()
    if len(src) < 3:
        raise MapFileError(f"the built map has {len(src)} occupied cells; too few to align (need walls)")
    if len(dst) < 3:
        raise MapFileError(f"the plan has {len(dst)} occupied cells; too few to align (is it a floor plan?)")
    say(f"built map: {len(src)} wall cells, plan: {len(dst)} wall cells")
    if len(src) > max_points:  # an even thinning keeps the walls' shape
        src = src[np.linspace(0, len(src) - 1, max_points).astype(np.int64)]
    tree = cKDTree(dst)
    # coarse cell: at most ~400 cells across the plan, never finer than either map
    ext = dst.max(axis=0) - dst.min(axis=0)
    cell = max(built.resolution, plan.resolution, float(ext.max()) / 400.0)
    field, field_origin = _likelihood_field(plan, cell)
    yaws = np.arange(-math.pi, math.pi, yaw_step)
    say(f"coarse search: {len(yaws)} headings x FFT translation at {cell:.2f} m over {len(src)} wall cells")
    scored = [(*_best_shift(src, yaw, field, field_origin, cell), yaw) for yaw in yaws]
    scored.sort(key=lambda t: -t[0])
    few = src[np.linspace(0, len(src) - 1, min(len(src), 2000)).astype(np.int64)]  # to rank candidates
    best: Alignment | None = None
    for score, tx, ty, yaw in _distinct(scored, candidates, 4 * yaw_step):
        # refine the heading finely around the coarse one, then ICP
        fine = [(*_best_shift(src, y, field, field_origin, cell), y) for y in yaw + np.linspace(-1, 1, 9) * yaw_step]
        score, tx, ty, yaw = max(fine, key=lambda t: t[0])
        a = _icp(few, tree, yaw, tx, ty, cell)
        say(f"candidate yaw {math.degrees(a.yaw):7.2f} deg: residual {a.residual:.3f} m after {a.iterations} ICP steps")
        if best is None or (a.inliers, -a.residual) > (best.inliers, -best.residual):
            best = a
    assert best is not None
    return _icp(src, tree, best.yaw, best.x, best.y, cell) if len(few) < len(src) else best


def _likelihood_field(plan: Grid, cell: float):
    """The plan's walls as a likelihood field on a grid of ``cell`` m (row 0 = bottom), padded."""
    pts = plan.wall_points()
    pad = 2.0 * cell
    lo = pts.min(axis=0) - pad - 5 * cell
    hi = pts.max(axis=0) + pad + 5 * cell
    w, h = (np.ceil((hi - lo) / cell).astype(int) + 1).tolist()
    occ = np.zeros((h, w), dtype=bool)
    ij = np.floor((pts - lo) / cell).astype(np.int64)
    occ[ij[:, 1], ij[:, 0]] = True
    d = ndimage.distance_transform_edt(~occ) * cell
    sigma = cell
    return np.exp(-0.5 * (d / sigma) ** 2), lo


def _best_shift(src: np.ndarray, yaw: float, field: np.ndarray, field_origin: np.ndarray, cell: float):
    """``(score, tx, ty)``: the translation that maximises the field summed over the rotated
    ``src`` (FFT cross-correlation over every integer-cell shift), and its score per point."""
    c, s = math.cos(yaw), math.sin(yaw)
    q = src @ np.array([[c, s], [-s, c]])
    qmin = q.min(axis=0)
    ij = np.floor((q - qmin) / cell).astype(np.int64)
    hb, wb = int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1
    hf, wf = field.shape
    shape = (fft.next_fast_len(hf + hb), fft.next_fast_len(wf + wb))
    img = np.bincount(ij[:, 1] * wb + ij[:, 0], minlength=hb * wb).reshape(hb, wb).astype(np.float64)
    corr = fft.irfft2(fft.rfft2(field, shape) * np.conj(fft.rfft2(img, shape)), shape)
    k = int(np.argmax(corr))
    si, sj = divmod(k, shape[1])
    si = si - shape[0] if si > shape[0] - hb else si  # negative shifts wrap to the end
    sj = sj - shape[1] if sj > shape[1] - wb else sj
    t = field_origin + np.array([sj, si]) * cell - qmin
    return float(corr.flat[k]) / len(src), float(t[0]), float(t[1])


def _distinct(scored, n: int, apart: float):
    """The ``n`` best ``(score, tx, ty, yaw)`` whose headings differ by more than ``apart``."""
    out = []
    for cand in scored:
        if all(abs(math.remainder(cand[3] - o[3], math.tau)) > apart for o in out):
            out.append(cand)
            if len(out) == n:
                break
    return out


def _icp(src: np.ndarray, tree: cKDTree, yaw: float, tx: float, ty: float, cell: float, iters: int = 60) -> Alignment:
    """Point-to-point ICP from ``(tx, ty, yaw)``: nearest plan wall per built wall, pairs within
    a gate that shrinks from 3 coarse cells, closed-form rigid fit; stops when it stops moving."""
    gate = 3.0 * cell
    R = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    t = np.array([tx, ty])
    it = 0
    while it < iters:
        it += 1
        moved = src @ R.T + t
        d, j = tree.query(moved, distance_upper_bound=gate)
        keep = np.isfinite(d)
        if keep.sum() < 3:
            break
        p, q = src[keep], tree.data[j[keep]]
        pc, qc = p.mean(axis=0), q.mean(axis=0)
        u, _, vt = np.linalg.svd((p - pc).T @ (q - qc))
        dm = np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))])
        R_new = vt.T @ dm @ u.T
        t_new = qc - R_new @ pc
        step = np.abs(t_new - t).max() + abs(math.atan2(R_new[1, 0], R_new[0, 0]) - math.atan2(R[1, 0], R[0, 0]))
        R, t = R_new, t_new
        gate = max(0.1, gate * 0.8)
        if step < 1e-5:
            break
    moved = src @ R.T + t
    d, _ = tree.query(moved)
    return Alignment(
        x=float(t[0]),
        y=float(t[1]),
        yaw=float(math.atan2(R[1, 0], R[0, 0])),
        residual=float(d.mean()),
        inliers=float((d <= 0.10 + 1e-9).mean()),
        points=len(src),
        iterations=it,
    )


def resample(built: Grid, a: Alignment, snap_to: Grid | None = None) -> Grid:
    """``built`` moved into the plan frame by ``a``: an axis-aligned grid (yaw 0) at the built map's
    resolution covering it (cell lines on ``snap_to``'s when given), each cell the built cell
    under its centre (nearest), unknown outside the built map."""
    res = built.resolution
    hb, wb = built.occupancy.shape
    corners = np.array([[0.0, 0.0], [wb * res, 0.0], [0.0, hb * res], [wb * res, hb * res]])
    moved = a.apply(built.to_world(corners))
    lo, hi = moved.min(axis=0), moved.max(axis=0)
    if snap_to is not None and snap_to.yaw == 0.0:
        so = np.array(snap_to.origin)
        lo = so + np.floor((lo - so) / res) * res
    w, h = (np.ceil((hi - lo) / res - 1e-9).astype(int)).tolist()
    cx = lo[0] + (np.arange(w) + 0.5) * res
    cy = lo[1] + (np.arange(h)[::-1] + 0.5) * res  # row 0 = top
    X, Y = np.meshgrid(cx, cy)
    c, s = math.cos(a.yaw), math.sin(a.yaw)
    dx, dy = X - a.x, Y - a.y
    b = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)  # R^T (p - t): the built map's world
    uv = built.to_grid(b)
    ix = np.floor(uv[..., 0] / res).astype(np.int64)
    iy = np.floor(uv[..., 1] / res).astype(np.int64)
    inside = (ix >= 0) & (ix < wb) & (iy >= 0) & (iy < hb)
    out = np.full((h, w), -1.0)
    out[inside] = built.occupancy[hb - 1 - iy[inside], ix[inside]]
    return Grid(out, res, (float(lo[0]), float(lo[1])))
