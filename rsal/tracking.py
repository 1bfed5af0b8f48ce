"""Tracking other robots between their position broadcasts: one Kalman filter per robot.

Robots broadcast their pose a few times a second (``send_position``, 2 Hz in the scenarios), and
the message is already some tens of milliseconds old when it arrives. An agent that acts on
another robot's pose -- a hunter chasing its prey, the ViewAgent mirroring a real robot into the
virtual world -- otherwise holds the last message until the next one, always behind a moving robot.

:class:`PoseTracker` runs a discrete constant-velocity Kalman filter (Kalman 1960; the
white-noise-acceleration model of Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to
Tracking and Navigation*, 2001, sec. 6.3.2) on the state ``[x, vx, y, vy, yaw, w]`` with
:class:`filterpy.kalman.KalmanFilter`; the process noise is filterpy's
:func:`~filterpy.common.Q_discrete_white_noise` per axis. Each broadcast ``(x, y, yaw, t)`` is a
measurement of ``x, y, yaw``; the yaw is unwrapped against the prediction so a turn through +-pi is
a small step. :meth:`PoseTracker.predict` answers the pose at any time between (or after) the
messages without touching the filter, extrapolating at most ``horizon`` seconds past the last one
(a robot that fell silent is not assumed to drive on for ever). Samples older than the latest are
rejected (a late message must not pull the track back in time).

Time is whatever the caller passes: agents pass the process's clock (:func:`rsal.clock.clock`) at
reception, so in a simulation at a speed-up the filter counts simulated seconds.
:class:`Tracks` keeps one tracker per robot id.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

__all__ = ["PoseTracker", "TrackedPose", "Tracks"]


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class TrackedPose:
    """A predicted pose (m, m, rad in (-pi, pi]) and velocity (m/s, m/s, rad/s) at time ``t``."""

    x: float
    y: float
    yaw: float
    vx: float
    vy: float
    w: float
    t: float


class PoseTracker:
    """A constant-velocity Kalman filter on one robot's broadcast poses.

    ``pos_std`` (m) and ``yaw_std`` (rad): the broadcast's measurement noise; ``accel_std`` (m/s^2)
    and ``yaw_accel_std`` (rad/s^2): how hard the robot may change its velocity (process noise);
    ``horizon`` (s): the longest extrapolation past the last sample.
    """

    def __init__(
        self,
        pos_std: float = 0.02,
        yaw_std: float = 0.02,
        accel_std: float = 0.5,
        yaw_accel_std: float = 1.5,
        horizon: float = 1.0,
    ):
        for name, v in (
            ("pos_std", pos_std),
            ("yaw_std", yaw_std),
            ("accel_std", accel_std),
            ("yaw_accel_std", yaw_accel_std),
            ("horizon", horizon),
        ):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"PoseTracker: {name} = {v!r} must be a positive number")
        self.accel_var = accel_std**2
        self.yaw_accel_var = yaw_accel_std**2
        self.horizon = horizon
        kf = KalmanFilter(dim_x=6, dim_z=3)
        kf.H = np.zeros((3, 6))
        kf.H[0, 0] = kf.H[1, 2] = kf.H[2, 4] = 1.0
        kf.R = np.diag([pos_std**2, pos_std**2, yaw_std**2])
        self.kf = kf
        self.t: float | None = None  # time of the last accepted sample
        self.samples = 0
        self.rejected = 0  # out-of-order or non-finite samples

    # ------------------------------------------------------------------ model
    @staticmethod
    def _F(dt: float) -> np.ndarray:
        F = np.eye(6)
        F[0, 1] = F[2, 3] = F[4, 5] = dt
        return F

    def _Q(self, dt: float) -> np.ndarray:
        q = np.zeros((6, 6))
        q[:4, :4] = Q_discrete_white_noise(dim=2, dt=dt, var=self.accel_var, block_size=2)
        q[4:, 4:] = Q_discrete_white_noise(dim=2, dt=dt, var=self.yaw_accel_var)
        return q

    # ------------------------------------------------------------------ input
    def update(self, x: float, y: float, yaw: float, t: float) -> bool:
        """One broadcast pose measured at time ``t`` (s); False (and counted in ``rejected``) if it is
        older than the last accepted one or not finite."""
        if not all(math.isfinite(v) for v in (x, y, yaw, t)):
            self.rejected += 1
            return False
        if self.t is None:
            kf = self.kf
            kf.x = np.array([[x], [0.0], [y], [0.0], [_wrap(yaw)], [0.0]])
            # unknown velocity at first: a wide prior on it, the measurement's noise on the pose
            kf.P = np.diag([kf.R[0, 0], 1.0, kf.R[1, 1], 1.0, kf.R[2, 2], 4.0])
            self.t = t
            self.samples = 1
            return True
        dt = t - self.t
        if dt < 0:
            self.rejected += 1
            return False
        kf = self.kf
        if dt > 0:
            kf.predict(F=self._F(dt), Q=self._Q(dt))
        yaw_pred = float(kf.x[4, 0])
        z = np.array([[x], [y], [yaw_pred + _wrap(yaw - yaw_pred)]])  # unwrapped against the prediction
        kf.update(z)
        kf.x[4, 0] = _wrap(float(kf.x[4, 0]))
        self.t = t
        self.samples += 1
        return True

    # ------------------------------------------------------------------ output
    @property
    def started(self) -> bool:
        return self.t is not None

    def predict(self, t: float) -> TrackedPose | None:
        """The pose at time ``t`` (None before the first sample): the filter's state moved on by
        ``t - last sample`` seconds, clamped to [0, ``horizon``]; the filter itself is unchanged."""
        if self.t is None:
            return None
        dt = min(max(0.0, t - self.t), self.horizon)
        s = self._F(dt) @ self.kf.x
        return TrackedPose(
            float(s[0, 0]),
            float(s[2, 0]),
            _wrap(float(s[4, 0])),
            float(s[1, 0]),
            float(s[3, 0]),
            float(s[5, 0]),
            self.t + dt,
        )


class Tracks:
    """One :class:`PoseTracker` per robot id, made with ``**params`` on its first sample."""

    def __init__(self, **params):
        PoseTracker(**params)  # check the parameters once, here
        self.params = params
        self.trackers: dict[str, PoseTracker] = {}

    def update(self, robot: str, x: float, y: float, yaw: float, t: float) -> bool:
        tr = self.trackers.get(robot)
        if tr is None:
            tr = self.trackers[robot] = PoseTracker(**self.params)
        return tr.update(x, y, yaw, t)

    def predict(self, robot: str, t: float) -> TrackedPose | None:
        tr = self.trackers.get(robot)
        return tr.predict(t) if tr is not None else None

    def __contains__(self, robot: str) -> bool:
        return robot in self.trackers

    def forget(self, robot: str) -> None:
        self.trackers.pop(robot, None)
