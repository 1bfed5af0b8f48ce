"""``rsal watch``: a live view of the fleet in Rerun (thesis 5.2.3 *User Interface*).

The thesis watched robot localizations and planned paths with Player's *Playernav* and the Stage
window (5.2.3), asked for a graphical interface to follow scenarios (3.4.2) and mixed simulated and
real robots on one map (4.3). This package is that view for the fabric: it subscribes to every
device matching a template, and to the agents' services, and logs to a Rerun recording (a native
viewer, the bundled web viewer, or an ``.rrd`` file):

- the map (any ``map`` device, ``rpc/get``) as an image placed in world coordinates;
- each robot's ground-truth pose when a simulation is present (``sim:simulation:0`` ``get_pose``,
  polled at ``--truth-rate`` and carried forward by odometry between polls, or a ``gps`` position2d),
  and its localized pose (``amcl``'s map-frame position2d and ``localize`` data) with the
  covariance ellipse; both drawn as the footprint from ``rpc/describe`` geometry;
- laser and sonar scans as points in the world frame, blobs seen and carried, planner paths with
  the current waypoint and goal, bumper segments (red while pressed), lines to the fiducials a
  finder sees with their ids, optionally AMCL particles (``get_particles``);
- agent service messages (``svc/**``), device events and joins as text logs, and per-robot time
  series: speed, localization error (where ground truth exists), battery;
- the fleet dispatcher's tasks (``task_state``), coloured by state, with a line from each robot to
  its active task's next point; ended tasks leave the map after ``--task-hold`` seconds.

Samples wait in Zenoh's ring buffers (no Python runs per sample on Zenoh's threads); one logger
thread ticks at a fixed rate, drains them into a latest-wins dict (one sample per device), decodes
only the newest, converts scans with numpy and downsamples them (every k-th beam, at most
``--scan-rate`` scans per second per device), so a 100-robot fleet at full rate does not make it
fall behind. Entity paths are documented in ``docs/watch.md`` and stay stable.

Modules: :mod:`~rsal.watch.subscriptions` (the intake), :mod:`~rsal.watch.app` (the logger,
:class:`Watcher`), :mod:`~rsal.watch.draw` (one drawing hook per interface, found by the interface's
name; interfaces without one are logged as their registry summary), :mod:`~rsal.watch.convert`
(pure conversions), :mod:`~rsal.watch.tasks` (the dispatcher's tasks),
:mod:`~rsal.watch.state` (options, per-robot state), :mod:`~rsal.watch.cli`
(the command). The package imports nothing above the RSAL layer: service messages are read as plain
msgpack maps.
"""

from __future__ import annotations

from .app import Watcher
from .cli import register, run_watch
from .convert import (
    beam_layout,
    cov_ellipse,
    ellipse_points,
    entity,
    footprint,
    map_image,
    map_transform,
    scan_to_world,
)
from .state import WatchOptions

__all__ = [
    "register",
    "run_watch",
    "Watcher",
    "WatchOptions",
    "beam_layout",
    "scan_to_world",
    "cov_ellipse",
    "ellipse_points",
    "footprint",
    "map_image",
    "map_transform",
    "entity",
]
