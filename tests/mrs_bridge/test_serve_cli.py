"""``rsal serve CONFIG`` as a real process: a bad configuration is one line naming the place and
exit 1 without a traceback; a good one with a replay laser is found by ``rsal ls``."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import pytest

from tests.conftest import rsal_cmd, wait_until

RSAL_SCRIPT = Path(sys.executable).with_name("rsal")


def rsal(*args: str) -> list[str]:
    """The installed console script (what a user types), or ``python -m rsal.cli`` without one."""
    return [str(RSAL_SCRIPT), *args] if RSAL_SCRIPT.exists() else rsal_cmd(*args)


def finish(proc, timeout: float = 20.0) -> tuple[int, str]:
    proc.p.wait(timeout)
    return proc.p.returncode, proc.output()


REPLAY_LASER = """\
[server]
node = "r0"

[[driver]]
name = "replay"
provides = ["laser:0"]
rate = 20
samples = 181
fov = 180
"""

BAD = {
    "not_toml": ('[server\nnode = "r0"\n', "{path}: not valid TOML: "),
    "unknown_driver": (
        REPLAY_LASER.replace('name = "replay"', 'name = "replya"'),
        "{path}: driver #1 (replya): unknown driver 'replya'; did you mean 'replay'?",
    ),
    "bad_parameter": (
        REPLAY_LASER + "fov_deg = 90\n",
        "{path}: driver #1 (replay): unknown parameter 'fov_deg'; did you mean 'fov'?",
    ),
    "bad_device": (
        REPLAY_LASER.replace('"laser:0"', '"laser"'),
        "{path}: driver #1 (replay): provides: device 'laser'",
    ),
    "duplicate": (
        REPLAY_LASER + '\n[[driver]]\nname = "replay"\nprovides = ["r0:laser:0"]\n',
        "{path}: driver #2 (replay): device r0:laser:0 is already provided by {path}: driver #1 (replay)",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_config_is_one_line_and_exit_1(case, tmp_path, procs, port):
    text, expected = BAD[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(text)
    code, out = finish(procs(rsal("serve", str(path), "--listen", f"tcp/127.0.0.1:{port}")))
    lines = out.strip().splitlines()
    assert code == 1, out
    assert len(lines) == 1, out
    assert lines[0].startswith("rsal serve: " + expected.format(path=path)), out
    assert "Traceback" not in out


def test_a_missing_config_file(tmp_path, procs, port):
    path = tmp_path / "nowhere.toml"
    code, out = finish(procs(rsal("serve", str(path), "--listen", f"tcp/127.0.0.1:{port}")))
    assert (code, out.strip()) == (1, f"rsal serve: {path}: no such configuration file")


def test_a_served_replay_laser_is_listed_by_rsal_ls(tmp_path, procs, port):
    cfg = tmp_path / "laser.toml"
    cfg.write_text(REPLAY_LASER)
    endpoint = f"tcp/127.0.0.1:{port}"
    server = procs(rsal("serve", str(cfg), "--listen", endpoint))
    wait_until(lambda: "device(s) up" in server.output() or not server.alive(), 20, "the server to start")
    assert server.alive(), server.output()
    assert f"[serve] {cfg}: 1 driver(s), 1 device(s) up" in server.output()

    code, out = finish(procs(rsal("ls", "--connect", endpoint)))
    assert code == 0, out
    rows = [line.split() for line in out.strip().splitlines()]
    assert rows[0] == ["NODE", "INTERFACE", "INDEX", "DRIVER", "RATE"]
    assert ["r0", "laser", "0", "replay", "20", "Hz"] in rows[1:]

    code, out = finish(procs(rsal("ls", "*:laser:*", "--connect", endpoint)))
    assert code == 0 and "replay" in out, out

    code, out = finish(procs(rsal("ls", "r9:*:*", "--connect", endpoint, "--wait", "0.5")))
    assert code == 1
    assert out.strip().splitlines()[-1].startswith("rsal ls: no devices match 'r9:*:*'")

    server.signal(signal.SIGTERM)
    code, out = finish(server)
    assert code == 0, out
    assert "Traceback" not in out
