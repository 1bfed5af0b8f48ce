"""``rsal control``: the control center, a web page that starts scenarios and commands robots
(thesis 3.4.2 *requirements: a graphical interface*, 5.2.3 *User Interface*).

The thesis asked for one place from which an operator starts the scenarios of chapter 4.2, sees
which agents and devices are alive, and helps a robot that localization cannot place by putting it
on the map by hand (3.4.2); it drove robots with Playernav and watched them in the Stage window
(5.2.3). ``rsal control`` is that place: a small HTTP server on ``127.0.0.1`` serving one page
(vanilla HTML/JS/CSS from ``agents/control/static/``, no build step) and a JSON API the page polls
about twice a second.

One Zenoh session listens on the fabric's endpoint (a free loopback port, or ``--listen EP``; with
``--connect EP`` it joins a running fabric instead), and everything started from the page connects
to that endpoint:

- applications of the scenario files in ``--scenarios`` (default ``deploy/scenarios``), each as a
  child ``rsal run FILE --app NAME --set K=V ... --connect EP`` (:mod:`agents.run`), stopped with
  SIGINT and waited for;
- wall-following on a robot, a child ``rsal agent WallfollowAgent --robot R --connect EP``;
- the Rerun web view of the same fabric, a child ``rsal watch --serve`` (:mod:`rsal.watch`) started
  when the first device appears, its URL shown in a frame beside the controls.

Liveliness subscribers (with history) on ``agents/*`` and ``rsal/*/*/*`` keep the lists of alive
agents and devices. Per robot the page can set the initial pose of its localizer
(:meth:`rsal.devices.Localize.set_position`, at the clicked map point and the dragged heading),
send a goal to its planner (:meth:`rsal.devices.Planner.set_goal`), stop it (planner stop and a
zero velocity on ``position2d:0``) and start or stop wall-following. The map is the ``rpc/get``
grid of a ``map`` device, served as a PNG with its origin and resolution.

The Tasks panel lists the fleet dispatcher's tasks live and submits and cancels them with the
messages ``rsal task`` sends (:mod:`~agents.control.tasks`).

The package: :mod:`~agents.control.http` (the server), :mod:`~agents.control.api` (the JSON API and
its input checks), :mod:`~agents.control.console` (the robot console), :mod:`~agents.control.tasks`
(the Tasks panel) and this module (the
:class:`Control` that holds the state, its children and the command). The API
(``docs/control.md``) validates every input; a bad one is answered with HTTP 400 and
``{"error": "<one line>"}``, never a traceback. SIGINT or SIGTERM stop every child by its PID
(SIGINT, a deadline, SIGTERM, then SIGKILL: :class:`rsal.procs.Child`, the one supervisor of
``rsal run``, ``rsal control`` and ``rsal demo``) and exit 0.
"""

from __future__ import annotations

import argparse
import logging
import re
import signal
import sys
import threading
import time
from pathlib import Path

from rsal.procs import Child, python_env, stop_all
from rsal.transport import free_port

from .api import ApiError, Run, ScenarioApi, map_png
from .console import RobotConsole, RobotState
from .http import Handler, make_server
from .tasks import TasksApi

__all__ = ["ApiError", "Control", "Handler", "Run", "RobotState", "map_png", "register", "run_control"]

log = logging.getLogger(__name__)

PROG = "rsal control"
#: seconds a child gets after SIGINT before SIGTERM: a run stops its agent hosts, servers and simulator
STOP_DEADLINES = {"run": 45.0, "agent": 15.0, "watch": 10.0}
#: output lines kept per child
KEEP_LINES = 40
#: seconds a child gets after SIGTERM (when SIGINT was not enough) before SIGKILL
TERM_DEADLINE = 5.0
_WATCH_URL = re.compile(r"web viewer: (http://\S+)")


def _steps(kind: str) -> tuple[tuple[int, float], ...]:
    """How a child of ``kind`` is stopped: SIGINT and its deadline, SIGTERM, then SIGKILL."""
    return ((signal.SIGINT, STOP_DEADLINES[kind]), (signal.SIGTERM, TERM_DEADLINE))


def _killed(c: Child, waited: float) -> None:
    c.lines.append(f"[control] pid {c.pid} did not stop within {waited:g} s; killed")


# ---------------------------------------------------------------------------- the control center
class Control(ScenarioApi, RobotConsole, TasksApi):
    """State and actions behind the API; thread-safe (HTTP handler threads, Zenoh threads)."""

    def __init__(
        self,
        scenarios_dir: Path,
        endpoint: str,
        *,
        watch: bool = True,
        zenoh_flags: list[str] | None = None,
    ):
        self.scenarios_dir = scenarios_dir
        self.endpoint = endpoint
        self.watch_enabled = watch
        self.zenoh_flags = list(zenoh_flags or [])
        self._lock = threading.Lock()
        self.agents: set[str] = set()
        self.devices: set[str] = set()  # node:iface:idx
        self.runs: dict[int, Run] = {}
        self._next_run = 1
        self.robots: dict[str, RobotState] = {}
        self.watch: Child | None = None
        self.watch_url: str | None = None
        self._watch_tried = 0.0
        self._maps: dict[str, dict] = {}
        self._handles: list = []
        self.fabric = None
        self._stop = threading.Event()
        self._poller: threading.Thread | None = None
        self._init_tasks()

    # ------------------------------------------------------------------ fabric
    def open(self, targs) -> None:
        import zenoh

        from rsal.client import Fabric

        self.fabric = Fabric.connect(targs)
        s = self.fabric.session

        def on_agent(sample) -> None:
            name = str(sample.key_expr).split("/", 1)[1]
            if name == self.desk_id:
                return
            with self._lock:
                (self.agents.add if sample.kind == zenoh.SampleKind.PUT else self.agents.discard)(name)

        def on_device(sample) -> None:
            parts = str(sample.key_expr).split("/")
            if len(parts) != 4:
                return
            addr = ":".join(parts[1:])
            alive = sample.kind == zenoh.SampleKind.PUT
            with self._lock:
                (self.devices.add if alive else self.devices.discard)(addr)
                if parts[2] == "map":
                    self._maps.pop(addr, None)
                st = self.robots.get(parts[1])
                if not alive and parts[2:] == ["position2d", "0"] and st is not None:
                    st.pose, st.pose_source, st.goal, st.note = None, "", None, ""  # the robot left

        lv = s.liveliness()
        self._handles = [
            lv.declare_subscriber("agents/*", on_agent, history=True),
            lv.declare_subscriber("rsal/*/*/*", on_device, history=True),
        ]
        self._start_tasks(s)
        self._poller = threading.Thread(target=self._poll_loop, name="control-poller", daemon=True)
        self._poller.start()

    def close(self) -> None:
        """Stop every child (runs, wall-followers, the watch) by PID, then leave the fabric."""
        self._stop.set()
        if self._poller is not None:
            self._poller.join(5.0)  # it may be starting the watch: let it finish first
        with self._lock:
            runs = [r.child for r in self.runs.values()]
            walls = [st.wallfollow for st in self.robots.values() if st.wallfollow is not None]
            watch = self.watch
        stop_all(runs + walls, _steps("run"), _killed)  # together: a run stops its own children first
        if watch is not None:
            self._stop_child(watch, "watch")
        self._stop_tasks()
        for h in self._handles:
            try:
                h.undeclare()
            except Exception:
                pass
        if self.fabric is not None:
            self.fabric.close()

    # ------------------------------------------------------------------ children
    def _spawn(self, kind: str, name: str, args: list[str], on_line=None) -> Child:
        if self._stop.is_set():
            raise ApiError("the control center is stopping; nothing new is started", 503)
        argv = [sys.executable, "-m", "rsal.cli", *args, "--connect", self.endpoint, *self.zenoh_flags]
        shown = " ".join(["rsal", *args, "--connect", self.endpoint, *self.zenoh_flags])
        return Child(
            name, argv, kind=kind, shown=shown, env=python_env(), cwd=Path.cwd(), on_line=on_line, keep=KEEP_LINES
        )

    def _stop_child(self, c: Child, kind: str, *, background: bool = False) -> None:
        """Stop a child by its PID (SIGINT, its kind's deadline, SIGTERM, SIGKILL); ``background``:
        on a thread of its own, so a request does not wait for it."""
        c.stopping = True
        if background:
            threading.Thread(target=c.stop, args=(_steps(kind), _killed), daemon=True).start()
        else:
            c.stop(_steps(kind), _killed)

    def _maybe_start_watch(self) -> None:
        """Start ``rsal watch --serve`` once devices are alive (again if it ended, at most every 10 s)."""
        if not self.watch_enabled or self._stop.is_set():
            return
        with self._lock:
            if not self.devices or (self.watch is not None and self.watch.poll() is None):
                return
            if time.monotonic() - self._watch_tried < 10.0:
                return
            self._watch_tried = time.monotonic()
        web, grpc = free_port(), free_port()
        args = ["watch", "--serve", "--web-port", str(web), "--grpc-port", str(grpc), "--wait", "30"]

        def on_line(line: str) -> None:
            m = _WATCH_URL.search(line)
            if m:
                self.watch_url = m.group(1)

        self.watch_url = None
        child = self._spawn("watch", "watch", args, on_line)
        with self._lock:
            self.watch = child

    # ------------------------------------------------------------------ poller thread
    def _poll_loop(self) -> None:
        while not self._stop.wait(0.5):
            try:
                self._maybe_start_watch()
                self._poll_poses()
            except ApiError:  # stopping
                return
            except Exception:  # the poller must survive a bad reply
                log.exception("control poller")

    def _robot(self, name: str) -> RobotState:
        with self._lock:
            return self.robots.setdefault(name, RobotState())


# ---------------------------------------------------------------------------- command
def run_control(args: argparse.Namespace) -> int:
    from rsal.transport import TransportArgs

    def fail(text: str) -> int:
        print(f"{PROG}: {text}", file=sys.stderr, flush=True)
        return 1

    if not (0 <= args.port <= 65535):
        return fail(f"--port {args.port} must be 0..65535 (0: a free port)")
    scen = Path(args.scenarios)
    if not scen.is_dir():
        return fail(f"--scenarios {args.scenarios!r} is not a directory; give the folder of the scenario files")
    if args.connect:
        endpoint, targs = args.connect, TransportArgs(connect=[args.connect])
    else:
        endpoint = args.listen or f"tcp/127.0.0.1:{free_port()}"
        targs = TransportArgs(listen=[endpoint])
    flags: list[str] = []
    if args.config:
        flags += ["--config", args.config]
        targs.config = args.config
    for item in args.cfg or []:
        flags += ["--cfg", item]
        targs.cfg.append(item)
    control = Control(scen, endpoint, watch=not args.no_watch, zenoh_flags=flags)
    try:
        httpd = make_server(args.port, control)
    except OSError as e:
        return fail(f"cannot serve on 127.0.0.1:{args.port}: {e.strerror}; choose another --port")
    try:
        control.open(targs)
    except ValueError as e:
        httpd.server_close()
        return fail(f"{e} (check --listen/--connect)")
    got: list[str] = []

    def on_signal(signum, frame) -> None:
        if not got:
            got.append(signal.Signals(signum).name)
            threading.Thread(target=httpd.shutdown, daemon=True).start()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    port = httpd.server_address[1]
    print(f"[control] http://127.0.0.1:{port}/ (fabric {endpoint}, scenarios {scen})", flush=True)
    try:
        httpd.serve_forever(poll_interval=0.2)
    finally:
        print(f"[control] {got[0] if got else 'stopped'}: stopping every child", flush=True)
        control.close()
        httpd.server_close()
        for s, h in old.items():
            signal.signal(s, h)
    print("[control] stopped", flush=True)
    return 0


def register(sub) -> None:
    p = sub.add_parser("control", help="the control center web page: start scenarios, command robots, watch")
    p.add_argument("--port", type=int, default=8470, help="HTTP port on 127.0.0.1 (default 8470; 0: a free port)")
    p.add_argument(
        "--scenarios",
        default=str(Path("deploy") / "scenarios"),
        help="folder of scenario files (default deploy/scenarios)",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--listen", metavar="ENDPOINT", help="the fabric's endpoint (default: a free port tcp/127.0.0.1:PORT)"
    )
    where.add_argument("--connect", metavar="ENDPOINT", help="join a running fabric at ENDPOINT instead")
    p.add_argument("--config", metavar="FILE", help="a Zenoh JSON5 configuration for the control and its children")
    p.add_argument("--cfg", action="append", metavar="KEY:VALUE", help="a Zenoh configuration entry (repeatable)")
    p.add_argument("--no-watch", action="store_true", help="do not start 'rsal watch --serve' beside the page")
    p.set_defaults(func=run_control)
