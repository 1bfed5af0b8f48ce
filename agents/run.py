"""``rsal run SCENARIO --app NAME``: start an application of a scenario file and judge the run
(thesis fig. 3.11: Jadex application files; the scenarios of 4.2).

The runner starts, each as its own process under the one supervisor (:class:`rsal.procs.Child`: own
session, PIDs kept and printed, output relayed):

1. the simulator, ``rsal sim WORLD --listen EP`` (if the application has one), and waits until its
   ``sim:simulation:0`` device is alive;
2. the rehearsal of a "real" robot, ``rsal rehearse WORLD ROBOT --connect EP`` (if the application
   has a ``rehearse`` section: emulated hardware in "the real world", served by the real drivers,
   docs/hardware.md), and waits until the robot's base, laser (and planner) and the real world's
   simulation device are alive, since an agent builds its robot from the devices present;
3. the device servers, ``rsal serve CONFIG --connect EP``;
4. one agent host, ``python -m agents.hostproc SCENARIO --app NAME --host GROUP [--set ..]``, per host
   group of agents (:mod:`agents.hostproc`): it reads the same scenario file with the same
   overrides, so the scenario has one schema, :mod:`agents.scenario`. A group whose entries name a
   ``machine`` is launched on that machine's host daemon instead (``rsal host``, :mod:`agents.hostd`,
   through :class:`agents.remote.RemoteHost`, which the runner judges as a local child); the daemons
   named must be on the fabric before anything starts, and one that leaves mid-run loses its agents
   (the run fails unless ``--tolerate-lost``).

``EP`` is a free loopback port unless ``--listen EP`` or ``--connect EP`` (join a running fabric)
says otherwise. The runner's own Zenoh session subscribes ``svc/outcome/*`` and the agent tokens
``agents/*``; it counts outcomes only from the agents it launched (the application's agent ids): an
outcome from any other sender -- on an open fabric anyone can put one -- is ignored, and each such
sender is reported once (``docs/security.md``, "Open fabric"). It prints every outcome as it arrives and
a progress line every few seconds, and relays
its children's output with their name in front. The run ends with success (exit 0) when the end
condition holds — ``count`` distinct subjects of ok ``event`` outcomes, or ``duration`` seconds
(counted from the moment every agent is alive) without a failed outcome — or at once with the ``ok``
of an outcome marked ``final``. With a simulator every claim is checked against its ground truth
first (:mod:`agents.verdict`; a rehearsed robot's against the rehearsal's world, "the real world";
also with ``--connect`` to a fabric whose simulation device is alive): a catch, an arrival, a
delivery or a final verdict the true poses contradict counts as failed, and a duration run's
``travel``/``clearance`` come from sampled true poses. It fails (exit 1) on its timeout, a failed
final outcome, a claim of its end event that ground truth refuses (at once: the agents believe the
claim and stop, so the end can no longer come), or a child that exits unexpectedly (one line naming
it and its last stderr line). A bad scenario file or argument exits 2 with one line; SIGINT/SIGTERM
stop everything and exit 130.
Stopping sends SIGTERM to the agent hosts, then the servers, then the rehearsal, then the simulator,
each with a deadline, and SIGKILL by PID to whatever is left. The format and the lines printed are
described in ``docs/scenarios.md``.

(About 700 lines, over the 500 of the house rule: the runner's phases, end conditions and summary
are one state machine over one event queue; the processes themselves are :mod:`rsal.procs`'s and
the remote ones :mod:`agents.remote`'s.)
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from rsal.cliutil import brief, positive
from rsal.clock import ENV as clock_env
from rsal.clock import SimClock
from rsal.keys import host_key
from rsal.procs import Child, python_env, stop_all
from rsal.transport import free_port

from .hostwire import SUFFIXES, LaunchRequest
from .remote import LOST, RemoteError, RemoteHost, daemon_alive
from .scenario import Application, Scenario, ScenarioError, check_classes, load_scenario, parse_set
from .verdict import SAMPLE_PERIOD, GroundTruth

__all__ = ["register", "run_scenario"]

PROG = "rsal run"
SIM_NODE = "sim"  # the node of the simulator that rsal sim serves
SIM_DEVICE = f"rsal/{SIM_NODE}/simulation/0"
#: seconds each kind of child gets to exit after SIGTERM before SIGKILL: more than the 10 s a
#: session's close may wait for a link to a cut host (docs/deployment.md, "Leases and cut links")
STOP_DEADLINES = {"host": 15.0, "server": 15.0, "rehearse": 15.0, "sim": 15.0}
#: what each kind of child is called in a failure line
CHILD_KINDS = {"sim": "the simulator", "rehearse": "the rehearsal", "server": "device server", "host": "agent host"}


def _err(text: str) -> None:
    print(f"{PROG}: {text}", file=sys.stderr, flush=True)


class _Out:
    """Whole lines on stdout from several threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()

    def line(self, text: str) -> None:
        with self._lock:
            print(text, flush=True)

    def say(self, text: str) -> None:
        self.line(f"[run] {text}")


@dataclass
class _Tally:
    """What the outcomes said so far."""

    subjects: dict[str, dict[str, str]] = field(default_factory=dict)  # event -> subject -> first text
    failed: list[str] = field(default_factory=list)
    refused: str | None = None  # the first claim of the end event that ground truth refused
    messages: collections.Counter = field(default_factory=collections.Counter)
    final: tuple[bool, str] | None = None


class Runner:
    def __init__(self, sc: Scenario, app: Application, args: argparse.Namespace, out: _Out):
        self.sc = sc
        self.app = app
        self.args = args
        self.out = out
        self.end = app.end
        self.timeout = args.timeout or app.end.timeout
        self.progress = args.progress
        self.events: queue.SimpleQueue = queue.SimpleQueue()
        self.children: list[Child] = []
        self.tally = _Tally()
        self.expected = [a.id for a in app.agents]
        self.own = frozenset(self.expected)  # the only senders whose outcomes count
        self.strangers: set[str] = set()  # other senders of outcomes, reported once each
        self.alive: set[str] = set()
        self.ever_alive: set[str] = set()
        self.lost: set[str] = set()  # agents of a machine that left the fabric mid-run
        self.devices: set[str] = set()
        self.signalled: list[str] = []
        self.result: tuple[bool, str] | None = None
        self.all_alive_at: float | None = None
        self.phase = "start"
        self.session = None
        self._handles: list = []
        # with a simulator, outcomes are checked against its ground truth (agents.verdict)
        self.truth: GroundTruth | None = None
        self._next_sample = 0.0
        # The run's clock: wall seconds until the simulation's clock runs, then simulated seconds,
        # so durations and timeouts mean the same at any speed-up (see _now).
        self.sim_clock: SimClock | None = None
        self._sim_base: tuple[float, float] | None = None
        # Zenoh settings every process of the run gets: a --config file (e.g. the secured profile's
        # fleet.json5, which names the endpoints itself) and --cfg entries (e.g. a shorter lease).
        self.zenoh_flags: list[str] = ["--config", args.config] if getattr(args, "config", None) else []
        cfg_flags = [f for item in getattr(args, "cfg", None) or [] for f in ("--cfg", item)]
        self.zenoh_flags += cfg_flags
        # the agent hosts' own identity in the secured profile (the runner itself is the operator)
        agents_config = getattr(args, "agents_config", None)
        self.agent_flags = ["--config", agents_config, *cfg_flags] if agents_config else self.zenoh_flags
        if args.connect:
            self.endpoint, self.sim_flag = args.connect, "--connect"
        elif getattr(args, "config", None) and not args.listen:
            self.endpoint, self.sim_flag = None, ""  # the config file says where the fabric is
        else:
            self.endpoint = args.listen or f"tcp/127.0.0.1:{free_port()}"
            self.sim_flag = "--listen"

    # ------------------------------------------------------------------ fabric
    def _open(self) -> None:
        import zenoh

        from rsal.transport import TransportArgs, open_session

        from .services import decode_message

        if self.endpoint is None:
            targs = TransportArgs()
        elif self.args.connect or self.app.simulator is not None:
            targs = TransportArgs(connect=[self.endpoint])
        else:  # nobody else listens: the runner is the fabric's meeting point
            targs = TransportArgs(listen=[self.endpoint])
        targs.config = getattr(self.args, "config", None)
        targs.cfg = list(getattr(self.args, "cfg", None) or [])
        self.session = open_session(targs)
        if self.app.simulator is not None and self.app.rehearse is None:  # a rehearsal: the wall clock
            self.sim_clock = SimClock().follow(self.session, SIM_NODE)
        if self.app.simulator is not None or self.app.rehearse is not None:
            self.truth = GroundTruth(self.session, self.sc, self.app)
        q = self.events

        def on_outcome(sample) -> None:
            sender = str(sample.key_expr).rsplit("/", 1)[-1]
            try:
                msg = decode_message("outcome", sender, sample.payload.to_bytes())
            except Exception as e:  # a malformed sample: reported, never counted
                q.put(("bad", sender, str(e)))
                return
            q.put(("outcome", sender, msg.body))

        def on_agent(sample) -> None:
            q.put(("agent", str(sample.key_expr).split("/", 1)[1], sample.kind == zenoh.SampleKind.PUT))

        def on_device(sample) -> None:
            q.put(("device", str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT))

        lv = self.session.liveliness()
        self._handles = [
            self.session.declare_subscriber("svc/outcome/*", on_outcome),
            lv.declare_subscriber("agents/*", on_agent, history=True),
            lv.declare_subscriber("rsal/*/*/*", on_device, history=True),
        ]
        if self.app.machines():  # host daemons whose token goes mid-run lose their agents

            def on_machine(sample) -> None:
                q.put(("machine", str(sample.key_expr).split("/", 1)[1], sample.kind == zenoh.SampleKind.PUT))

            self._handles.append(lv.declare_subscriber(host_key("*"), on_machine))

    def _close(self) -> None:
        if self.truth is not None:
            self.truth.close()
        for h in self._handles:
            try:
                h.undeclare()
            except Exception:
                pass
        if self.session is not None:
            try:
                self.session.close()
            except Exception:
                pass

    # ------------------------------------------------------------------ children
    def _start(self, name: str, kind: str, argv: list[str], shown: str) -> Child:
        env = python_env(self.sc.source.parent.resolve())
        if kind == "host" and self.app.simulator is not None and self.app.rehearse is None:
            env[clock_env] = SIM_NODE  # the agents follow the simulation's clock (rsal.clock)
        # With a rehearsal they keep the wall clock, as agents of real robots do: the real world runs
        # in real time, whatever pace a loaded virtual simulator manages (a real robot's broadcasts
        # on the virtual clock fall behind the robot, and so does its proxy).
        c = Child(name, argv, kind=kind, shown=shown, env=env, forward=self.out.line, stderr_apart=True)
        self.children.append(c)
        self.out.say(f"started {name} (pid {c.pid}): {shown}")
        return c

    def _start_sim(self) -> None:
        s = self.app.simulator
        flags = ([self.sim_flag, self.endpoint] if self.endpoint else []) + self.zenoh_flags
        if s.nav:
            flags += ["--nav", s.nav]
        if s.nav_robots:
            flags += ["--nav-robots", ",".join(s.nav_robots)]
        if s.nav_servers:
            flags += ["--nav-servers", str(s.nav_servers)]
        speedup = getattr(self.args, "speedup", None) or s.speedup
        if speedup is not None:
            flags += ["--speedup", f"{speedup:g}"]
        if s.seed is not None:
            flags += ["--seed", str(s.seed)]
        if s.threads is not None:
            flags += ["--threads", str(s.threads)]
        argv = [sys.executable, "-m", "rsal.cli", "sim", str(s.world), *flags]
        self._start("sim", "sim", argv, " ".join(["rsal sim", _rel(s.world), *flags]))

    def _start_rehearsal(self) -> None:
        r = self.app.rehearse
        flags = self._member_flags()  # it joins the fabric (the simulator or the runner listens)
        for key in ("nav", "pioneer", "laser", "seed"):
            if getattr(r, key) is not None:
                flags += [f"--{key}", str(getattr(r, key))]
        flags += ["--node", r.node]
        argv = [sys.executable, "-m", "rsal.cli", "rehearse", str(r.world), r.robot, *flags]
        self._start("rehearse", "rehearse", argv, " ".join(["rsal rehearse", _rel(r.world), r.robot, *flags]))

    def _rehearsed(self) -> bool:
        """Whether every device the rehearsed robot is awaited by is alive."""
        return all(f"rsal/{d}" in self.devices for d in self.app.rehearse.devices)

    def _start_nav_servers(self) -> None:
        """The simulator's ``nav_servers``: ``rsal sim WORLD --nav .. --nav-part I/N`` each, servers
        that require the robots' devices over the fabric (stopped with the other servers)."""
        s = self.app.simulator
        for i in range(s.nav_servers if s is not None else 0):
            flags = ["--nav", s.nav] + (["--nav-robots", ",".join(s.nav_robots)] if s.nav_robots else [])
            if s.seed is not None:
                flags += ["--seed", str(s.seed)]
            flags += ["--nav-part", f"{i}/{s.nav_servers}", *self._member_flags()]
            argv = [sys.executable, "-m", "rsal.cli", "sim", str(s.world), *flags]
            self._start(f"nav{i}", "server", argv, " ".join(["rsal sim", _rel(s.world), *flags]))

    def _start_rest(self) -> None:
        if self.truth is not None:
            self.truth.record_homes()  # where the collectors truly start, before they move
        self._start_nav_servers()
        for i, cfg in enumerate(self.app.servers):
            name = "serve" if len(self.app.servers) == 1 else f"serve{i}"
            flags = self._member_flags()
            argv = [sys.executable, "-m", "rsal.cli", "serve", str(cfg), *flags]
            self._start(name, "server", argv, " ".join(["rsal serve", _rel(cfg), *flags]))
        machines = self.app.machines()
        for group, entries in self.app.groups().items():
            if group in machines:
                self._launch_remote(group, machines[group], entries)
                if self.result is not None:
                    return
                continue
            # the host reads the scenario this run parsed, with the same overrides (no second schema)
            argv = [sys.executable, "-m", "agents.hostproc", str(self.sc.source.resolve()), "--app", self.app.name]
            argv += ["--host", group, "--report-every", f"{self.args.host_report:g}"]
            for item in self.args.set or []:
                argv += ["--set", item]
            argv += ["-v"] * min(int(getattr(self.args, "verbose", 0) or 0), 2)  # -v: a line per agent
            argv += self._member_flags(self.agent_flags)
            ids = brief(a.id for a in entries)
            self._start(group, "host", argv, f"agent host with {len(entries)} agent(s): {ids}")

    def _check_machines(self) -> None:
        """Before anything starts: every machine the application names has its host daemon on the
        fabric (else ``self.result`` is the one line naming it and the fix)."""
        machines = self.app.machines()
        for m in dict.fromkeys(machines.values()):
            if not daemon_alive(self.session, m):
                groups = ", ".join(g for g, mm in machines.items() if mm == m)
                self.result = (
                    False,
                    f"machine {m!r} (host group {groups}): no host daemon {host_key(m)} on the fabric; "
                    f"start 'rsal host --name {m}' there (docs/deployment.md) or remove its 'machine'",
                )
                return

    def _launch_remote(self, group: str, machine: str, entries) -> None:
        """Launch host group ``group`` on host daemon ``machine`` (:mod:`agents.remote`): it gets the
        scenario's text, the application, the group and the overrides."""
        import uuid

        req = LaunchRequest(
            run=uuid.uuid4().hex[:12],
            app=self.app.name,
            group=group,
            scenario=self.sc.source.read_text(),
            suffix=self.sc.source.suffix if self.sc.source.suffix in SUFFIXES else ".yaml",
            overrides=tuple(self.args.set or []),
            report_every=self.args.host_report,
            sim_clock=SIM_NODE if self.app.simulator is not None else "",
        )
        rh = RemoteHost(self.session, machine, req, self.events)
        try:
            rh.launch()
        except RemoteError as e:
            self.result = (False, str(e))
            return
        self.children.append(rh)  # type: ignore[arg-type]
        ids = ", ".join(a.id for a in entries)
        self.out.say(
            f"launched {group} on machine {machine} (run {req.run}, pid {rh.pid}): {len(entries)} agent(s): {ids}"
        )

    def _member_flags(self, zenoh_flags: list[str] | None = None) -> list[str]:
        """Transport flags of the servers and agent hosts: they join the fabric's endpoint."""
        return (["--connect", self.endpoint] if self.endpoint else []) + (zenoh_flags or self.zenoh_flags)

    def _stop_children(self) -> None:
        """SIGTERM to the agent hosts, then the servers, then the simulator, each group with its
        deadline, and SIGKILL by PID to whatever is left (:func:`rsal.procs.stop_all`)."""

        def killed(c: Child, waited: float) -> None:
            self.out.say(f"{c.name} (pid {c.pid}) did not stop within {waited:g} s; killed")

        remote = [c for c in self.children if isinstance(c, RemoteHost)]
        stoppers = [threading.Thread(target=c.stop, args=(STOP_DEADLINES["host"],)) for c in remote if c.alive()]
        for t in stoppers:
            t.start()
        for t in stoppers:
            t.join()
        for c in remote:
            if c.alive():
                self.out.say(
                    f"{c.name} on machine {c.machine} did not report its end within {STOP_DEADLINES['host']:g} s"
                )
            c.close()
        while True:  # their last lines (the run's result and tally are settled: nothing else counts now)
            try:
                item = self.events.get_nowait()
            except queue.Empty:
                break
            if item[0] == "line":
                self.out.line(item[2])
        for kind in ("host", "server", "rehearse", "sim"):
            group = [c for c in self.children if c.kind == kind and c.poll() is None and not isinstance(c, RemoteHost)]
            stop_all(group, [(signal.SIGTERM, STOP_DEADLINES[kind])], killed)
        for c in self.children:
            c.drained()

    # ------------------------------------------------------------------ events
    def _drain(self, wait: float) -> None:
        try:
            item = self.events.get(timeout=wait)
        except queue.Empty:
            return
        while True:
            self._handle(item)
            try:
                item = self.events.get_nowait()
            except queue.Empty:
                return

    def _handle(self, item) -> None:
        kind, who, what = item
        if kind == "outcome" and who not in self.own:
            if who not in self.strangers:
                self.strangers.add(who)
                self.out.say(f"ignored an outcome from {who}, no agent of this application: {what.text!r}")
            return
        if kind == "outcome":
            t = self.tally
            t.messages[what.event] += 1
            if self.truth is None and SIM_DEVICE in self.devices:  # joined a fabric with a simulation
                self.truth = GroundTruth(self.session, self.sc, self.app)
            false = self.truth.check(who, what) if self.truth is not None else None
            mark = "" if what.ok else " (failed)"
            if false:  # a claim the simulator contradicts counts as a failure, with the truth's reason
                mark = f" (not confirmed: {false})"
            self.out.say(f"outcome from {who}: {what.text}{mark}")
            if self.truth is not None and self.truth.note:
                self.out.say(self.truth.note)
            if false:
                what = dataclasses.replace(what, text=f"{what.text} -- {false}", ok=False)
                if what.event == self.end.event and t.refused is None:
                    t.refused = what.text
            if what.final:
                if t.final is None:
                    t.final = (what.ok, what.text)
            elif not what.ok:
                t.failed.append(what.text)
            else:
                t.subjects.setdefault(what.event, {}).setdefault(what.subject, what.text)
        elif kind == "bad":
            self.out.say(f"dropped a malformed outcome from {who}: {what}")
        elif kind == "agent":
            if what:
                if who not in self.alive and len(self.expected) <= 10:
                    self.out.say(f"agent {who} is up")
                self.alive.add(who)
                self.ever_alive.add(who)
            elif who in self.alive:
                self.alive.discard(who)
                if self.result is None:
                    self.out.say(f"agent {who} left")
        elif kind == "device":
            (self.devices.add if what else self.devices.discard)(who)
        elif kind == "line":
            self.out.line(what)
        elif kind == "machine" and not what:
            for c in self.children:
                if isinstance(c, RemoteHost) and c.machine == who:
                    c.lost()

    def _next_phase(self) -> None:
        """After the simulator (if any): the rehearsal, if any, else the servers and agents."""
        if self.app.rehearse is not None:
            self._start_rehearsal()
            self.phase = "rehearse"
        else:
            self._start_rest()
            self.phase = "run"

    def _now(self) -> float:
        """Seconds of the run: the wall clock until the simulation's clock has started, then that
        moment plus simulated seconds (a paused simulation pauses durations and timeouts)."""
        w = time.monotonic()
        c = self.sim_clock
        if c is None or not c.started:
            return w
        if self._sim_base is None:
            self._sim_base = (w, c.now())
        return self._sim_base[0] + (c.now() - self._sim_base[1])

    def _count_text(self) -> str:
        e = self.end
        if e.event is not None:
            return f"{e.event} {len(self.tally.subjects.get(e.event, {}))}/{e.count}"
        if self.all_alive_at is None:
            return f"0.0/{e.duration:g} s"
        return f"{min(e.duration, self._now() - self.all_alive_at):.1f}/{e.duration:g} s"

    def _check(self, now: float, t0: float) -> None:
        """Set ``self.result`` when the run is over."""
        for c in self.children:
            rc = c.poll()
            if rc is None or c.reported:
                continue
            c.reported = True
            c.drained()
            if c.kind == "host" and rc == 0:
                self.out.say(f"agent host {c.name} exited: its agents ended")
                continue
            if rc == LOST and isinstance(c, RemoteHost):
                ids = [a.id for a in self.app.groups()[c.name]]
                self.lost.update(ids)
                self.out.say(
                    f"machine {c.machine} lost mid-run: agents {', '.join(ids)} of host group {c.name} are lost"
                )
                if getattr(self.args, "tolerate_lost", False):
                    continue
            what = CHILD_KINDS[c.kind]
            name = "" if c.kind in ("sim", "rehearse") else f" {c.name!r}"
            self.result = (False, f"{what}{name} (pid {c.pid}) {c.exit_reason()}")
            return
        t = self.tally
        if t.final is not None:
            self.result = t.final
            return
        if self.phase == "run":
            if self.all_alive_at is None and all(a in self.ever_alive for a in self.expected):
                self.all_alive_at = now
                self.out.say(f"all {len(self.expected)} agent(s) alive after {now - t0:.1f} s")
            e = self.end
            if e.event is not None and t.refused is not None:
                # the agents believe the claim (hunters stop chasing a prey claimed caught): the run
                # cannot reach its end any more, so it fails now rather than at its timeout
                self.result = (False, f"a {e.event} claim that ground truth refuses: {t.refused}")
                return
            if e.event is not None:
                got = t.subjects.get(e.event, {})
                if len(got) >= e.count:
                    truth = self._truth_problems()
                    if truth:
                        self.result = (False, f"ground truth: {'; '.join(truth)}")
                    else:
                        seen = f" (ground truth: {self.truth.summary()})" if self.truth and self.truth.samples else ""
                        self.result = (True, "; ".join(list(got.values())[: e.count]) + seen)
                    return
            elif self.all_alive_at is not None and now - self.all_alive_at >= e.duration:
                truth = self._truth_problems()
                if t.failed:
                    self.result = (False, f"{len(t.failed)} failed outcome(s): {t.failed[0]}")
                elif truth:
                    self.result = (False, f"ground truth: {'; '.join(truth)}")
                else:
                    seen = f" (ground truth: {self.truth.summary()})" if self.truth and self.truth.samples else ""
                    self.result = (True, f"ran {e.duration:g} s with every agent started and no failed outcome{seen}")
                return
        if now - t0 >= self.timeout:
            if self.phase == "sim":
                why = f"the simulator's devices did not appear within {self.timeout:g} s"
            elif self.phase == "rehearse":
                missing = [d for d in self.app.rehearse.devices if f"rsal/{d}" not in self.devices]
                why = f"the rehearsed robot's devices did not appear within {self.timeout:g} s: {', '.join(missing)}"
            else:
                up = len([a for a in self.expected if a in self.ever_alive])
                why = f"timeout after {self.timeout:g} s ({self._count_text()}, {up}/{len(self.expected)} agents up)"
            self.result = (False, why)

    def _sample_truth(self, now: float) -> None:
        """True poses for ``end.travel``/``end.clearance`` and the batteries for ``end.never_flat`` /
        ``end.charged``, every SAMPLE_PERIOD s once all agents live; a robot run flat ends the run."""
        if self.truth is None or not self.truth.samples or self.all_alive_at is None or now < self._next_sample:
            return
        self._next_sample = now + SAMPLE_PERIOD
        try:
            self.truth.sample()
        except Exception as e:  # counted as a problem at the end if it leaves no samples
            self.out.say(f"ground truth sample failed: {type(e).__name__}: {e}")
            return
        flat = self.truth.flat_robots() if self.end.never_flat else []
        if flat and self.result is None:  # the battery record says so: no need to wait for the end
            self.result = (False, f"ground truth: {'; '.join(flat)}")

    def _truth_problems(self) -> list[str]:
        if self.truth is None or not self.truth.samples:
            return []
        self._next_sample = 0.0
        self._sample_truth(self._now())  # the last pose, at the end
        return self.truth.problems()

    # ------------------------------------------------------------------ main
    def _loop(self, t0: float) -> None:
        """Until the run is over or a signal came: events, phases, end checks, progress lines."""
        next_progress = t0 + self.progress
        while self.result is None and not self.signalled:
            self._drain(0.1)
            now = self._now()
            if self.phase == "sim" and SIM_DEVICE in self.devices:
                self.out.say(f"simulator up after {now - t0:.1f} s: {len(self.devices)} device(s)")
                self._next_phase()
            if self.phase == "rehearse" and self._rehearsed():
                self.out.say(f"rehearsed robot {self.app.rehearse.robot} up after {now - t0:.1f} s")
                self._start_rest()
                self.phase = "run"
            self._sample_truth(now)
            self._check(now, t0)
            if self.result is None and now >= next_progress:
                next_progress = now + self.progress
                if self.phase == "sim":
                    self.out.say(f"t={now - t0:.1f} s waiting for the simulator's devices")
                elif self.phase == "rehearse":
                    self.out.say(f"t={now - t0:.1f} s waiting for the rehearsed robot {self.app.rehearse.robot}")
                else:
                    n = len([a for a in self.expected if a in self.alive])
                    self.out.say(f"t={now - t0:.1f} s agents {n}/{len(self.expected)} alive, {self._count_text()}")

    def run(self) -> int:
        def on_signal(signum, frame) -> None:
            self.signalled.append(signal.Signals(signum).name)

        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        t0 = self._now()
        wall0 = time.monotonic()
        desc = f" ({self.app.description})" if self.app.description else ""
        where = self.endpoint or f"as configured in {self.args.config}"
        self.out.say(f"scenario {self.sc.name}, application {self.app.name}{desc}; fabric {where}")
        interrupted = ""
        try:
            try:
                self._open()
            except ValueError as e:
                _err(str(e))
                return 1
            self._check_machines()
            if self.result is not None:
                pass
            elif self.app.simulator is not None:
                self.phase = "sim"
                self._start_sim()
            else:
                self._next_phase()
            self._loop(t0)
            if self.signalled:
                interrupted = self.signalled[0]
                self.out.say(f"{interrupted}: stopping")
            elif not self.result[0]:
                _err(self.result[1])
            self._stop_children()
        finally:
            self._stop_children()  # also after an unexpected error: no child outlives the run
            self._close()
            for s, h in old.items():
                signal.signal(s, h)
        elapsed = self._now() - t0
        wall = time.monotonic() - wall0
        if interrupted:
            result = f"interrupted ({interrupted})"
            code = 130
        else:
            ok, text = self.result
            result = f"{'ok' if ok else 'FAILED'} — {text}"
            code = 0 if ok else 1
        self.out.say(f"result: {result}")
        counts = ", ".join(
            f"{ev} {len(self.tally.subjects.get(ev, {}))} ({n} message(s))"
            for ev, n in sorted(self.tally.messages.items())
        )
        self.out.say(
            f"elapsed {elapsed:.1f} s; agents started {len(self.ever_alive & set(self.expected))}/"
            f"{len(self.expected)}; outcomes: {counts or 'none'}"
            + (f"; failed outcomes {len(self.tally.failed)}" if self.tally.failed else "")
            + (f"; agents lost {len(self.lost)}" if self.lost else "")
            + (f"; times on the simulation's clock ({wall:.1f} s of wall time)" if self._sim_base is not None else "")
        )
        return code


def _rel(p: Path) -> str:
    try:
        return str(p.relative_to(Path.cwd()))
    except ValueError:
        return str(p)


def _list(sc: Scenario) -> None:
    print(f"scenario {sc.name}: {sc.description}".rstrip(": "))
    print("applications:")
    w = max(len(n) for n in sc.applications)
    for name, app in sc.applications.items():
        print(f"  {name.ljust(w)}  {app.description}".rstrip())


def run_scenario(args: argparse.Namespace) -> int:
    try:
        sc = load_scenario(args.scenario, parse_set(args.set or []))
    except ScenarioError as e:
        _err(str(e))
        return 2
    if args.list:
        _list(sc)
        return 0
    if args.app is None and len(sc.applications) > 1:
        _list(sc)
        _err(f"{args.scenario}: choose an application with --app ({', '.join(sc.applications)})")
        return 2
    name = args.app or next(iter(sc.applications))
    app = sc.applications.get(name)
    if app is None:
        _list(sc)
        _err(f"{args.scenario}: no application {name!r}; use one of {', '.join(sc.applications)}")
        return 2
    for p in (str(sc.source.parent.resolve()), os.getcwd()):  # module:Class names next to the scenario
        if p not in sys.path:
            sys.path.insert(0, p)
    try:
        check_classes(sc, app)
    except ScenarioError as e:
        _err(str(e))
        return 2
    if app.rehearse is not None and getattr(args, "speedup", None) not in (None, 1.0):
        _err(f"--speedup {args.speedup:g}: application {name!r} rehearses a real robot, which runs in real time")
        return 2
    machines = app.machines()
    if machines and not (args.connect or args.listen or getattr(args, "config", None)):
        m = next(iter(machines.values()))
        _err(
            f"{args.scenario}: application {app.name!r} places agents on machine {m!r}, whose host daemon joins a "
            "running fabric: give --connect EP (e.g. a router's, rsal router --listen EP) or --config FILE"
        )
        return 2
    agents_config = getattr(args, "agents_config", None)
    if agents_config and not os.path.isfile(agents_config):
        _err(
            f"--agents-config {agents_config}: no such file (give an agent host's member file, rsal secure add-agents)"
        )
        return 2
    return Runner(sc, app, args, _Out()).run()


def register(sub) -> None:
    p = sub.add_parser("run", help="start an application of a scenario file and judge the run")
    p.add_argument(
        "scenario", metavar="SCENARIO", help="scenario file (YAML or TOML), e.g. deploy/scenarios/wander.yaml"
    )
    p.add_argument("--app", help="the application to start (default: the only one; --list shows them)")
    p.add_argument("--list", action="store_true", help="list the scenario's applications and exit")
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a global argument (repeatable; VALUE is YAML: 2, 1.5, true, r0)",
    )
    p.add_argument(
        "--speedup",
        type=positive,
        help="run the simulator this many times faster than real time (overrides the scenario's speedup); "
        "agents, durations and timeouts follow the simulation's clock, so the run means the same",
    )
    p.add_argument("--timeout", type=positive, help="seconds after which the run fails (default: the end's timeout)")
    p.add_argument("--progress", type=positive, default=5.0, help="seconds between progress lines (default 5)")
    p.add_argument(
        "--host-report",
        type=positive,
        default=30.0,
        help="seconds between the agent hosts' own progress lines (default 30)",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument("--connect", metavar="ENDPOINT", help="join a running fabric at ENDPOINT")
    where.add_argument(
        "--listen", metavar="ENDPOINT", help="the fabric's endpoint (default: a free port tcp/127.0.0.1:PORT)"
    )
    p.add_argument(
        "--tolerate-lost",
        action="store_true",
        help="a machine (host daemon) that leaves mid-run loses its agents but does not fail the run",
    )
    p.add_argument("--config", metavar="FILE", help="a Zenoh JSON5 configuration for every process of the run")
    p.add_argument(
        "--agents-config",
        metavar="FILE",
        help="the agent hosts' own Zenoh configuration (default: --config); in a secured fleet the runner "
        "runs as an operator and its agents as their agent host's identity (docs/security.md)",
    )
    p.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="a Zenoh configuration entry for every process, e.g. --cfg 'transport/link/tx/lease:3000'",
    )
    p.set_defaults(func=run_scenario)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="rsal")
    register(ap.add_subparsers(dest="command"))
    args = ap.parse_args(["run", *(argv if argv is not None else sys.argv[1:])])
    return run_scenario(args)


if __name__ == "__main__":
    from rsal.errnet import run_guarded

    sys.exit(run_guarded("rsal run", main))
