"""``ros2_export`` driver: ``rsal ros2`` inside a device server (docs/ros2.md, "In a server").

The exporter (:mod:`mrs_bridge.ros2.export`) on the server's own Zenoh session, so that one
``rsal serve`` process runs a robot's drivers and its ROS 2 face together (on a robot host:
``p2os`` + ``hokuyo`` + ``ros2_export``)::

    [[driver]]
    name = "ros2_export"
    robots = ["r0"]           # names or patterns (default every robot the server can see)
    domain = 0

It provides no device (like ``simulation``, it is allowed an empty ``provides``) and requires
none: robots are found by liveliness as by ``rsal ros2``, local ones included. Parameters are
``rsal ros2``'s flags: ``robots``, ``domain``, ``frame_prefix``, ``node_name``, ``map_frame``,
``map_node``, ``clock``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from rsal.client import Fabric

from ..driver import Driver, register
from ..params import param, parse_params
from .export import ExportConfig, Exporter

__all__ = ["Ros2Export"]

_CHUNK = re.compile(r"^[A-Za-z0-9_\-.*]+$")


@dataclass(frozen=True)
class Ros2ExportParams:
    robots: tuple[str, ...] = param(("*",), doc="robot names or patterns ('r*')")
    domain: int = param(0, min=0, max=232)
    frame_prefix: str = param("{robot}/")
    node_name: str = param("rsal")
    map_frame: str = param("map")
    map_node: str = param("*", doc="node of the map device published as /map ('' for none)")
    clock: bool = param(True, doc="publish /clock from a simulation device")

    def __post_init__(self):
        bad = [r for r in self.robots if not _CHUNK.match(r) or "**" in r]
        if not self.robots or bad:
            raise ValueError(f"robots = {list(self.robots)!r} must be robot names or patterns like 'r0' or 'r*'")
        if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", self.node_name):
            raise ValueError(f"node_name = {self.node_name!r} must be a ROS node name (letters, digits, _)")
        try:
            self.frame_prefix.format(robot="r0")
        except (KeyError, IndexError, ValueError):
            raise ValueError(
                f"frame_prefix = {self.frame_prefix!r} may only use {{robot}}, e.g. '{{robot}}/'"
            ) from None


@register("ros2_export")
class Ros2Export(Driver):
    driver_name = "ros2_export"
    interfaces = ()
    default_rate = 0.0

    def __init__(self, cfg, server):
        super().__init__(cfg, server)
        p = parse_params(Ros2ExportParams, cfg)
        self.config = ExportConfig(
            p.domain, tuple(p.robots), p.frame_prefix, p.node_name, p.map_frame, p.map_node, p.clock
        )
        self.fabric: Fabric | None = None
        self.exporter: Exporter | None = None

    def setup(self) -> None:
        self.fabric = Fabric(self.server.session, own_session=False)
        self.exporter = Exporter(self.fabric, self.config, self._changed)

    def _changed(self, ex: Exporter) -> None:
        robots = ex.robots()
        line = ", ".join(f"{n} ({' '.join(t)})" for n, t in robots.items()) or "none yet"
        self.log.info("%s: domain %d: %d robot(s) exported: %s", self.cfg.where, self.config.domain, len(robots), line)

    def shutdown(self) -> None:
        if self.exporter is not None:
            self.exporter.close()
        if self.fabric is not None:
            self.fabric.close()
