"""The fleet-wide topics of ``rsal ros2``: ``/map`` and ``/clock``, from one ROS node ``/<node name>``
in the root namespace (the robots' nodes are ``/<robot>/<node name>``: docs/ros2.md).

- ``/map`` (``nav_msgs/msg/OccupancyGrid``): the first ``map`` device found (``sim:map:0`` under
  ``rsal sim``; ``map_node`` chooses the node), fetched once by ``rpc/get`` and published transient
  local like Nav2's map_server: late subscribers get it from the publisher's cache. Stamp 0 (tf's
  "latest": the map holds at every time).
- ``/clock`` (``rosgraph_msgs/msg/Clock``, best effort, keep last 1 as rclcpp's clock QoS): the
  simulation's time from a ``simulation`` device's data, when a simulator runs. Every exported
  stamp is then simulated time, and ROS tools follow it with ``use_sim_time:=true``.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Any

from rsal.keys import DeviceAddr

from . import types
from .rmw import Node, Publisher
from .wire import QoS

if TYPE_CHECKING:
    from .export import Exporter

__all__ = ["FleetTopics", "MAP_QOS", "CLOCK_QOS"]

log = logging.getLogger(__name__)

MAP_QOS = QoS(durability=1, depth=1)  # Nav2's map_server: reliable, transient local, keep last 1
CLOCK_QOS = QoS(reliability=2, depth=1)  # rclcpp's ClockQoS: best effort, keep last 1


class FleetTopics:
    """``/map`` and ``/clock`` of one exporter; discovery on the fabric's dispatcher thread."""

    def __init__(self, ex: Exporter):
        self.ex = ex
        self._node: Node | None = None
        self._lock = threading.Lock()
        self.map: tuple[DeviceAddr, Publisher] | None = None
        self.clock: tuple[DeviceAddr, Publisher, Any, Any] | None = None  # addr, pub, proxy, listener
        c = ex.config
        templates = ([f"rsal/{c.map_node}/map/*"] if c.map_node else []) + (["rsal/*/simulation/0"] if c.clock else [])
        self._dnode = ex.fabric.node(*templates) if templates else None
        if self._dnode is not None:
            self._dnode.on_join(self._join)
            self._dnode.on_leave(self._leave)
            for a in self._dnode.devices():
                ex.fabric.dispatcher.submit(self._join, a)

    def topics(self) -> list[str]:
        return [t for t, on in (("map", self.map), ("clock", self.clock)) if on]

    def _fleet_node(self) -> Node:
        if self._node is None:
            self._node = self.ex.part.node("/", self.ex.config.node_name)
        return self._node

    def _join(self, addr: DeviceAddr) -> None:
        if self.ex._closed:
            return
        if addr.interface == "map":
            self._join_map(addr)
        elif addr.interface == "simulation":
            self._join_clock(addr)

    def _join_map(self, addr: DeviceAddr) -> None:
        if self.map is not None:
            if self.map[0] != addr:
                log.info("%s: not exported, /map is %s already", addr, self.map[0])
            return
        try:
            grid = self.ex.fabric.device(addr).get_map(timeout=10.0)
        except Exception as e:
            log.warning("%s: could not fetch the map (%s); /map not published", addr, e)
            return
        pub = self._fleet_node().publisher("/map", "nav_msgs/msg/OccupancyGrid", MAP_QOS)
        self.map = (addr, pub)
        frame = self.ex.config.map_frame
        self.ex.outbox.post(pub, lambda g: types.occupancy_grid(g, 0.0, frame), grid)
        log.info("/map: %s (%d x %d cells of %g m)", addr, grid.width, grid.height, grid.resolution)
        self.ex._changed()

    def _join_clock(self, addr: DeviceAddr) -> None:
        if self.clock is not None:
            if self.clock[0] != addr:
                log.info("%s: not exported, /clock follows %s already", addr, self.clock[0])
            return
        pub = self._fleet_node().publisher("/clock", "rosgraph_msgs/msg/Clock", CLOCK_QOS)
        proxy = self.ex.fabric.device(addr)
        post, Clock = self.ex.outbox.post, types.TYPESTORE.types["rosgraph_msgs/msg/Clock"]

        def on_sim(data) -> None:
            post(pub, lambda d: Clock(clock=types.stamp(d.t)), data)

        self.clock = (addr, pub, proxy, on_sim)
        proxy.add_listener(on_sim, inline=True)
        self.ex._changed()

    def _leave(self, addr: DeviceAddr) -> None:
        if self.ex._closed:
            return
        if self.map is not None and self.map[0] == addr:
            self.map[1].close()
            self.map = None
            log.info("/map withdrawn: %s left", addr)
        elif self.clock is not None and self.clock[0] == addr:
            _, pub, proxy, fn = self.clock
            self.clock = None
            proxy.remove_listener(fn)
            proxy.undeclare()
            pub.close()
        else:
            return
        if self.map is None and self.clock is None and self._node is not None:
            self._node.close()
            self._node = None
        self.ex._changed()

    def close(self) -> None:
        if self._dnode is not None:
            self._dnode.close()
        if self._node is not None:
            self._node.close()
