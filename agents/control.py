"""``rsal control``: the control center, a web page that starts scenarios and commands robots
(thesis 3.4.2 *requirements: a graphical interface*, 5.2.3 *User Interface*).

The thesis asked for one place from which an operator starts the scenarios of chapter 4.2, sees
which agents and devices are alive, and helps a robot that localization cannot place by putting it
on the map by hand (3.4.2); it drove robots with Playernav and watched them in the Stage window
(5.2.3). ``rsal control`` is that place: a small HTTP server on ``127.0.0.1`` serving one page
(vanilla HTML/JS/CSS from ``agents/control_static/``, no build step) and a JSON API the page polls
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

The API (``docs/control.md``) validates every input; a bad one is answered with HTTP 400 and
``{"error": "<one line>"}``, never a traceback. SIGINT or SIGTERM stop every child by its PID
(SIGINT, a deadline, SIGTERM, then SIGKILL: :class:`rsal.procs.Child`, the one supervisor of
``rsal run``, ``rsal control`` and ``rsal demo``) and exit 0.
"""

from __future__ import annotations

import argparse
import io
import json
import logging
import math
import os
import re
import signal
import socket
import sys
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from rsal.errors import RsalError
from rsal.procs import Child, stop_all

__all__ = ["ApiError", "Control", "map_png", "register", "run_control"]

log = logging.getLogger(__name__)

PROG = "rsal control"
REPO_ROOT = Path(__file__).resolve().parent.parent
STATIC = Path(__file__).resolve().parent / "control_static"
STATIC_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css"}
#: seconds a child gets after SIGINT before SIGKILL: a run stops its agent hosts, servers and simulator
STOP_DEADLINES = {"run": 45.0, "agent": 15.0, "watch": 10.0}
#: output lines kept per child
KEEP_LINES = 40
#: seconds a child gets after SIGTERM (when SIGINT was not enough) before SIGKILL
TERM_DEADLINE = 5.0
_NAME = re.compile(r"^[A-Za-z0-9_\-.]+$")
_WATCH_URL = re.compile(r"web viewer: (http://\S+)")
MAX_BODY = 64 * 1024


class ApiError(RsalError, ValueError):
    """A request the API refuses: HTTP ``status`` with a one-line message."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _steps(kind: str) -> tuple[tuple[int, float], ...]:
    """How a child of ``kind`` is stopped: SIGINT and its deadline, SIGTERM, then SIGKILL."""
    return ((signal.SIGINT, STOP_DEADLINES[kind]), (signal.SIGTERM, TERM_DEADLINE))


def _killed(c: Child, waited: float) -> None:
    c.lines.append(f"[control] pid {c.pid} did not stop within {waited:g} s; killed")


def map_png(cells: np.ndarray) -> bytes:
    """A Player grid (int8 rows from the bottom, -1 free, 0 unknown, +1 occupied) as a grey PNG
    with the top row first: free white, unknown grey, occupied black."""
    from PIL import Image

    lut = np.array([255, 200, 0], dtype=np.uint8)
    img = lut[np.clip(np.asarray(cells, dtype=np.int16), -1, 1) + 1][::-1]
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img)).save(buf, format="PNG")
    return buf.getvalue()


@dataclass
class Run:
    id: int
    scenario: str
    app: str
    set: dict[str, str]
    child: Child
    agents: list[str]

    def info(self) -> dict:
        i = self.child.info()
        result = next((ln for ln in reversed(i["lines"]) if "[run] result:" in ln), "")
        return {
            "id": self.id,
            "scenario": self.scenario,
            "app": self.app,
            "set": self.set,
            "agents": self.agents,
            "result": result.split("result:", 1)[-1].strip() if result else "",
            **i,
        }


@dataclass
class RobotState:
    pose: list[float] | None = None  # x, y, yaw (rad) in the map frame
    pose_source: str = ""
    goal: dict | None = None
    note: str = ""
    wallfollow: Child | None = None
    pending: set[str] = field(default_factory=set)


# ---------------------------------------------------------------------------- the control center
class Control:
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

    # ------------------------------------------------------------------ fabric
    def open(self, targs) -> None:
        import zenoh

        from rsal.client import Fabric

        self.fabric = Fabric.connect(targs)
        s = self.fabric.session

        def on_agent(sample) -> None:
            name = str(sample.key_expr).split("/", 1)[1]
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
            watch.stop(_steps("watch"), _killed)
        for h in self._handles:
            try:
                h.undeclare()
            except Exception:
                pass
        if self.fabric is not None:
            self.fabric.close()

    # ------------------------------------------------------------------ children
    def _env(self) -> dict:
        env = dict(os.environ)
        paths = [os.getcwd(), str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])
        env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
        env["PYTHONUNBUFFERED"] = "1"
        return env

    def _spawn(self, kind: str, name: str, args: list[str], on_line=None) -> Child:
        if self._stop.is_set():
            raise ApiError("the control center is stopping; nothing new is started", 503)
        argv = [sys.executable, "-m", "rsal.cli", *args, "--connect", self.endpoint, *self.zenoh_flags]
        shown = " ".join(["rsal", *args, "--connect", self.endpoint, *self.zenoh_flags])
        return Child(
            name, argv, kind=kind, shown=shown, env=self._env(), cwd=Path.cwd(), on_line=on_line, keep=KEEP_LINES
        )

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
        web, grpc = _free_port(), _free_port()
        args = ["watch", "--serve", "--web-port", str(web), "--grpc-port", str(grpc), "--wait", "30"]

        def on_line(line: str) -> None:
            m = _WATCH_URL.search(line)
            if m:
                self.watch_url = m.group(1)

        self.watch_url = None
        child = self._spawn("watch", "watch", args, on_line)
        with self._lock:
            self.watch = child

    # ------------------------------------------------------------------ robot poses (poller thread)
    def _poll_loop(self) -> None:
        while not self._stop.wait(0.5):
            try:
                self._maybe_start_watch()
                self._poll_poses()
            except ApiError:  # stopping
                return
            except Exception:  # the poller must survive a bad reply
                log.exception("control poller")

    def _poll_poses(self) -> None:
        with self._lock:
            devices = set(self.devices)
        robots = sorted({d.split(":")[0] for d in devices if d.split(":")[1] == "position2d"} - {"sim"})
        sim = "sim:simulation:0" in devices
        for r in robots:
            st = self._robot(r)
            loc = f"{r}:localize:0"
            if loc in devices:
                p = self.fabric.device(loc).position
                if p is not None:
                    st.pose, st.pose_source = [p.x, p.y, p.yaw], "localize"
                    continue
            if sim and "truth" not in st.pending:
                st.pending.add("truth")
                fut = self.fabric.rpc_async(_addr("sim:simulation:0"), "get_pose", {"name": r}, timeout=2.0)
                fut.add_done_callback(lambda f, st=st: self._on_truth(st, f))

    @staticmethod
    def _on_truth(st: RobotState, fut: Future) -> None:
        st.pending.discard("truth")
        try:
            pose = fut.result()["pose"]
        except Exception:
            return
        if st.pose_source != "localize":
            st.pose, st.pose_source = [float(v) for v in pose[:3]], "simulation"

    def _robot(self, name: str) -> RobotState:
        with self._lock:
            return self.robots.setdefault(name, RobotState())

    # ------------------------------------------------------------------ scenarios
    def _scenario_files(self) -> list[Path]:
        if not self.scenarios_dir.is_dir():
            return []
        return sorted(p for p in self.scenarios_dir.iterdir() if p.suffix in (".yaml", ".yml", ".toml"))

    def scenarios(self) -> list[dict]:
        from .scenario import ScenarioError, load_scenario

        out = []
        for path in self._scenario_files():
            try:
                sc = load_scenario(path)
            except ScenarioError as e:
                out.append({"file": str(path), "name": path.stem, "error": str(e)})
                continue
            apps = []
            for a in sc.applications.values():
                apps.append(
                    {
                        "name": a.name,
                        "description": a.description,
                        "agents": [x.id for x in a.agents],
                        "simulator": str(a.simulator.world.name) if a.simulator else None,
                        "end": {k: v for k, v in vars(a.end).items() if v is not None},
                    }
                )
            out.append(
                {
                    "file": str(path),
                    "name": sc.name,
                    "description": sc.description,
                    "arguments": sc.arguments,
                    "arguments_yaml": {k: _yaml_text(v) for k, v in sc.arguments.items()},
                    "applications": apps,
                }
            )
        return out

    def _find_scenario(self, name: str) -> Path:
        from .scenario import ScenarioError, load_scenario

        names = []
        for path in self._scenario_files():
            try:
                sc_name = load_scenario(path).name
            except ScenarioError:
                sc_name = path.stem
            if name in (sc_name, path.stem, path.name):
                return path
            names.append(sc_name)
        raise ApiError(f"scenario {name!r} is not in {self.scenarios_dir}; use one of {', '.join(names) or '(none)'}")

    def start_run(self, body: dict) -> dict:
        from .scenario import ScenarioError, check_classes, load_scenario, parse_set

        _only(body, "run", ("scenario", "app", "set"))
        name = _text(body, "scenario")
        app_name = _text(body, "app")
        sets = body.get("set") or {}
        if not isinstance(sets, dict):
            raise ApiError('set must be a map of argument names to YAML text, e.g. {"report_every": "2"}')
        items = []
        for k, v in sets.items():
            if not isinstance(k, str) or not k.isidentifier():
                raise ApiError(f"set: argument name {k!r} must be a name (letters, digits, '_')")
            if not isinstance(v, str) or any(ch in v for ch in "\r\n\0"):
                raise ApiError(f'set.{k} must be one line of YAML text, e.g. "2" or "r0"')
            items.append(f"{k}={v}")
        path = self._find_scenario(name)
        try:
            sc = load_scenario(path, parse_set(items))
            app = sc.applications.get(app_name)
            if app is None:
                known = ", ".join(sc.applications)
                raise ApiError(f"scenario {sc.name!r} has no application {app_name!r}; use one of {known}")
            for p in (str(path.parent.resolve()), os.getcwd()):
                if p not in sys.path:
                    sys.path.insert(0, p)
            check_classes(sc, app)
        except ScenarioError as e:
            raise ApiError(str(e)) from None
        with self._lock:
            busy = [r for r in self.runs.values() if r.child.poll() is None]
            if busy:
                r = busy[0]
                raise ApiError(f"run {r.id} ({r.scenario}/{r.app}) is still running on this fabric; stop it first")
            rid = self._next_run
            self._next_run += 1
            args = ["run", str(path), "--app", app_name]
            for it in items:
                args += ["--set", it]
            child = self._spawn("run", f"run{rid}", args)
            run = Run(rid, sc.name, app_name, dict(sets), child, [a.id for a in app.agents])
            self.runs[rid] = run
        log.info("started run %d (pid %d): %s", rid, child.pid, child.shown)
        return run.info()

    def stop_run(self, rid: int) -> dict:
        with self._lock:
            run = self.runs.get(rid)
        if run is None:
            raise ApiError(f"no run {rid}; see /api/state for the runs", 404)
        if run.child.poll() is not None:
            raise ApiError(f"run {rid} is not running ({run.child.state}, exit code {run.child.poll()})")
        if not run.child.stopping:
            run.child.stopping = True
            threading.Thread(target=run.child.stop, args=(_steps("run"), _killed), daemon=True).start()
        return run.info()

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        with self._lock:
            agents = sorted(self.agents)
            devices = sorted(self.devices)
            runs = [r.info() for r in sorted(self.runs.values(), key=lambda r: r.id)]
            robots_st = dict(self.robots)
            watch = self.watch
        nodes: dict[str, list[str]] = {}
        for d in devices:
            n, iface, idx = d.split(":")
            nodes.setdefault(n, []).append(f"{iface}:{idx}")
        robots = []
        for n, ifs in nodes.items():
            if "position2d:0" not in ifs or n == "sim":
                continue
            st = robots_st.get(n) or RobotState()
            wf = st.wallfollow
            robots.append(
                {
                    "name": n,
                    "localize": "localize:0" in ifs,
                    "planner": "planner:0" in ifs,
                    "pose": st.pose,
                    "pose_source": st.pose_source,
                    "goal": st.goal,
                    "note": st.note,
                    "wallfollow": wf.info() if wf is not None else None,
                }
            )
        if not self.watch_enabled:
            w = {"state": "off", "url": None, "hint": "started with --no-watch; run 'rsal watch --serve' yourself"}
        elif watch is None:
            w = {"state": "waiting", "url": None, "hint": "'rsal watch --serve' starts when the first device is alive"}
        else:
            w = {"state": watch.state, "url": self.watch_url, "pid": watch.pid, "lines": list(watch.lines)[-5:]}
        return {
            "fabric": self.endpoint,
            "agents": agents,
            "devices": devices,
            "nodes": nodes,
            "robots": robots,
            "maps": [d for d in devices if d.split(":")[1] == "map"],
            "runs": runs,
            "watch": w,
        }

    # ------------------------------------------------------------------ map
    def map_info(self, device: str | None) -> dict:
        with self._lock:
            maps = sorted(d for d in self.devices if d.split(":")[1] == "map")
        if device is None:
            if not maps:
                raise ApiError("no map device is alive (start a simulator, e.g. a scenario application)", 404)
            device = "sim:map:0" if "sim:map:0" in maps else maps[0]
        if device not in maps:
            raise ApiError(f"map device {device!r} is not alive; alive: {', '.join(maps) or '(none)'}", 404)
        with self._lock:
            cached = self._maps.get(device)
        if cached is not None:
            return cached
        from rsal.msgs import MapData

        try:
            m = MapData.from_dict(self.fabric.rpc(_addr(device), "get", timeout=10.0))
        except Exception as e:
            raise ApiError(f"{device}: cannot fetch the map: {_one_line(e)}", 502) from None
        entry = {
            "device": device,
            "width": m.width,
            "height": m.height,
            "resolution": m.resolution,
            "origin": list(m.origin),
            "png": map_png(m.cells),
        }
        with self._lock:
            self._maps[device] = entry
        return entry

    # ------------------------------------------------------------------ robot actions
    def _need_robot(self, name: str) -> None:
        if not isinstance(name, str) or not _NAME.match(name):
            raise ApiError(f"robot {name!r} must be a node name like r0")
        with self._lock:
            ok = f"{name}:position2d:0" in self.devices
        if not ok:
            raise ApiError(f"robot {name!r} has no position2d:0 on the fabric; see the robots in /api/state", 404)

    def _need_device(self, robot: str, iface: str, hint: str) -> str:
        addr = f"{robot}:{iface}:0"
        with self._lock:
            ok = addr in self.devices
        if not ok:
            raise ApiError(f"robot {robot!r} has no {iface}:0 ({hint})")
        return addr

    def robot_action(self, name: str, action: str, body: dict) -> dict:
        from rsal.data import Position
        from rsal.msgs import RpcError

        self._need_robot(name)
        st = self._robot(name)
        if action == "pose":
            _only(body, "pose", ("x", "y", "yaw"))
            x, y, yaw = _num(body, "x"), _num(body, "y"), _num(body, "yaw", 0.0)
            addr = self._need_device(name, "localize", "start the simulator with --nav, or an amcl driver")
            try:
                self.fabric.device(addr).set_position(Position(x, y, math.radians(yaw)))
            except (RpcError, TimeoutError, ValueError) as e:
                raise ApiError(f"{addr}: set pose failed: {_one_line(e)}", 502) from None
            st.note = f"initial pose set to ({x:.2f}, {y:.2f}, {yaw:.0f} deg)"
            return {"ok": True, "robot": name, "note": st.note}
        if action == "goal":
            _only(body, "goal", ("x", "y", "yaw"))
            x, y, yaw = _num(body, "x"), _num(body, "y"), _num(body, "yaw", 0.0)
            addr = self._need_device(name, "planner", "start the simulator with --nav, or a wavefront driver")
            planner = self.fabric.device(addr)
            fut = planner.set_goal(Position(x, y, math.radians(yaw)), timeout=10.0)
            if fut.done() and fut.exception() is not None:
                raise ApiError(f"{addr}: goal ({x:.2f}, {y:.2f}) refused: {_one_line(fut.exception())}")
            goal = {"x": x, "y": y, "yaw": yaw, "status": "driving"}
            st.goal = goal

            def done(f: Future, goal=goal) -> None:
                e = f.exception()
                goal["status"] = "done" if e is None else f"ended: {_one_line(e)}"

            fut.add_done_callback(done)
            return {"ok": True, "robot": name, "goal": goal, "waypoints": planner.waypoint_count}
        if action == "stop":
            _only(body, "stop", ())
            done_what = []
            with self._lock:
                has_planner = f"{name}:planner:0" in self.devices
            wf = st.wallfollow
            if wf is not None and wf.poll() is None:
                wf.stop(_steps("agent"), _killed)
                done_what.append("wall-following stopped")
            if has_planner:
                try:
                    self.fabric.device(f"{name}:planner:0").stop()
                    done_what.append("planner stopped")
                except (RpcError, TimeoutError) as e:
                    done_what.append(f"planner stop failed: {_one_line(e)}")
            self.fabric.device(f"{name}:position2d:0").stop()
            done_what.append("zero velocity sent")
            if st.goal is not None and st.goal.get("status") == "driving":
                st.goal["status"] = "stopped"
            st.note = "; ".join(done_what)
            return {"ok": True, "robot": name, "note": st.note}
        if action == "wallfollow":
            _only(body, "wallfollow", ("on",))
            on = body.get("on", True)
            if not isinstance(on, bool):
                raise ApiError("wallfollow.on must be true or false")
            wf = st.wallfollow
            running = wf is not None and wf.poll() is None
            if on:
                if running:
                    raise ApiError(f"robot {name!r} is already wall-following (pid {wf.pid})")
                with self._lock:
                    taken = [a for a in self.agents if a == f"wallfollow-{name}"]
                if taken:
                    raise ApiError(f"agent {taken[0]!r} is already alive on the fabric; stop it first")
                args = ["agent", "WallfollowAgent", "--robot", name, "--id", f"wallfollow-{name}"]
                st.wallfollow = self._spawn("agent", f"wallfollow-{name}", args)
                st.note = f"wall-following started (pid {st.wallfollow.pid})"
            else:
                if not running:
                    raise ApiError(f"robot {name!r} is not wall-following from this page")
                threading.Thread(target=wf.stop, args=(_steps("agent"), _killed), daemon=True).start()
                wf.stopping = True
                st.note = "wall-following stopping"
            return {"ok": True, "robot": name, "note": st.note}
        if action == "estop":
            return self.estop(body, name)
        raise ApiError(f"unknown robot action {action!r}; use pose, goal, stop, estop or wallfollow", 404)

    def estop(self, body: dict, name: str | None = None) -> dict:
        """Latch (``{"release": true}``: release) the emergency stop of robot ``name``'s bases, or of
        every base on the fabric: the bases refuse every commander, running scenarios' agents included."""
        from rsal.estop import estop

        _only(body, "estop", ("release",))
        release = body.get("release", False)
        if not isinstance(release, bool):
            raise ApiError("estop.release must be true or false")
        res = estop(self.fabric.session, name, release=release)
        if not res.confirmed:
            who = f"no base of robot {name!r}" if name else "no robot"
            raise ApiError(f"{who} answered the emergency stop; is it on the fabric?", 502)
        return {"ok": not res.failed, "robots": res.robots, "note": res.summary(), "failed": res.failed}


def _addr(text: str):
    from rsal.keys import parse_device

    return parse_device(text)


def _yaml_text(value: Any) -> str:
    """A value as the one-line YAML text ``--set`` reads back (``1.0`` stays ``1.0``)."""
    import yaml

    text = yaml.safe_dump(value, default_flow_style=True, width=1_000_000).strip()
    return text[: -len("...")].strip() if text.endswith("\n...") else text


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _only(body: dict, what: str, allowed: tuple[str, ...]) -> None:
    if not isinstance(body, dict):
        raise ApiError(f"{what}: the body must be a JSON object")
    for k in body:
        if k not in allowed:
            known = ", ".join(allowed) or "none"
            raise ApiError(f"{what}: unknown field {k!r}; known fields: {known}")


def _text(body: dict, key: str) -> str:
    v = body.get(key)
    if not isinstance(v, str) or not v:
        raise ApiError(f"{key} must be a non-empty string")
    return v


def _num(body: dict, key: str, default: float | None = None) -> float:
    v = body.get(key, default)
    if v is None:
        raise ApiError(f"{key} is missing; give a number")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ApiError(f"{key} must be a finite number, not {v!r}")
    return float(v)


# ---------------------------------------------------------------------------- HTTP
class Handler(BaseHTTPRequestHandler):
    server_version = "rsal-control/1"
    control: Control  # set on the subclass made by serve()

    def log_message(self, fmt: str, *args) -> None:  # quiet: the page polls twice a second
        log.debug("%s %s", self.address_string(), fmt % args)

    def _send(self, status: int, body: bytes, ctype: str, extra: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, obj: Any, status: int = 200) -> None:
        self._send(status, json.dumps(obj).encode(), "application/json")

    def _error(self, message: str, status: int = 400) -> None:
        self._json({"error": message}, status)

    def _body(self) -> dict:
        ctype = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if ctype != "application/json":
            # a JSON content type makes a browser ask before a cross-site request (CORS preflight,
            # which this server never grants): another web site cannot start processes here
            raise ApiError(f"send the body as Content-Type application/json, not {ctype or 'none'!r}", 415)
        try:
            n = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            raise ApiError("Content-Length must be a number") from None
        if n > MAX_BODY:
            raise ApiError(f"the body is {n} bytes; at most {MAX_BODY} are accepted", 413)
        raw = self.rfile.read(n) if n else b"{}"
        try:
            body = json.loads(raw or b"{}")
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            why = e.msg if isinstance(e, json.JSONDecodeError) else "not UTF-8"
            raise ApiError(f"the body is not valid JSON ({why}); send a JSON object") from None
        if not isinstance(body, dict):
            raise ApiError('the body must be a JSON object, e.g. {"scenario": "wander", "app": "wallfollow"}')
        return body

    def _dispatch(self, method: str) -> None:
        url = urlsplit(self.path)
        parts = [p for p in url.path.split("/") if p]
        query = parse_qs(url.query)
        c = self.control
        try:
            host = (self.headers.get("Host") or "").rsplit(":", 1)[0]
            if host not in ("127.0.0.1", "localhost", "[::1]"):
                # a page of another site reaching this port through a rebound DNS name
                raise ApiError(f"Host {host!r} refused; open the page as http://127.0.0.1:PORT/", 403)
            if method == "GET":
                if not parts or parts == ["index.html"]:
                    return self._static("index.html")
                if parts[0] == "static" and len(parts) == 2:
                    return self._static(parts[1])
                if parts == ["api", "state"]:
                    return self._json(c.state())
                if parts == ["api", "scenarios"]:
                    return self._json(c.scenarios())
                if parts == ["api", "map"]:
                    m = c.map_info(_query_one(query, "device"))
                    info = {k: v for k, v in m.items() if k != "png"}
                    return self._json(info | {"png": f"/api/map.png?device={m['device']}"})
                if parts == ["api", "map.png"]:
                    m = c.map_info(_query_one(query, "device"))
                    return self._send(200, m["png"], "image/png")
            elif method == "POST":
                if parts == ["api", "runs"]:
                    return self._json(c.start_run(self._body()))
                if len(parts) == 4 and parts[:2] == ["api", "runs"] and parts[3] == "stop":
                    self._body()
                    try:
                        rid = int(parts[2])
                    except ValueError:
                        raise ApiError(f"run id {parts[2]!r} must be a number", 404) from None
                    return self._json(c.stop_run(rid))
                if parts == ["api", "estop"]:
                    return self._json(c.estop(self._body()))
                if len(parts) == 4 and parts[:2] == ["api", "robots"]:
                    return self._json(c.robot_action(parts[2], parts[3], self._body()))
            raise ApiError(f"no such API: {method} {url.path}; see docs/control.md", 404)
        except ApiError as e:
            return self._error(str(e), e.status)
        except Exception as e:  # never a traceback to the page: one line, logged here
            log.exception("%s %s", method, self.path)
            return self._error(f"internal error: {_one_line(e)}", 500)

    def _static(self, name: str) -> None:
        path = STATIC / name
        if not _NAME.match(name) or path.suffix not in STATIC_TYPES or not path.is_file():
            raise ApiError(f"no such file: {name}", 404)
        self._send(200, path.read_bytes(), STATIC_TYPES[path.suffix])

    def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
        self._dispatch("GET")

    def do_HEAD(self) -> None:  # noqa: N802
        self._dispatch("GET")

    def do_POST(self) -> None:  # noqa: N802
        self._dispatch("POST")


def _query_one(query: dict, key: str) -> str | None:
    v = query.get(key)
    return v[-1] if v else None


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
        endpoint = args.listen or f"tcp/127.0.0.1:{_free_port()}"
        targs = TransportArgs(listen=[endpoint])
    flags: list[str] = []
    if args.config:
        flags += ["--config", args.config]
        targs.config = args.config
    for item in args.cfg or []:
        flags += ["--cfg", item]
        targs.cfg.append(item)
    try:
        httpd = ThreadingHTTPServer(("127.0.0.1", args.port), type("H", (Handler,), {}))
    except OSError as e:
        return fail(f"cannot serve on 127.0.0.1:{args.port}: {e.strerror}; choose another --port")
    httpd.daemon_threads = True
    control = Control(scen, endpoint, watch=not args.no_watch, zenoh_flags=flags)
    httpd.RequestHandlerClass.control = control
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
