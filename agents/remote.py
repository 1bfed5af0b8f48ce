"""An agent host launched on another machine's host daemon, as ``rsal run`` sees it (the
daemon is :mod:`agents.hostd`, the wire :mod:`agents.hostwire`).

:class:`RemoteHost` has the face of :class:`rsal.procs.Child` that the runner uses (``name``,
``kind``, ``pid``, ``poll()``, ``exit_reason()``, ``drained()``, ``reported``), so a host group placed
on a machine (``machine:`` in the scenario) is judged as a local one. Before it asks, it declares
its token ``hosts/<machine>/run/<run>/runner`` (the daemon stops the run when it goes) and
subscribes to the run's ``out`` and ``exit``; each output line becomes an event
``("line", group, text)`` on the runner's queue, so Zenoh's threads never print. When the daemon's
own token goes while the run is alive, :meth:`lost` makes the run end with :data:`LOST`.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading
import time

from rsal.errors import RsalError
from rsal.keys import host_key, host_rpc_key, host_run_key
from rsal.msgs import MessageError, RpcError, decode, encode, parse_reply

from .hostwire import LaunchRequest, OutLine, RunExit, StopRequest

__all__ = ["LOST", "RemoteError", "RemoteHost", "daemon_alive"]

log = logging.getLogger(__name__)
#: the exit code of a run whose daemon left the fabric
LOST = -1000
#: seconds a launch or stop request may take to be answered
ASK_TIMEOUT = 10.0


class RemoteError(RsalError, ValueError):
    """A launch that could not be made; one line naming the machine and the fix."""


def daemon_alive(session, machine: str, timeout: float = 5.0) -> bool:
    """Whether the host daemon ``machine``'s token is on the fabric, looked up until ``timeout`` s: a
    session just opened may not know the fabric's tokens yet (a lookup then ends at once, empty)."""
    deadline = time.monotonic() + timeout
    while True:
        if any(r.ok is not None for r in session.liveliness().get(host_key(machine), timeout=1.0)):
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.2)


class RemoteHost:
    """Host group ``request.group`` launched on ``machine``."""

    kind = "host"

    def __init__(self, session, machine: str, request: LaunchRequest, events: queue.SimpleQueue):
        self.session = session
        self.machine = machine
        self.req = request
        self.name = request.group
        self.events = events
        self.pid: str = "?"
        self.reported = False
        self.stopping = False
        self.errors: collections.deque[str] = collections.deque(maxlen=5)
        self._exit: RunExit | None = None
        self._lost = False
        self._ended = threading.Event()
        self._token = session.liveliness().declare_token(host_run_key(machine, request.run, "runner"))
        self._sub = session.declare_subscriber(host_run_key(machine, request.run, "*"), self._on_sample)

    # ------------------------------------------------------------------ Zenoh's threads
    def _on_sample(self, sample) -> None:
        part = str(sample.key_expr).rsplit("/", 1)[-1]
        try:
            if part == "out":
                m = decode(OutLine, sample.payload.to_bytes())
                if m.err:
                    self.errors.append(m.line)
                text = m.line if m.line.startswith("[") else f"[{self.name}] {m.line}"
                self.events.put(("line", self.name, text))
            elif part == "exit":
                self._exit = decode(RunExit, sample.payload.to_bytes())
                self._ended.set()
        except MessageError as e:
            log.warning("%s on %s: dropped a malformed %s: %s", self.name, self.machine, part, e)

    # ------------------------------------------------------------------ requests
    def _ask(self, op: str, payload: bytes) -> dict:
        key = host_rpc_key(self.machine, op)
        for reply in self.session.get(key, payload=payload, timeout=ASK_TIMEOUT):
            if reply.ok is not None:
                return parse_reply(reply.ok.payload.to_bytes(), key=key)
            parse_reply(reply.err.payload.to_bytes(), is_error=True, key=key, timeout=ASK_TIMEOUT)
        raise RpcError("unavailable", f"no host daemon answered within {ASK_TIMEOUT:g} s", key)

    def launch(self) -> None:
        """Ask the daemon to start the group; raises :class:`RemoteError` with its refusal."""
        try:
            m = self._ask("launch", encode(self.req))
        except RpcError as e:
            self.close()
            raise RemoteError(
                f"machine {self.machine!r} refused host group {self.name!r}: {e.code}: {e.message}"
            ) from None
        self.pid = f"{m.get('pid', '?')} on {self.machine}"

    def stop(self, deadline: float) -> bool:
        """Ask the daemon to stop the run and wait up to ``deadline`` s for its exit; True if it ended."""
        if self.stopping:  # asked already: the daemon escalates on its own
            return self.poll() is not None
        self.stopping = True
        if self.poll() is None:
            try:
                self._ask("stop", encode(StopRequest(self.req.run)))
            except RpcError as e:
                log.info("%s on %s: stop: %s", self.name, self.machine, e)
            self._ended.wait(deadline)
        return self.poll() is not None

    def lost(self) -> None:
        """The daemon's token went: the run is over unless its exit came first."""
        if self._exit is None:
            self._lost = True
            self._ended.set()

    def close(self) -> None:
        for h in (self._sub, self._token):
            try:
                h.undeclare()
            except Exception:
                pass

    # ------------------------------------------------------------------ Child's face
    def poll(self) -> int | None:
        if self._exit is not None:
            return self._exit.code
        return LOST if self._lost else None

    def alive(self) -> bool:
        return self.poll() is None

    def drained(self, timeout: float = 2.0) -> None:
        """Lines come before the exit on one session: nothing to wait for (``timeout`` for Child's face)."""

    def last_error(self) -> str:
        return self.errors[-1] if self.errors else "(no error output)"

    def exit_reason(self) -> str:
        if self._lost:
            return f"was lost: host daemon {self.machine!r} left the fabric (its token {host_key(self.machine)} went)"
        if self._exit is None:
            return "running"
        return self._exit.reason
