"""Options and per-robot state of ``rsal watch``: :class:`WatchOptions` (the command's flags),
the view's belief about each robot (:class:`RobotView`: poses from ground truth, odometry and
localization) and the counters behind its progress lines."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import keys
from ..geometry import compose_array, invert_array

__all__ = ["WatchOptions", "RobotView", "Stats"]


@dataclass
class WatchOptions:
    template: str = "**"
    rate: float = 10.0  # logger ticks per second
    scan_rate: float = 5.0  # scans logged per second per device, at most
    max_beams: int = 180  # beams per logged scan, at most (every k-th)
    truth_rate: float = 1.0  # ground-truth polls per robot per second
    plot_rate: float = 2.0  # time-series points per robot per second, at most
    particles: bool = False
    particles_rate: float = 1.0
    services: bool = True
    max_text: int = 200  # text log entries per tick, at most
    ring: int = 8192  # samples a Zenoh ring buffer holds between two ticks
    report_every: float = 5.0
    task_hold: float = 5.0  # seconds an ended dispatcher task stays on the map

    def check(self) -> None:
        if not (isinstance(self.task_hold, (int, float)) and math.isfinite(self.task_hold) and self.task_hold >= 0):
            raise ValueError(f"--task-hold {self.task_hold!r} must be a number of seconds >= 0")
        for name in ("rate", "scan_rate", "truth_rate", "plot_rate", "particles_rate", "report_every"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"--{name.replace('_', '-')} {v!r} must be a positive number")
        if self.max_beams < 1:
            raise ValueError(f"--max-beams {self.max_beams} must be at least 1")
        keys.template_to_keyexpr(self.template)  # raises ValueError with the template in it


@dataclass
class RobotView:
    name: str
    color: int
    size: tuple[float, float] = (0.44, 0.38)
    odom: tuple[float, float, float] | None = None  # latest odometry pose
    speed: float | None = None
    anchor: tuple[np.ndarray, np.ndarray | None] | None = None  # (truth, odometry) at the last truth poll
    gps: tuple[float, float, float] | None = None  # a ground-truth position2d
    loc: tuple[float, float, float] | None = None
    cov: tuple[float, ...] | None = None
    battery: float | None = None
    carrying: str | None = None
    gripper_pose: tuple[float, float, float] = (0.2, 0.0, 0.0)
    dirty: bool = False
    cov_dirty: bool = False
    last_plot: float = -math.inf
    shapes: dict = field(default_factory=dict)  # footprint size logged per entity kind
    shown: dict = field(default_factory=dict)  # pose last logged per entity kind

    def truth(self) -> np.ndarray | None:
        if self.gps is not None:
            return np.asarray(self.gps)
        if self.anchor is None:
            return None
        t, o = self.anchor
        if self.odom is None or o is None:
            return t
        return compose_array(t, compose_array(invert_array(o), self.odom))

    def best(self) -> np.ndarray | None:
        """The pose sensors are drawn from: ground truth, else the localized pose."""
        t = self.truth()
        if t is not None:
            return t
        return np.asarray(self.loc) if self.loc is not None else None


@dataclass
class Stats:
    n_in: int = 0  # data samples received
    taken: int = 0  # data samples the logger took (the rest were overwritten: latest wins)
    n_text: int = 0  # service messages and events received
    logged: int = 0  # rr.log calls
    downsampled: int = 0  # scans skipped by the per-device rate limit
    text_dropped: int = 0
    malformed: int = 0
    late: int = 0  # ticks that took longer than their period
    tick_max: float = 0.0
    drain_max: int = 0  # most samples taken from the ring buffers in one tick
