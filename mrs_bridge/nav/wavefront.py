"""Wavefront global path planner: NF1 navigation function over a configuration-space grid.

Implements the wavefront (NF1) planner of Latombe, *Robot Motion Planning* (Kluwer, 1991),
ch. 7: the robot is shrunk to a point and the obstacles grown by its radius, a wave of costs
spreads from the goal over the free configuration space, and the path descends that potential
from the start. It behaves as Player's ``wavefront`` driver as documented in the Player manual
(thesis 3.4.1 and appendix A.3): the same parameters (``safety_dist``, ``max_radius``,
``dist_penalty``; the executive adds ``distance_epsilon``, ``angle_epsilon``,
``replan_dist_thresh``, ``replan_min_time``) and the same behaviour: paths keep
``robot_radius + safety_dist`` from obstacles, prefer the middle of corridors, and reach the
local planner as intermediate goals in line of sight of each other, one at a time.

Configuration space (:class:`Wavefront`, built once per map): a cell is *allowed* when its
centre is at least ``robot_radius + safety_dist`` from every occupied or unknown cell centre.
Moving a length ``l`` between neighbouring cells ``a`` and ``b`` costs
``l * (w(a) + w(b)) / 2`` with ``w(c) = 1 + dist_penalty * max(0, max_radius - clearance(c))``:
pure length in the open, more near walls. (Player adds its penalty per cell step; here it is
per metre, so the same ``dist_penalty`` means the same thing at every map resolution.)

Search: Dijkstra's algorithm over the 8-connected grid from the goal (diagonal steps cost
``sqrt 2`` cells and may not cut the corner of a forbidden cell), compiled with numba, with an
indexed binary heap. A plan orders the wave by cost plus the octile distance to the start (A*,
Hart, Nilsson and Raphael 1968) and stops it once the start is settled; the cost to the goal of
every settled cell is then that of the full wavefront. The wave is kept: a replan to the same
goal (the robot strayed) continues it, usually settling nothing new, and
:meth:`Wavefront.potential` completes it over the whole map for display. Whether the start can
reach the goal at all is known before searching, from the connected components of the allowed
cells, so an unreachable goal fails in microseconds.

Path and waypoints: the cell path follows each cell's settled predecessor from the start to the
goal (steepest descent of the potential). Waypoints are the corners left after line-of-sight
simplification: from each waypoint, the next is the farthest path point reachable by a straight
segment that crosses only allowed cells (an exact grid traversal, Amanatides and Woo 1987, that
also checks both cells beside a segment passing exactly through a cell corner).

:class:`~mrs_bridge.nav.executive.Executive` (its own module; still importable from here) drives
a plan as Player's driver does: it hands the waypoints one by one to the local planner, advances
within ``distance_epsilon``, finishes at the goal within ``distance_epsilon`` and
``angle_epsilon``, and replans when the robot strays from the path.

Errors are :class:`PlanError` with a ``code``: ``"outside_map"``, ``"in_obstacle"``,
``"unreachable"``. Memory: the configuration space takes 9 bytes per cell and is shared by
:meth:`Wavefront.clone`; each planner's search state 17 bytes per cell (28 MB on the 1280 x 1280
arena), allocated by its first plan. A planner is not thread-safe (use one per robot); the
compiled kernels release the GIL.

The module stays whole at over 500 lines: the compiled kernels (indexed heap, the A*-ordered
wavefront, the path trace, the exact line-of-sight traversal) and :class:`Wavefront`, which owns
their configuration space and search state, are one algorithm that no caller uses in parts.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy import ndimage

from rsal.errors import RsalError

from .grid import NavGrid

__all__ = ["PlanError", "Plan", "Wavefront"]

_SQRT2 = math.sqrt(2.0)
# Neighbour steps: four sides, then four diagonals.
_DX = np.array([1, -1, 0, 0, 1, -1, 1, -1], dtype=np.int64)
_DY = np.array([0, 0, 1, -1, 1, 1, -1, -1], dtype=np.int64)
_NO_PARENT = 255
# The heuristic is scaled by (1 + this) so that among equal estimates the cell nearer the start
# is settled first; the path found is then within this fraction of optimal.
_TIE_BREAK = 1e-6


class PlanError(RsalError):
    """No plan: ``code`` is ``"outside_map"``, ``"in_obstacle"`` or ``"unreachable"``."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


@dataclass
class Plan:
    """A planned path in world metres.

    Every segment between waypoints crosses allowed cells only, except, when the start lay in
    the forbidden band, the first: from the start to the allowed cell it was moved to (which is
    then ``waypoints[1]`` and ``path[0]``), across free cells.
    """

    #: ``(k, 2)`` waypoints, ``k >= 2``: the start as given, the corners, the goal as given
    waypoints: np.ndarray
    #: ``(m, 2)`` centres of the cells the path crosses, start cell first, goal cell last
    path: np.ndarray
    #: metres along the waypoints
    length: float


# ---------------------------------------------------------------------------------------- kernels
@nb.njit(cache=True, nogil=True, inline="always")
def _sift_up(keys, cells, pos, k):
    key = keys[k]
    c = cells[k]
    while k > 0:
        p = (k - 1) >> 1
        if keys[p] <= key:
            break
        keys[k] = keys[p]
        cells[k] = cells[p]
        pos[cells[k]] = k
        k = p
    keys[k] = key
    cells[k] = c
    pos[c] = k


@nb.njit(cache=True, nogil=True, inline="always")
def _sift_down(keys, cells, pos, k, n):
    key = keys[k]
    c = cells[k]
    while True:
        ch = 2 * k + 1
        if ch >= n:
            break
        if ch + 1 < n and keys[ch + 1] < keys[ch]:
            ch += 1
        if keys[ch] >= key:
            break
        keys[k] = keys[ch]
        cells[k] = cells[ch]
        pos[cells[k]] = k
        k = ch
    keys[k] = key
    cells[k] = c
    pos[c] = k


@nb.njit(cache=True, nogil=True, inline="always")
def _octile(x, y, tx, ty, hscale):
    ax = abs(x - tx)
    ay = abs(y - ty)
    return hscale * (max(ax, ay) + (_SQRT2 - 1.0) * min(ax, ay))


@nb.njit(cache=True, nogil=True)
def _search(allowed, weight, wp, res, goal, target, g, stamp, parent, pos, keys, cells, n, gen, fresh):
    """Grow the wavefront from ``goal``; returns ``(cells settled, heap size, keys, cells)``.

    All per-cell arrays are flat over the padded grid (row length ``wp``, a forbidden border so
    no bounds checks). ``g`` is the cost to the goal, ``parent`` the step index from a cell's
    predecessor to it, ``stamp`` ``2*gen`` while open and ``2*gen+1`` once settled (older values:
    untouched). The open cells are a binary heap (``keys``, ``cells``, size ``n``) indexed by
    ``pos``, so an improved cost moves its cell up instead of adding a duplicate.

    ``fresh`` starts a new wave; otherwise the heap of an earlier call for the same goal is
    re-keyed and the wave continues: settled costs are final whatever order the rest is settled
    in. With ``target >= 0`` the heap is ordered by cost plus the octile distance to the target
    (A*) and the wave stops once the target is settled; with ``target < 0`` it runs until every
    reachable cell is settled.
    """
    opened = 2 * gen
    settled = 2 * gen + 1
    if target >= 0:
        tx = target % wp
        ty = target // wp
        hscale = res * (1.0 + _TIE_BREAK)
    else:
        tx = 0
        ty = 0
        hscale = 0.0
    if fresh:
        g[goal] = 0.0
        stamp[goal] = opened
        parent[goal] = _NO_PARENT
        keys[0] = 0.0
        cells[0] = goal
        pos[goal] = 0
        n = 1
    else:
        if target >= 0 and stamp[target] == settled:
            return 0, n, keys, cells
        for k in range(n):
            c = cells[k]
            keys[k] = g[c] + _octile(c % wp, c // wp, tx, ty, hscale)
        for k in range(n // 2 - 1, -1, -1):
            _sift_down(keys, cells, pos, k, n)
    cap = keys.shape[0]
    diag = res * _SQRT2
    count = 0
    while n > 0:
        c = cells[0]
        n -= 1
        if n > 0:
            keys[0] = keys[n]
            cells[0] = cells[n]
            _sift_down(keys, cells, pos, 0, n)
        stamp[c] = settled
        count += 1
        gc = g[c]
        wc = weight[c]
        cx = c % wp
        cy = c // wp
        for d in range(8):
            ni = c + _DX[d] + _DY[d] * wp
            if not allowed[ni]:
                continue
            st = stamp[ni]
            if st == settled:
                continue
            if d >= 4:
                if not allowed[c + _DX[d]] or not allowed[c + _DY[d] * wp]:
                    continue  # would cut the corner of a forbidden cell
                step = diag
            else:
                step = res
            ng = gc + step * 0.5 * (wc + weight[ni])
            if st != opened:
                g[ni] = ng
                stamp[ni] = opened
                parent[ni] = d
                if n == cap:
                    cap *= 2
                    nk = np.empty(cap, dtype=keys.dtype)
                    nc = np.empty(cap, dtype=cells.dtype)
                    nk[:n] = keys[:n]
                    nc[:n] = cells[:n]
                    keys = nk
                    cells = nc
                keys[n] = ng + _octile(cx + _DX[d], cy + _DY[d], tx, ty, hscale)
                cells[n] = ni
                _sift_up(keys, cells, pos, n)
                n += 1
            elif ng < g[ni]:
                k = pos[ni]
                keys[k] -= g[ni] - ng
                g[ni] = ng
                parent[ni] = d
                _sift_up(keys, cells, pos, k)
        if c == target:
            break
    return count, n, keys, cells


@nb.njit(cache=True, nogil=True)
def _trace(parent, wp, start):
    """Unpadded cells ``(ix, iy)`` from ``start`` along the predecessors to the goal."""
    m = 1
    c = start
    while parent[c] != _NO_PARENT:
        d = parent[c]
        c = c - _DX[d] - _DY[d] * wp
        m += 1
    out = np.empty((m, 2), dtype=np.int64)
    c = start
    for k in range(m):
        out[k, 0] = c % wp - 1
        out[k, 1] = c // wp - 1
        if k + 1 < m:
            d = parent[c]
            c = c - _DX[d] - _DY[d] * wp
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _ok(allowed2, ix, iy):
    h, w = allowed2.shape
    return 0 <= ix < w and 0 <= iy < h and allowed2[iy, ix]


@nb.njit(cache=True, nogil=True)
def _visible(allowed2, fx0, fy0, fx1, fy1):
    """True when the segment between two points in cell units crosses only allowed cells.

    Visits every cell the segment meets (Amanatides-Woo traversal); where it passes exactly
    through a cell corner, both cells beside the corner must be allowed too.
    """
    ix = int(math.floor(fx0))
    iy = int(math.floor(fy0))
    if not _ok(allowed2, ix, iy):
        return False
    dx = fx1 - fx0
    dy = fy1 - fy0
    if dx > 0.0:
        sx = 1
        tmx = (ix + 1 - fx0) / dx
        tdx = 1.0 / dx
    elif dx < 0.0:
        sx = -1
        tmx = (fx0 - ix) / -dx
        tdx = -1.0 / dx
    else:
        sx = 0
        tmx = math.inf
        tdx = math.inf
    if dy > 0.0:
        sy = 1
        tmy = (iy + 1 - fy0) / dy
        tdy = 1.0 / dy
    elif dy < 0.0:
        sy = -1
        tmy = (fy0 - iy) / -dy
        tdy = -1.0 / dy
    else:
        sy = 0
        tmy = math.inf
        tdy = math.inf
    while True:
        t = min(tmx, tmy)
        if t >= 1.0:
            return True
        if abs(tmx - tmy) <= 1e-9:
            if not _ok(allowed2, ix + sx, iy) or not _ok(allowed2, ix, iy + sy):
                return False
            ix += sx
            iy += sy
            tmx += tdx
            tmy += tdy
        elif tmx < tmy:
            ix += sx
            tmx += tdx
        else:
            iy += sy
            tmy += tdy
        if not _ok(allowed2, ix, iy):
            return False


@nb.njit(cache=True, nogil=True)
def _simplify(allowed2, fx, fy):
    """Indices of the points kept by greedy line-of-sight simplification (first and last kept).

    Consecutive points are taken as connected even when not visible (the first step out of a
    snapped start).
    """
    n = fx.shape[0]
    keep = np.empty(n, dtype=np.int64)
    keep[0] = 0
    k = 1
    i = 0
    while i < n - 1:
        j = i + 1
        while j + 1 < n and _visible(allowed2, fx[i], fy[i], fx[j + 1], fy[j + 1]):
            j += 1
        keep[k] = j
        k += 1
        i = j
    return keep[:k]


# ---------------------------------------------------------------------------------------- planner
def _fmt(p) -> str:
    return f"({p[0]:.2f}, {p[1]:.2f})"


def _point(p, what: str) -> tuple[float, float]:
    try:
        x, y = float(p[0]), float(p[1])
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"{what} must be (x, y[, yaw]) in metres, not {p!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"{what} must be finite metres, not {p!r}")
    return x, y


class Wavefront:
    """Global planner on one map: configuration space built once, a wavefront per plan.

    ``robot_radius`` and ``safety_dist`` (metres) make the forbidden band around obstacles;
    ``max_radius`` (metres) is the clearance below which cells cost extra, ``dist_penalty``
    (per metre travelled per metre of missing clearance) how much. A start in the forbidden
    band is moved to the nearest allowed cell within ``snap_radius`` metres (default
    ``robot_radius + safety_dist``: any free start is that close to allowed space).
    """

    def __init__(
        self,
        grid: NavGrid,
        *,
        robot_radius: float = 0.25,
        safety_dist: float = 0.25,
        max_radius: float = 1.0,
        dist_penalty: float = 1.0,
        snap_radius: float | None = None,
    ):
        for name, v in (
            ("robot_radius", robot_radius),
            ("safety_dist", safety_dist),
            ("max_radius", max_radius),
            ("dist_penalty", dist_penalty),
        ):
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a non-negative number of metres, not {v!r}")
        self.grid = grid
        self.robot_radius = float(robot_radius)
        self.safety_dist = float(safety_dist)
        self.max_radius = float(max_radius)
        self.dist_penalty = float(dist_penalty)
        #: the clearance a cell needs to be allowed
        self.min_clearance = self.robot_radius + self.safety_dist
        self.snap_radius = self.min_clearance if snap_radius is None else float(snap_radius)
        blocked = grid.cells >= 0  # occupied or unknown
        if not blocked.any():
            clear = np.full(blocked.shape, np.float32(1e6), dtype=np.float32)
        elif (grid.cells == 0).any():
            clear = (ndimage.distance_transform_edt(~blocked) * grid.resolution).astype(np.float32)
        else:
            clear = grid.distance
        #: metres from each cell centre to the nearest occupied or unknown cell centre
        self.clearance = clear
        # The search runs on copies padded with a forbidden border (no bounds checks).
        h, w = clear.shape
        self._wp = w + 2
        self._allowed_p = np.zeros((h + 2, w + 2), dtype=np.bool_)
        self._allowed_p[1:-1, 1:-1] = clear >= self.min_clearance
        #: cells the robot's centre may occupy (a view)
        self.allowed = self._allowed_p[1:-1, 1:-1]
        self._weight_p = np.ones((h + 2, w + 2), dtype=np.float32)
        self._weight_p[1:-1, 1:-1] += np.float32(self.dist_penalty) * np.maximum(
            np.float32(self.max_radius) - clear, np.float32(0.0)
        )
        # With no corner cutting, 8-connected moves join exactly the 4-connected components.
        self._labels, _ = ndimage.label(self.allowed)
        for a in (self._allowed_p, self.allowed, self._weight_p, self._labels):
            a.flags.writeable = False  # shared by clones
        self._new_search_state()

    def clone(self) -> Wavefront:
        """A planner on the same configuration space (shared, read-only) with its own search state.

        For several robots of one size on one map: each needs its own planner, but only one copy of
        the map-sized configuration space.
        """
        other = copy.copy(self)
        other._new_search_state()
        return other

    def _new_search_state(self) -> None:
        # Map-sized search buffers are allocated by the first plan.
        self._g: np.ndarray | None = None
        self._stamp: np.ndarray | None = None
        self._parent: np.ndarray | None = None
        self._pos: np.ndarray | None = None
        self._keys = np.empty(4096, dtype=np.float64)
        self._cells = np.empty(4096, dtype=np.int32)
        self._heap_n = 0
        self._gen = 0
        self._goal_cell: int | None = None  # padded index of the goal the wave state belongs to
        self._complete = False
        self._potential: np.ndarray | None = None
        #: cells the last call settled (0 when an earlier wave to the same goal already covered the start)
        self.last_expanded = 0

    # ------------------------------------------------------------------ planning
    def plan(self, start, goal) -> Plan:
        """Plan from ``start`` to ``goal`` (``(x, y)`` or ``(x, y, yaw)``, world metres)."""
        sx, sy = _point(start, "start")
        gx, gy = _point(goal, "goal")
        grid = self.grid
        gc = self._cell_or_raise((gx, gy), "goal")
        if not self.allowed[gc[1], gc[0]]:
            raise PlanError(
                "in_obstacle",
                f"goal {_fmt((gx, gy))} is {self.clearance[gc[1], gc[0]]:.2f} m from an obstacle, closer than "
                f"robot_radius + safety_dist = {self.min_clearance:.2f} m; pick a goal in open space "
                "or lower safety_dist",
            )
        glabel = self._labels[gc[1], gc[0]]
        sc = self._start_cell((sx, sy), glabel)
        if self._labels[sc[1], sc[0]] != glabel:
            raise PlanError(
                "unreachable",
                f"no path from start {_fmt((sx, sy))} to goal {_fmt((gx, gy))}: they are not connected by space "
                f"at least robot_radius + safety_dist = {self.min_clearance:.2f} m from obstacles; "
                "pick a goal in the start's free region or lower safety_dist",
            )
        wp = self._wp
        goal_i = (int(gc[1]) + 1) * wp + int(gc[0]) + 1
        start_i = (int(sc[1]) + 1) * wp + int(sc[0]) + 1
        self._grow(goal_i, start_i)
        cells = _trace(self._parent, wp, start_i)
        path = np.column_stack(grid.cell_to_world(cells[:, 0], cells[:, 1])).astype(np.float64)
        pts = np.vstack([[sx, sy], path, [gx, gy]])
        res = grid.resolution
        fx = (pts[:, 0] - grid.origin[0]) / res
        fy = (pts[:, 1] - grid.origin[1]) / res
        keep = _simplify(self.allowed, fx, fy)
        waypoints = pts[keep]
        length = float(np.hypot(*np.diff(waypoints, axis=0).T).sum())
        return Plan(waypoints=waypoints, path=path, length=length)

    def potential(self) -> np.ndarray:
        """The last goal's wavefront: ``(height, width)`` cost to the goal, ``inf`` where unreachable.

        Computed over the whole map on the first call after a plan (the plans themselves stop
        the wave at the start); all ``inf`` before any plan and after :meth:`reset`.
        """
        grid = self.grid
        if self._goal_cell is None:
            return np.full((grid.height, grid.width), np.inf)
        if self._potential is None:
            self._grow(self._goal_cell, -1)
            settled = self._stamp.reshape(grid.height + 2, self._wp)[1:-1, 1:-1] == 2 * self._gen + 1
            self._potential = np.where(settled, self._g.reshape(grid.height + 2, self._wp)[1:-1, 1:-1], np.inf)
            self._potential.flags.writeable = False
        return self._potential

    def reset(self) -> None:
        """Forget the kept wave: the next plan starts a fresh one even to the same goal."""
        self._goal_cell = None
        self._heap_n = 0
        self._complete = False
        self._potential = None

    # ------------------------------------------------------------------ helpers
    def _grow(self, goal: int, target: int) -> None:
        """Grow the wave from ``goal`` (padded index) until ``target`` is settled (all cells if -1).

        A wave to the same goal as the last call is continued, so replanning to an unchanged goal
        only settles the cells the earlier waves had not reached.
        """
        if self._g is None:
            # Written through now, so no later plan pays the page faults of first touching them.
            n = self._allowed_p.size
            self._g = np.full(n, np.inf)
            self._stamp = np.full(n, 0, dtype=np.int32)
            self._parent = np.full(n, _NO_PARENT, dtype=np.uint8)
            self._pos = np.full(n, -1, dtype=np.int32)
        fresh = goal != self._goal_cell
        if fresh:
            self._gen += 1
            if self._gen >= 2**30 - 1:
                self._stamp.fill(0)
                self._gen = 1
            self._goal_cell = goal
            self._complete = False
            self._potential = None
        elif self._complete:
            self.last_expanded = 0
            return
        count, self._heap_n, self._keys, self._cells = _search(
            self._allowed_p.ravel(),
            self._weight_p.ravel(),
            self._wp,
            self.grid.resolution,
            goal,
            target,
            self._g,
            self._stamp,
            self._parent,
            self._pos,
            self._keys,
            self._cells,
            self._heap_n,
            self._gen,
            fresh,
        )
        self.last_expanded = int(count)
        if self._heap_n == 0:
            self._complete = True

    def _cell_or_raise(self, p: tuple[float, float], what: str) -> tuple[int, int]:
        grid = self.grid
        ix, iy = grid.world_to_cell(p[0], p[1])
        ix, iy = int(ix), int(iy)
        if not grid.in_bounds_cell(ix, iy):
            x0, x1, y0, y1 = grid.extent
            raise PlanError(
                "outside_map",
                f"{what} {_fmt(p)} is outside the map (x {x0:.2f} .. {x1:.2f}, y {y0:.2f} .. {y1:.2f}); "
                f"pick a {what} inside the map",
            )
        v = grid.cells[iy, ix]
        if v >= 0:
            kind = "an obstacle" if v > 0 else "unknown space"
            fix = "pick a goal in open space" if what == "goal" else "relocalize the robot or move it clear"
            raise PlanError("in_obstacle", f"{what} {_fmt(p)} is inside {kind} on the map; {fix}")
        return ix, iy

    def _start_cell(self, p: tuple[float, float], label: int) -> tuple[int, int]:
        """The start's cell or, in the forbidden band, the nearest allowed cell within ``snap_radius``
        in straight sight over free cells (one in the goal's region if there is one)."""
        ix, iy = self._cell_or_raise(p, "start")
        if self.allowed[iy, ix]:
            return ix, iy
        grid = self.grid
        r = int(math.ceil(self.snap_radius / grid.resolution)) + 1
        x0, x1 = max(ix - r, 0), min(ix + r + 1, grid.width)
        y0, y1 = max(iy - r, 0), min(iy + r + 1, grid.height)
        cx, cy = grid.cell_to_world(np.arange(x0, x1), np.arange(y0, y1))
        d = np.hypot(cx[None, :] - p[0], cy[:, None] - p[1])
        ok = self.allowed[y0:y1, x0:x1] & (d <= self.snap_radius)
        same = self._labels[y0:y1, x0:x1] == label
        ky, kx = np.nonzero(ok)
        order = np.lexsort((d[ky, kx], ~same[ky, kx]))  # the goal's region first, then nearest
        fx = (p[0] - grid.origin[0]) / grid.resolution
        fy = (p[1] - grid.origin[1]) / grid.resolution
        for k in order:
            if _visible(grid.free, fx, fy, x0 + kx[k] + 0.5, y0 + ky[k] + 0.5):
                return x0 + int(kx[k]), y0 + int(ky[k])
        raise PlanError(
            "in_obstacle",
            f"start {_fmt(p)} is {self.clearance[iy, ix]:.2f} m from an obstacle and no cell within "
            f"{self.snap_radius:.2f} m has robot_radius + safety_dist = {self.min_clearance:.2f} m of clearance; "
            "move the robot into open space or lower safety_dist",
        )


def __getattr__(name: str):
    """``Executive`` lives in :mod:`mrs_bridge.nav.executive` (which imports this module)."""
    if name == "Executive":
        from .executive import Executive

        return Executive
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
