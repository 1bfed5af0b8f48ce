"""docs/simulator.md is true: every world example loads, every error and warning shown is the real
one, the Python examples run, the command lines work, and the maps table matches maps/maps.yaml.

Examples are marked in the Markdown source by an HTML comment on the line before their fence:

* ``<!-- check: load FILE models=a,b [warnings] -->``: the block is written to FILE and loaded with
  :func:`simulator.load_world`; the model names must be exactly ``a,b`` in order. Without
  ``warnings`` it must load cleanly; with it, the next ``text`` block lists the warnings.
* ``<!-- check: file FILE -->``: the block is written to FILE (an include for later examples).
* ``<!-- check: error FILE -->``: loading FILE must fail with the message of the next ``text`` block.
* ``<!-- check: run -->``: a ``python`` block, executed from the repository root.
* ``<!-- check: cli-error -->``: a ``console`` block ``$ command`` / output line; the command must
  exit 1 printing exactly that line on stderr.

Every ``yaml``, ``stage`` and ``python`` block must carry a marker. All world examples share one
directory that stands in for ``maps/``: the shipped bitmaps are linked into it, and includes are
found in ``maps/include/`` as for any world. Every command in a ``sh`` block is run: simulator runs
with ``--duration`` cut to 0.5 s, ``rsal sim`` until its devices are up (on a free loopback port),
``--help`` as is, and ``maps/generate.py`` on a copy whose output must equal the shipped files.
"""

from __future__ import annotations

import re
import shlex
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

# Submodules, not the package: under pytest, tests/simulator/ can shadow the package's __init__.
from simulator.errors import WorldFileError
from simulator.loader import load_world
from simulator.world import World
from tests.conftest import ROOT, Proc, free_port, wait_until

DOC = ROOT / "docs" / "simulator.md"
MAPS = ROOT / "maps"
BIN = Path(sys.executable).parent

_FENCE = re.compile(r"^```(\S*)\s*$")
_MARK = re.compile(r"^<!--\s*check:\s*(.*?)\s*-->$")


@dataclass
class Block:
    lang: str
    text: str
    line: int  # of the opening fence, 1-based
    mark: str | None  # the check marker right before the fence, if any

    @property
    def where(self) -> str:
        return f"docs/simulator.md:{self.line}"


def blocks() -> list[Block]:
    out: list[Block] = []
    lines = DOC.read_text().splitlines()
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        start = i
        j = i + 1
        while j < len(lines) and lines[j] != "```":
            j += 1
        assert j < len(lines), f"docs/simulator.md:{start + 1}: fence never closed"
        k = start - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        mm = _MARK.match(lines[k].strip()) if k >= 0 else None
        out.append(Block(m.group(1), "\n".join(lines[start + 1 : j]) + "\n", start + 1, mm.group(1) if mm else None))
        i = j + 1
    return out


BLOCKS = blocks()


def _following_text(b: Block) -> str:
    i = BLOCKS.index(b)
    nxt = BLOCKS[i + 1] if i + 1 < len(BLOCKS) else None
    assert nxt is not None and nxt.lang == "text", f"{b.where}: expected a ```text block after this example"
    return nxt.text.strip()


# ------------------------------------------------------------------------------ world examples
def test_every_world_and_python_example_is_marked():
    for b in BLOCKS:
        if b.lang in ("yaml", "stage", "python"):
            assert b.mark, f"{b.where}: ```{b.lang} block without a <!-- check: ... --> marker"
        if b.mark:
            assert b.mark.split()[0] in ("load", "file", "error", "run", "cli-error"), f"{b.where}: {b.mark!r}"
    kinds = [b.mark.split()[0] for b in BLOCKS if b.mark]
    assert kinds.count("load") >= 6 and kinds.count("error") >= 3 and kinds.count("run") >= 2


@pytest.fixture
def example_dir(tmp_path, monkeypatch) -> Path:
    """A directory standing in for maps/: the shipped bitmaps, no world files."""
    d = tmp_path / "maps"
    d.mkdir()
    for png in MAPS.glob("*.png"):
        (d / png.name).symlink_to(png)
    monkeypatch.chdir(d)  # examples load by relative name, so messages read "file.world:3: ..."
    monkeypatch.delenv("STAGEPATH", raising=False)
    return d


def test_world_examples_load_as_documented(example_dir):
    checked = 0
    for b in BLOCKS:
        if not b.mark or b.mark.split()[0] not in ("load", "file", "error"):
            continue
        words = b.mark.split()
        kind, name = words[0], words[1]
        assert b.lang in ("stage", "yaml"), f"{b.where}: a {kind} marker on a ```{b.lang} block"
        assert (name.endswith((".world", ".inc")) and b.lang == "stage") or (
            name.endswith((".yaml", ".yml")) and b.lang == "yaml"
        ), f"{b.where}: {name} does not match the block's language {b.lang}"
        (example_dir / name).write_text(b.text)
        if kind == "file":
            continue
        checked += 1
        if kind == "error":
            with pytest.raises(WorldFileError) as ei:
                load_world(name)
            assert str(ei.value) == _following_text(b), b.where
            continue
        opts = dict(w.split("=", 1) for w in words[2:] if "=" in w)
        spec = load_world(name)
        assert [m.name for m in spec.models] == opts["models"].split(","), b.where
        if "warnings" in words:
            assert "\n".join(spec.warnings) == _following_text(b), b.where
        else:
            assert spec.warnings == [], f"{b.where}: unexpected warnings {spec.warnings}"
        world = World(spec)  # the bitmap loads and the world steps
        world.step()
    assert checked >= 9


def test_documented_details_of_the_examples(example_dir):
    """Facts the prose states about the examples above."""
    for b in BLOCKS:
        if b.mark and b.mark.split()[0] in ("load", "file"):
            (example_dir / b.mark.split()[1]).write_text(b.text)
    scouts = load_world("scouts.world")
    assert scouts.seed == 7 and scouts.interval_sim == pytest.approx(0.05) and scouts.speedup == float("inf")
    s0, s1 = scouts.model("s0"), scouts.model("s1")
    assert [(r.kind, len(r.sensors)) for r in s0.rangers] == [("sonar", 8), ("laser", 1)]
    assert s0.rangers[1].sensors[0].samples == 1080 and s0.rangers[1].interval == pytest.approx(0.05)
    assert s1.odom_error == (0, 0, 0) and s1.odom_noise == (0, 0, 0)
    old = load_world("stage3.world")
    assert old.speedup == pytest.approx(2.0)
    r = old.model("old0")
    assert [(x.kind, len(x.sensors)) for x in r.rangers] == [("laser", 1), ("sonar", 2)]
    assert r.rangers[0].sensors[0].samples == 361 and r.rangers[0].sensors[0].range_max == 8
    bf = r.blobfinders[0]
    assert bf.colors == [(255, 0, 0)] and bf.fov == pytest.approx(1.0471975511965976) and bf.range_max == 5
    fp = load_world("mapfile.world").floorplan
    assert fp.resolution == 0.05 and fp.origin == (-31.475, -7.8)
    room = load_world("room.yaml")
    assert room.model("r1").color == (0, 0, 255) and room.model("r1").rangers[1].kind == "sonar"
    assert [x.name for x in room.model("r0").rangers] == ["sonar", "laser"]


def test_python_examples_run():
    """Each in a fresh interpreter in the repository root, as a user would run it."""
    out = []
    for b in BLOCKS:
        if b.mark == "run":
            assert b.lang == "python", b.where
            p = subprocess.run([sys.executable, "-c", b.text], cwd=ROOT, capture_output=True, text=True, timeout=180)
            assert p.returncode == 0, f"{b.where}:\n{p.stderr}"
            out.append(p.stdout)
    assert len(out) >= 3
    assert "['blob0']" in "".join(out)


# ------------------------------------------------------------------------------ tables
def test_maps_table_matches_maps_yaml():
    text = DOC.read_text()
    maps = yaml.safe_load((MAPS / "maps.yaml").read_text())["maps"]
    for name, m in maps.items():
        row = next((ln for ln in text.splitlines() if ln.startswith(f"| `{name}` | `{m['image']}`")), None)
        assert row is not None, f"no row for {name} in the maps table"
        cells = [c.strip() for c in row.strip("|").split("|")]
        w, h = m["size_px"]
        sx, sy = m["size_m"]
        assert cells[2] == f"{w} x {h}"
        assert float(cells[3]) == m["resolution"]
        assert cells[4] == f"{sx:g} x {sy:g}"
        assert cells[5] == f"({m['origin'][0]}, {m['origin'][1]})"
        world = load_world(MAPS / f"{name}.world")
        assert world.floorplan.resolution == pytest.approx(m["resolution"])
        assert world.floorplan.origin == pytest.approx(tuple(m["origin"]))
        for robot in world.robots():
            assert f"`{robot.name}`" in cells[6], f"{name}: robot {robot.name} not in the maps table"


def test_laser_preset_table_matches_the_presets():
    import math

    from simulator.presets import urg04lx, utm30lx

    text = DOC.read_text()
    for f in (urg04lx, utm30lx):
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| `{f.__name__}` |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        s = f().sensors[0]
        assert float(cells[2]) == pytest.approx(math.degrees(s.fov))
        assert int(cells[3]) == s.samples
        assert float(cells[4]) == pytest.approx(math.degrees(s.fov) / (s.samples - 1), abs=5e-4)
        lo, hi = (float(x) for x in cells[5].split(".."))
        assert (lo, hi) == (s.range_min, s.range_max) and float(cells[6]) == s.noise


# ------------------------------------------------------------------------------ command lines
def _commands() -> list[tuple[Block, list[str]]]:
    out = []
    for b in BLOCKS:
        if b.lang != "sh":
            continue
        for line in b.text.splitlines():
            args = shlex.split(line, comments=True)
            if args:
                out.append((b, args))
    return out


def _executable(args: list[str]) -> list[str]:
    head = args[0]
    if head in ("python", ".venv/bin/python"):
        return [sys.executable, *args[1:]]
    if head in ("rsal", "rsal-simulate"):
        return [str(BIN / head), *args[1:]]
    raise AssertionError(f"the doc shows a command this test does not know how to run: {shlex.join(args)}")


def _short(args: list[str]) -> list[str]:
    """A simulator run cut to 0.5 simulated seconds."""
    out = list(args)
    if "--duration" in out:
        out[out.index("--duration") + 1] = "0.5"
    else:
        out += ["--duration", "0.5"]
    return out


COMMANDS = _commands()


def test_the_doc_shows_each_kind_of_command():
    shown = {shlex.join(a[:3]) for _, a in COMMANDS}
    assert any(s.startswith("python -m simulator") for s in shown)
    assert any(s.startswith("rsal-simulate") for s in shown)
    assert any(s.startswith("rsal sim") for s in shown)
    assert any(s.startswith("python maps/generate.py") for s in shown)


@pytest.mark.parametrize("args", [a for _, a in COMMANDS], ids=[shlex.join(a) for _, a in COMMANDS])
def test_command_lines_run(args, tmp_path, procs):
    argv = _executable(args)
    if args[:2] == ["python", "maps/generate.py"]:
        (tmp_path / "maps").mkdir()
        shutil.copy(MAPS / "generate.py", tmp_path / "maps" / "generate.py")
        p = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert p.returncode == 0, p.stderr
        for f in ("floor.png", "arena.png", "hall.png", "testroom.png", "maps.yaml", "hall.yaml"):
            assert (tmp_path / "maps" / f).read_bytes() == (MAPS / f).read_bytes(), f"{f} differs from generate.py"
        return
    if "--help" in args:
        p = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert p.returncode == 0 and p.stdout.startswith("usage:"), p.stderr
        return
    if args[:2] == ["rsal", "sim"]:
        # Never the default port 7447: a free loopback port of this test's own.
        assert not {"--listen", "-l", "--connect", "-e", "--config", "-c"} & set(args), "transport flags in the doc"
        proc: Proc = procs([*argv, "--listen", f"tcp/127.0.0.1:{free_port()}"])
        wait_until(lambda: "device(s) up" in proc.output() or not proc.alive(), 90, "rsal sim to serve its devices")
        assert proc.alive(), proc.output()
        proc.signal(signal.SIGINT)
        assert proc.p.wait(30) == 0, proc.output()
        assert "[sim] summary:" in proc.output()
        return
    # python -m simulator / rsal-simulate
    p = subprocess.run(_short(argv), cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert p.returncode == 0, p.stderr
    assert "[sim] summary: robots=" in p.stdout, p.stdout


def test_cli_error_examples():
    seen = 0
    for b in BLOCKS:
        if b.mark != "cli-error":
            continue
        lines = b.text.strip().splitlines()
        assert lines[0].startswith("$ "), b.where
        argv = _executable(shlex.split(lines[0][2:]))
        p = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert p.returncode == 1, b.where
        assert p.stderr.strip() == "\n".join(lines[1:]).strip(), b.where
        seen += 1
    assert seen >= 1
