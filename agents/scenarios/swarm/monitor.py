"""The Swarm scenario's judge (thesis 4.2.3): :class:`SwarmMonitor` reads the simulation's ground truth.

Every ``sample_every`` seconds it asks the ``simulation`` device for every robot's true pose, checks
that no two robots overlap, follows the spread (mean nearest-neighbour distance), merges the agents'
``swarm_stats`` and after ``duration`` simulated seconds publishes the verdict as an ``outcome``.
The judged run begins when every watched robot's agent has reported once (a crowd of agents takes a
while to start): the duration counts from then, and each agent's latencies from its first report
after then, so the p99 is that of the running swarm, not of its start-up.
With a ``neighbourhood`` radius it also listens to every cell's broadcasts and judges delivery on
ground truth (:class:`.delivery.NeighbourhoodDelivery`: every receiver within the radius of the
sender at send time must have received it).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Sequence

import numpy as np

from agents.registry import agent_class
from agents.runtime import Agent
from agents.services import BundleSubscription, Message, Outcome, SendPosition, Subscription
from rsal.client import Fabric
from rsal.clock import clock

from .delivery import Delivery, NeighbourhoodDelivery
from .messages import STATS_SERVICE
from .metrics import LatencyHistogram, sequence

__all__ = ["SwarmMonitor"]

log = logging.getLogger(__name__)


def _ms(v: float) -> str:
    """A latency bound in ms as the histogram's edges read (31.5, 50, 630; inf)."""
    return f"{v:.0f}" if not v < 100 else f"{v:.3g}"


@agent_class("SwarmMonitor")
class SwarmMonitor(Agent):
    """Judges a swarm run from the simulation's ground truth (thesis 4.2.3).

    Every ``sample_every`` seconds it reads the true pose of each robot from the ``simulation``
    device of node ``simulation``, counts overlaps (two centres closer than ``2 * radius -
    tolerance``; ``radius`` is the robot's inscribed radius, so a count is a certain overlap) and the
    mean nearest-neighbour distance (the spread); it merges the ``swarm_stats`` of the agents. After
    ``duration`` simulated seconds it publishes ``Outcome("verdict", "swarm", ok=..., final=True)``:
    ok when there was no overlap, the delivery ratio is at least ``min_delivery`` percent, the p99
    latency at most ``max_p99_ms`` and every robot's agent reported. ``robots`` is a count (robots
    ``<prefix>0`` .. ``<prefix>N-1``) or a list of robot ids. The judged run begins when every
    robot's agent has reported (module docstring), or at once with ``await_reports=False`` (agents
    that send no ``swarm_stats``, as in a benchmark). Every ``log_every`` seconds it logs the
    figures so far (not ``report_every``: that is the swarm agents' broadcast period, which a
    scenario's arguments give every agent that takes it).

    With ``neighbourhood`` R > 0 (the agents' own radius) the delivery ratio is the ground-truth
    one of :class:`.delivery.NeighbourhoodDelivery` (``settle`` s at either end of each receiver's
    listening time are not judged), and a broadcast the monitor itself missed is a problem too.
    """

    capabilities = ("outcome",)

    def __init__(
        self,
        agent_id: str,
        *,
        robot: str = "",
        robots: int | Sequence[str] = 100,
        prefix: str = "r",
        duration: float = 60.0,
        sample_every: float = 0.5,
        radius: float = 0.19,
        tolerance: float = 0.02,
        min_delivery: float = 100.0,
        max_p99_ms: float = 50.0,
        simulation: str = "sim",
        startup_timeout: float = 60.0,
        log_every: float = 10.0,
        neighbourhood: float = 0.0,
        settle: float = 1.0,
        await_reports: bool = True,
        min_rtf: float = 0.0,
        max_overrun_pct: float | None = None,
    ):
        super().__init__(agent_id, period=sample_every, robot=robot)
        if isinstance(robots, bool) or not isinstance(robots, (int, list, tuple)):
            raise ValueError(f"agent {agent_id}: robots {robots!r} must be a count or a list of robot ids")
        if isinstance(robots, int):
            if robots < 1:
                raise ValueError(f"agent {agent_id}: robots {robots!r} must be at least 1")
            robots = [f"{prefix}{i}" for i in range(robots)]
        if not robots or not all(isinstance(r, str) and r for r in robots):
            raise ValueError(f"agent {agent_id}: robots must name at least one robot id")
        if not duration > 0:
            raise ValueError(f"agent {agent_id}: duration {duration!r} must be a positive number of seconds")
        self.robots = list(robots)
        self.duration = float(duration)
        self.sample_every = float(sample_every)
        self.min_dist = 2.0 * float(radius) - float(tolerance)
        self.min_delivery = float(min_delivery)
        self.max_p99_ms = float(max_p99_ms)
        for name, v in (("min_rtf", min_rtf), ("max_overrun_pct", max_overrun_pct)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0):
                raise ValueError(f"agent {agent_id}: {name} {v!r} must be a number >= 0")
        self.min_rtf = float(min_rtf)
        self.max_overrun_pct = None if max_overrun_pct is None else float(max_overrun_pct)
        self.loops: dict[str, tuple[int, int]] = {}  # control loop id -> its latest (cycles, overruns)
        self.loop_base: dict[str, tuple[int, int]] = {}  # ... at its first report of the judged run
        self.sim_node = simulation
        self.startup_timeout = float(startup_timeout)
        self.await_reports = bool(await_reports)
        self.log_every = float(log_every)
        self.stats: dict[str, dict] = {}  # sender -> its latest swarm_stats body
        self._parts: dict[str, list[dict]] = {}  # sender -> the new_ranges of its parts so far
        self._next_part: dict[str, int] = {}
        self.parts_lost = 0  # swarm_stats parts that never came (their ranges are missing)
        self.window_from: float | None = None  # wall time the judged run began (every agent reported)
        self.base: dict[str, LatencyHistogram] = {}  # sender -> its latencies at its first report of the judged run
        self.samples = 0
        self.overlaps = 0  # pairs found overlapping, summed over samples
        self.closest = math.inf  # smallest centre distance seen, m
        self.spread: list[tuple[float, float]] = []  # (sim time, mean nearest-neighbour distance)
        self.verdict: Outcome | None = None
        self.fabric: Fabric | None = None
        if isinstance(neighbourhood, bool) or not isinstance(neighbourhood, (int, float)) or neighbourhood < 0:
            raise ValueError(f"agent {agent_id}: neighbourhood {neighbourhood!r} must be a radius in metres >= 0")
        self.neighbourhood = float(neighbourhood)
        self.delivery = NeighbourhoodDelivery(self.robots, self.neighbourhood, settle) if neighbourhood else None
        self._sends: Subscription | None = None
        self._bundles: BundleSubscription | None = None
        self._sent: deque[tuple[str, str, int, float]] = deque()  # from Zenoh's thread, for the loop
        self._all_reported: asyncio.Event | None = None  # set (on the loop) when every agent reported

    async def created(self) -> None:
        self._all_reported = asyncio.Event()
        self.subscribe(STATS_SERVICE, self._on_stats)
        if self.delivery is not None:  # every cell's broadcasts: the send times of what is owed
            services = self._require_host().services
            self._sends = Subscription(
                services,
                SendPosition.SERVICE,
                self._on_send,
                None,
                self.id,
                keyexpr=f"svc/{SendPosition.SERVICE}/*/*",
                arrival=True,
                on_thread=True,  # every broadcast of the swarm: no loop wake-up for each
            )
            self._bundles = BundleSubscription(
                services, SendPosition.SERVICE, self._on_bundle, self.id, on_thread=True
            )  # the broadcasts of hosts that bundle them (agents.services)

    def _on_send(self, msg: Message, arrived: float) -> None:  # Zenoh's thread
        # the send time is when the broadcast reached this session (Zenoh's thread), not when the
        # loop served it: a loop busy starting a crowd serves it seconds later, after receivers that
        # started meanwhile, which could not have had it, began to listen
        seq = sequence(msg.conversation)
        if seq is not None:
            self._sent.append((msg.sender, msg.body.robot, seq, arrived))  # atomic: drained by the loop

    def _on_bundle(self, entries: list[tuple[str, Message]], arrived: float) -> None:  # Zenoh's thread
        for _cell, msg in entries:
            self._on_send(msg, arrived)

    def account_sends(self) -> None:  # the host's loop
        """Account the broadcasts queued by :meth:`_on_send` (each sample does; call it before
        judging ``delivery`` yourself)."""
        if self.delivery is None:
            return
        q = self._sent
        for _ in range(len(q)):
            self.delivery.sent(*q.popleft())

    def _on_stats(self, msg: Message) -> None:
        if isinstance(msg.body, dict) and isinstance(msg.body.get("latency"), dict):
            if self.window_from is not None and msg.sender not in self.base:
                try:  # its latencies count from here (parsed once, not at every judging)
                    self.base[msg.sender] = LatencyHistogram.from_dict(msg.body["latency"])
                except (TypeError, ValueError) as e:
                    log.warning("%s: ignored bad swarm_stats from %s: %s", self.id, msg.sender, e)
                    return
            part, new = msg.body.get("part"), msg.body.get("new_ranges")
            if isinstance(part, int) and isinstance(new, dict):  # what came since its previous part
                self.parts_lost += max(0, part - self._next_part.get(msg.sender, 0))
                self._next_part[msg.sender] = part + 1
                self._parts.setdefault(msg.sender, []).append(new)
            loop = msg.body.get("loop")
            if isinstance(loop, dict) and isinstance(loop.get("id"), str):
                c, o = loop.get("cycles"), loop.get("overruns")
                if isinstance(c, int) and isinstance(o, int):
                    self.loops[loop["id"]] = (c, o)
                    if self.window_from is not None:
                        self.loop_base.setdefault(loop["id"], (c, o))
            self.stats[msg.sender] = msg.body
            if len(self.stats) == len(self.robots) and self._all_reported is not None:
                self._all_reported.set()

    def _simulation(self):  # a worker thread
        # the proxies' data on Zenoh's threads: a judge of 100 robots' localize poses held 200 threads
        self.fabric = Fabric(self._require_host().session, own_session=False, direct_callbacks=True)
        node = self.fabric.node(f"{self.sim_node}:simulation:0")
        try:
            node.wait_for(f"{self.sim_node}:simulation:0", 1, self.startup_timeout)
            sim = node.device(f"{self.sim_node}:simulation:0")
            sim.wait_for_data(self.startup_timeout)
        except TimeoutError:
            raise TimeoutError(
                f"{self.id}: no simulation device {self.sim_node}:simulation:0 within {self.startup_timeout:g} s "
                "(is 'rsal sim' running and reachable?)"
            ) from None
        finally:
            node.close()
        return sim

    async def _await_reports(self) -> None:
        """Open the judged run once every watched robot's agent has reported (or after
        ``startup_timeout``, with a warning)."""
        if self.await_reports and self._all_reported is not None and len(self.stats) < len(self.robots):
            try:
                await asyncio.wait_for(self._all_reported.wait(), self.startup_timeout)
            except TimeoutError:
                pass
        if self.await_reports and len(self.stats) < len(self.robots):
            log.warning(
                "%s: %d of %d agents reported within %g s; judging from now",
                self.id,
                len(self.stats),
                len(self.robots),
                self.startup_timeout,
            )
        self.window_from = time.time()

    async def poses(self, sim) -> np.ndarray:
        """(n, 2) true positions of the watched robots (one ``get_poses``: one simulated instant)."""
        reply = await asyncio.wrap_future(sim.rpc_async("get_poses", names=self.robots))
        return np.array([p[:2] for p in reply["poses"]], dtype=float)

    def check(self, xy: np.ndarray, t: float) -> None:
        """Account one ground-truth sample: overlaps, closest pair, spread."""
        from scipy.spatial import cKDTree

        self.samples += 1
        if len(xy) < 2:
            return
        tree = cKDTree(xy)
        self.overlaps += len(tree.query_pairs(self.min_dist))
        d, _ = tree.query(xy, k=2)
        nn = d[:, 1]
        self.closest = min(self.closest, float(nn.min()))
        self.spread.append((t, float(nn.mean())))

    def reports(self) -> dict[str, dict]:
        """Each agent's latest ``swarm_stats`` with ``ranges``: everything it received, from its
        parts' ``new_ranges`` added up (or its own ``ranges``, if it sent them whole)."""
        out = {}
        for sender, body in self.stats.items():
            parts = self._parts.get(sender)
            if parts and "ranges" not in body:
                ranges: dict[str, list] = {}
                for p in parts:
                    for s, flat in p.items():
                        if isinstance(flat, list):
                            ranges.setdefault(s, []).extend(flat)
                body = {**body, "ranges": ranges}
            out[sender] = body
        return out

    def merged(self) -> tuple[int, int, LatencyHistogram, int]:
        """(received, expected, latency histogram, reporting agents) over the latest stats; the
        latencies of an agent that reported in the judged run count from its first report there."""
        got = want = 0
        hist = LatencyHistogram()
        for sender, s in self.stats.items():
            try:
                got += int(s.get("received", 0))
                want += int(s.get("expected", 0))
                h = LatencyHistogram.from_dict(s["latency"])
                base = self.base.get(sender)
                if base is not None:  # its first report of the judged run minus itself is empty
                    h.subtract(base)
                hist.merge(h)
            except (TypeError, ValueError) as e:
                log.warning("%s: ignored bad swarm_stats: %s", self.id, e)
        return got, want, hist, len(self.stats)

    def overrun_pct(self) -> float | None:
        """The share of the agents' control-loop cycles in the judged run that overran their
        period, in % (over every host's loop that reported twice in it), or None."""
        cycles = over = 0
        for lid, (c0, o0) in self.loop_base.items():
            c, o = self.loops[lid]
            cycles += c - c0
            over += o - o0
        return 100.0 * over / cycles if cycles > 0 else None

    def judge(self, elapsed: float, final: bool = True, wall: float | None = None) -> Outcome:
        """The verdict after ``elapsed`` simulated seconds of the judged run (``wall``: the wall
        seconds they took, for the real-time factor)."""
        got, want, hist, reporting = self.merged()
        nd: Delivery | None = None
        if self.delivery is not None:  # ground truth within the radius (final: the whole run)
            nd = self.delivery.result(self.reports()) if final else Delivery()
            got, want = nd.received, nd.expected
        delivery = 100.0 * got / want if want else 0.0
        p99 = 1000.0 * hist.quantile(0.99) if hist.n else math.inf
        n = len(self.robots)
        problems = []
        if self.overlaps:
            problems.append(f"{self.overlaps} overlap(s), closest {self.closest:.2f} m")
        if final and delivery < self.min_delivery:
            problems.append(f"delivery {delivery:.2f} % < {self.min_delivery:g} %")
            if nd is not None and nd.missing:
                problems.append("missing (receiver, sender, seq, m): " + ", ".join(map(str, nd.missing)))
        if self.parts_lost:
            problems.append(f"{self.parts_lost} swarm_stats part(s) never came (their receptions are not counted)")
        if nd is not None and nd.monitor_missed:
            problems.append(f"the monitor itself missed {nd.monitor_missed} broadcast(s)")
        if not p99 <= self.max_p99_ms:
            problems.append(f"p99 latency {_ms(p99)} ms > {self.max_p99_ms:g} ms")
        rtf = elapsed / wall if wall and wall > 0 else None
        if rtf is not None and rtf < self.min_rtf:
            problems.append(f"simulation at {rtf:.2f} x real time < {self.min_rtf:g}")
        overrun = self.overrun_pct()
        if self.max_overrun_pct is not None and overrun is not None and overrun >= self.max_overrun_pct:
            problems.append(f"control overruns {overrun:.1f} % >= {self.max_overrun_pct:g} %")
        if reporting < n:
            problems.append(f"stats from {reporting} of {n} agents")
        s0 = self.spread[0][1] if self.spread else math.nan
        s1 = self.spread[-1][1] if self.spread else math.nan
        scope = f" within {self.neighbourhood:g} m" if nd is not None else ""
        judged = (
            f"delivery{scope} {delivery:.1f} % ({got}/{want})"
            if final or nd is None
            else (f"{self.delivery.nsent} broadcasts seen")
        )
        text = (
            f"{n} robots {elapsed:.0f} s: {'no overlap' if not self.overlaps else f'{self.overlaps} overlap(s)'}, "
            f"{judged}, p99 latency {_ms(p99)} ms, spread {s0:.1f} -> {s1:.1f} m"
        )
        if rtf is not None:
            text += f", {rtf:.2f} x real time"
        if overrun is not None:
            text += f", overruns {overrun:.1f} %"
        if problems:
            text += " -- " + "; ".join(problems)
        return Outcome("verdict", "swarm", text, ok=not problems, final=True)

    async def body(self) -> None:
        sim = await asyncio.to_thread(self._simulation)
        await self._await_reports()
        t0 = sim.latest.t
        wall0 = time.monotonic()
        next_report = clock().now() + self.log_every
        while True:
            started = clock().now()
            t = sim.latest.t
            try:
                w0 = time.time()
                xy = await self.poses(sim)
                w1 = time.time()
            except Exception as e:  # a slow or restarting simulator: skip this sample
                log.warning("%s: ground-truth sample failed: %s", self.id, e)
            else:
                self.check(xy, t)
                if self.delivery is not None:
                    self.account_sends()
                    self.delivery.truth(0.5 * (w0 + w1), xy)
            if t - t0 >= self.duration:
                self.account_sends()
                self.verdict = self.judge(t - t0, wall=time.monotonic() - wall0)
                self.publish(Outcome.SERVICE, self.verdict)
                log.info("%s: %s", self.id, self.verdict.text)
                return
            if clock().now() >= next_report:
                next_report += self.log_every
                log.info("%s: %s", self.id, self.judge(t - t0, final=False, wall=time.monotonic() - wall0).text)
            await clock().asleep_until(started + self.sample_every)

    async def killed(self) -> None:
        if self._sends is not None:
            self._sends.close()
        if self._bundles is not None:
            self._bundles.close()
        if self.fabric is not None:
            self.fabric.close()
