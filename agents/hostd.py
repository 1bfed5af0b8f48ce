"""``rsal host [--name NAME] [--host-config FILE]``: the per-machine daemon that starts agent hosts
on request (thesis 3.6.1: Jadex placed an application's agents on any platform;
outlook, "Awareness": agents that start when a robot appears).

The daemon declares the liveliness token ``hosts/<name>`` once its queryable
``hosts/<name>/rpc/*`` answers (:mod:`agents.hostwire` has the wire):

- ``launch`` (:class:`~agents.hostwire.LaunchRequest`): writes the scenario text it was sent to a
  private temporary folder, checks the application, the host group and its agent classes, and runs
  ``python -m agents.hostproc COPY --remote --app APP --host GROUP [--set ..]`` as a supervised child
  (:class:`rsal.procs.Child`), joined to the fabric as the daemon is (or with the identity of its
  configuration's ``[agents] config``). Each output line is put on ``hosts/<name>/run/<run>/out``,
  the exit on ``.../exit``. Replies ``{ok, pid}``, or a typed refusal in one line: ``bad_request``
  (malformed request or scenario, a run id in use), ``not_found`` (no such application, host group
  or agent class), ``unavailable`` (the launcher's token ``.../runner`` is not alive).
- ``stop {run}``: SIGTERM to that agent host, SIGKILL after ``STOP_DEADLINE`` s.
  At most ``MAX_RUNS`` runs at once: a launch beyond is refused ``busy``.
- ``status``: the daemon's runs (run, app, group, pid, state).

A run is also stopped when its launcher's token ``hosts/<name>/run/<run>/runner`` disappears (the
runner ended or lost the fabric) and, with every other, on the daemon's own SIGTERM/SIGINT, after
which it withdraws its token and exits 0. Its children die with it (``PR_SET_PDEATHSIG``).

The optional configuration (TOML, ``--host-config``)::

    name = "robot1"                    # default: --name, else the machine's host name
    [agents]
    config = "members/hunters.json5"   # the launched agent hosts' Zenoh configuration (identity)
    [awareness]                        # optional: one agent per robot whose devices appear
    class = "WanderAgent"              # any agents.registry class or module:Class
    robots = ["r*"]                    # node name patterns (fnmatch); default every robot
    args = {report_every = 2.0}        # constructor arguments

Awareness is :mod:`agents.awareness`. Errors in the configuration or flags exit 2 with one line.
"""

from __future__ import annotations

import argparse
import logging
import queue
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rsal.errors import RsalError
from rsal.keys import check_name, host_key, host_rpc_key, host_run_key
from rsal.msgs import ErrorCode, MessageError, encode, error_reply, ok_reply
from rsal.procs import Child, python_env, stop_all
from rsal.suggest import did_you_mean
from rsal.transport import TransportArgs, add_transport_args

from .hostwire import LaunchRequest, OutLine, RunExit, StopRequest

__all__ = ["HostConfig", "HostDaemon", "load_host_config", "register"]

log = logging.getLogger(__name__)
PROG = "rsal host"
#: seconds a launched agent host gets after SIGTERM before SIGKILL
STOP_DEADLINE = 15.0
#: seconds to look for a launcher's token before a launch is refused
RUNNER_LOOKUP = 3.0
#: runs one daemon keeps at once; a launch beyond is refused ``busy`` (no request grows it unbounded)
MAX_RUNS = 32

_TOP = ("name", "agents", "awareness")
_AGENTS = ("config",)
_AWARE = ("class", "robots", "args", "period")


class HostConfigError(RsalError, ValueError):
    """A daemon configuration that cannot be used; one line naming the file, the key and a fix."""


@dataclass
class HostConfig:
    """The daemon's configuration file, parsed once."""

    name: str = ""
    agents_config: str | None = None
    aware_class: str | None = None
    aware_robots: tuple[str, ...] = ("*",)
    aware_args: dict[str, Any] = field(default_factory=dict)


def _keys(src: str, where: str, m: Any, allowed: tuple[str, ...]) -> dict:
    if not isinstance(m, dict):
        raise HostConfigError(f"{src}: {where}: must be a table with keys {', '.join(allowed)}")
    for k in m:
        if k not in allowed:
            near = did_you_mean(k, allowed)
            hint = f"did you mean {near!r}?" if near else f"known keys: {', '.join(allowed)}"
            raise HostConfigError(f"{src}: {where + '.' if where else ''}{k}: unknown key; {hint}")
    return m


def load_host_config(path: str | None) -> HostConfig:
    """Read and check the TOML configuration (``None``: the defaults)."""
    if path is None:
        return HostConfig()
    try:
        doc = tomllib.loads(Path(path).read_text())
    except OSError as e:
        raise HostConfigError(f"--host-config {path}: cannot read it ({e.strerror}); check the path") from None
    except tomllib.TOMLDecodeError as e:
        raise HostConfigError(f"{path}: not valid TOML: {e}") from None
    top = _keys(path, "", doc, _TOP)
    cfg = HostConfig(name=str(top.get("name") or ""))
    agents = _keys(path, "agents", top.get("agents", {}), _AGENTS)
    if agents.get("config") is not None:
        p = Path(str(agents["config"]))
        p = p if p.is_absolute() else Path(path).parent / p
        if not p.is_file():
            raise HostConfigError(f"{path}: agents.config: no file {str(p)!r} (an agent host's member file)")
        cfg.agents_config = str(p)
    if "awareness" in top:
        aw = _keys(path, "awareness", top["awareness"], _AWARE)
        if not isinstance(aw.get("class"), str) or not aw["class"]:
            raise HostConfigError(f"{path}: awareness.class: name the agent class to start, e.g. class = 'WanderAgent'")
        robots = aw.get("robots", ["*"])
        if isinstance(robots, str):
            robots = [robots]
        if not isinstance(robots, list) or not all(isinstance(r, str) and r for r in robots):
            raise HostConfigError(f"{path}: awareness.robots: a list of node name patterns, e.g. ['r*']")
        args = aw.get("args", {})
        if not isinstance(args, dict):
            raise HostConfigError(f"{path}: awareness.args: a table of constructor arguments")
        cfg.aware_class, cfg.aware_robots, cfg.aware_args = aw["class"], tuple(robots), dict(args)
    return cfg


@dataclass
class _Run:
    req: LaunchRequest
    child: Child
    folder: str
    seq: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    stopping: str = ""
    watcher: threading.Thread | None = None


class HostDaemon:
    """One daemon: a Zenoh session, its token and queryable, the runs it launched. :meth:`serve`
    runs until :meth:`shutdown` (the signal handlers call it)."""

    def __init__(self, name: str, targs: TransportArgs, config: HostConfig | None = None):
        self.name = check_name("host name", name)
        self.targs = targs
        self.config = config or HostConfig()
        self.runs: dict[str, _Run] = {}
        self.runners: set[str] = set()  # runs whose launcher's token is alive
        self._lock = threading.Lock()
        self.work: queue.SimpleQueue = queue.SimpleQueue()
        self.session = None
        self.awareness = None

    # ------------------------------------------------------------------ helpers
    def say(self, text: str) -> None:
        print(f"[host {self.name}] {text}", flush=True)

    def child_flags(self) -> list[str]:
        """Transport flags of a launched agent host: the configuration's identity, else the daemon's
        own way onto the fabric (its --connect endpoints, or the ones it listens on)."""
        t = self.targs
        cfg = [f for item in t.cfg for f in ("--cfg", item)]
        if self.config.agents_config:
            return ["--config", self.config.agents_config, *cfg]
        flags = [f for ep in (t.connect or t.listen) for f in ("--connect", ep)]
        if t.config:
            flags += ["--config", t.config]
        if t.mode:
            flags += ["--mode", "client" if t.mode == "router" else t.mode]
        return flags + cfg

    # ------------------------------------------------------------------ requests
    def _on_query(self, query) -> None:  # Zenoh's thread: hand over, never block
        self.work.put(("query", query))

    def _on_runner(self, sample) -> None:
        import zenoh

        run = str(sample.key_expr).split("/")[-2]
        with self._lock:
            (self.runners.add if sample.kind == zenoh.SampleKind.PUT else self.runners.discard)(run)
        if sample.kind == zenoh.SampleKind.DELETE:
            self.work.put(("runner-gone", run))

    def _handle_query(self, query) -> None:
        op = str(query.key_expr).rsplit("/", 1)[-1]
        raw = query.payload.to_bytes() if query.payload is not None else b""
        try:
            if op == "launch":
                reply = self._launch(LaunchRequest.from_bytes(raw))
            elif op == "stop":
                reply = self._stop(StopRequest.from_bytes(raw).run, "stop request")
            elif op == "status":
                reply = ok_reply(name=self.name, runs=[self._status(r) for r in self.runs.values()])
            else:
                raise _Refusal(ErrorCode.UNKNOWN_OP, f"no operation {op!r}; use launch, stop or status")
        except MessageError as e:
            query.reply_err(error_reply(ErrorCode.BAD_REQUEST, f"{op}: {e}"))
        except _Refusal as e:
            query.reply_err(error_reply(e.code, str(e)))
        else:
            query.reply(str(query.key_expr), reply)

    def _status(self, r: _Run) -> dict:
        rc = r.child.poll()
        state = "running" if rc is None else ("stopped" if r.stopping else ("finished" if rc == 0 else "failed"))
        return {"run": r.req.run, "app": r.req.app, "group": r.req.group, "pid": r.child.pid, "state": state}

    def _launch(self, req: LaunchRequest) -> bytes:
        from .hostproc import HostError, host_agents
        from .registry import AgentClassError, resolve
        from .scenario import ScenarioError, load_scenario, parse_set

        if len(self.runs) >= MAX_RUNS:
            raise _Refusal(ErrorCode.BUSY, f"{MAX_RUNS} runs are running here already; stop one or use another host")
        if req.run in self.runs:
            raise _Refusal(ErrorCode.BAD_REQUEST, f"run {req.run!r} is already launched here; use a new run id")
        if not self._runner_alive(req.run):
            raise _Refusal(
                ErrorCode.UNAVAILABLE,
                f"the launcher's token {host_run_key(self.name, req.run, 'runner')} is not alive; declare it first",
            )
        folder = tempfile.mkdtemp(prefix=f"rsal-host-{req.run}-")
        path = Path(folder) / f"scenario{req.suffix}"
        path.write_text(req.scenario)
        try:
            sc = load_scenario(path, parse_set(list(req.overrides)), check_files=False)
            entries = host_agents(sc, req.app, req.group)
            for e in entries:
                resolve(e.cls)
        except ScenarioError as e:
            shutil.rmtree(folder, ignore_errors=True)
            raise _Refusal(ErrorCode.BAD_REQUEST, f"the scenario sent: {_strip(str(e), path)}") from None
        except (HostError, AgentClassError) as e:
            shutil.rmtree(folder, ignore_errors=True)
            raise _Refusal(ErrorCode.NOT_FOUND, _strip(str(e), path)) from None
        argv = [sys.executable, "-m", "agents.hostproc", str(path), "--remote", "--app", req.app]
        argv += ["--host", req.group, "--report-every", f"{req.report_every:g}"]
        for item in req.overrides:
            argv += ["--set", item]
        argv += self.child_flags()
        env = python_env()
        if req.sim_clock:
            from rsal.clock import ENV as clock_env

            env[clock_env] = req.sim_clock
        out_key = host_run_key(self.name, req.run, "out")
        holder: list[_Run] = []

        def on_output(line: str, is_err: bool) -> None:  # the child's reader thread
            r = holder[0] if holder else None
            if r is None:
                return
            with r.lock:
                seq, r.seq = r.seq, r.seq + 1
            try:
                self.session.put(out_key, encode(OutLine(seq, line, is_err)))
            except Exception as e:  # the session closed under us: the line is lost, not the run
                log.debug("%s: line not sent: %s", req.run, e)

        child = Child(req.group, argv, kind="host", env=env, cwd=folder, on_output=on_output, stderr_apart=True)
        r = _Run(req, child, folder)
        holder.append(r)
        self.runs[req.run] = r
        r.watcher = threading.Thread(target=self._watch, args=(r,), name=f"run-{req.run}", daemon=True)
        r.watcher.start()
        ids = ", ".join(e.id for e in entries)
        self.say(f"launched run {req.run}: {sc.name}/{req.app} group {req.group} (pid {child.pid}): {ids}")
        return ok_reply(pid=child.pid, agents=[e.id for e in entries])

    def _runner_alive(self, run: str) -> bool:
        """The launcher's token, as the subscriber saw it or a lookup finds it, within RUNNER_LOOKUP s
        (its declaration may reach this daemon after the launch request did)."""
        key = host_run_key(self.name, run, "runner")
        deadline = time.monotonic() + RUNNER_LOOKUP
        while True:
            with self._lock:
                if run in self.runners:
                    return True
            try:
                if any(rep.ok is not None for rep in self.session.liveliness().get(key, timeout=1.0)):
                    return True
            except Exception as e:
                log.debug("%s: lookup failed: %s", key, e)
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.1)

    def _watch(self, r: _Run) -> None:
        """Until the agent host exits: then its last lines, its exit on the fabric, its folder gone."""
        rc = r.child.p.wait()
        r.child.drained()
        reason = r.child.exit_reason()
        if r.stopping:
            reason = f"stopped ({r.stopping}); {reason}"
        try:
            self.session.put(host_run_key(self.name, r.req.run, "exit"), encode(RunExit(rc, reason)))
        except Exception as e:
            log.debug("%s: exit not sent: %s", r.req.run, e)
        shutil.rmtree(r.folder, ignore_errors=True)
        self.say(f"run {r.req.run} ({r.req.group}) ended: {reason}")
        self.work.put(("ended", r.req.run))

    def _stop(self, run: str, why: str) -> bytes:
        r = self.runs.get(run)
        if r is None:
            raise _Refusal(ErrorCode.NOT_FOUND, f"no run {run!r} here (status lists the runs)")
        if r.child.poll() is None and not r.stopping:
            r.stopping = why
            self.say(f"stopping run {run} ({why})")
            threading.Thread(target=stop_all, args=([r.child], [(signal.SIGTERM, STOP_DEADLINE)]), daemon=True).start()
        return ok_reply(run=run, state="stopping" if r.child.poll() is None else "ended")

    # ------------------------------------------------------------------ main
    def shutdown(self, why: str = "signal") -> None:
        self.work.put(("shutdown", why))

    def serve(self) -> int:
        from rsal.transport import open_session

        self.session = open_session(self.targs)
        lv = self.session.liveliness()
        handles = [
            self.session.declare_queryable(host_rpc_key(self.name), self._on_query),
            lv.declare_subscriber(host_run_key(self.name, "*", "runner"), self._on_runner),
        ]
        if self.config.aware_class:
            from .awareness import Awareness

            self.awareness = Awareness(self, self.config)
            handles.append(self.awareness.declare())
        token = lv.declare_token(host_key(self.name))  # last: the token means it answers
        self.say(f"up: token {host_key(self.name)}, requests on {host_rpc_key(self.name)}")
        why = ""
        try:
            while not why:
                kind, what = self.work.get()
                if kind == "query":
                    try:
                        self._handle_query(what)
                    except Exception as e:  # a bug must not end the daemon: refuse, log, carry on
                        log.exception("request failed")
                        what.reply_err(error_reply(ErrorCode.INTERNAL, f"{type(e).__name__}: {e}"))
                    finally:
                        del what  # the query is finished when dropped
                elif kind == "runner-gone" and what in self.runs:
                    self._stop(what, "its launcher left the fabric")
                elif kind == "ended":
                    self.runs.pop(what, None)
                elif kind == "aware" and self.awareness is not None:
                    self.awareness.handle(*what)
                elif kind == "shutdown":
                    why = what
        finally:
            self.say(f"stopping ({why or 'error'}): {len(self.runs)} run(s)")
            running = [r.child for r in self.runs.values() if r.child.poll() is None]
            for r in self.runs.values():
                r.stopping = r.stopping or f"host daemon stopped ({why})"
            if self.awareness is not None:
                running += self.awareness.children()
            stop_all(running, [(signal.SIGTERM, STOP_DEADLINE)])
            for r in list(self.runs.values()):  # their exits on the fabric before the session closes
                if r.watcher is not None:
                    r.watcher.join(5.0)
            for h in handles:
                h.undeclare()
            token.undeclare()
            self.session.close()
        return 0


class _Refusal(RsalError):
    """A launch, stop or status request the daemon refuses: its typed code and one line."""

    def __init__(self, code: ErrorCode, text: str):
        super().__init__(text)
        self.code = code


def _strip(text: str, path: Path) -> str:
    """A scenario error names the daemon's temporary copy: say "the scenario" instead."""
    return text.replace(f"{path}: ", "").replace(str(path), "the scenario")


def run_host(args: argparse.Namespace) -> int:
    def fail(text: str) -> int:
        print(f"{PROG}: {text}", file=sys.stderr, flush=True)
        return 2

    try:
        cfg = load_host_config(args.host_config)
        name = check_name("--name", args.name or cfg.name or socket.gethostname().split(".")[0])
    except (HostConfigError, ValueError) as e:
        return fail(str(e))
    daemon = HostDaemon(name, TransportArgs.from_namespace(args), cfg)
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda signum, frame: daemon.shutdown(signal.Signals(signum).name))
    return daemon.serve()


def register(sub) -> None:
    p = sub.add_parser(
        "host", help="a per-machine daemon that launches agent hosts for rsal run (and awareness agents)"
    )
    p.add_argument("--name", help="the daemon's name, hosts/<name> (default: the configuration's, else the host name)")
    p.add_argument("--host-config", metavar="FILE", help="the daemon's TOML configuration (docs/deployment.md)")
    add_transport_args(p)
    p.set_defaults(func=run_host)


if __name__ == "__main__":
    from rsal.errnet import run_guarded

    ap = argparse.ArgumentParser(prog="rsal")
    register(ap.add_subparsers(dest="command"))
    sys.exit(run_guarded(PROG, lambda: run_host(ap.parse_args(["host", *sys.argv[1:]]))))
