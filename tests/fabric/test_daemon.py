"""The per-robot daemons (deploy/systemd/rsal-serve@.service; rsal-host.service below): its ExecStart line, run the way
systemd runs it (the instance's env file substituted, the install path replaced by this checkout),
serves the configured devices; SIGTERM, the unit's KillSignal, withdraws them and exits 0 within the
unit's TimeoutStopSec. The example env file only names files and flags that exist."""

from __future__ import annotations

import configparser
import shlex
import signal
import sys
import time

from rsal.transport import TransportArgs, open_session
from tests.conftest import ROOT, Proc, free_port, wait_until

UNIT = ROOT / "deploy" / "systemd" / "rsal-serve@.service"
ENV = ROOT / "deploy" / "systemd" / "r0.env"
INSTALL = "/opt/rsal-fabric"

REPLAY = """\
[server]
node = "r0"

[[driver]]
name = "replay"
provides = ["laser:0"]
rate = 10
"""


def unit() -> configparser.ConfigParser:
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str
    cp.read(UNIT)
    return cp


def env_file(path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            k, _, v = line.partition("=")
            out[k] = v
    return out


def expand(cmd: str, env: dict[str, str]) -> list[str]:
    """systemd's rule: ``$VAR`` expands to the variable's words, ``${VAR}`` to one word."""
    words = []
    for w in shlex.split(cmd):
        if w.startswith("$") and not w.startswith("${"):
            words += shlex.split(env.get(w[1:], ""))
        else:
            words.append(w)
    return words


def test_the_unit_names_what_the_daemon_needs():
    svc = unit()["Service"]
    assert svc["KillSignal"] == "SIGTERM" and svc["Restart"] == "on-failure"
    assert svc["EnvironmentFile"] == "/etc/rsal/%i.env"
    assert svc["ExecStart"].startswith(f"{INSTALL}/.venv/bin/rsal serve $RSAL_CONFIG")
    env = env_file(ENV)
    assert set(env) == {"RSAL_CONFIG", "RSAL_ARGS"}
    assert (ROOT / "deploy" / env["RSAL_CONFIG"].rsplit("/", 1)[-1]).exists(), "the example config is in deploy/"


def test_exec_start_serves_and_sigterm_withdraws_within_the_stop_timeout(tmp_path):
    svc = unit()["Service"]
    cfg = tmp_path / "r0.toml"
    cfg.write_text(REPLAY)
    port = free_port()
    env = {"RSAL_CONFIG": str(cfg), "RSAL_ARGS": f"--listen tcp/127.0.0.1:{port}"}
    argv = expand(svc["ExecStart"], env)
    assert argv[0] == f"{INSTALL}/.venv/bin/rsal"
    argv = [sys.executable, "-m", "rsal.cli", *argv[1:]]  # this checkout instead of the install path
    _start_then_sigterm(svc, argv, port, "rsal/r0/**", ["rsal/r0/laser/0"], "the daemon's laser token")


def _start_then_sigterm(svc, argv: list[str], port: int, selector: str, want: list[str], what: str) -> None:
    """Start the unit's command, wait for its liveliness tokens (``want`` under ``selector``), send
    the unit's KillSignal: the process exits 0 within TimeoutStopSec, the tokens go, no traceback."""
    proc = Proc(argv)
    session = open_session(TransportArgs(connect=[f"tcp/127.0.0.1:{port}"]))
    try:

        def tokens() -> list[str]:
            return [str(r.ok.key_expr) for r in session.liveliness().get(selector, timeout=1.0) if r.ok]

        wait_until(lambda: tokens() == want, 30, what)
        t0 = time.monotonic()
        proc.signal(getattr(signal, svc["KillSignal"]))
        stop_timeout = float(svc["TimeoutStopSec"])
        wait_until(lambda: not proc.alive(), stop_timeout, "the daemon to exit within TimeoutStopSec")
        assert proc.p.returncode == 0, proc.output()
        assert time.monotonic() - t0 < stop_timeout
        wait_until(lambda: tokens() == [], 5, "the token to be withdrawn")
        assert "Traceback" not in proc.output()
    finally:
        session.close()
        proc.close()


HOST_UNIT = ROOT / "deploy" / "systemd" / "rsal-host.service"
HOST_ENV = ROOT / "deploy" / "systemd" / "host.env"


def test_the_host_daemon_unit_announces_the_host_and_sigterm_withdraws_it(tmp_path):
    """deploy/systemd/rsal-host.service with its example env file and the example host.toml (this
    checkout's copy): the daemon's token hosts/r0 appears; SIGTERM withdraws it, exit 0 in time."""
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str
    cp.read(HOST_UNIT)
    svc = cp["Service"]
    assert svc["KillSignal"] == "SIGTERM" and svc["Restart"] == "on-failure"
    assert svc["EnvironmentFile"] == "/etc/rsal/host.env"
    env = env_file(HOST_ENV)
    assert set(env) == {"RSAL_HOST_CONFIG", "RSAL_ARGS"}
    example = ROOT / "deploy" / "systemd" / env["RSAL_HOST_CONFIG"].rsplit("/", 1)[-1]
    assert example.exists(), "the example host configuration is in deploy/systemd/"
    port = free_port()
    argv = expand(svc["ExecStart"], {"RSAL_HOST_CONFIG": str(example), "RSAL_ARGS": f"--listen tcp/127.0.0.1:{port}"})
    assert argv[0] == f"{INSTALL}/.venv/bin/rsal" and argv[1] == "host"
    argv = [sys.executable, "-m", "rsal.cli", *argv[1:]]
    _start_then_sigterm(svc, argv, port, "hosts/*", ["hosts/r0"], "the host daemon's token")
