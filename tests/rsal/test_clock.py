"""The process clock (rsal.clock): the simulation's clock followed from its samples, and sleeping
on it; then a real simulator at a speed-up driving it over Zenoh."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from rsal.clock import SimClock, WallClock, clock, set_clock, wait_for
from tests.conftest import ROOT, rsal_cmd


class FakeWall:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_sim_clock_extrapolates_at_the_measured_speed_and_no_further_than_max_ahead():
    w = FakeWall()
    c = SimClock(wall=w)
    assert not c.started and c.now() == 0.0
    c.feed(10.0)
    w.t += 0.1
    c.feed(10.5)  # 0.5 simulated seconds in 0.1 wall seconds: five times real time
    assert c.speed == pytest.approx(5.0)
    w.t += 0.05
    assert c.now() == pytest.approx(10.75)
    w.t += 10.0  # no samples for a long time (a stalled simulation): the clock stops
    assert c.now() == pytest.approx(10.5 + SimClock.MAX_AHEAD * 5.0)
    assert c.wall(1.0) == pytest.approx(0.2)


def test_sim_clock_never_goes_backwards_and_stops_when_paused():
    w = FakeWall()
    c = SimClock(wall=w)
    c.feed(0.0)
    w.t += 0.1
    c.feed(1.0)  # speed 10
    w.t += 0.1
    ahead = c.now()  # extrapolated to 2.0
    assert ahead == pytest.approx(2.0)
    c.feed(1.5)  # the simulation fell behind the extrapolation
    assert c.now() == pytest.approx(ahead)
    c.feed(3.0, paused=True)
    t = c.now()
    w.t += 5.0
    assert c.now() == t == pytest.approx(3.0)


def test_a_sleeper_wakes_on_the_sample_that_passes_its_deadline():
    c = SimClock()
    c.feed(0.0, paused=True)  # paused: only samples move the clock
    woke: list[float] = []
    t = threading.Thread(target=lambda: (c.sleep_until(5.0), woke.append(c.now())))
    t.start()
    for s in (1.0, 2.0, 4.0):
        c.feed(s, paused=True)
    time.sleep(0.2)  # a sleeper that woke too early would have appended by now
    assert woke == []
    c.feed(5.0, paused=True)
    t.join(2.0)
    assert woke == [5.0]


def test_wait_for_times_out_in_clock_seconds():
    c = SimClock()
    c.feed(0.0)

    async def main() -> float:
        async def never() -> None:
            await asyncio.Event().wait()

        feeder = asyncio.ensure_future(_feed(c))
        try:
            with pytest.raises(TimeoutError):
                await wait_for(never(), 3.0)
            return c.now()
        finally:
            feeder.cancel()

    old = set_clock(c)
    try:
        t = asyncio.run(asyncio.wait_for(main(), 10.0))
    finally:
        set_clock(old)
    assert t >= 3.0
    assert isinstance(clock(), WallClock)


async def _feed(c: SimClock) -> None:
    t = 0.0
    while True:  # 1 simulated second every 20 ms: 50 times real time
        await asyncio.sleep(0.02)
        t += 1.0
        c.feed(t)


def test_sim_clock_follows_a_real_simulation_at_its_speed_up(procs, port, fabric_factory):
    procs(rsal_cmd("sim", str(ROOT / "maps" / "testroom.world"), "--speedup", "5", "--listen", f"tcp/127.0.0.1:{port}"))
    fab = fabric_factory(port)
    fab.node("sim:*:*").wait_for("sim:simulation:0", 1, 30.0)
    c = SimClock().follow(fab.session, "sim")
    try:
        assert c.wait_started(10.0), "no sample of the simulation's clock"
        sim = fab.device("sim:simulation:0")
        w0, s0 = time.monotonic(), c.now()
        assert c.sleep(5.0) is False  # five simulated seconds: about one wall second
        wall, slept = time.monotonic() - w0, c.now() - s0
        assert slept >= 5.0
        assert wall < 3.0, f"5 simulated seconds took {wall:.1f} s of wall time at speed-up 5"
        truth = sim.latest.t  # the simulation's own time, as it publishes it
        assert abs(c.now() - truth) < 0.3 * c.speed + 0.2
        assert 3.0 < c.speed < 7.0
    finally:
        c.close()


def test_an_async_sleeper_replans_when_the_simulation_speeds_up():
    c = SimClock()

    async def main() -> tuple[float, float, float]:
        async def feed() -> None:  # 10 samples per wall second: real time for 0.5 s, then 20 times that
            t = 0.0
            for k in range(400):
                await asyncio.sleep(0.02)
                t += 0.02 if k < 25 else 0.4
                c.feed(t)

        c.feed(0.0)
        feeder = asyncio.ensure_future(feed())
        await asyncio.sleep(0.2)  # the speed measured: ~1
        start = time.monotonic()
        await c.asleep_until(4.0)  # planned at ~1x: ~3.8 wall s; at 20x after 0.3 s: ~0.5 s in all
        woke = c.now()
        feeder.cancel()
        return time.monotonic() - start, woke, c.speed

    took, woke, speed = asyncio.run(asyncio.wait_for(main(), 20.0))
    assert woke >= 4.0  # never early
    assert speed > 10  # it did speed up
    assert took < 2.0  # woken to plan again, not left sleeping out the real-time plan


def test_an_async_sleeper_on_a_paused_simulation_wakes_after_it_resumes():
    c = SimClock()

    async def main() -> float:
        c.feed(0.0)
        c.feed(1.0, paused=True)
        sleeper = asyncio.ensure_future(c.asleep_until(1.5))
        await asyncio.sleep(0.3)
        assert not sleeper.done()  # paused: the clock stands still
        for k in range(1, 30):
            c.feed(1.0 + 0.05 * k)
            await asyncio.sleep(0.02)
            if sleeper.done():
                break
        await asyncio.wait_for(sleeper, 2.0)
        return c.now()

    assert asyncio.run(asyncio.wait_for(main(), 10.0)) >= 1.5
