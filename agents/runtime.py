"""The agent runtime: Jadex MicroAgents on one asyncio loop per process (thesis 3.6.1, fig. 3.8).

The thesis's agents "consist of three methods that model the lifetime of the agent": *agentCreated*
initialises, *executeBody* runs the agent's steps, *agentKilled* cleans up. :class:`Agent` keeps that
lifecycle as ``created()`` → ``body()`` → ``killed()``. The default ``body()`` calls the small,
non-blocking ``step()`` every ``period`` seconds; an agent that needs another rhythm overrides
``body()``. A body that returns leaves the agent alive (its services keep working) until killed, as
in Jadex. A ``step()`` or ``body()`` that raises is logged and kills that agent only (SPADE's rule);
``killed()`` still runs.

:class:`AgentHost` runs one or hundreds of agents on one asyncio loop with one Zenoh session. While
an agent lives the host holds its liveliness token ``agents/<agent_id>`` and its ``hello``
queryable ``svc/hello/<agent_id>`` (:mod:`agents.services`); both are withdrawn when it is killed
and when the host stops. Zenoh callbacks never run agent code: they hand work to the loop with
``loop.call_soon_threadsafe`` (STYLE rule 2).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any

import zenoh

from rsal.clock import clock
from rsal.keys import AGENTS_PREFIX, agent_key
from rsal.transport import TransportArgs, open_session

from .services import Filter, Hello, Message, Services, Subscription, check_name

__all__ = ["AGENTS_PREFIX", "Agent", "AgentHost", "agent_key"]

log = logging.getLogger(__name__)


class Agent:
    """Base class of agents (the thesis's MicroAgent). Override ``created``, ``step`` (or ``body``)
    and ``killed``; all are coroutines run on the host's loop and must not block it.

    ``period`` is the step interval in seconds; ``robot`` names the robot the agent controls (``""``
    for none) and ``capabilities`` what it offers; both are answered on ``hello``.
    """

    capabilities: tuple[str, ...] = ()

    def __init__(
        self, agent_id: str, *, period: float = 0.1, robot: str = "", capabilities: tuple[str, ...] | None = None
    ):
        self.id = check_name("agent id", agent_id)
        if not period > 0:
            raise ValueError(f"agent {agent_id}: period {period!r} must be a positive number of seconds")
        self.period = float(period)
        self.robot = robot
        if capabilities is not None:
            self.capabilities = tuple(capabilities)
        self.state = "new"  # new → running → stopping → killed
        self.host: AgentHost | None = None
        self.error: BaseException | None = None  # what killed it, if a step raised
        self._task: asyncio.Task | None = None
        self._subs: list[Subscription] = []
        self._token: zenoh.LivelinessToken | None = None
        self._hello_q: zenoh.Queryable | None = None
        self._killed: asyncio.Event | None = None

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.id} {self.state}>"

    # ------------------------------------------------------------------ lifecycle (override)
    async def created(self) -> None:
        """Initialise (thesis *agentCreated*); runs before the token is declared."""

    async def step(self) -> None:
        """One small, non-blocking step of the body, called every ``period`` seconds."""

    async def body(self) -> None:
        """The agent's life (thesis *executeBody*): by default ``step()`` every ``period`` seconds,
        on a fixed schedule that skips ahead (never bursts) when a step overran. Periods are
        seconds of the process's clock (:mod:`rsal.clock`: simulated seconds under a simulation)."""
        clk = clock()
        due = clk.now()
        while True:
            await self.step()
            due += self.period
            now = clk.now()
            if due < now:
                due = now
            await clk.asleep_until(due)

    async def killed(self) -> None:
        """Clean up (thesis *agentKilled*); runs after the body stopped."""

    # ------------------------------------------------------------------ helpers for subclasses
    @property
    def hello(self) -> Hello:
        return Hello(self.id, type(self).__name__, self.robot, tuple(self.capabilities))

    def publish(self, service: str, body: Any, *, conversation: str | None = None, cell: str | None = None) -> str:
        """Send ``body`` on ``svc/<service>/<self.id>`` (with ``cell``: ``svc/<service>/<cell>/<self.id>``,
        :mod:`agents.cells`); returns the conversation id."""
        return self._require_host().services.publish(
            service, body, sender=self.id, conversation=conversation, cell=cell
        )

    def subscribe(
        self, service: str, callback: Callable[[Message], Awaitable[None] | None], filter: Filter | None = None
    ) -> Subscription:
        """Receive messages of ``service`` that ``filter`` accepts; closed when the agent is killed."""
        sub = self._require_host().services.subscribe(service, callback, filter, owner=self.id)
        self._subs.append(sub)
        return sub

    def kill(self) -> None:
        """Ask the host to kill this agent (returns at once; safe from inside ``step``)."""
        if self.host is not None:
            self.host.kill_soon(self)

    def _require_host(self) -> AgentHost:
        if self.host is None:
            raise RuntimeError(f"agent {self.id} is not started on a host")
        return self.host


class AgentHost:
    """Runs agents on the current asyncio loop with one Zenoh session.

    Use ``async with AgentHost.connect(TransportArgs(...)) as host:`` (the host owns and closes the
    session) or ``AgentHost(session)`` with a session the caller closes. Leaving the context (or
    ``await host.stop()``) kills every agent and withdraws their tokens.
    """

    def __init__(self, session: zenoh.Session, *, own_session: bool = False):
        self.session = session
        self._own = own_session
        self.agents: dict[str, Agent] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tasks: set[asyncio.Task] = set()
        self._stopped = False
        self.services = Services(self)

    @classmethod
    def connect(cls, args: TransportArgs | None = None) -> AgentHost:
        return cls(open_session(args), own_session=True)

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        return self._loop

    async def __aenter__(self) -> AgentHost:
        _ = self.loop
        return self

    async def __aexit__(self, *exc) -> None:
        await self.stop()

    # ------------------------------------------------------------------ agents
    async def start(self, agent: Agent) -> Agent:
        """Run ``created()``, declare the token and ``hello``, then start the body. If ``created()``
        raises, the agent is cleaned up and the exception propagates."""
        if self._stopped:
            raise RuntimeError("the agent host is stopped")
        if agent.state != "new":
            raise RuntimeError(f"agent {agent.id} was already started ({agent.state})")
        if agent.id in self.agents:
            raise ValueError(f"an agent with id {agent.id!r} already runs on this host")
        _ = self.loop
        agent.host = self
        agent.state = "running"
        agent._killed = asyncio.Event()
        self.agents[agent.id] = agent
        try:
            await agent.created()
        except BaseException:
            log.exception("agent %s: created() failed", agent.id)
            agent.state = "stopping"
            await self._release(agent)
            raise
        agent._token = self.session.liveliness().declare_token(agent_key(agent.id))
        agent._hello_q = self.services.declare_hello(agent.hello)
        if agent.state == "running":  # created() may already have asked for a kill
            agent._task = self.loop.create_task(self._life(agent), name=f"agent:{agent.id}")
        else:
            self.spawn(self._finish(agent), f"{agent.id}: kill")
        return agent

    async def _life(self, agent: Agent) -> None:
        try:
            await agent.body()
            await asyncio.Event().wait()  # body done: alive until killed (cancelled)
        except asyncio.CancelledError:
            pass
        except Exception as e:
            agent.error = e
            log.exception("agent %s (%s): its body failed; killing the agent", agent.id, type(agent).__name__)
        agent.state = "stopping"
        await self._finish(agent)

    async def _finish(self, agent: Agent) -> None:
        try:
            await agent.killed()
        except Exception:
            log.exception("agent %s: killed() failed", agent.id)
        await self._release(agent)

    async def _release(self, agent: Agent) -> None:
        for sub in agent._subs:
            sub.close()
        agent._subs.clear()
        self.services.release(agent.id)  # its cell broadcasts' publishers
        for handle in (agent._hello_q, agent._token):
            if handle is not None:
                try:
                    handle.undeclare()
                except Exception:  # the session may be closing
                    pass
        agent._hello_q = agent._token = None
        agent.state = "killed"
        self.agents.pop(agent.id, None)
        if agent._killed is not None:
            agent._killed.set()

    def kill_soon(self, agent: Agent) -> None:
        """Request the end of ``agent`` without waiting (safe from its own step)."""
        if agent.state == "running":
            agent.state = "stopping"
            if agent._task is not None:
                agent._task.cancel()

    async def kill(self, agent: Agent | str) -> None:
        """Kill an agent (or agent id) and wait until ``killed()`` ran and its token is withdrawn."""
        a = self.agents.get(agent) if isinstance(agent, str) else agent
        if a is None or a.host is not self:
            return
        self.kill_soon(a)
        if a._task is not None and a._task is asyncio.current_task():
            return  # killing itself: the cancellation ends the body at its next await
        if a._killed is not None:
            await a._killed.wait()

    async def wait_killed(self, agent: Agent, timeout: float | None = None) -> None:
        """Wait until ``agent`` is killed (by itself, a failed step or another agent)."""
        if agent._killed is not None:
            await asyncio.wait_for(agent._killed.wait(), timeout)

    def spawn(self, coro: Coroutine | Awaitable, name: str = "") -> asyncio.Task:
        """Run a coroutine on the loop, keeping a reference and logging its failure."""
        task = asyncio.ensure_future(coro, loop=self.loop)
        self._tasks.add(task)

        def done(t: asyncio.Task) -> None:
            self._tasks.discard(t)
            if not t.cancelled() and t.exception() is not None:
                log.error("%s failed", name or t, exc_info=t.exception())

        task.add_done_callback(done)
        return task

    async def who_is_there(self, timeout: float = 1.0) -> list[Hello]:
        """Every agent on the fabric that answers ``hello`` within ``timeout`` seconds."""
        return await self.services.who_is_there(timeout)

    async def stop(self) -> None:
        """Kill every agent (tokens withdrawn), then close the session if the host owns it."""
        if self._stopped:
            return
        self._stopped = True
        await asyncio.gather(*(self.kill(a) for a in list(self.agents.values())))
        for t in list(self._tasks):
            t.cancel()
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        self.services.release()
        if self._own:
            try:
                self.session.close()
            except Exception:
                pass
