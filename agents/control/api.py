"""The control center's JSON API (``docs/control.md``): scenario files and their runs, the fabric's
state, the map image, and the input checks every endpoint uses (thesis 3.4.2: one place from which
an operator starts the scenarios of 4.2 and sees what is alive).

Every input is checked where it enters: :func:`_only` (no unknown field), :func:`_text` (a non-empty
string), :func:`_num` (a finite number); a refusal is an :class:`ApiError` with the HTTP status and
one line, which :mod:`agents.control.http` answers as ``{"error": "<line>"}``. :class:`ScenarioApi`
holds the endpoints of scenarios and runs; it is a part of :class:`agents.control.Control`, whose
state (lock, alive devices, runs, children) it uses.
"""

from __future__ import annotations

import io
import logging
import math
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rsal.errors import RsalError
from rsal.procs import Child

__all__ = ["ApiError", "Run", "ScenarioApi", "map_png"]

log = logging.getLogger("agents.control")

#: a node, file or robot name the API accepts
NAME = re.compile(r"^[A-Za-z0-9_\-.]+$")


class ApiError(RsalError, ValueError):
    """A request the API refuses: HTTP ``status`` with a one-line message."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


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


class ScenarioApi:
    """The endpoints of scenarios, runs, state and maps (a part of :class:`agents.control.Control`)."""

    # ------------------------------------------------------------------ scenarios
    def _scenario_files(self) -> list[Path]:
        if not self.scenarios_dir.is_dir():
            return []
        return sorted(p for p in self.scenarios_dir.iterdir() if p.suffix in (".yaml", ".yml", ".toml"))

    def scenarios(self) -> list[dict]:
        from ..scenario import ScenarioError, load_scenario

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
        from ..scenario import ScenarioError, load_scenario

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
        from ..scenario import ScenarioError, check_classes, load_scenario, parse_set

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
            self._stop_child(run.child, "run", background=True)
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
        robots = self._robot_list(nodes, robots_st)
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
