"""AMCL over a recorded tour, offline: how well a robot localizes on a map, judged against the truth.

The ``amcl`` driver's filter (:class:`mrs_bridge.nav.amcl.Amcl`, thesis 3.3) fed from one robot's
scans and odometry as :func:`rsal.mapping.reader.read_scans` takes them out of a recording, as fast
as it computes, on any map (a shipped floor plan, or one ``rsal map`` built). With the true poses
of a simulated tour (``rsal tour``) it says whether a built map is good enough to navigate on: the
thesis's requirement is 0.30 m; the mapping benchmark asks 0.15 m (docs/mapping.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import profile
from .amcl import Amcl
from .amclparams import AmclParams
from .grid import NavGrid

__all__ = ["Localized", "localize_scans"]


@dataclass
class Localized:
    """The estimate at every scan, and its position error against the truth where known."""

    poses: np.ndarray  # (N, 3) the filter's estimate after each scan
    error: np.ndarray | None  # (N,) m, |estimate - truth| (None without truth)

    def after(self, t: np.ndarray, settle_s: float) -> np.ndarray:
        """The errors from ``settle_s`` seconds after the first scan on (the filter converged)."""
        if self.error is None:
            raise ValueError("no true poses to judge the estimate by")
        return self.error[t - t[0] >= settle_s]


def localize_scans(
    grid: NavGrid, scans, start, *, params: AmclParams | None = None, spread=(0.1, 0.1, 0.05)
) -> Localized:
    """Run AMCL on ``grid`` over ``scans`` (an :class:`rsal.mapping.reader.Scans`) from a Gaussian
    belief at ``start`` (x, y, yaw) with standard deviations ``spread`` (m, m, rad). ``params``
    default to the navigation stack's (:data:`mrs_bridge.nav.profile.AMCL`), as ``rsal sim --nav``
    and the deploy files run the ``amcl`` driver."""
    amcl = Amcl(grid, params if params is not None else AmclParams.from_dict(profile.AMCL))
    amcl.init_pose(np.asarray(start, dtype=float), np.diag(np.square(spread)))
    mount = np.asarray(scans.mount, dtype=float)
    bearings = np.asarray(scans.angles, dtype=float) + mount[2]
    origins = np.broadcast_to(mount[:2], (bearings.size, 2))
    out = np.empty((len(scans.t), 3))
    for i in range(len(scans.t)):  # one filter step per scan: the filter itself is vectorised
        if amcl.odometry(scans.odom[i]):
            amcl.sensor(scans.ranges[i], bearings, origins, scans.range_min, scans.range_max)
        out[i] = amcl.estimate()[0]
    err = None
    if scans.truth is not None:
        err = np.hypot(out[:, 0] - scans.truth[:, 0], out[:, 1] - scans.truth[:, 1])
    return Localized(out, err)
