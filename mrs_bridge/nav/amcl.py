"""Adaptive Monte Carlo Localization (AMCL) on a :class:`NavGrid`: the filter behind the ``amcl`` driver.

A particle filter over the robot's map pose ``(x, y, yaw)`` (thesis 3.3, appendix A.3) with
Player's ``amcl`` parameter names, vectorised over particles and beams at once:

* **Motion**: ``sample_motion_model_odometry`` of Thrun, Burgard and Fox, *Probabilistic Robotics*
  (2005), ch. 5.4. The odometry change since the last filter update is split into a rotation, a
  translation and a second rotation in the robot frame, each perturbed by Gaussian noise whose
  variance grows with ``odom_alpha1..4`` (rotation from rotation, rotation from translation,
  translation from translation, translation from rotation), so the odometry frame's origin does not
  matter. When the robot reverses, the rotation noise uses the smaller of ``rot`` and ``pi - rot``.
  As in Player, particles move only when the robot has moved ``update_thresh`` since the last
  update (a fresh belief takes the first scan regardless); :meth:`Amcl.estimate` adds the odometry
  motion since then.
* **Measurement**: the likelihood-field range model, ch. 6.4: a beam endpoint at distance ``d`` from
  the nearest obstacle surface (capped at ``laser_likelihood_max_dist``) has likelihood
  ``z_hit * N(d; 0, sigma_hit) + z_rand / z_max``; a particle's log-likelihood is the sum over at
  most ``laser_max_beams`` beams spread evenly over the valid ones (max-range readings skipped).
  ``d`` counts depth inside obstacles too: the grid's own field, 0 anywhere inside a wall, pulls
  the estimate towards poses whose beams end deep in thick walls (0.25 m off on the floor map).
  Beams carry their own origins and bearings in the robot frame, so a laser and a Pioneer sonar
  ring share the code. A compiled kernel (numba) makes one fused pass over particles x beams.
* **Measurement of sonar cones** (``beam_width`` > 0): the beam model, ch. 6.3, with the expected
  range the least over :data:`CONE_RAYS` rays cast across the cone (:mod:`.conebeam`, which says
  why the likelihood field is biased towards walls for cones).
* **Distance filter** (an extension, ``laser_unmodeled_margin``; Fox, Burgard and Thrun, "Markov
  localization for mobile robots in dynamic environments", JAIR 11, 1999, sec. 4.2): while the
  belief is tight, laser readings much shorter than the map predicts at the mean pose (a robot or a
  person not on the map cut them short) are left out of the update (:mod:`.distfilter`).
* **Tempering** (an extension, ``pf_temper_ess``): beams are not independent, and with the plain
  product of 30 beams one update can leave a single particle standing. Each scan's likelihood is
  raised to the largest power ``beta`` in (0, 1] that keeps the effective sample size of the new
  weights at least ``pf_temper_ess`` times that of the old ones (adaptive tempering, as adaptive
  sequential Monte Carlo chooses its temperatures). While the particles are spread (global
  localization, after a kidnapping) evidence is let in gradually and rival hypotheses survive
  until the robot has seen enough to tell them apart; 0 applies the full likelihood.
* **Resampling**: low-variance (systematic) resampling, ch. 4.3 (table 4.4), every
  ``resample_interval`` sensor updates, with the particle count from KLD-sampling (Fox, "Adapting
  the sample size in particle filters through KLD-sampling", IJRR 22(12), 2003): the smallest
  ``n`` whose samples occupy ``k`` histogram bins (0.5 m x 0.5 m x 10 deg) with
  ``n >= (k - 1) / (2 pf_err) * (1 - 2/(9(k-1)) + sqrt(2/(9(k-1))) pf_z) ** 3``, between
  ``pf_min_samples`` and ``pf_max_samples``; ``k(n)`` is counted on i.i.d. draws as in Fox's
  sequential algorithm, in growing chunks, with ``np.unique`` on the bin indices.
* **Recovery**: Augmented MCL, ch. 8.3.5 (table 8.3): short- and long-term averages
  (``recover_alpha_fast``, ``recover_alpha_slow``) of the measurement likelihood; each resampled
  particle is replaced by a uniform random pose on a free cell with probability
  ``max(0, 1 - w_fast / w_slow)``. The likelihood averaged is the per-beam geometric mean under the
  untempered posterior (how well the best hypotheses explain the scan), so neither the beam count,
  nor the tempering, nor the random particles themselves move it. Injected particles stay out of
  the estimate until a scan has weighed them.
* **Output**: the weighted mean and 3x3 covariance of the particles (thesis eq. 3.3-3.4), yaw by
  circular statistics; and Player's ``localize`` hypotheses, one per cluster of connected occupied
  KLD bins (``scipy.ndimage.label``, yaw periodic).

Not thread-safe: call an :class:`Amcl` from one thread.

The module stays whole at over 500 lines: motion, measurement, tempering, resampling, recovery and
output are the steps of one filter over one set of particle arrays, with the compiled kernel the
measurement step runs; its parameters are in :mod:`mrs_bridge.nav.amclparams` (re-exported here).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from rsal.geometry import compose_array, relative, wrap

from .amclparams import AmclParams
from .conebeam import CONE_RAYS, ConeMap, cone_beam_jit, cone_expected_jit
from .distfilter import expected_ranges, unmodeled
from .grid import NavGrid
from .knownobstacles import explained_by_obstacles
from .landmarks import landmark_beam_jit

__all__ = [
    "CONE_RAYS",
    "Amcl",
    "AmclParams",
    "kld_sample_count",
    "likelihood_field_jit",
    "likelihood_field_numpy",
    "systematic_indices",
]

BIN_XY = 0.5  # m, KLD histogram bin (Fox 2003; Player's amcl)
BIN_YAW = math.radians(10.0)  # rad
_N_YAW_BINS = int(round(2.0 * math.pi / BIN_YAW))
_MAX_RANGE_TOL = 1e-3  # m: a reading this close to range_max is a max-range reading


# ---------------------------------------------------------------------- sampling helpers
def systematic_indices(cdf: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Low-variance (systematic) resampling, *Probabilistic Robotics* table 4.4: ``n`` indices drawn
    with one random offset and a stride of ``1/n`` through the cumulative weights ``cdf``."""
    pos = (rng.random() + np.arange(n)) / n
    return np.minimum(np.searchsorted(cdf, pos, side="right"), cdf.shape[0] - 1)


def kld_sample_count(k, err: float, z: float) -> np.ndarray:
    """Fox 2003, eq. 12: samples needed so that, with ``k`` occupied bins, the KL divergence between
    the sample histogram and the true one stays below ``err`` with the confidence of quantile ``z``
    (Wilson-Hilferty approximation of the chi-square quantile). Vectorised over ``k``."""
    k = np.asarray(k, dtype=np.float64)
    km1 = np.maximum(k - 1.0, 1.0)
    b = 2.0 / (9.0 * km1)
    n = km1 / (2.0 * err) * (1.0 - b + np.sqrt(b) * z) ** 3
    return np.where(k > 1.0, np.ceil(n), 0.0)


def _bin_triples(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    bx = np.floor(p[:, 0] / BIN_XY).astype(np.int64)
    by = np.floor(p[:, 1] / BIN_XY).astype(np.int64)
    bt = np.floor((wrap(p[:, 2]) + math.pi) / BIN_YAW).astype(np.int64) % _N_YAW_BINS
    return bx, by, bt


def _bin_keys(p: np.ndarray) -> np.ndarray:
    """One int64 per particle naming its KLD bin."""
    bx, by, bt = _bin_triples(p)
    return ((bx + (1 << 20)) << 26) | ((by + (1 << 20)) << 6) | bt


def _mean_cov(p: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and covariance (thesis eq. 3.3-3.4 with weights); circular mean and variance of yaw."""
    w = w / w.sum()
    # Plain ufunc reductions, not BLAS: a threaded BLAS dot costs milliseconds on a busy machine.
    x, y, t = (np.ascontiguousarray(p[:, i]) for i in range(3))
    sn, cs = np.sin(t), np.cos(t)
    mx, my, sc, cc = (float((w * v).sum()) for v in (x, y, sn, cs))
    mt = math.atan2(sc, cc)
    d = (x - mx, y - my, wrap(t - mt))
    cov = np.empty((3, 3))
    for i in range(3):
        wd = w * d[i]
        for j in range(i, 3):
            cov[i, j] = cov[j, i] = float((wd * d[j]).sum())
    cov[2, 2] = -2.0 * math.log(max(min(math.hypot(sc, cc), 1.0), 1e-300))  # circular variance
    return np.array([mx, my, mt]), cov


@nb.njit(cache=True)
def _ess_fraction(log_prior, loglik, beta):  # pragma: no cover - compiled
    """Effective sample size over particle count of the weights ``exp(log_prior + beta * loglik)``."""
    n = log_prior.shape[0]
    top = -np.inf
    for i in range(n):
        top = max(top, log_prior[i] + beta * loglik[i])
    s1 = 0.0
    s2 = 0.0
    for i in range(n):
        e = math.exp(log_prior[i] + beta * loglik[i] - top)
        s1 += e
        s2 += e * e
    return s1 * s1 / s2 / n


def tempering_exponent(log_prior: np.ndarray, loglik: np.ndarray, ess_ratio: float, iters: int = 10) -> float:
    """The largest ``beta`` in (0, 1] for which the weights ``prior * likelihood ** beta`` keep an
    effective sample size of at least ``ess_ratio`` times that of the prior weights (1 if the full
    likelihood does). Bisection on ``log beta`` between 1e-4 and 1, to about 1 %."""
    if ess_ratio <= 0.0:
        return 1.0
    target = ess_ratio * _ess_fraction(log_prior, loglik, 0.0)
    if _ess_fraction(log_prior, loglik, 1.0) >= target:
        return 1.0
    lo, hi = math.log(1e-4), 0.0
    if _ess_fraction(log_prior, loglik, math.exp(lo)) < target:
        return math.exp(lo)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if _ess_fraction(log_prior, loglik, math.exp(mid)) >= target:
            lo = mid
        else:
            hi = mid
    return math.exp(lo)


# ---------------------------------------------------------------------- likelihood field kernels
@nb.njit(cache=True)
def likelihood_field_jit(px, py, pth, lx, ly, rays, table, ox, oy, inv_res, width, height):  # pragma: no cover
    """Compiled likelihood-field sum over beams for every particle.

    Particle ``i`` at ``(px[i], py[i], pth[i])``; beam endpoints ``(lx, ly)`` in the robot frame,
    ``rays`` consecutive entries per beam (a sonar cone's rays, 1 for a laser): a beam scores the
    best of its rays. ``table`` is the flattened ``(height + 2, width + 2)`` log-likelihood grid
    padded by one far cell; endpoints off the map land on the pad. One fused pass, no temporaries.
    """
    n = px.shape[0]
    k = lx.shape[0] // rays
    out = np.empty(n)
    stride = width + 2
    umax = width + 1.0
    vmax = height + 1.0
    for i in range(n):
        c = math.cos(pth[i])
        s = math.sin(pth[i])
        bu = (px[i] - ox) * inv_res + 1.0
        bv = (py[i] - oy) * inv_res + 1.0
        acc = 0.0
        for j in range(k):
            best = -np.inf
            for r in range(j * rays, (j + 1) * rays):
                u = min(max(bu + (c * lx[r] - s * ly[r]) * inv_res, 0.0), umax)
                v = min(max(bv + (s * lx[r] + c * ly[r]) * inv_res, 0.0), vmax)
                best = max(best, table[int(v) * stride + int(u)])
            acc += best
        out[i] = acc
    return out


def likelihood_field_numpy(px, py, pth, lx, ly, rays, table, ox, oy, inv_res, width, height) -> np.ndarray:
    """The same sum as :func:`likelihood_field_jit` with numpy broadcasting over ``(n, k, rays)``: the
    reference the compiled kernel is tested and benchmarked against."""
    c = np.cos(pth)[:, None]
    s = np.sin(pth)[:, None]
    u = ((px - ox) * inv_res + 1.0)[:, None] + (c * lx - s * ly) * inv_res
    v = ((py - oy) * inv_res + 1.0)[:, None] + (s * lx + c * ly) * inv_res
    iu = np.clip(u, 0.0, width + 1.0).astype(np.intp)
    iv = np.clip(v, 0.0, height + 1.0).astype(np.intp)
    t = table[iv * (width + 2) + iu].reshape(px.shape[0], -1, rays)
    return t.max(axis=2).sum(axis=1, dtype=np.float64)


# ---------------------------------------------------------------------- the filter
class Amcl:
    """An adaptive particle filter localizing one robot on a static map.

    Feed every odometry pose to :meth:`odometry` and every scan to :meth:`sensor`; read
    :meth:`estimate` or :meth:`hypotheses`. ``particles`` is ``(n, 3)`` map poses, ``weights``
    their normalised weights, ``n_updates`` the number of sensor updates applied so far (never
    reset), ``temper`` the power the last scan's likelihood was raised to and
    :attr:`recovery_probability` Augmented MCL's current share of random particles.
    """

    def __init__(self, grid: NavGrid, params: AmclParams | None = None):
        self.grid = grid
        self.params = params if params is not None else AmclParams()
        self._rng = np.random.default_rng(self.params.seed)
        fx, fy = grid.free_cells()
        if fx.size == 0:
            raise ValueError("the map has no free cells to localize in")
        self._free_x, self._free_y = grid.cell_to_world(fx, fy)
        self._fields: dict[float, np.ndarray] = {}  # log-likelihood tables per range_max
        self._surface: np.ndarray | None = None
        self._blocked: np.ndarray | None = None  # cells a beam stops at (distance filter)
        self._cones: ConeMap | None = None  # ray-casting grids of the cone beam model
        #: readings of the last scan the distance filter left out (``laser_unmodeled_margin``)
        self.n_unmodeled = 0
        #: known moving obstacles, ``(m, 3)`` discs ``x, y, radius`` in the map frame
        #: (:meth:`set_obstacles`); readings they explain are not scored against the map
        self.obstacles = np.zeros((0, 3))
        #: readings of the last scan the known obstacles explained and left out
        self.n_explained = 0
        #: the power the last scan's likelihood was raised to (1: none; see ``pf_temper_ess``)
        self.temper = 1.0
        self.n_updates = 0
        self._odom_ref: np.ndarray | None = None  # odometry pose the particles correspond to
        self._odom_last: np.ndarray | None = None
        self._stamp = 0  # bumped whenever particles or weights change (estimate cache)
        self._cached: tuple[int, np.ndarray, np.ndarray] | None = None
        self._fresh = np.zeros(0, dtype=bool)
        self.particles = np.zeros((0, 3))
        self.weights = np.zeros(0)
        p = self.params
        self.init_pose(p.init_pose, np.diag(p.init_pose_var))

    @property
    def particles(self) -> np.ndarray:
        """``(n, 3)`` map poses ``(x, y, yaw)``; assign a new array to replace them."""
        return self._particles

    @particles.setter
    def particles(self, value) -> None:
        self._particles = np.asarray(value, dtype=np.float64)
        if self._fresh.shape[0] != self._particles.shape[0]:
            self._fresh = np.zeros(self._particles.shape[0], dtype=bool)
        self._stamp += 1

    @property
    def weights(self) -> np.ndarray:
        """``(n,)`` normalised particle weights; assign a new array to replace them."""
        return self._weights

    @weights.setter
    def weights(self, value) -> None:
        self._weights = np.asarray(value, dtype=np.float64)
        self._stamp += 1

    # ------------------------------------------------------------------ initialisation
    def _reset(self, particles: np.ndarray) -> None:
        particles[:, 2] = wrap(particles[:, 2])
        self.particles = particles
        self.weights = np.full(particles.shape[0], 1.0 / particles.shape[0])
        self._fresh = np.zeros(particles.shape[0], dtype=bool)  # injected by recovery, not yet weighed
        self._w_slow = self._w_fast = 0.0
        self._since_resample = 0
        self._due = True  # a fresh belief takes the next scan, moved or not
        self._odom_ref = self._odom_last

    def init_pose(self, mean, cov) -> None:
        """Restart from a Gaussian belief: ``mean`` ``(x, y, yaw)``, ``cov`` a 3x3 covariance (m, rad)."""
        m = np.asarray(mean, dtype=np.float64).reshape(-1)
        c = np.asarray(cov, dtype=np.float64)
        if m.shape != (3,) or not np.isfinite(m).all():
            raise ValueError(f"init_pose mean {mean!r} must be 3 finite numbers (x m, y m, yaw rad)")
        if c.shape != (3, 3) or not np.isfinite(c).all() or not np.allclose(c, c.T, atol=1e-12):
            raise ValueError("init_pose covariance must be a finite symmetric 3x3 matrix (m^2, rad^2)")
        lam, vec = np.linalg.eigh(c)
        if lam.min() < -1e-9 * max(1.0, float(np.abs(lam).max())):
            raise ValueError(f"init_pose covariance is not positive semi-definite (eigenvalues {lam.round(6)})")
        n = self.params.pf_max_samples
        z = self._rng.standard_normal((n, 3))
        self._reset(m + np.einsum("nj,ij->ni", z * np.sqrt(np.maximum(lam, 0.0)), vec))

    def init_global(self) -> None:
        """Restart from a uniform belief over the free cells, ``pf_max_samples`` particles."""
        self._reset(self._random_poses(self.params.pf_max_samples))

    def _random_poses(self, n: int) -> np.ndarray:
        i = self._rng.integers(0, self._free_x.shape[0], n)
        r = self.grid.resolution
        u = self._rng.random((n, 3))
        return np.stack(
            [
                self._free_x[i] + (u[:, 0] - 0.5) * r,
                self._free_y[i] + (u[:, 1] - 0.5) * r,
                (u[:, 2] * 2.0 - 1.0) * math.pi,
            ],
            axis=1,
        )

    # ------------------------------------------------------------------ motion
    def odometry(self, pose) -> bool:
        """Feed an odometry pose ``(x, y, yaw)`` (odometry frame); returns whether a sensor update is due.

        The first pose only anchors the odometry. Once the robot has moved ``update_thresh``
        (distance or turn) since the last update, the motion model moves the particles and the
        next scan is applied; motion after that, until the scan arrives, is applied with it. After
        (re-)initialisation the next scan is due whether or not the robot moves, as in Player.
        """
        p = np.asarray(pose, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"odometry pose {pose!r} must be 3 finite numbers (x m, y m, yaw rad)")
        self._odom_last = p
        if self._odom_ref is None:
            self._odom_ref = p
            return self._due
        if not self._due:
            d = p - self._odom_ref
            dist_t, ang_t = self.params.update_thresh
            if math.hypot(d[0], d[1]) > dist_t or abs(float(wrap(d[2]))) > ang_t:
                self._move()
                self._due = True
        return self._due

    def _move(self) -> None:
        """Apply the odometry motion from the reference pose to the latest one to all particles."""
        p0, p1 = self._odom_ref, self._odom_last
        if p0 is None or p1 is None or np.array_equal(p0, p1):
            return
        dx, dy = p1[0] - p0[0], p1[1] - p0[1]
        trans = math.hypot(dx, dy)
        rot1 = float(wrap(math.atan2(dy, dx) - p0[2])) if trans > 0.01 else 0.0
        rot2 = float(wrap(p1[2] - p0[2] - rot1))
        # Reversing is a small rotation plus a negative translation, not a half turn.
        n1 = min(abs(rot1), math.pi - abs(rot1))
        n2 = min(abs(rot2), math.pi - abs(rot2))
        p = self.params
        a1, a2, a3, a4 = p.odom_alpha1, p.odom_alpha2, p.odom_alpha3, p.odom_alpha4
        sd = np.sqrt(
            [
                a1 * n1 * n1 + a2 * trans * trans,
                a3 * trans * trans + a4 * (n1 * n1 + n2 * n2),
                a1 * n2 * n2 + a2 * trans * trans,
            ]
        )
        n = self.particles.shape[0]
        e = self._rng.standard_normal((n, 3)) * sd
        r1 = rot1 - e[:, 0]
        tr = trans - e[:, 1]
        r2 = rot2 - e[:, 2]
        q = self.particles
        h = q[:, 2] + r1
        q[:, 0] += tr * np.cos(h)
        q[:, 1] += tr * np.sin(h)
        q[:, 2] = wrap(h + r2)
        self._stamp += 1
        self._odom_ref = p1

    # ------------------------------------------------------------------ measurement
    def _surface_distance(self) -> np.ndarray:
        """:meth:`_surface_distance_of` the grid, computed once per grid (:meth:`NavGrid.derived`)."""
        return self.grid.derived("amcl.surface", self._surface_distance_of)

    def _surface_distance_of(self) -> np.ndarray:
        """Metres from each cell centre to the nearest obstacle surface, outside and inside obstacles
        (unknown cells count as obstacles).

        The grid's distance field runs between cell centres and is 0 anywhere inside an obstacle,
        which rewards poses whose beams end deep inside thick walls (a bias of up to a wall's
        thickness). Here a free cell next to a wall is half a cell from its surface, and an
        occupied cell counts its depth below the surface, so the true pose scores best.
        """
        g = self.grid
        # Unknown cells (neither free nor occupied: a built map's unexplored space, which begins
        # right behind every wall it saw) count as obstacles: a beam can only have ended where the
        # map has no free space. Maps without unknown cells are unchanged. Counted as free instead,
        # the gaps of a built map's thinly seen walls lower the fit at the true pose enough for
        # Augmented MCL's recovery to take over (docs/mapping.md: a second tour diverged by metres).
        blocked = ~g.free
        if not blocked.any():
            return np.full(g.occupied.shape, 1e6)
        half = 0.5 * g.resolution
        if np.array_equal(blocked, g.occupied):  # no unknown cells: the grid's own field
            out = g.distance.astype(np.float64) - half
        else:
            out = ndimage.distance_transform_edt(~blocked) * g.resolution - half
        depth = ndimage.distance_transform_edt(blocked) * g.resolution - half
        return np.where(blocked, depth, out)

    def _field(self, range_max: float) -> np.ndarray:
        """Log-likelihood of a beam endpoint per cell, padded by one far cell on every side."""
        range_max = round(range_max, 3)
        f = self._fields.get(range_max)
        if f is None:
            p = self.params
            if self._surface is None:
                self._surface = self._surface_distance()
            d = np.minimum(self._surface, p.laser_likelihood_max_dist)
            d = np.pad(d, 1, constant_values=p.laser_likelihood_max_dist)
            log_hit = math.log(p.laser_z_hit) - 0.5 * (d / p.laser_sigma_hit) ** 2
            log_hit -= math.log(p.laser_sigma_hit * math.sqrt(2.0 * math.pi))
            log_rand = math.log(p.laser_z_rand / range_max) if p.laser_z_rand > 0 else -np.inf
            f = np.ascontiguousarray(np.logaddexp(log_hit, log_rand).astype(np.float32))
            self._fields[range_max] = f
        return f

    def _log_likelihood(self, lx: np.ndarray, ly: np.ndarray, rays: int, range_max: float) -> np.ndarray:
        """Log-likelihood of a scan for every particle, ``(n,)``; ``lx, ly`` are the beam endpoints
        in the robot frame, ``rays`` per beam."""
        g = self.grid
        q = self.particles
        return likelihood_field_jit(
            np.ascontiguousarray(q[:, 0]),
            np.ascontiguousarray(q[:, 1]),
            np.ascontiguousarray(q[:, 2]),
            np.ascontiguousarray(lx, dtype=np.float64),
            np.ascontiguousarray(ly, dtype=np.float64),
            int(rays),
            self._field(range_max).reshape(-1),
            g.origin[0],
            g.origin[1],
            1.0 / g.resolution,
            g.width,
            g.height,
        )

    def _cone_map(self) -> ConeMap:
        if self._cones is None:  # one per grid: filters on a shared grid share it (read-only)
            g = self.grid
            self._cones = g.derived("amcl.cones", lambda: ConeMap(~g.free, g.resolution, g.origin))
        return self._cones

    def _beam_args(self, z, bearings, origins, rays: int) -> tuple:
        """The particles and one scan's beams, as the cone kernels take them (contiguous float64)."""
        q = self.particles
        return (
            np.ascontiguousarray(q[:, 0]),
            np.ascontiguousarray(q[:, 1]),
            np.ascontiguousarray(q[:, 2]),
            np.ascontiguousarray(origins[:, 0], dtype=np.float64),
            np.ascontiguousarray(origins[:, 1], dtype=np.float64),
            np.ascontiguousarray(bearings, dtype=np.float64),
            np.ascontiguousarray(z, dtype=np.float64),
            int(rays),
        )

    def _cone_log_likelihood(self, z, bearings, origins, rays: int, range_max: float) -> np.ndarray:
        """Log-likelihood of a sonar scan for every particle, ``(n,)``, under the cone beam model
        (:mod:`.conebeam`); ``bearings`` holds ``rays`` entries per reading ``z``."""
        cm, p = self._cone_map(), self.params
        return cone_beam_jit(
            *self._beam_args(z, bearings, origins, rays),
            cm.blocked,
            cm.clear,
            cm.resolution,
            cm.origin[0],
            cm.origin[1],
            float(range_max),
            float(p.laser_z_hit),
            float(p.laser_z_rand),
            float(p.laser_sigma_hit),
        )

    def _landmark_log_likelihood(self, z, bearings, origins, rays: int, range_max: float, use) -> np.ndarray:
        """As :meth:`_cone_log_likelihood`, the readings ``use`` scored against the map and the
        declared neighbours' bodies (:mod:`.landmarks`)."""
        cm, p = self._cone_map(), self.params
        d = self.obstacles
        return landmark_beam_jit(
            *self._beam_args(z, bearings, origins, rays),
            np.ascontiguousarray(use, dtype=np.bool_),
            np.ascontiguousarray(d[:, 0]),
            np.ascontiguousarray(d[:, 1]),
            np.full(d.shape[0], float(p.known_obstacle_body)),
            cm.blocked,
            cm.clear,
            cm.resolution,
            cm.origin[0],
            cm.origin[1],
            float(range_max),
            float(p.laser_z_hit),
            float(p.laser_z_rand),
            float(p.laser_sigma_hit),
            float(p.known_obstacle_sigma),
        )

    def sensor(self, ranges, bearings, origins, range_min, range_max, *, beam_width=0.0) -> bool:
        """Apply one range scan if an update is due; returns whether it was applied.

        ``ranges (n,)`` in metres, ``bearings (n,)`` in radians and ``origins (n, 2)`` in metres give
        each beam in the robot frame (a laser: one origin; a sonar ring: one per transducer).
        ``range_min`` and ``range_max`` are scalars or per-beam arrays; readings at ``range_max`` (no
        echo), below ``range_min`` or not finite are skipped. ``beam_width`` (rad, scalar or per
        beam) is a sonar's cone: the echo came from the nearest surface anywhere in it, so the
        expected range is the least of :data:`CONE_RAYS` rays cast across the cone (the beam
        model, :mod:`.conebeam`); 0 is a laser ray, scored by the likelihood field.
        """
        z = np.asarray(ranges, dtype=np.float64).reshape(-1)
        b = np.asarray(bearings, dtype=np.float64).reshape(-1)
        o = np.asarray(origins, dtype=np.float64)
        n = z.shape[0]
        if b.shape != (n,) or o.shape != (n, 2):
            raise ValueError(f"scan of {n} ranges needs {n} bearings and ({n}, 2) origins, got {b.shape} and {o.shape}")
        try:
            rmin = np.broadcast_to(np.asarray(range_min, dtype=np.float64), (n,))
            rmax = np.broadcast_to(np.asarray(range_max, dtype=np.float64), (n,))
            width = np.broadcast_to(np.asarray(beam_width, dtype=np.float64), (n,))
        except ValueError:
            raise ValueError(f"range_min, range_max and beam_width must be scalars or {n} values each") from None
        if not self._due:
            return False
        self._move()  # motion since the update became due
        self._due = False
        # A sonar cone's max-range reading is evidence too (no surface within range anywhere in
        # the cone): skipped, poses nearer a wall than the robot would go unpunished for the echoes
        # they predict. The beam model scores it as a reading of range_max.
        short = z < rmax - _MAX_RANGE_TOL
        ok = np.isfinite(z) & (z >= rmin) & (short | (width > 0.0)) & np.isfinite(b) & np.isfinite(o).all(axis=1)
        z = np.where(short, z, rmax)
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            return False
        k = self.params.laser_max_beams
        if idx.size > k:
            idx = idx[np.linspace(0, idx.size - 1, k).round().astype(np.intp)]
        zi, bi, oi, wi = z[idx], b[idx], o[idx], width[idx]
        rays = CONE_RAYS if np.any(wi > 0.0) else 1
        margin = self.params.laser_unmodeled_margin
        if rays > 1:  # sonar cones: rays beam-major (beam j: j*rays .. j*rays+rays-1)
            bi = (bi[:, None] + wi[:, None] * np.linspace(-0.5, 0.5, rays)).reshape(-1)
        landmarks = self.params.known_obstacle_sigma > 0.0 and rays > 1
        if self.obstacles.shape[0]:  # readings a known obstacle explains (before the distance filter:
            # in a crowd most readings are cut short, and it gives up on the scan when most are)
            seen = self._explained(zi, b[idx], oi, width[idx]) & (zi < rmax[idx] - _MAX_RANGE_TOL)
            self.n_explained = int(seen.sum())
            if landmarks:  # scored against the neighbours (nav.landmarks), spared the distance filter
                keep = np.ones(seen.size, dtype=bool)
            else:
                keep = ~seen
                idx, zi, oi, seen = idx[keep], zi[keep], oi[keep], seen[keep]
                bi = bi.reshape(-1, rays)[keep].reshape(-1)
            if idx.size == 0:
                return False
        else:
            self.n_explained = 0
            seen = np.zeros(idx.size, dtype=bool)
        if margin > 0.0:  # leave out readings cut short by what the map lacks
            keep = ~self._unmodeled(zi, bi, oi, rays, float(rmax[idx].max()), margin) | seen
            self.n_unmodeled = int(keep.size - keep.sum())
            idx, zi, oi, seen = idx[keep], zi[keep], oi[keep], seen[keep]
            bi = bi.reshape(-1, rays)[keep].reshape(-1)
            if idx.size == 0:
                return False
        if rays > 1 and seen.any():  # neighbours as landmarks
            loglik = self._landmark_log_likelihood(zi, bi, oi, rays, float(rmax[idx].max()), seen)
        elif rays > 1:  # sonar cones: the beam model
            loglik = self._cone_log_likelihood(zi, bi, oi, rays, float(rmax[idx].max()))
        else:
            lx = oi[:, 0] + zi * np.cos(bi)
            ly = oi[:, 1] + zi * np.sin(bi)
            loglik = self._log_likelihood(lx, ly, rays, float(rmax[idx].max()))
        self._weigh(loglik, idx.size)
        self.n_updates += 1
        self._since_resample += 1
        if self._since_resample >= self.params.resample_interval:
            self._resample()
            self._since_resample = 0
        return True

    def set_obstacles(self, discs) -> None:
        """Declare the known moving obstacles, ``(m, 3)`` discs ``x, y, radius`` (m, map frame), e.g.
        the neighbours of a swarm where their broadcasts put them; they replace the earlier ones
        (an empty list: none). Every later scan leaves out the readings they explain
        (:mod:`.knownobstacles`)."""
        d = np.asarray(discs, dtype=np.float64).reshape(-1, 3)
        if not np.isfinite(d).all() or (d[:, 2] <= 0).any():
            raise ValueError("obstacles must be finite [x, y, radius] discs with radius > 0 (m)")
        self.obstacles = d

    def _explained(self, z, bearings, origins, width) -> np.ndarray:
        """The readings (``bearings``: one per reading) the known obstacles explain, judged at the
        weighted mean pose."""
        mean, _ = self._belief()
        return explained_by_obstacles(mean, z, bearings, origins, width, self.obstacles)

    def _unmodeled(self, z, bearings, origins, rays: int, range_max: float, margin: float) -> np.ndarray:
        """The distance filter (:mod:`mrs_bridge.nav.distfilter`) at the weighted mean pose, while
        the belief's position standard deviation is at most ``margin``; else nothing is left out.
        A sonar cone (``rays`` > 1 bearings per reading) predicts the least range across it."""
        mean, cov = self._belief()
        if math.sqrt(max(float(np.linalg.eigvalsh(cov[:2, :2])[-1]), 0.0)) > margin:
            return np.zeros(z.shape[0], dtype=bool)
        if rays > 1:
            cm = self._cone_map()
            exp = cone_expected_jit(
                float(mean[0]), float(mean[1]), float(mean[2]),
                np.ascontiguousarray(origins[:, 0], dtype=np.float64),
                np.ascontiguousarray(origins[:, 1], dtype=np.float64),
                np.ascontiguousarray(bearings, dtype=np.float64),
                int(rays), cm.blocked, cm.clear, cm.resolution, cm.origin[0], cm.origin[1], float(range_max),
            )  # fmt: skip
            return unmodeled(z, exp, margin)
        if self._blocked is None:
            self._blocked = ~self.grid.free
        g = self.grid
        exp = expected_ranges(self._blocked, g.resolution, g.origin, mean, bearings, origins, range_max)
        return unmodeled(z, exp, margin)

    def _weigh(self, loglik: np.ndarray, n_beams: int) -> None:
        lw0 = np.log(np.maximum(self.weights, 1e-300))
        beta = tempering_exponent(lw0, loglik, self.params.pf_temper_ess)
        self.temper = beta
        lw = lw0 + beta * loglik
        w = np.exp(lw - lw.max())
        self.weights = w / w.sum()
        # Augmented MCL's measure of fit: the per-beam geometric mean likelihood averaged under the
        # untempered posterior, i.e. how well the best hypotheses explain the scan.
        lf = lw0 + loglik
        wf = np.exp(lf - lf.max())
        w_avg = float((wf * np.exp(loglik / n_beams)).sum() / wf.sum())
        p = self.params
        if self._w_slow == 0.0:
            self._w_slow = self._w_fast = w_avg
        else:
            self._w_slow += p.recover_alpha_slow * (w_avg - self._w_slow)
            self._w_fast += p.recover_alpha_fast * (w_avg - self._w_fast)
        self._fresh[:] = False

    # ------------------------------------------------------------------ resampling
    @property
    def recovery_probability(self) -> float:
        """Augmented MCL's chance of replacing a resampled particle by a random one, ``max(0, 1 - w_fast/w_slow)``."""
        if self._w_slow <= 0.0:
            return 0.0
        return max(0.0, 1.0 - self._w_fast / self._w_slow)

    def _kld_count(self, cdf: np.ndarray, keys: np.ndarray, w_diff: float) -> int:
        """KLD-sampling's particle count (Fox 2003, table 1), vectorised: draw i.i.d. samples (with
        Augmented MCL's random replacements) in growing chunks; ``k(n)`` = bins occupied by the first
        ``n``; the count is the first ``n >= limit(k(n))``, at least ``pf_min_samples``."""
        p = self.params
        rng = self._rng
        nmax, n_old = p.pf_max_samples, cdf.shape[0]
        m = min(nmax, max(p.pf_min_samples, 2 * n_old, 256))
        drawn = np.empty(0, dtype=np.int64)
        while True:
            extra = m - drawn.shape[0]
            idx = np.minimum(np.searchsorted(cdf, rng.random(extra), side="right"), n_old - 1)
            more = keys[idx]
            if w_diff > 0.0:
                inj = rng.random(extra) < w_diff
                if inj.any():
                    more[inj] = _bin_keys(self._random_poses(int(inj.sum())))
            drawn = np.concatenate([drawn, more])
            first = np.zeros(m, dtype=bool)
            first[np.unique(drawn, return_index=True)[1]] = True
            count = np.arange(1, m + 1)
            enough = (count >= kld_sample_count(np.cumsum(first), p.pf_err, p.pf_z)) & (count >= p.pf_min_samples)
            if enough.any():
                return int(count[np.argmax(enough)])
            if m >= nmax:
                return nmax
            m = min(nmax, 2 * m)

    def _resample(self) -> None:
        rng = self._rng
        cdf = np.cumsum(self.weights)
        cdf /= cdf[-1]
        w_diff = self.recovery_probability
        n = self._kld_count(cdf, _bin_keys(self.particles), w_diff)
        # The new set: a low-variance draw of n, then Augmented MCL's random replacements.
        new = self.particles[systematic_indices(cdf, n, rng)]
        inj = rng.random(n) < w_diff if w_diff > 0.0 else np.zeros(n, dtype=bool)
        if inj.any():
            new[inj] = self._random_poses(int(inj.sum()))
        self.particles = new
        self._fresh = inj
        self.weights = np.full(n, 1.0 / n)

    # ------------------------------------------------------------------ output
    def _pending(self) -> np.ndarray:
        """Odometry motion since the particles were last moved, in the robot frame ``(dx, dy, dyaw)``."""
        p0, p1 = self._odom_ref, self._odom_last
        if p0 is None or p1 is None:
            return np.zeros(3)
        return np.array(relative(p0, p1))

    def _weighed(self) -> tuple[np.ndarray, np.ndarray]:
        """Particles and weights without the random ones injected since the last scan: until a
        scan has weighed them they are guesses, not evidence, and would drag the mean across the map."""
        if self._fresh.any() and not self._fresh.all():
            keep = ~self._fresh
            return self.particles[keep], self.weights[keep]
        return self.particles, self.weights

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean pose ``(x, y, yaw)`` and 3x3 covariance of the particles (thesis eq. 3.3-3.4).

        Yaw's mean is the circular mean and its variance ``-2 ln R`` (``R`` the mean resultant
        length); the mean includes the odometry motion since the last update. Cached between
        updates, so calling it at the odometry rate costs little.
        """
        mean, cov = self._belief()
        return compose_array(mean, self._pending()), cov.copy()

    def _belief(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean and covariance of the particles as they are (no pending odometry), computed
        once per change of particles or weights: a sonar update asks for it up to three times (known
        obstacles, distance filter, estimate). Read-only arrays: callers copy to change them."""
        if self._cached is None or self._cached[0] != self._stamp:
            q, w = self._weighed()
            self._cached = (self._stamp, *_mean_cov(q, w))
        return self._cached[1], self._cached[2]

    def hypotheses(self) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """``(weight, mean, covariance)`` per cluster of particles, heaviest first.

        Clusters are the connected components (26-neighbourhood, yaw periodic) of the occupied
        KLD bins, as Player's ``localize`` hypotheses.
        """
        q, w = self._weighed()
        w = w / w.sum()
        bx, by, bt = _bin_triples(q)
        ux, bx = np.unique(bx, return_inverse=True)
        uy, by = np.unique(by, return_inverse=True)
        # Compress empty rows/columns of bins only where a gap separates them (keep adjacency).
        bx = np.concatenate([[0], np.cumsum(np.minimum(np.diff(ux), 2))])[bx]
        by = np.concatenate([[0], np.cumsum(np.minimum(np.diff(uy), 2))])[by]
        occ = np.zeros((int(bx.max()) + 1, int(by.max()) + 1, _N_YAW_BINS), dtype=bool)
        occ[bx, by, bt] = True
        lab, nlab = ndimage.label(occ, structure=np.ones((3, 3, 3), dtype=bool))
        # Yaw wraps: join labels that touch across the -pi/pi seam.
        a, b = lab[:, :, -1], np.pad(lab[:, :, 0], 1)
        pairs = []
        for sx in range(3):
            for sy in range(3):
                bb = b[sx : sx + a.shape[0], sy : sy + a.shape[1]]
                m = (a > 0) & (bb > 0)
                pairs.append(np.stack([a[m], bb[m]], axis=1))
        pr = np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=np.int64)
        graph = coo_matrix((np.ones(pr.shape[0]), (pr[:, 0], pr[:, 1])), shape=(nlab + 1, nlab + 1))
        _, comp = connected_components(graph, directed=False)
        cid = np.unique(comp[lab[bx, by, bt]], return_inverse=True)[1]
        nc = int(cid.max()) + 1
        wsum = np.bincount(cid, w, nc)
        wn = w / wsum[cid]
        mx = np.bincount(cid, wn * q[:, 0], nc)
        my = np.bincount(cid, wn * q[:, 1], nc)
        sn = np.bincount(cid, wn * np.sin(q[:, 2]), nc)
        cs = np.bincount(cid, wn * np.cos(q[:, 2]), nc)
        mt = np.arctan2(sn, cs)
        r = np.minimum(np.hypot(sn, cs), 1.0)
        d = np.stack([q[:, 0] - mx[cid], q[:, 1] - my[cid], wrap(q[:, 2] - mt[cid])], axis=1)
        cov = np.zeros((nc, 3, 3))
        for i in range(3):
            for j in range(i, 3):
                cov[:, i, j] = cov[:, j, i] = np.bincount(cid, wn * d[:, i] * d[:, j], nc)
        cov[:, 2, 2] = -2.0 * np.log(np.maximum(r, 1e-300))
        means = compose_array(np.stack([mx, my, mt], axis=1), self._pending())
        order = np.argsort(-wsum, kind="stable")
        return [(float(wsum[i]), means[i], cov[i]) for i in order]
