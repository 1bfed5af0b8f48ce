"""Awareness: one agent started for every robot whose devices appear, stopped when they go (the
thesis's outlook: Jadex "Awareness" discovers platforms and starts agents on them).

A host daemon (:mod:`agents.hostd`) with an ``[awareness]`` section follows the liveliness tokens
of robot bases, ``rsal/<node>/position2d/<idx>``. When the first base of a node whose name matches
one of ``robots`` (fnmatch patterns) appears, it starts ``rsal agent CLASS --robot NODE [--arg
K=V ...]`` as a supervised child (:class:`rsal.procs.Child`, output relayed as ``[aware NODE]``),
joined to the fabric as the daemon's launched agent hosts are; when the node's last base token
goes, it stops that agent (SIGTERM, SIGKILL after the daemon's deadline). An agent that exits on its
own is started again when its robot's base appears again. Token events arrive on Zenoh's threads and
are handed to the daemon's loop (``("aware", (node, key, present))``), so nothing here blocks Zenoh.
"""

from __future__ import annotations

import fnmatch
import json
import signal
import sys
import threading

from rsal.procs import Child, python_env, stop_all

__all__ = ["Awareness"]

BASES = "rsal/*/position2d/*"


class Awareness:
    """The awareness agents of one daemon (``daemon`` gives ``work``, ``session``, ``say`` and the
    launched agent hosts' transport flags)."""

    def __init__(self, daemon, config):
        self.daemon = daemon
        self.cls = config.aware_class
        self.patterns = config.aware_robots
        self.args = dict(config.aware_args)
        self.bases: dict[str, set[str]] = {}  # node -> its base tokens present
        self.agents: dict[str, Child] = {}

    def declare(self):
        """The liveliness subscriber on every robot base (with the ones already there)."""
        import zenoh

        def on_base(sample) -> None:  # Zenoh's thread
            key = str(sample.key_expr)
            self.daemon.work.put(("aware", (key.split("/")[1], key, sample.kind == zenoh.SampleKind.PUT)))

        return self.daemon.session.liveliness().declare_subscriber(BASES, on_base, history=True)

    def wanted(self, node: str) -> bool:
        return any(fnmatch.fnmatchcase(node, p) for p in self.patterns)

    def handle(self, node: str, key: str, present: bool) -> None:
        if not self.wanted(node):
            return
        keys = self.bases.setdefault(node, set())
        (keys.add if present else keys.discard)(key)
        child = self.agents.get(node)
        running = child is not None and child.poll() is None
        if keys and not running:
            self._start(node)
        elif not keys and running:
            self.daemon.say(f"aware: robot {node}'s devices went; stopping its {self.cls} (pid {child.pid})")
            stop = [(signal.SIGTERM, 15.0)]
            threading.Thread(target=stop_all, args=([child], stop), daemon=True).start()

    def _start(self, node: str) -> None:
        argv = [sys.executable, "-m", "rsal.cli", "agent", self.cls, "--robot", node]
        for k, v in self.args.items():
            argv += ["--arg", f"{k}={json.dumps(v)}"]  # JSON is YAML, as --arg reads it
        argv += self.daemon.child_flags()
        name = f"aware {node}"
        child = Child(name, argv, kind="agent", env=python_env(), forward=_print, stderr_apart=True)
        self.agents[node] = child
        self.daemon.say(f"aware: robot {node} appeared; started {self.cls} for it (pid {child.pid})")

    def children(self) -> list[Child]:
        """The awareness agents still running."""
        return [c for c in self.agents.values() if c.poll() is None]


def _print(line: str) -> None:
    print(line, flush=True)
