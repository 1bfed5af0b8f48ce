"""The map an agent plans on: one ``map`` device's occupancy grid (Player's ``map`` interface,
docs/protocol.md), fetched over the agent's own session; the dispatcher and the distribution
coordinator both use it."""

from __future__ import annotations

from rsal.client import Fabric
from rsal.msgs import MapData

__all__ = ["fetch_map"]


def fetch_map(session, map_addr: str, timeout: float, who: str, hint: str) -> MapData:
    """``map_addr``'s map, waiting up to ``timeout`` s for the device to appear (a worker thread:
    it blocks). A missing device is a :class:`TimeoutError` of one line naming ``who``, the device
    and ``hint`` (what to do about it)."""
    fab = Fabric(session, own_session=False)
    node = fab.node(map_addr)
    try:
        node.wait_for(map_addr, 1, timeout)
        return node.device(map_addr).get_map(timeout=10.0)
    except TimeoutError:
        raise TimeoutError(f"{who}: no map device {map_addr} within {timeout:g} s ({hint})") from None
    finally:
        node.close()
        fab.close()
