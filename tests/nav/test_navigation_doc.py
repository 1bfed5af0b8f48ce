"""docs/navigation.md (and the navigation parts of docs/configuration.md) against the code.

(a) Every ```toml block of navigation.md is a marked configuration (``<!-- config: PATH -->``) that
loads with :mod:`mrs_bridge.config` and whose drivers are created (parameters checked) by a
:class:`~mrs_bridge.server.DeviceServer` over an in-memory fake session. (b) The parameter tables
(``<!-- params: DRIVER -->``) of both pages list exactly the drivers' parameters, with the defaults
the code has. (c) configuration.md's "simulation with navigation" is what ``rsal sim --nav vfh``
runs. (d) The configuration errors the page shows are the ones the drivers raise. (e) The page's
Python example compiles, imports only ``rsal`` and the standard library, and, run verbatim against
``rsal sim maps/testroom.world --nav vfh``, drives r0 to its goal; the invalid goals the page shows
are refused with the documented messages.
"""

from __future__ import annotations

import ast
import math
import re
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest

import mrs_bridge.drivers  # noqa: F401  (registers the built-in drivers)
from mrs_bridge.config import ConfigError, parse_config
from mrs_bridge.server import DeviceServer
from rsal.testing import FakeSession
from tests.conftest import MAPS, ROOT, Proc, free_port, rsal_cmd, wait_until

NAV = ROOT / "docs" / "navigation.md"
CONF = ROOT / "docs" / "configuration.md"
TOML = re.compile(r"^```toml\n(.*?)^```\n", re.S | re.M)
MARKER = re.compile(r"<!-- config: (\S+) -->\n$")
EXAMPLE_MARKER = "<!-- navigation-example"
STDLIB_OK = {"__future__", "argparse", "math", "sys", "time"}
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e-?\d+)?")


def text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def toml_blocks(path: Path) -> list[tuple[str, str, int]]:
    """(marked path or "", block, line) for every ```toml block of a page."""
    page = text(path)
    out = []
    for m in TOML.finditer(page):
        before = page[: m.start()]
        mk = MARKER.search(before[before.rfind("<!--") :]) if "<!--" in before else None
        out.append((mk[1] if mk else "", m[1], page.count("\n", 0, m.start()) + 1))
    return out


def load(path: str, block: str):
    return parse_config(block, source=path, base_dir=(ROOT / path).parent)


def start(cfg) -> None:
    """Create every driver of ``cfg`` (ConfigError for a bad parameter), then withdraw them."""
    server = DeviceServer(cfg, FakeSession())  # type: ignore[arg-type]
    try:
        server.start()
        assert len(server.slots) == len(cfg.drivers)
    finally:
        server.close()


# ---------------------------------------------------------------------------- (a) TOML blocks
NAV_BLOCKS = toml_blocks(NAV)


def test_every_toml_block_is_a_marked_config():
    assert NAV_BLOCKS, "docs/navigation.md has no ```toml block"
    assert [line for path, _, line in NAV_BLOCKS if not path] == []


@pytest.mark.parametrize(("path", "block"), [(p, b) for p, b, _ in NAV_BLOCKS], ids=[p for p, _, _ in NAV_BLOCKS])
def test_documented_config_loads_and_its_drivers_are_created(path, block):
    cfg = load(path, block)
    names = [d.name for d in cfg.drivers]
    assert {"amcl", "wavefront"} <= set(names) and set(names) & {"vfh", "nd", "snd"}
    start(cfg)


def test_the_a3_config_requires_the_robot_from_another_server():
    path, block, _ = next(b for b in NAV_BLOCKS if b[0] == "deploy/r0-nav.toml")
    cfg = load(path, block)
    provided = {str(a) for d in cfg.drivers for a in d.provides}
    required = {str(r.without_key()) for d in cfg.drivers for r in d.requires}
    assert {"r0:position2d:0", "r0:laser:0"} <= required - provided
    # the local planner's tolerances are tighter than the global planner's (thesis 3.4.1)
    vfh = next(d for d in cfg.drivers if d.name == "vfh").params
    wf = next(d for d in cfg.drivers if d.name == "wavefront").params
    assert vfh["distance_epsilon"] < wf["distance_epsilon"] and vfh["angle_epsilon"] < wf["angle_epsilon"]


# ---------------------------------------------------------------------------- (b) parameter tables
def param_tables(path: Path) -> dict[str, dict[str, str]]:
    """``{driver: {parameter: default cell}}`` from the tables after ``<!-- params: DRIVER -->``."""
    page = text(path)
    out: dict[str, dict[str, str]] = {}
    for m in re.finditer(r"<!-- params: (\w+) -->\n((?:\|.*\n)+)", page):
        rows = [[c.strip() for c in r.strip().strip("|").split("|")] for r in m[2].splitlines()[2:]]
        table = {}
        for cells in rows:
            for name in re.findall(r"`(\w+)`", cells[0]):
                table[name] = cells[2].strip()
        out[m[1]] = table
    return out


def numbers(cell: str) -> list[float]:
    return [float(x) for x in NUMBER.findall(cell.split("(")[0])]


def amcl_defaults() -> dict[str, object]:
    """AmclParams' defaults in the units of the configuration file (degrees where Player has them)."""
    from mrs_bridge.nav.amcl import AmclParams

    d: dict[str, object] = {f.name: f.default for f in fields(AmclParams)}
    d["update_thresh"] = (d["update_thresh"][0], math.degrees(d["update_thresh"][1]))
    d["init_pose"] = (*d["init_pose"][:2], math.degrees(d["init_pose"][2]))
    d["init_pose_var"] = (*d["init_pose_var"][:2], math.degrees(d["init_pose_var"][2]))
    d.update({"laser_pose": None, "laser_range_max": None, "global": False})
    return d


def wavefront_defaults() -> dict[str, object]:
    from mrs_bridge.drivers.wavefront import PARAMS, WavefrontDriver

    cfg = parse_config(
        '[[driver]]\nname = "wavefront"\nprovides = ["r0:planner:0"]\n'
        'requires = ["output::r0:position2d:1", "input::r0:position2d:2", "r0:map:0"]\n',
        source="wavefront.toml",
    ).drivers[0]
    drv = WavefrontDriver(cfg, None)
    d = {k: getattr(drv, k) for k in PARAMS}
    d["angle_epsilon"] = math.degrees(d["angle_epsilon"])
    return d


def local_defaults(name: str) -> dict[str, object]:
    from mrs_bridge.drivers.localplanner import NDDriver, SNDDriver, VFHDriver

    algo = {"vfh": VFHDriver, "nd": NDDriver, "snd": SNDDriver}[name].algorithm
    return {k: (p.default if p.same_as is None else ("=", p.same_as, p.factor)) for k, p in algo.PARAMS.items()}


DEFAULTS = {
    "amcl": amcl_defaults,
    "wavefront": wavefront_defaults,
    "vfh": lambda: local_defaults("vfh"),
    "nd": lambda: local_defaults("nd"),
    "snd": lambda: local_defaults("snd"),
}


@pytest.mark.parametrize("page", [NAV, CONF], ids=["navigation.md", "configuration.md"])
def test_parameter_tables_match_the_code(page):
    tables = param_tables(page)
    assert set(tables) == set(DEFAULTS), f"{page.name}: parameter tables for {sorted(tables)}"
    for driver, table in tables.items():
        code = DEFAULTS[driver]()
        assert set(table) == set(code), f"{page.name} {driver}: documented {sorted(table)} vs code {sorted(code)}"
        for name, default in code.items():
            cell = table[name]
            if isinstance(default, tuple) and default[:1] == ("=",):
                scale = "" if len(default) < 3 or default[2] == 1 else f"{default[2]:g} x "
                assert cell == f"= {scale}`{default[1]}`", f"{page.name} {driver}.{name}: {cell!r}"
            elif isinstance(default, bool):
                assert cell == f"`{str(default).lower()}`", f"{page.name} {driver}.{name}: {cell!r}"
            elif isinstance(default, int | float | tuple) and cell.startswith("`"):
                want = list(default) if isinstance(default, tuple) else [default]
                assert numbers(cell) == pytest.approx(want, rel=5e-3), f"{page.name} {driver}.{name}: {cell!r}"
            else:  # derived at run time (None in the code): the page says from what, not a number
                assert default is None and not cell.startswith("`"), f"{page.name} {driver}.{name}: {cell!r}"


def test_both_pages_show_the_same_tables():
    assert param_tables(NAV) == param_tables(CONF)


# ---------------------------------------------------------------------------- (c) rsal sim --nav
def test_the_documented_simulation_with_navigation_is_what_rsal_sim_runs():
    from mrs_bridge.cli import sim_config
    from simulator.loader import load_world
    from simulator.world import World

    path, block, _ = next(b for b in toml_blocks(CONF) if b[0] == "deploy/testroom-nav.toml")
    doc = load(path, block)
    gen = sim_config(World(load_world(MAPS / "testroom.world")), nav="vfh")

    def shape(cfg):
        out = []
        for d in cfg.drivers:
            params = {k: list(v) if isinstance(v, list | tuple) else v for k, v in d.params.items()}
            out.append((d.name, [str(a) for a in d.provides], [str(r) for r in d.requires], params))
        return out

    for (dn, dp, dr, dpar), (gn, gp, gr, gpar) in zip(shape(doc), shape(gen), strict=True):
        assert (dn, dp, dr) == (gn, gp, gr)
        if dn == "simulation":  # the file names its world; rsal sim hands the loaded world over
            continue
        assert set(dpar) == set(gpar), dn
        for k, v in gpar.items():
            assert dpar[k] == (pytest.approx(v, abs=1e-3) if not isinstance(v, str) else v), (dn, k)


# ---------------------------------------------------------------------------- (d) config errors
def documented_errors() -> list[str]:
    page = text(NAV)
    block = page[page.rindex("```text\nrsal serve:") :]
    return [ln for ln in block.split("```")[1].splitlines() if ln.startswith("rsal serve:")]


def test_documented_config_errors_are_the_drivers():
    path, block, _ = next(b for b in NAV_BLOCKS if b[0] == "deploy/r0-nav.toml")
    broken = [
        block.replace("safety_dist = 0.15", "safety_distance = 0.15"),
        block.replace("max_speed = 0.4 ", "max_speed = 9 "),
        block.replace('"r0:laser:0", "laser::map:0"', '"laser::map:0"'),  # amcl without its laser
    ]
    errors = documented_errors()
    assert len(errors) == len(broken)
    for b, line in zip(broken, errors, strict=True):
        assert b != block
        with pytest.raises(ConfigError) as e:
            start(load(path, b))
        assert f"rsal serve: {e.value}" == line


# ---------------------------------------------------------------------------- (e) the Python example
def doc_example() -> str:
    page = text(NAV)
    m = re.compile(r"```python\n(.*?)```", re.S).search(page, page.index(EXAMPLE_MARKER))
    assert m is not None, "docs/navigation.md: no ```python block after the example marker"
    return m.group(1)


def test_example_compiles_and_uses_only_rsal():
    tree = ast.parse(doc_example())
    compile(tree, "nav_goto.py", "exec")
    top = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            top |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            top.add((node.module or "").split(".")[0])
    assert top - STDLIB_OK == {"rsal"}


def invalid_goal_rows() -> dict[tuple[float, float], str]:
    """The exact messages of the "Invalid goals" table that carry real coordinates."""
    page = text(NAV)
    table = page[page.index("### Invalid goals") : page.index("### Other errors")]
    out = {}
    for msg in re.findall(r"\| `(goal \(([-\d.]+), ([-\d.]+)\) is (?:outside|inside an obstacle)[^`]*)` \|", table):
        out[(float(msg[1]), float(msg[2]))] = msg[0]
    return out


@pytest.fixture(scope="module")
def nav_server():
    port = free_port()
    world = str(MAPS / "testroom.world")
    proc = Proc(rsal_cmd("sim", world, "--nav", "vfh", "--speedup", "2", "--listen", f"tcp/127.0.0.1:{port}"))
    try:
        yield proc, port
    finally:
        proc.close()


def test_example_drives_r0_to_its_goal(nav_server, tmp_path):
    proc, port = nav_server
    script = tmp_path / "nav_goto.py"
    script.write_text(doc_example(), encoding="utf-8")
    goal = (1.0, -2.0, 0.0)
    args = [*(f"{v:g}" for v in goal), "--connect", f"tcp/127.0.0.1:{port}", "--timeout", "25"]
    out = subprocess.run(
        [sys.executable, str(script), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stdout + out.stderr + proc.output()[-2000:]
    m = re.fullmatch(r"done: r0 at \((\S+), (\S+), (\S+) deg\)\n", out.stdout)
    assert m, out.stdout
    x, y, yaw = float(m[1]), float(m[2]), float(m[3])
    # wavefront's tolerances in rsal sim --nav: 0.4 m and 10 degrees (the pose moves on a little after)
    assert math.hypot(x - goal[0], y - goal[1]) < 0.5 and abs(yaw - goal[2]) < 15, out.stdout
    assert proc.alive()


def test_documented_invalid_goals_are_refused_with_their_messages(nav_server, fabric_factory):
    from rsal.data import Position
    from rsal.msgs import ErrorCode, RpcError

    _, port = nav_server
    rows = invalid_goal_rows()
    assert len(rows) >= 2
    fab = fabric_factory(port)
    fab.node("r0:planner:0").wait_for("r0:planner:0", timeout=30)
    planner = fab.device("r0:planner:0")

    def refused(goal):
        fut = planner.set_goal(Position(*goal, 0.0))
        err = fut.exception(timeout=5) if fut.done() else None
        return err if isinstance(err, RpcError) and err.code != ErrorCode.UNAVAILABLE else None

    cli = re.search(r"\$ rsal goto r0 2\.5 0\n(rsal goto: .*)\n", text(NAV))
    assert cli, "the rsal goto example line"
    for goal, message in rows.items():
        err = wait_until(lambda goal=goal: refused(goal), 30, f"the planner to refuse {goal}", interval=0.2)
        assert err.code == ErrorCode.NOT_FOUND and err.message == f"invalid goal: {message}", err.message
        if goal == (2.5, 0.0):
            assert f"rsal goto: r0:planner:0: {err}" == cli[1]
