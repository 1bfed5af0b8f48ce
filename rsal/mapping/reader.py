"""One robot's laser scans and odometry out of a recording (the input of ``rsal map``).

Reads a file of ``rsal record`` / ``rsal tour`` (layout: :mod:`rsal.record.format`, read with
:class:`rsal.record.player.Recording`, so a truncated file is read as far as it is valid): the
robot's laser (``laser:N``, or a ``ranger:N`` whose ``describe`` says it is not a sonar), its
``position2d:0`` odometry, the laser's mount from its ``describe`` geometry, and, when the file has
one, the simulator's true pose (``truth/<robot>``). The odometry is interpolated at each scan's
source time. Bad input -- not MCAP, empty, no laser or no odometry for the robot, too few scans --
raises :class:`MapInputError` with one line naming the file and what is missing.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import ormsgpack

from ..errors import RsalError
from ..interfaces.position2d import Position2dData
from ..interfaces.ranger import RangerData
from ..record.format import TRUTH_PREFIX, RecordingError

__all__ = ["MapInputError", "Scans", "read_scans", "MIN_SCANS"]

MIN_SCANS = 10
_DEV = re.compile(r"^rsal/([^/]+)/(laser|ranger|position2d)/(\d+)/(data|rpc/describe)$")


class MapInputError(RsalError, ValueError):
    """A recording ``rsal map`` cannot build a map from; one line naming the file and the fix."""


@dataclass
class Scans:
    """A robot's scans with the odometry at each scan's time (and the true pose, if recorded)."""

    robot: str
    t: np.ndarray  # (N,) s, source times
    ranges: np.ndarray  # (N, B) float32 metres
    angles: np.ndarray  # (B,) rad, in the laser's frame
    range_min: float
    range_max: float
    odom: np.ndarray  # (N, 3) odometry pose at each scan
    mount: np.ndarray  # (3,) the laser's pose on the robot
    truth: np.ndarray | None = None  # (N, 3) true pose at each scan (from a simulator's tour)


def _interp_pose(t_src: np.ndarray, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
    yaw = np.unwrap(poses[:, 2])
    out = np.stack([np.interp(t, t_src, poses[:, 0]), np.interp(t, t_src, poses[:, 1]), np.interp(t, t_src, yaw)], 1)
    out[:, 2] = (out[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return out


def read_scans(path: str | Path, robot: str | None = None) -> Scans:
    """The scans of ``robot`` (default: the only robot with a laser) in the recording ``path``."""
    from ..record.player import Recording

    try:
        rec = Recording(path)
        lasers: dict[str, dict[str, list]] = {}  # robot -> laser key -> messages
        odo: dict[str, list] = {}
        truth: dict[str, list] = {}
        describes: dict[str, dict] = {}
        for s in rec.samples():
            if s.kind == "truth" and s.key.startswith(TRUTH_PREFIX + "/"):
                truth.setdefault(s.key.split("/", 1)[1], []).append(s.data)
                continue
            m = _DEV.match(s.key)
            if m is None:
                continue
            node, iface, idx, what = m.groups()
            dev = f"rsal/{node}/{iface}/{idx}"
            if what == "rpc/describe":
                try:
                    describes[dev] = ormsgpack.unpackb(s.data)
                except Exception:
                    pass
            elif iface == "position2d":
                if idx == "0":
                    odo.setdefault(node, []).append(s.data)
            else:
                lasers.setdefault(node, {}).setdefault(dev, []).append(s.data)
    except RecordingError as e:
        raise MapInputError(str(e)) from None
    skipped = rec.skipped

    def is_laser(dev: str) -> bool:
        g = describes.get(dev, {}).get("geometry", {}) if isinstance(describes.get(dev), dict) else {}
        return "/laser/" in dev or (isinstance(g, dict) and g.get("kind") not in (None, "sonar"))

    have = {n: sorted(d for d in devs if is_laser(d)) for n, devs in lasers.items()}
    have = {n: d for n, d in have.items() if d}
    if robot is None:
        if not have:
            raise MapInputError(f"{path}: no laser scans in the recording; record a robot's laser (rsal record r0:*:*)")
        if len(have) > 1:
            raise MapInputError(
                f"{path}: lasers of several robots ({', '.join(sorted(have))}); choose one with --robot"
            )
        robot = next(iter(have))
    if robot not in have:
        names = sorted(set(have) | set(odo))
        raise MapInputError(
            f"{path}: no laser scans of robot {robot!r}; the recording has "
            + (f"lasers of {', '.join(sorted(have))}" if have else "no laser scans")
            + (f" and robots {', '.join(names)}" if names else "")
        )
    if robot not in odo:
        raise MapInputError(
            f"{path}: no odometry (position2d:0 data) of robot {robot!r}; record it too (rsal record {robot}:*:*)"
            + (f"; odometry of: {', '.join(sorted(odo))}" if odo else "")
        )
    dev = have[robot][0]
    scans = [RangerData.from_bytes(b) for b in lasers[robot][dev]]
    scans = [s for s in scans if len(s.ranges) > 1 and s.angle_step != 0.0]
    nbeams = max((len(s.ranges) for s in scans), default=0)
    scans = [s for s in scans if len(s.ranges) == nbeams]
    if len(scans) < MIN_SCANS:
        raise MapInputError(
            f"{path}: only {len(scans)} laser scan(s) of {robot!r}{' (' + skipped + ')' if skipped else ''}; "
            f"a map needs at least {MIN_SCANS}: record a longer tour"
        )
    pos = [Position2dData.from_bytes(b) for b in odo[robot]]
    pt = np.array([p.t for p in pos])
    pp = np.array([p.pose for p in pos], dtype=float)
    order = np.argsort(pt, kind="stable")
    pt, pp = pt[order], pp[order]
    t = np.array([s.t for s in scans])
    inside = (t >= pt[0]) & (t <= pt[-1])
    if inside.sum() < MIN_SCANS:
        raise MapInputError(f"{path}: the odometry of {robot!r} does not cover its scans' times; record both together")
    scans = [s for s, k in zip(scans, inside, strict=True) if k]
    t = t[inside]
    s0 = scans[0]
    angles = s0.angle_min + s0.angle_step * np.arange(nbeams)
    geo = describes.get(dev, {}).get("geometry", {}) if isinstance(describes.get(dev), dict) else {}
    mount = np.zeros(3)
    if isinstance(geo, dict) and isinstance(geo.get("pose"), (list, tuple)) and len(geo["pose"]) >= 3:
        mount = np.asarray(geo["pose"][:3], dtype=float)
        sens = geo.get("sensors") or []
        if sens and isinstance(sens[0], dict) and len(sens[0].get("pose", ())) >= 2:
            mount[:2] += np.asarray(sens[0]["pose"][:2], dtype=float)  # the sensor's own offset
    tr = None
    if robot in truth:
        msgs = [ormsgpack.unpackb(b) for b in truth[robot]]
        tt = np.array([m["t"] for m in msgs], dtype=float)
        tp = np.array([m["pose"] for m in msgs], dtype=float)
        tr = _interp_pose(tt, tp, t)
    return Scans(
        robot=robot,
        t=t,
        ranges=np.stack([np.asarray(s.ranges, dtype=np.float32) for s in scans]),
        angles=angles,
        range_min=float(s0.range_min),
        range_max=float(s0.range_max),
        odom=_interp_pose(pt, pp, t),
        mount=mount,
        truth=tr,
    )
