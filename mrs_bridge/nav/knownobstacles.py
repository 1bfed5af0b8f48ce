"""Known moving obstacles: range readings that a robot whose position is known (a neighbour's
broadcast) explains are left out of the measurement update.

The map holds walls, not the other robots of a swarm. In a dense crowd most of a sonar ring's
echoes come from neighbours; scored against the map, each pulls the filter towards poses where a
wall would have made it. Probabilistic Robotics (Thrun, Burgard and Fox, 2005, ch. 6.3.2) puts such
readings in the beam model's ``z_short`` part ("unexpected objects"); when the unexpected objects
are in fact *known* -- their positions are shared, as the thesis's swarm broadcasts them (4.2.3) --
the simpler and stronger answer is to not score those beams at all: the distance filter of Fox,
Burgard and Thrun (JAIR 11, 1999, sec. 4.2; :mod:`.distfilter`) does the same for readings the
map's prediction alone shows to be cut short, but cannot see a neighbour standing just in front of
a wall.

A known obstacle is a disc ``(x, y, radius)`` in the map frame, the radius covering the robot's
body and the uncertainty of where it is. A reading is *explained* by it when the disc meets the
beam's cone (its bearing within the cone's half-width plus the disc's angular half-size, widened by
``yaw_tol``) and the reading lies across the disc (from its near edge to its centre, give or take
``range_tol``): the echo can have come off that robot. A disc beyond the reading (behind the wall
the beam hit), well short of it (the echo came from farther: a wall seen past the robot's edge), or
outside the cone explains nothing, and neither does a max-range reading (no echo at all: the
evidence that nothing stands in the cone is kept). The test is made once per scan at the filter's mean pose (the
belief is unimodal while tracking), for all beams and discs at once (numpy, no per-beam loop).

Leaving the echoes out cures the pull towards walls, but a crowd's inner robot, with no wall within
its sonars' range, then has nothing but odometry. With ``known_obstacle_sigma`` > 0 (the sonar
profile's) the explained readings are instead scored against the neighbours as landmarks
(:mod:`.landmarks`): this module then only picks which readings those are.
"""

from __future__ import annotations

import math

import numpy as np

from rsal.interfaces.localize import first_bad_disc

__all__ = ["explained_by_obstacles", "parse_obstacles"]


def explained_by_obstacles(
    pose,
    ranges,
    bearings,
    origins,
    beam_width,
    obstacles,
    *,
    range_tol: float = 0.3,
    yaw_tol: float = math.radians(5.0),
) -> np.ndarray:
    """Booleans ``(k,)``: which readings a known obstacle explains (module docstring).

    ``pose`` (x, y, yaw) is the robot's map pose; ``ranges``, ``bearings`` (rad) and ``origins``
    ``(k, 2)`` give each beam in the robot frame and ``beam_width`` (rad, scalar or ``(k,)``) its
    cone (0: a ray); ``obstacles`` is ``(m, 3)`` discs ``x, y, radius`` (m, map frame).
    ``range_tol`` (m) and ``yaw_tol`` (rad) allow for the errors of both robots' poses."""
    z = np.asarray(ranges, dtype=np.float64).reshape(-1)
    k = z.shape[0]
    obs = np.asarray(obstacles, dtype=np.float64).reshape(-1, 3)
    if k == 0 or obs.shape[0] == 0:
        return np.zeros(k, dtype=bool)
    x, y, th = (float(v) for v in pose)
    c, s = math.cos(th), math.sin(th)
    o = np.asarray(origins, dtype=np.float64).reshape(k, 2)
    sx = x + c * o[:, 0] - s * o[:, 1]  # (k,) beam origins, map frame
    sy = y + s * o[:, 0] + c * o[:, 1]
    dx = obs[None, :, 0] - sx[:, None]  # (k, m)
    dy = obs[None, :, 1] - sy[:, None]
    r = obs[None, :, 2]
    d = np.hypot(dx, dy)
    inside = d <= r  # the beam starts within the disc: it explains the echo, whatever the bearing
    half = np.arcsin(np.clip(r / np.maximum(d, 1e-9), 0.0, 1.0))  # the disc's angular half-size
    ang = th + np.asarray(bearings, dtype=np.float64).reshape(-1)
    off = np.abs(np.angle(np.exp(1j * (np.arctan2(dy, dx) - ang[:, None]))))
    w = np.broadcast_to(np.asarray(beam_width, dtype=np.float64), (k,))
    in_cone = off <= (0.5 * w + yaw_tol)[:, None] + half
    zz = z[:, None]
    at_disc = (zz >= d - r - range_tol) & (zz <= d + range_tol)  # the echo came off the disc
    return (inside | (in_cone & at_disc)).any(axis=1)


def parse_obstacles(value, where: str = "obstacles") -> np.ndarray:
    """``(m, 3)`` float array from a list of ``[x, y, radius]`` (m); ``ValueError`` naming
    ``where`` and the offending entry when a disc is not three finite numbers with a radius > 0."""
    if not isinstance(value, list | tuple):
        raise ValueError(f"{where} must be a list of [x, y, radius] discs (m, map frame), got {type(value).__name__}")
    bad = first_bad_disc(value)
    if bad is not None:
        raise ValueError(
            f"{where}[{bad}] = {value[bad]!r} must be [x, y, radius]: three finite numbers, radius > 0 (m)"
        )
    return np.array(value, dtype=float).reshape(-1, 3)
