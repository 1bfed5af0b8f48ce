"""Neighbourhood-scoped broadcasts: a coarse spatial cell in a service's key.

The thesis's swarm (4.2.3) broadcasts every robot's position to every other robot, so messages
grow as N squared; its outlook (5.3) asks for "information-hiding" instead of "polluting the
network". Here a sender publishes on ``svc/<service>/<cell>/<sender>``, where ``<cell>`` names the
square of side ``size`` metres its position falls in (``c<ix>_<iy>``, :func:`cell_of`), and a
receiver subscribes only to the cells that come within ``radius`` of where it is
(:func:`cells_near`), re-subscribing as it moves (:class:`agents.services.CellSubscription`).

Delivery within the radius is complete if the subscription is never late: a receiver that
re-computes its cells every ``refresh`` seconds and moves at most ``speed`` m/s subscribes with a
margin of ``speed * refresh`` plus a slack for the subscription to reach the publishers
(:func:`margin`), so a sender within ``radius`` of the receiver's true position at send time is
always in a subscribed cell. Zenoh routes each put only to the sessions subscribed to its cell.

The all-to-all form (``svc/<service>/<sender>``) stays; a listener that wants both subscribes to
``svc/<service>/**``.
"""

from __future__ import annotations

import math

__all__ = ["cell_of", "cells_near", "margin"]


def cell_of(x: float, y: float, size: float) -> str:
    """The cell of the point (x, y) on a grid of ``size`` m squares: ``c<ix>_<iy>``."""
    return f"c{math.floor(x / size)}_{math.floor(y / size)}"


def cells_near(x: float, y: float, radius: float, size: float) -> set[str]:
    """Every cell that has a point within ``radius`` m of (x, y)."""
    ix0, ix1 = math.floor((x - radius) / size), math.floor((x + radius) / size)
    iy0, iy1 = math.floor((y - radius) / size), math.floor((y + radius) / size)
    r2 = radius * radius
    out = set()
    for ix in range(ix0, ix1 + 1):
        dx = max(ix * size - x, 0.0, x - (ix + 1) * size)
        for iy in range(iy0, iy1 + 1):
            dy = max(iy * size - y, 0.0, y - (iy + 1) * size)
            if dx * dx + dy * dy <= r2:
                out.add(f"c{ix}_{iy}")
    return out


def margin(speed: float, refresh: float, slack: float = 0.5) -> float:
    """How much farther than the radius a receiver subscribes: the distance it may cover before
    its next re-subscription (``speed`` m/s for ``refresh`` s) plus ``slack`` s of motion for a new
    subscriber to reach the publishers."""
    return max(0.0, speed) * (max(0.0, refresh) + max(0.0, slack))
