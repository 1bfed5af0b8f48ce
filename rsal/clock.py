"""One clock for agents, robots, behaviours and timeouts: the wall clock, or the simulation's.

Every periodic loop and every timeout of the client side (agent steps, a robot's control cycle, a
behaviour's timers, held commands, a scenario's duration) reads time from the process's clock,
:func:`clock`. By default that is the wall clock (``time.monotonic()``). A process that works with
a simulator can follow the **simulation's clock** instead -- what ROS calls ``use_sim_time``: then
a 0.1 s agent period is 0.1 *simulated* seconds, so a simulation run at ten times real time runs
its agents ten times faster too, and a scenario behaves the same at any speed-up.

:class:`SimClock` follows the ``simulation`` device's data (``rsal/<node>/simulation/0/data``,
simulated time ``t`` about ten times per wall second). Between two samples it extrapolates with the
measured rate of simulated over wall time, never more than :data:`SimClock.MAX_AHEAD` wall seconds
past the last sample (a paused or stalled simulation stops the clock instead of letting it run
away), and it never goes backwards. Sleeping on it wakes on the sample that passes the deadline.
An asyncio sleeper sleeps the wall time its deadline is predicted to take at the measured speed,
in one go (a thousand agents polling every 50 ms were 20,000 wake-ups a second); a sample that
changes the plan -- the simulation reset, resumed or sped up by more than :data:`SimClock.REPLAN`
-- wakes the sleepers to plan again.

Select it with ``RSAL_SIM_TIME=<node>`` in the environment (``rsal run`` sets it for the agent hosts
of a scenario that runs a simulator) or call :func:`use_sim_time`. Servers keep their own time: a
simulated base counts its command timeout on the world's clock (:mod:`mrs_bridge.baseguard`).
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import threading
import time
from collections.abc import Callable

__all__ = [
    "ENV",
    "Clock",
    "SimClock",
    "WallClock",
    "clock",
    "set_clock",
    "sim_time_from_env",
    "use_sim_time",
    "wait_for",
]

log = logging.getLogger(__name__)

ENV = "RSAL_SIM_TIME"  # name of the simulation's node to follow ("sim"), unset or "" for the wall clock


class Clock:
    """Monotonic seconds and sleeping on them. ``speed`` is clock seconds per wall second."""

    def now(self) -> float:
        raise NotImplementedError

    @property
    def speed(self) -> float:
        return 1.0

    def wall(self, dt: float) -> float:
        """About how many wall seconds ``dt`` seconds of this clock take now (for network timeouts)."""
        s = self.speed
        return dt / s if s > 0 and math.isfinite(s) else dt

    def sleep(self, dt: float, wake: threading.Event | None = None) -> bool:
        """Block for ``dt`` seconds of this clock; returns True early if ``wake`` is set."""
        return self.sleep_until(self.now() + dt, wake)

    def sleep_until(self, t: float, wake: threading.Event | None = None) -> bool:
        raise NotImplementedError

    async def asleep(self, dt: float) -> None:
        """``asyncio.sleep`` for ``dt`` seconds of this clock."""
        await self.asleep_until(self.now() + dt)

    async def asleep_until(self, t: float) -> None:
        raise NotImplementedError


class WallClock(Clock):
    """``time.monotonic()``."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float, wake: threading.Event | None = None) -> bool:
        delay = t - time.monotonic()
        if wake is not None:
            return wake.wait(max(0.0, delay))
        if delay > 0:
            time.sleep(delay)
        return False

    async def asleep_until(self, t: float) -> None:
        await asyncio.sleep(max(0.0, t - time.monotonic()))

    def __repr__(self) -> str:
        return "<WallClock>"


class SimClock(Clock):
    """The simulated time of a ``simulation`` device, fed by :meth:`feed` (or by a subscription
    made with :meth:`follow`)."""

    MAX_AHEAD = 0.25  # wall seconds past the last sample that the clock extrapolates
    POLL = 0.05  # wall seconds: the longest a thread sleeper (or any, paused) waits before looking again
    REPLAN = 1.25  # a speed-up by this factor wakes the asyncio sleepers to plan again

    def __init__(self, wall: Callable[[], float] = time.monotonic):
        self._wall = wall
        self._cond = threading.Condition()
        self._t: float | None = None  # simulated time of the last sample
        self._w = 0.0  # wall time it arrived
        self._speed = 1.0  # simulated seconds per wall second, measured
        self._measured = False
        self._paused = False
        self._last = -math.inf  # the largest value now() returned
        self._sub = None
        self._sleepers: set[tuple[asyncio.AbstractEventLoop, asyncio.Future]] = set()  # asleep_until's
        self._plan_speed = math.inf  # the slowest speed a current sleeper planned with

    # ------------------------------------------------------------------ input
    def feed(self, t: float, paused: bool = False, wall: float | None = None) -> None:
        """A sample of the simulation's time ``t``, received at wall time ``wall`` (now)."""
        w = self._wall() if wall is None else wall
        with self._cond:
            replan = self._paused and not paused
            if self._t is not None and t < self._t - 1e-9:  # the simulation was reset or restarted
                self._last = -math.inf
                replan = True
            elif self._t is not None and w - self._w > 1e-3 and not paused and not self._paused:
                rate = (t - self._t) / (w - self._w)
                # smooth: samples arrive with network jitter; a step change shows within a few samples
                self._speed = rate if not self._measured else 0.5 * self._speed + 0.5 * rate
                self._measured = True
            self._t, self._w, self._paused = float(t), w, bool(paused)
            self._cond.notify_all()
            if self._sleepers and (replan or self._speed > self._plan_speed * self.REPLAN):
                self._plan_speed = math.inf
                by_loop: dict[asyncio.AbstractEventLoop, list[asyncio.Future]] = {}
                for loop, fut in self._sleepers:
                    by_loop.setdefault(loop, []).append(fut)
                for loop, futs in by_loop.items():  # one hand-over per loop, not per sleeper (500 in a swarm host)
                    try:
                        loop.call_soon_threadsafe(_wake_all, futs)
                    except RuntimeError:  # that loop is closed
                        pass

    def follow(self, session, node: str = "sim") -> SimClock:
        """Subscribe ``session`` to ``node``'s simulation data; returns self."""
        from . import keys
        from .msgs import SimulationData, decode

        key = f"{keys.PREFIX}/{node}/simulation/0/data"

        def on_sample(sample) -> None:
            try:
                m = decode(SimulationData, sample.payload.to_bytes())
            except Exception as e:  # a malformed sample moves no clock
                log.debug("clock: bad sample on %s: %s", key, e)
                return
            self.feed(m.t, m.paused)

        self._sub = session.declare_subscriber(key, on_sample)
        return self

    def close(self) -> None:
        if self._sub is not None:
            try:
                self._sub.undeclare()
            except Exception:
                pass
            self._sub = None

    # ------------------------------------------------------------------ reading
    @property
    def started(self) -> bool:
        return self._t is not None

    @property
    def speed(self) -> float:
        return self._speed

    def wait_started(self, timeout: float) -> bool:
        """Wait up to ``timeout`` wall seconds for the first sample."""
        with self._cond:
            return self._cond.wait_for(lambda: self._t is not None, timeout)

    def now(self) -> float:
        with self._cond:
            return self._now()

    def _now(self) -> float:
        if self._t is None:
            return 0.0
        t = self._t
        if not self._paused:
            t += min(max(0.0, self._wall() - self._w), self.MAX_AHEAD) * self._speed
        if t < self._last:
            t = self._last
        self._last = t
        return t

    def _wall_wait(self, t: float) -> float:
        """Wall seconds to wait before looking again for time ``t``."""
        left = t - self._now()
        if left <= 0:
            return 0.0
        if self._t is None or self._paused or self._speed <= 0:
            return self.POLL
        return min(max(left / self._speed, 0.0005), self.POLL)

    def sleep_until(self, t: float, wake: threading.Event | None = None) -> bool:
        while True:
            if wake is not None and wake.is_set():
                return True
            with self._cond:
                d = self._wall_wait(t)
                if d <= 0:
                    return False
                if wake is None:
                    self._cond.wait(d)
                    continue
            if wake.wait(d):
                return True

    async def asleep_until(self, t: float) -> None:
        loop = asyncio.get_running_loop()
        while True:
            with self._cond:
                left = t - self._now()
                if left <= 0:
                    return
                if self._t is None or self._paused or self._speed <= 0:
                    d = self.POLL
                else:  # the whole predicted wait; a sample that changes the plan wakes it (feed)
                    d = max(left / self._speed, 0.0005)
                    self._plan_speed = min(self._plan_speed, self._speed)
                fut = loop.create_future()
                me = (loop, fut)
                self._sleepers.add(me)
            timer = loop.call_later(d, _wake, fut)
            try:
                await fut
            finally:
                timer.cancel()
                with self._cond:
                    self._sleepers.discard(me)

    def __repr__(self) -> str:
        return f"<SimClock t={self._t} speed={self._speed:.3g}{' paused' if self._paused else ''}>"


def _wake(fut: asyncio.Future) -> None:
    if not fut.done():
        fut.set_result(None)


def _wake_all(futs: list[asyncio.Future]) -> None:
    for fut in futs:
        _wake(fut)


_clock: Clock = WallClock()


async def wait_for(aw, timeout: float | None):
    """``asyncio.wait_for`` with ``timeout`` in seconds of the process's clock."""
    c = _clock
    if timeout is None or isinstance(c, WallClock):
        return await asyncio.wait_for(aw, timeout)
    task = asyncio.ensure_future(aw)
    timer = asyncio.ensure_future(c.asleep(timeout))
    try:
        await asyncio.wait({task, timer}, return_when=asyncio.FIRST_COMPLETED)
    except asyncio.CancelledError:
        task.cancel()
        raise
    finally:
        timer.cancel()
    if task.done():
        return task.result()
    task.cancel()
    try:
        await task
    except asyncio.CancelledError:
        pass
    raise TimeoutError


def clock() -> Clock:
    """The process's clock."""
    return _clock


def set_clock(c: Clock) -> Clock:
    """Make ``c`` the process's clock; returns the previous one."""
    global _clock
    old, _clock = _clock, c
    return old


def use_sim_time(session, node: str = "sim", *, wait: float = 0.0) -> SimClock:
    """Follow ``node``'s simulation clock over ``session`` from now on (process-wide); wait up to
    ``wait`` wall seconds for its first sample."""
    c = SimClock().follow(session, node)
    if wait > 0 and not c.wait_started(wait):
        log.warning("clock: no time from %s's simulation within %g s yet; waiting for it", node, wait)
    set_clock(c)
    return c


def sim_time_from_env(session, *, wait: float = 0.0) -> SimClock | None:
    """:func:`use_sim_time` if ``RSAL_SIM_TIME`` names a simulation's node, else None."""
    node = os.environ.get(ENV, "").strip()
    if not node:
        return None
    return use_sim_time(session, node, wait=wait)
