"""docs/configuration.md: every TOML example loads, and every bad example fails as the page says.

Each ```toml block on the page is preceded by a marker: ``<!-- config: PATH -->`` (a working
configuration meant to live at PATH in the repository, so its relative paths resolve from there) or
``<!-- bad-config: PATH -->`` (a broken one, followed by a ```text block with the line
``rsal serve`` prints for it). Working blocks are parsed with :mod:`mrs_bridge.config` and started
by a :class:`~mrs_bridge.server.DeviceServer` over an in-memory fake session, which creates every
driver (loading maps and worlds) without a network. Broken blocks run through the real
``rsal serve`` on a free loopback port, all at once (fixture ``refusals``); its stderr must be exactly
the documented line.
"""

from __future__ import annotations

import re
import subprocess
import time
from dataclasses import dataclass

import pytest

import mrs_bridge.drivers  # noqa: F401  (registers the built-in drivers)
from mrs_bridge.cli import sim_config
from mrs_bridge.config import parse_config
from mrs_bridge.server import DeviceServer
from rsal.testing import FakeSession
from tests.conftest import MAPS, ROOT, free_port, rsal_cmd

DOC = ROOT / "docs" / "configuration.md"
BLOCK = re.compile(r"^```toml\n(.*?)^```\n", re.S | re.M)
MARKER = re.compile(r"<!-- (config|bad-config): (\S+) -->\n$")
TEXT = re.compile(r"```text\n(.*?)```\n", re.S)


@dataclass
class Example:
    kind: str  # "config" or "bad-config"
    path: str  # where the file would live, relative to the repository root
    toml: str
    line: int  # line of the ```toml fence in the page
    error: str = ""  # the documented error line of a bad example

    @property
    def id(self) -> str:
        return f"{self.kind}@{self.line}"


def examples() -> list[Example]:
    text = DOC.read_text(encoding="utf-8")
    out = []
    for m in BLOCK.finditer(text):
        line = text.count("\n", 0, m.start()) + 1
        before = text[: m.start()]
        mk = MARKER.search(before[before.rfind("<!--", 0, len(before)) :]) if "<!--" in before else None
        if mk is None:
            out.append(Example("unmarked", "", m[1], line))
            continue
        ex = Example(mk[1], mk[2], m[1], line)
        if ex.kind == "bad-config":
            t = TEXT.match(text, m.end())
            ex.error = t[1].strip() if t else ""
        out.append(ex)
    return out


EXAMPLES = examples()
GOOD = [e for e in EXAMPLES if e.kind == "config"]
BAD = [e for e in EXAMPLES if e.kind == "bad-config"]


def load(ex: Example):
    return parse_config(ex.toml, source=ex.path, base_dir=(ROOT / ex.path).parent)


def test_every_toml_block_is_marked():
    assert [e.line for e in EXAMPLES if e.kind == "unmarked"] == []
    assert len(GOOD) >= 5 and len(BAD) >= 10
    assert all(e.error.startswith("rsal serve: ") and "\n" not in e.error for e in BAD)


@pytest.mark.parametrize("ex", GOOD, ids=lambda e: e.path)
def test_documented_config_loads_and_its_drivers_start(ex):
    cfg = load(ex)
    session = FakeSession(silent=True)  # no other server: required devices never appear
    server = DeviceServer(cfg, session)  # type: ignore[arg-type]
    try:
        server.start()
        assert len(server.slots) == len(cfg.drivers)
        # Tokens come once a driver has run its first update (ready means ready): a short while of
        # scheduling, then every driver that needs nothing from the fabric has announced its devices.
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not all(
            s.announced for s in server.slots if not s.driver.cfg.requires and s.state == "running"
        ):
            server.run(until=time.monotonic() + 0.05)
        for slot in server.slots:
            want = {f"rsal/{a.path}" for a in slot.driver.cfg.provides}
            if slot.driver.cfg.requires:  # waits for its devices on the fabric
                assert slot.state == "waiting" and not want & set(session.tokens)
            else:
                assert slot.state == "running" and want <= set(session.tokens), slot.name
    finally:
        server.close()


def test_rsal_sim_runs_the_documented_config():
    from simulator.loader import load_world
    from simulator.world import World

    doc = load(next(e for e in GOOD if e.path == "deploy/testroom-sim.toml"))
    gen = sim_config(World(load_world(MAPS / "testroom.world")))

    def shape(cfg):
        return [(d.name, [str(a) for a in d.provides], d.params.get("model")) for d in cfg.drivers]

    assert shape(doc) == shape(gen)


@pytest.fixture(scope="module")
def refusals(tmp_path_factory) -> dict[str, subprocess.CompletedProcess]:
    """Every bad example through the real ``rsal serve`` at once, each in a folder of its own on a
    free loopback port (independent refusals: started together, one process start-up's wait instead
    of one per example); the tests below read each one's result. Stopped by PID if still running."""
    started: dict[str, subprocess.Popen] = {}
    try:
        for ex in BAD:
            d = tmp_path_factory.mktemp("bad-config")
            f = d / ex.path
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(ex.toml, encoding="utf-8")
            started[ex.id] = subprocess.Popen(
                rsal_cmd("serve", ex.path, "--listen", f"tcp/127.0.0.1:{free_port()}"),
                cwd=d,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                start_new_session=True,
            )
        deadline = time.monotonic() + 120
        done = {}
        for name, p in started.items():
            out, err = p.communicate(timeout=max(1.0, deadline - time.monotonic()))
            done[name] = subprocess.CompletedProcess(p.args, p.returncode, out, err)
        return done
    finally:
        for p in started.values():
            if p.poll() is None:
                p.kill()
                p.wait(5)


@pytest.mark.parametrize("ex", BAD, ids=lambda e: e.id)
def test_bad_config_fails_with_the_documented_line(ex, refusals):
    out = refusals[ex.id]
    assert out.returncode == 1, out.stdout + out.stderr
    assert out.stderr.strip() == ex.error
    assert "[serve]" not in out.stdout  # it never started serving


def test_a_documented_bad_example_is_really_rejected_in_process():
    """The same errors come from mrs_bridge.config + DeviceServer, the library the CLI uses."""
    for ex in BAD:
        with pytest.raises(ValueError) as ei:
            cfg = load(ex)
            server = DeviceServer(cfg, FakeSession())  # type: ignore[arg-type]
            try:
                server.start()
            finally:
                server.close()
        msg = ex.error.removeprefix("rsal serve: ")
        assert str(ei.value) == msg, ex.id
