"""Agent classes that the ``rsal run`` tests name in their scenario files (``module:Class``).

:class:`Reporter` publishes ``outcome`` messages (thesis 4.2's counted events) on a schedule, so a
test can check that the runner ends a run exactly when the end condition is met; with ``after`` it
starts only once a device is alive on the fabric (a run can end as soon as what a test waits for is up).
"""

from __future__ import annotations

import asyncio

from agents.runtime import Agent
from agents.services import Outcome
from rsal.keys import device_key, parse_device


class Reporter(Agent):
    """Publishes ``event`` about each of ``subjects`` in turn, one every ``every`` seconds, and starts
    over (a sample sent before the runner's subscription reached this peer comes again; a repeated
    subject must not count twice). ``final`` marks the outcomes as ending the run with ``ok``;
    ``after`` (a device, ``node:interface:index``) holds the first outcome back until that device's
    liveliness token is on the fabric."""

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        period: float = 0.1,
        event: str = "caught",
        subjects: list[str] | tuple[str, ...] = ("r0",),
        every: float = 0.5,
        ok: bool = True,
        final: bool = False,
        delay: float = 0.0,
        after: str = "",
    ):
        super().__init__(agent_id, period=period, robot=robot)
        if not subjects:
            raise ValueError(f"agent {agent_id}: subjects must not be empty")
        self.event = event
        self.subjects = [str(s) for s in subjects]
        self.every = float(every)
        self.ok = bool(ok)
        self.final = bool(final)
        self.delay = float(delay)
        self.after = device_key(parse_device(after)) if after else ""
        self.sent = 0

    def _alive(self, key: str) -> bool:
        """Whether a liveliness token on ``key`` answers a query (blocking: run in a thread)."""
        replies = self._require_host().session.liveliness().get(key, timeout=1.0)
        return any(r.ok is not None for r in replies)

    async def body(self) -> None:
        while self.after and not await asyncio.to_thread(self._alive, self.after):
            await asyncio.sleep(0.2)
        await asyncio.sleep(self.delay)
        t0 = asyncio.get_running_loop().time()
        while True:
            subject = self.subjects[self.sent % len(self.subjects)]
            t = asyncio.get_running_loop().time() - t0
            text = f"{self.event} {subject} reported by {self.id} after {t:.1f} s"
            self.publish(Outcome.SERVICE, Outcome(self.event, subject, text, ok=self.ok, final=self.final))
            self.sent += 1
            await asyncio.sleep(self.every)

    def status(self) -> str:
        return f"sent {self.sent} outcome(s)"
