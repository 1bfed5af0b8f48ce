"""Neighbourhood-scoped broadcasts (agents.cells, Services.subscribe_cells).

(a) The cell arithmetic: every point within the radius lies in one of :func:`cells_near`'s cells
(checked against brute force on random points), and no cell lies wholly outside the radius;
:func:`cells_near_many` gives every row the same cells as :func:`cells_near`, on cell borders too.
(b) Over real Zenoh sessions: a receiver agent drives across several cell borders while senders
on another host (another session) publish into their cells every tick. Every message whose sender
was within the radius of the receiver's position at the moment it was sent arrives; messages of
senders that were never near are never delivered (the scoping works), both judged from the
positions the test itself moved (the ground truth of this test).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from agents.cells import cell_of, cells_near, cells_near_many, margin
from agents.runtime import Agent
from tests.conftest import wait_until


def test_cells_near_covers_the_disc_and_no_more():
    rng = np.random.default_rng(7)
    for _ in range(300):
        x, y = rng.uniform(-20, 20, 2)
        r, size = rng.uniform(0.5, 6.0), rng.uniform(0.5, 5.0)
        near = cells_near(x, y, r, size)
        ang = rng.uniform(0, 2 * math.pi, 200)
        dist = r * np.sqrt(rng.uniform(0, 1, 200))
        for px, py in zip(x + dist * np.cos(ang), y + dist * np.sin(ang), strict=True):
            assert cell_of(px, py, size) in near, (x, y, r, size, px, py)
        for c in near:  # each cell has a point within r: its nearest point to (x, y)
            ix, iy = (int(v) for v in c[1:].split("_"))
            nx, ny = min(max(x, ix * size), (ix + 1) * size), min(max(y, iy * size), (iy + 1) * size)
            assert math.hypot(nx - x, ny - y) <= r + 1e-9


def test_cells_near_many_gives_each_row_the_cells_of_cells_near():
    rng = np.random.default_rng(11)
    for r, size in [(5.5, 5.0), (2.5, 2.0), (1.0, 3.0), (5.0, 5.0), (0.0, 1.0), (0.3, 0.25)]:
        xy = np.concatenate(
            [
                rng.uniform(-40, 40, (400, 2)),
                rng.integers(-8, 8, (100, 2)) * size,  # on cell corners
                rng.integers(-8, 8, (100, 2)) * size + (r, -r),  # the radius reaching a border exactly
            ]
        )
        rows, cell, names = cells_near_many(xy, r, size)
        assert len(set(names)) == len(names) and (np.diff(cell) >= 0).all()  # grouped by cell
        got: list[set[str]] = [set() for _ in xy]
        for i, c in zip(rows.tolist(), cell.tolist(), strict=True):
            assert names[c] not in got[i]
            got[i].add(names[c])
        for (x, y), cells in zip(xy.tolist(), got, strict=True):
            assert cells == cells_near(x, y, r, size), (x, y, r, size)
    rows, cell, names = cells_near_many(np.zeros((0, 2)), 5.0, 5.0)
    assert len(rows) == len(cell) == len(names) == 0


class Receiver(Agent):
    def __init__(self, agent_id: str, **kw):
        super().__init__(agent_id, **kw)
        self.got: list[tuple[str, int]] = []
        self.lock = threading.Lock()
        self.cells = None

    async def created(self):
        self.cells = self._require_host().services.subscribe_cells("send_position", self._on, owner=self.id)

    def _on(self, msg):
        with self.lock:
            self.got.append((msg.sender, int(msg.conversation)))


def test_a_moving_receiver_gets_every_neighbour_and_nobody_else(hosts):
    lt, recv_host, send_host = hosts
    rx = lt.run(recv_host.start(Receiver("rx")))
    radius, size, speed, dt = 3.0, 3.0, 2.0, 0.05
    extra = margin(speed, dt)
    # senders along the receiver's path (y = 0.5, x from -7 to 7) and two far away from it
    senders = {f"s{i}": (x, y) for i, (x, y) in enumerate([(-6, 2), (-2.5, -1.5), (0, 3), (3.1, 0.5), (6.5, -2)])}
    senders |= {"far1": (0.0, 12.0), "far2": (-20.0, 0.5)}
    expected: set[tuple[str, int]] = set()
    ever_near: set[str] = set()

    async def watch(x: float, y: float) -> None:
        rx.cells.watch(cells_near(x, y, radius + extra, size))

    x, y, seq = -7.0, 0.5, 0
    lt.run(watch(x, y))
    svc = send_host.services

    def probe_arrived() -> bool:  # the first subscribers have reached the sending session
        svc.publish("send_position", _pos("probe", x, y), sender="probe", conversation="0", cell=cell_of(x, y, size))
        return ("probe", 0) in rx.got

    wait_until(probe_arrived, 10, "the receiver's first cells at the sending host", interval=0.05)
    while x <= 7.0:
        x += speed * dt
        lt.run(watch(x, y))  # re-subscribe from the new position, then the senders publish
        seq += 1
        for name, (sx, sy) in senders.items():
            cell = cell_of(sx, sy, size)
            svc.publish("send_position", _pos(name, sx, sy), sender=name, conversation=str(seq), cell=cell)
            if math.hypot(sx - x, sy - y) <= radius:
                expected.add((name, seq))
                ever_near.add(name)
        time.sleep(dt)
    assert {"s0", "s1", "s2", "s3", "s4"} <= ever_near and not ({"far1", "far2"} & ever_near)
    wait_until(lambda: expected <= set(rx.got), 10, "every message of a sender within the radius")
    got = set(rx.got)
    assert not any(name.startswith("far") for name, _ in got), sorted(n for n, _ in got if n.startswith("far"))
    # scoped: the receiver got far fewer messages than all-to-all would have delivered
    assert len(got) < 0.6 * seq * len(senders), (len(got), seq * len(senders))
    print(f"{len(expected)} within the radius, all delivered; {len(got)} delivered of {seq * len(senders)} sent")


def _pos(name: str, x: float, y: float):
    from agents.services import SendPosition

    return SendPosition(name, float(x), float(y), 0.0)


def test_watch_adds_before_it_drops_and_close_undeclares(hosts):
    lt, recv_host, _ = hosts
    rx = lt.run(recv_host.start(Receiver("rx2")))

    async def go():
        rx.cells.watch({"c0_0", "c1_0"})
        first = rx.cells.cells
        rx.cells.watch({"c1_0", "c2_0"})
        second = rx.cells.cells
        rx.cells.close()
        return first, second, rx.cells.cells

    first, second, after = lt.run(go())
    assert first == {"c0_0", "c1_0"} and second == {"c1_0", "c2_0"} and after == set()

    async def bad():
        recv_host.services.subscribe_cells("send_position", print).watch({"a/b"})

    with pytest.raises(ValueError, match="cell 'a/b'"):
        lt.run(bad())
