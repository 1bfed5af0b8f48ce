"""Neighbourhood-scoped broadcasts: a coarse spatial cell in a service's key.

The thesis's swarm (4.2.3) broadcasts every robot's position to every other robot, so messages
grow as N squared; its outlook (5.3) asks for "information-hiding" instead of "polluting the
network". Here a sender publishes on ``svc/<service>/<cell>/<sender>``, where ``<cell>`` names the
square of side ``size`` metres its position falls in (``c<ix>_<iy>``, :func:`cell_of`), and a
receiver subscribes only to the cells that come within ``radius`` of where it is
(:func:`cells_near`; :func:`cells_near_many` for many receivers in one numpy pass), re-subscribing
as it moves (:class:`agents.cellsub.CellSubscription`: a subscriber per cell, or one wildcard
subscriber filtered by cell when the cells are many).

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

import numpy as np

__all__ = ["cell_of", "cells_near", "cells_near_many", "margin"]


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


def cells_near_many(xy: np.ndarray, radius: float, size: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """:func:`cells_near` of every row of the (n, 2) array ``xy`` in one numpy pass (the same
    arithmetic, so the same cells): ``(rows, cell, names)``, one entry of ``rows`` and ``cell`` per
    (row, cell) pair, grouped by cell, ``cell`` indexing ``names`` (each distinct cell's name,
    formatted once)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if not len(xy):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), []
    x, y = xy[:, :1], xy[:, 1:]
    span = int(math.floor(2 * radius / size)) + 2  # the most cells a (2 * radius) interval touches
    k = np.arange(span, dtype=float)
    ix = np.floor((x - radius) / size) + k  # (n, span)
    iy = np.floor((y - radius) / size) + k
    dx = np.maximum(np.maximum(ix * size - x, 0.0), x - (ix + 1) * size)
    dy = np.maximum(np.maximum(iy * size - y, 0.0), y - (iy + 1) * size)
    dx[ix > np.floor((x + radius) / size)] = math.inf
    dy[iy > np.floor((y + radius) / size)] = math.inf
    ok = dx[:, :, None] * dx[:, :, None] + dy[:, None, :] * dy[:, None, :] <= radius * radius
    rows, a, b = np.nonzero(ok)  # (n, span, span)
    cx = ix[rows, a].astype(np.int64)
    cy = iy[rows, b].astype(np.int64)
    codes = (cx << 32) + (cy & 0xFFFFFFFF)
    order = np.argsort(codes, kind="stable")
    rows, cx, cy, codes = rows[order], cx[order], cy[order], codes[order]
    first = np.r_[True, codes[1:] != codes[:-1]]
    names = [f"c{i}_{j}" for i, j in zip(cx[first].tolist(), cy[first].tolist(), strict=True)]
    return rows, np.cumsum(first) - 1, names


def margin(speed: float, refresh: float, slack: float = 0.5) -> float:
    """How much farther than the radius a receiver subscribes: the distance it may cover before
    its next re-subscription (``speed`` m/s for ``refresh`` s) plus ``slack`` s of motion for a new
    subscriber to reach the publishers."""
    return max(0.0, speed) * (max(0.0, refresh) + max(0.0, slack))
