"""Scenario files: which agents run where, on which world, and when a run is over (thesis fig. 3.11).

Jadex starts a multi-agent system from an *application file*: the agent types, the applications that
instantiate them with arguments, and the platform they run on (thesis 3.6.1, fig. 3.11, and the
scenarios of 4.2). A scenario file plays that role here, in YAML (or TOML, same structure)::

    scenario: hunt_prey
    description: Hunt and Prey (thesis 4.2.1)
    arguments: {report_every: 1.0}         # given to every agent whose class accepts them
    agent_types: {hunter: FollowAgent, prey: EscapeAgent}
    applications:
      virtual:
        description: 2 hunters chase 1 prey
        simulator: {world: ../../maps/hunt.world, nav: vfh, nav_robots: [r1, r2], speedup: 1.0}
        rehearse: {world: ../../maps/real.world, robot: c1, nav: vfh}   # a "real" robot (optional)
        servers: []
        agents:
          - {type: prey, robot: r0}
          - {type: hunter, robot: "r{i}", count: 2, id: "hunter{i}", host: hunters, args: {prey: r0}}
        end: {event: caught, count: 1, timeout: 240}

:func:`load_scenario` parses and validates a file into frozen dataclasses; every problem is one
:class:`ScenarioError` line naming the file, the key path and a fix. :func:`check_classes` resolves
the agent classes (:mod:`agents.registry`) and their keyword arguments before any process starts, and
:func:`constructor_kwargs` is the one rule both the runner and the agent hosts use to pass arguments:
entry ``args`` always, global ``arguments`` only where the constructor accepts them. The full format
is in ``docs/scenarios.md``.
"""

from __future__ import annotations

import inspect
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rsal.errors import RsalError
from rsal.suggest import did_you_mean

from .services import check_name

__all__ = [
    "DEFAULT_TIMEOUT",
    "AgentEntry",
    "Application",
    "End",
    "Scenario",
    "ScenarioError",
    "SimulatorSpec",
    "check_classes",
    "constructor_kwargs",
    "load_scenario",
    "parse_set",
    "RehearsalSpec",
]

#: seconds after which a run without another end fails
DEFAULT_TIMEOUT = 300.0

_TOP = ("scenario", "description", "arguments", "agent_types", "applications")
_APP = ("description", "simulator", "rehearse", "servers", "agents", "end")
_SIM = ("world", "nav", "nav_robots", "nav_servers", "speedup", "seed", "threads")
_REHEARSE = ("world", "robot", "nav", "pioneer", "laser", "node", "seed")
_PIONEERS = ("P2DX", "P3AT")  # mrs_bridge.emulators.p2os.DIST_CONV
_LASERS = ("URG-04LX", "UTM-30LX")  # mrs_bridge.emulators.urg.SENSORS
_AGENT = ("type", "robot", "id", "args", "host", "hosts", "machine", "count")
_END = ("event", "count", "timeout", "duration", "travel", "clearance", "never_flat", "charged")
_NAV = ("vfh", "nd", "snd")


class ScenarioError(RsalError, ValueError):
    """A scenario file (or an override) that cannot be run; the message is one line."""


@dataclass(frozen=True)
class SimulatorSpec:
    """The simulator started first: ``rsal sim WORLD [--nav ..] [--nav-robots ..] [--speedup ..]``."""

    world: Path
    nav: str | None = None
    nav_robots: tuple[str, ...] = ()
    speedup: float | None = None
    seed: int | None = None
    #: navigation stacks in this many extra servers (``rsal sim .. --nav-part I/N``), 0: in the simulator's
    nav_servers: int = 0
    #: the ray caster's threads (``rsal sim --threads``; 0 or 1: the stepping thread alone), None: the world's
    threads: int | None = None


@dataclass(frozen=True)
class RehearsalSpec:
    """A "real" robot on emulated hardware, started after the simulator: ``rsal rehearse WORLD
    ROBOT [--nav ..] [--pioneer ..] [--laser ..] [--node ..] [--seed ..]`` (docs/hardware.md). Its
    world is "the real world": its simulation device ``NODE:simulation:0`` is the ground truth of
    ``robot``, which the run waits for (its base, its laser and, with ``nav``, its planner)."""

    world: Path
    robot: str
    nav: str | None = None
    pioneer: str | None = None
    laser: str | None = None
    node: str = "world"
    seed: int | None = None

    @property
    def devices(self) -> tuple[str, ...]:
        """The devices (``node/iface/idx``) whose liveliness says the rehearsed robot is served."""
        own = [f"{self.robot}/position2d/0", f"{self.robot}/laser/0", f"{self.node}/simulation/0"]
        return tuple(own + ([f"{self.robot}/planner/0"] if self.nav else []))


@dataclass(frozen=True)
class AgentEntry:
    """One agent of an application (``count`` entries already expanded)."""

    type: str
    cls: str
    id: str
    robot: str = ""
    args: dict[str, Any] = field(default_factory=dict)
    host: str | None = None
    machine: str | None = None  # the host daemon (rsal host --name MACHINE) its group is launched on

    @property
    def group(self) -> str:
        """The agent-host process it runs in: its ``host``, else its own (named after its id)."""
        return self.host or self.id


@dataclass(frozen=True)
class End:
    """When a run is over: ``count`` distinct subjects of ok ``event`` outcomes (success), or
    ``duration`` seconds without a failed outcome (success); ``timeout`` seconds: failure. With a
    simulator, ``travel`` (m) and ``clearance`` (m) are judged on ground truth (:mod:`agents.verdict`):
    every agent's robot must have truly driven at least ``travel`` metres and kept its centre at
    least ``clearance`` metres from every wall of the map; with ``never_flat`` no agent's robot's
    battery may ever run empty (the run fails the moment one does), and at least ``charged``
    of them must have truly gained charge on a charger (the simulation's battery record)."""

    event: str | None = None
    count: int = 1
    timeout: float = DEFAULT_TIMEOUT
    duration: float | None = None
    travel: float | None = None
    clearance: float | None = None
    never_flat: bool = False
    charged: int = 0


@dataclass(frozen=True)
class Application:
    name: str
    description: str
    simulator: SimulatorSpec | None
    servers: tuple[Path, ...]
    agents: tuple[AgentEntry, ...]
    end: End
    rehearse: RehearsalSpec | None = None

    def groups(self) -> dict[str, list[AgentEntry]]:
        """Agent-host processes to start: group name -> its agents, in file order."""
        out: dict[str, list[AgentEntry]] = {}
        for a in self.agents:
            out.setdefault(a.group, []).append(a)
        return out

    def machines(self) -> dict[str, str]:
        """Host group -> the machine (host daemon) it is launched on, for groups that name one; the
        others run on the runner's own machine."""
        return {a.group: a.machine for a in self.agents if a.machine}


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    arguments: dict[str, Any]
    agent_types: dict[str, str]
    applications: dict[str, Application]
    source: Path


# ---------------------------------------------------------------------------- helpers
class _Ctx:
    def __init__(self, source: Path, check_files: bool = True):
        self.source = source
        self.check_files = check_files

    def fail(self, where: str, text: str) -> ScenarioError:
        return ScenarioError(f"{self.source}: {where}: {text}" if where else f"{self.source}: {text}")

    def map(self, value: Any, where: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be a map with keys {', '.join(allowed)}, not {_kind(value)}")
        for k in value:
            if not isinstance(k, str) or k not in allowed:
                near = did_you_mean(str(k), allowed)
                hint = f"did you mean {near!r}?" if near else f"known keys: {', '.join(allowed)}"
                raise self.fail(_join(where, str(k)), f"unknown key; {hint}")
        for k in required:
            if k not in value:
                raise self.fail(where, f"the key {k!r} is missing; add it")
        return value

    def text(self, value: Any, where: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(where, f"must be a non-empty string, not {_kind(value)}")
        return value

    def number(self, value: Any, where: str, *, positive: bool = True) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(where, f"must be a number, not {_kind(value)}")
        if positive and not value > 0:
            raise self.fail(where, f"must be a positive number, not {value!r}")
        return float(value)

    def whole(self, value: Any, where: str, lo: int = 1) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(where, f"must be a whole number, not {_kind(value)}")
        if value < lo:
            raise self.fail(where, f"must be at least {lo}, not {value}")
        return value

    def path(self, value: Any, where: str) -> Path:
        p = Path(self.text(value, where))
        full = p if p.is_absolute() else (self.source.parent / p)
        if not self.check_files:  # the runner's files, on another machine (a host daemon's copy)
            return full
        if not full.is_file():
            raise self.fail(where, f"file {str(p)!r} does not exist (paths are relative to the scenario file)")
        return full.resolve()


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    return {dict: "a map", list: "a list", str: f"the string {value!r}", bool: f"{value}"}.get(
        type(value), f"{type(value).__name__} {value!r}"
    )


def parse_set(items: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``--set KEY=VALUE`` items as a dict (VALUE parsed as a YAML scalar: ``2`` → 2, ``no`` → False)."""
    out: dict[str, Any] = {}
    for item in items:
        key, eq, text = item.partition("=")
        key = key.strip()
        if not eq or not key.isidentifier():
            raise ScenarioError(f"--set {item!r}: must be KEY=VALUE with KEY a name, e.g. --set report_every=2")
        try:
            out[key] = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError as e:
            raise ScenarioError(f"--set {item!r}: VALUE is no YAML scalar ({_first_line(e)})") from None
    return out


def _first_line(e: BaseException) -> str:
    return " ".join(str(e).split())


def _read(path: Path) -> Any:
    try:
        text = path.read_text()
    except OSError as e:
        raise ScenarioError(f"{path}: cannot read the scenario file ({e.strerror}); check the path") from None
    if path.suffix == ".toml":
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ScenarioError(f"{path}: not valid TOML: {e}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(e, "problem", None) or _first_line(e)
        raise ScenarioError(f"{path}: {where}not valid YAML: {problem}") from None


# ---------------------------------------------------------------------------- loader
def load_scenario(path: str | Path, overrides: dict[str, Any] | None = None, *, check_files: bool = True) -> Scenario:
    """Parse and validate a scenario file; ``overrides`` replace global arguments (``--set``).
    ``check_files=False`` leaves the files it names (world, server configurations) unchecked: a
    host daemon's copy of the runner's scenario, whose files are on the runner's machine.
    Raises :class:`ScenarioError` with one line."""
    src = Path(path)
    c = _Ctx(src, check_files)
    doc = _read(src)
    if doc is None:
        raise c.fail("", "the file is empty; see docs/scenarios.md for the format")
    top = c.map(doc, "", _TOP, required=("scenario", "agent_types", "applications"))
    name = c.text(top["scenario"], "scenario")
    description = top.get("description") or ""
    if not isinstance(description, str):
        raise c.fail("description", f"must be a string, not {_kind(description)}")
    arguments = top.get("arguments") or {}
    if not isinstance(arguments, dict) or not all(isinstance(k, str) for k in arguments):
        raise c.fail("arguments", f"must be a map of argument names to values, not {_kind(arguments)}")
    arguments = {**arguments, **(overrides or {})}
    types_raw = top["agent_types"]
    if not isinstance(types_raw, dict) or not types_raw:
        raise c.fail("agent_types", "must be a non-empty map of type names to agent classes, e.g. {prey: EscapeAgent}")
    agent_types: dict[str, str] = {}
    for t, cls in types_raw.items():
        agent_types[c.text(t, "agent_types")] = c.text(cls, f"agent_types.{t}")
    apps_raw = top["applications"]
    if not isinstance(apps_raw, dict) or not apps_raw:
        raise c.fail("applications", "must be a non-empty map of application names to applications")
    apps = {}
    for app_name, raw in apps_raw.items():
        apps[str(app_name)] = _application(c, str(app_name), raw, agent_types)
    return Scenario(name, description, arguments, agent_types, apps, src)


def _application(c: _Ctx, name: str, raw: Any, agent_types: dict[str, str]) -> Application:
    where = f"applications.{name}"
    m = c.map(raw, where, _APP, required=("agents", "end"))
    description = m.get("description") or ""
    if not isinstance(description, str):
        raise c.fail(f"{where}.description", f"must be a string, not {_kind(description)}")
    sim = None
    if m.get("simulator") is not None:
        sim = _simulator(c, f"{where}.simulator", m["simulator"])
    rehearse = None
    if m.get("rehearse") is not None:
        rehearse = _rehearse(c, f"{where}.rehearse", m["rehearse"], sim)
    servers_raw = m.get("servers") or []
    if not isinstance(servers_raw, list):
        raise c.fail(f"{where}.servers", f"must be a list of server configuration files, not {_kind(servers_raw)}")
    servers = tuple(c.path(s, f"{where}.servers[{i}]") for i, s in enumerate(servers_raw))
    agents_raw = m["agents"]
    if not isinstance(agents_raw, list) or not agents_raw:
        raise c.fail(f"{where}.agents", "must be a non-empty list of agents, e.g. [{type: prey, robot: r0}]")
    agents: list[AgentEntry] = []
    seen: dict[str, str] = {}
    per_type: dict[str, int] = {}
    for i, a in enumerate(agents_raw):
        for entry in _agents(c, f"{where}.agents[{i}]", a, agent_types, per_type):
            if entry.id in seen:
                raise c.fail(
                    f"{where}.agents[{i}]",
                    f"agent id {entry.id!r} is used twice (also by {seen[entry.id]}); give each agent its own 'id'",
                )
            seen[entry.id] = f"{where}.agents[{i}]"
            agents.append(entry)
    machine_of: dict[str, str | None] = {}
    for a in agents:
        other = machine_of.setdefault(a.group, a.machine)
        if other != a.machine:
            raise c.fail(
                f"{where}.agents",
                f"host group {a.group!r} is placed on machine {other or 'here'!r} and on {a.machine or 'here'!r}; "
                "one agent host runs on one machine: give its entries the same 'machine'",
            )
    end = _end(c, f"{where}.end", m["end"])
    truth = [k for k in ("travel", "clearance") if getattr(end, k) is not None]
    truth += [k for k in ("never_flat", "charged") if getattr(end, k)]
    if truth and sim is None:
        why = "is judged on the simulator's ground truth; add a 'simulator' or remove it"
        raise c.fail(f"{where}.end.{truth[0]}", why)
    return Application(name, description, sim, servers, tuple(agents), end, rehearse)


def _simulator(c: _Ctx, where: str, raw: Any) -> SimulatorSpec:
    m = c.map(raw, where, _SIM, required=("world",))
    world = c.path(m["world"], f"{where}.world")
    nav = m.get("nav")
    if nav is not None and nav not in _NAV:
        raise c.fail(f"{where}.nav", f"unknown local planner {nav!r}; use one of {', '.join(_NAV)}")
    robots = m.get("nav_robots") or []
    if isinstance(robots, str):
        robots = [r for r in robots.split(",") if r]
    if not isinstance(robots, list) or not all(isinstance(r, str) and r for r in robots):
        raise c.fail(f"{where}.nav_robots", f"must be a list of robot names, e.g. [r1, r2], not {_kind(robots)}")
    if robots and nav is None:
        raise c.fail(f"{where}.nav_robots", "needs 'nav' (vfh, nd or snd) to choose the local planner")
    speedup = None if m.get("speedup") is None else c.number(m["speedup"], f"{where}.speedup")
    seed = None if m.get("seed") is None else c.whole(m["seed"], f"{where}.seed", lo=0)
    servers = 0 if m.get("nav_servers") is None else c.whole(m["nav_servers"], f"{where}.nav_servers", lo=0)
    if servers and nav is None:
        raise c.fail(f"{where}.nav_servers", "needs 'nav' (vfh, nd or snd): the servers run navigation stacks")
    threads = None if m.get("threads") is None else c.whole(m["threads"], f"{where}.threads", lo=0)
    return SimulatorSpec(world, nav, tuple(robots), speedup, seed, servers, threads)


def _rehearse(c: _Ctx, where: str, raw: Any, sim: SimulatorSpec | None) -> RehearsalSpec:
    m = c.map(raw, where, _REHEARSE, required=("world", "robot"))
    world = c.path(m["world"], f"{where}.world")
    robot = c.text(m["robot"], f"{where}.robot")
    node = "world" if m.get("node") is None else c.text(m["node"], f"{where}.node")
    for key, val in (("robot", robot), ("node", node)):
        if not all(ch.isalnum() or ch in "_-" for ch in val):
            raise c.fail(f"{where}.{key}", f"{val!r} is no node name; use letters, digits, _ and -")
    if sim is not None and node == "sim":
        raise c.fail(f"{where}.node", "'sim' is the virtual simulator's node; name the real world's another")
    if sim is not None and sim.speedup not in (None, 1.0):
        why = f"the rehearsed real world runs in real time; remove speedup {sim.speedup:g} or the rehearsal"
        raise c.fail(f"{where[: -len('.rehearse')]}.simulator.speedup", why)
    nav = m.get("nav")
    if nav is not None and nav not in _NAV:
        raise c.fail(f"{where}.nav", f"unknown local planner {nav!r}; use one of {', '.join(_NAV)}")
    choices = {"pioneer": _PIONEERS, "laser": _LASERS}
    picked = {}
    for key, allowed in choices.items():
        v = m.get(key)
        if v is not None and v not in allowed:
            near = did_you_mean(str(v), allowed)
            hint = f"did you mean {near!r}?" if near else f"use one of {', '.join(allowed)}"
            raise c.fail(f"{where}.{key}", f"unknown {key} {v!r}; {hint}")
        picked[key] = v
    seed = None if m.get("seed") is None else c.whole(m["seed"], f"{where}.seed", lo=0)
    return RehearsalSpec(world, robot, nav, picked["pioneer"], picked["laser"], node, seed)


def _agents(c: _Ctx, where: str, raw: Any, agent_types: dict[str, str], per_type: dict[str, int]) -> list[AgentEntry]:
    m = c.map(raw, where, _AGENT, required=("type",))
    t = c.text(m["type"], f"{where}.type")
    if t not in agent_types:
        near = did_you_mean(t, agent_types)
        hint = f"did you mean {near!r}?" if near else f"add it to agent_types (known: {', '.join(agent_types)})"
        raise c.fail(f"{where}.type", f"unknown agent type {t!r}; {hint}")
    robot = "" if m.get("robot") is None else c.text(m["robot"], f"{where}.robot")
    agent_id = None if m.get("id") is None else c.text(m["id"], f"{where}.id")
    host = None if m.get("host") is None else c.text(m["host"], f"{where}.host")
    machine = None if m.get("machine") is None else c.text(m["machine"], f"{where}.machine")
    if machine is not None:
        try:
            check_name("machine", machine)
        except ValueError as e:
            raise c.fail(f"{where}.machine", f"{e}; it is the host daemon's --name") from None
    args = m.get("args") or {}
    if not isinstance(args, dict) or not all(isinstance(k, str) for k in args):
        raise c.fail(f"{where}.args", f"must be a map of argument names to values, not {_kind(args)}")
    has_count = m.get("count") is not None
    count = c.whole(m["count"], f"{where}.count") if has_count else 1
    if count > 1 and robot and "{i}" not in robot:
        raise c.fail(f"{where}.robot", f'{count} agents cannot share robot {robot!r}; write e.g. robot: "r{{i}}"')
    if count > 1 and agent_id is not None and "{i}" not in agent_id:
        raise c.fail(f"{where}.id", f'{count} agents cannot share id {agent_id!r}; write e.g. id: "{agent_id}{{i}}"')
    hosts = 1
    if m.get("hosts") is not None:
        hosts = c.whole(m["hosts"], f"{where}.hosts")
        if host is None:
            raise c.fail(
                f"{where}.hosts",
                f"spreads the agents over {hosts} host groups named after 'host'; add e.g. host: swarm",
            )
        if hosts > count:
            raise c.fail(
                f"{where}.hosts", f"{hosts} agent hosts for {count} agent(s); give at most count ({count}) hosts"
            )
        if "{i}" in host:
            raise c.fail(
                f"{where}.host", f"with 'hosts' the groups are named {host!r} + 0..{hosts - 1}; remove '{{i}}'"
            )
    out = []
    for i in range(count):
        r = robot.replace("{i}", str(i)) if has_count else robot
        if agent_id is not None:
            aid = agent_id.replace("{i}", str(i)) if has_count else agent_id
        elif r:
            aid = f"{t}-{r}"
        else:
            n = per_type.get(t, 0)
            aid = f"{t}{n}"
        per_type[t] = per_type.get(t, 0) + 1
        try:
            check_name("agent id", aid)
        except ValueError as e:
            raise c.fail(f"{where}.id", f"{e}; choose another id") from None
        group = f"{host}{i * hosts // count}" if hosts > 1 else host  # consecutive blocks: neighbours together
        out.append(AgentEntry(t, agent_types[t], aid, r, dict(args), group, machine))
    return out


def _end(c: _Ctx, where: str, raw: Any) -> End:
    m = c.map(raw, where, _END)
    event = None if m.get("event") is None else c.text(m["event"], f"{where}.event")
    duration = None if m.get("duration") is None else c.number(m["duration"], f"{where}.duration")
    if event is None and duration is None:
        raise c.fail(where, "needs 'event' (with 'count') or 'duration' (seconds); e.g. end: {event: caught, count: 1}")
    if event is not None and duration is not None:
        raise c.fail(where, "give either 'event' (with 'count') or 'duration', not both")
    if "count" in m and event is None:
        raise c.fail(f"{where}.count", "counts outcomes of an 'event'; add 'event' or remove 'count'")
    count = c.whole(m["count"], f"{where}.count") if "count" in m else 1
    default = DEFAULT_TIMEOUT if duration is None else max(DEFAULT_TIMEOUT, duration + 60.0)
    timeout = default if m.get("timeout") is None else c.number(m["timeout"], f"{where}.timeout")
    if duration is not None and timeout <= duration:
        raise c.fail(f"{where}.timeout", f"{timeout:g} s must be longer than the duration {duration:g} s")
    travel = None if m.get("travel") is None else c.number(m["travel"], f"{where}.travel")
    clearance = None if m.get("clearance") is None else c.number(m["clearance"], f"{where}.clearance")
    never_flat = m.get("never_flat", False)
    if not isinstance(never_flat, bool):
        raise c.fail(f"{where}.never_flat", f"must be true or false, got {never_flat!r}")
    charged = c.whole(m["charged"], f"{where}.charged", lo=0) if "charged" in m else 0
    return End(event, count, timeout, duration, travel, clearance, never_flat, charged)


# ---------------------------------------------------------------------------- classes and arguments
def _accepts(cls: type) -> tuple[set[str], bool]:
    """The keyword names ``cls(agent_id, ...)`` accepts and whether it takes any keyword at all.

    A constructor with ``**kwargs`` passes them on to its base class's (``super().__init__(agent_id,
    **kw)``), so the names of the bases' constructors count too, down the MRO, until one that takes
    no ``**kwargs``; only if every constructor on the way does is the answer "anything"."""
    names: set[str] = set()
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        if klass is object:
            return names, True
        try:
            sig = inspect.signature(init)
        except (TypeError, ValueError):
            return names, True
        var_kw = False
        for i, p in enumerate(sig.parameters.values()):
            if p.kind is p.VAR_KEYWORD:
                var_kw = True
            elif p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) and i > 1:  # after self, agent_id
                names.add(p.name)
        if not var_kw:
            return names, False
    return names, True


def constructor_kwargs(cls: type, robot: str, global_args: dict[str, Any], args: dict[str, Any]) -> dict[str, Any]:
    """The keyword arguments of ``cls(agent_id, **kwargs)``: ``robot``, the global arguments the
    constructor accepts and the entry's own ``args`` (always passed; they win)."""
    names, var_kw = _accepts(cls)
    out = {k: v for k, v in global_args.items() if var_kw or k in names}
    if robot or "robot" in names or var_kw:
        out["robot"] = robot
    out.update(args)
    return out


def check_classes(scenario: Scenario, app: Application) -> None:
    """Resolve every agent class the application uses and check the entries' ``args`` against the
    constructors; raises :class:`ScenarioError` naming the type and the argument."""
    from .registry import AgentClassError, resolve

    for t, cls_name in scenario.agent_types.items():
        if not any(a.type == t for a in app.agents):
            continue
        try:
            cls = resolve(cls_name)
        except AgentClassError as e:
            raise ScenarioError(f"{scenario.source}: agent_types.{t}: {e}") from None
        names, var_kw = _accepts(cls)
        if var_kw:
            continue
        for a in app.agents:
            if a.type != t:
                continue
            for k in a.args:
                if k not in names:
                    near = did_you_mean(k, sorted(names))
                    hint = f"did you mean {near!r}?" if near else f"it takes: {', '.join(sorted(names))}"
                    raise ScenarioError(
                        f"{scenario.source}: applications.{app.name}: agent {a.id}: args.{k}: "
                        f"{cls.__name__} takes no argument {k!r}; {hint}"
                    )
