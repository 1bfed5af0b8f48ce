"""The secured profile (deploy/secure/make-profile.sh, a wrapper of ``rsal secure``): TLS to
``rsal router``, a password per identity and access-control rules on the router. With ``rsal sim``
joined as the robot host ``simhost`` (nodes ``sim`` and ``r0``), the operator ``fleet`` and the
viewer ``viewer`` the script makes:

- a peer without credentials, with a wrong password or without TLS cannot connect;
- an authenticated viewer sees the robots (tokens, odometry, ``describe``) but cannot drive one: its
  velocity commands have no effect while odometry keeps arriving, and its ``set_velocity`` rpc gets
  no reply;
- the operator works as before: rpc answered, the same command moves the robot.

Skipped with the reason when openssl is missing. Every wait has a deadline.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import threading

import pytest
import zenoh

from rsal.keys import cmd_key, data_key, parse_device, rpc_key
from rsal.msgs import Position2dData, VelocityCmd, decode, encode
from rsal.transport import TransportArgs, open_session
from tests.conftest import MAPS, ROOT, free_port, rsal_cmd, wait_until

SCRIPT = ROOT / "deploy" / "secure" / "make-profile.sh"
BASE = parse_device("r0:position2d:0")

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make certificates")


def _client_config(port: int, *, ca: str | None, user: str | None = None, password: str | None = None, proto="tls"):
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", json.dumps([f"{proto}/127.0.0.1:{port}"]))
    if ca:
        c.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(ca))
    if user:
        c.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
    return c


@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    """A profile, the router and ``rsal sim`` as a fleet member; yields (profile dir, port)."""
    from tests.conftest import Proc

    out = tmp_path_factory.mktemp("profile")
    port = free_port()
    subprocess.run([str(SCRIPT), str(out), "127.0.0.1", str(port)], check=True, capture_output=True, timeout=60)
    subprocess.run(
        rsal_cmd("secure", "add-robot", "simhost", "--nodes", "sim,r0", "--dir", str(out)), check=True, timeout=60
    )
    router = Proc(rsal_cmd("router", "--config", str(out / "router.json5")))
    sim = Proc(rsal_cmd("sim", str(MAPS / "testroom.world"), "--config", str(out / "members" / "simhost.json5")))
    try:
        yield out, port, router, sim
    finally:
        sim.close()
        router.close()


class Odometry:
    """Counts r0's odometry messages as a session receives them."""

    def __init__(self, session):
        self.lock = threading.Lock()
        self.msgs: list[Position2dData] = []
        self.sub = session.declare_subscriber(data_key(BASE), self._on)

    def _on(self, sample) -> None:
        m = decode(Position2dData, sample.payload.to_bytes())
        with self.lock:
            self.msgs.append(m)

    @property
    def count(self) -> int:
        with self.lock:
            return len(self.msgs)

    @property
    def last(self) -> Position2dData:
        with self.lock:
            return self.msgs[-1]


def _travel(a: Position2dData, b: Position2dData) -> float:
    return math.hypot(b.pose[0] - a.pose[0], b.pose[1] - a.pose[1]) + abs(b.pose[2] - a.pose[2])


def test_without_credentials_or_tls_nobody_connects(secured):
    out, port, router, _ = secured
    wait_until(lambda: "routing on" in router.output(), 30, "the router to listen")
    ca = str(out / "ca.pem")
    for what, conf in (
        ("no credentials", _client_config(port, ca=ca)),
        ("a wrong password", _client_config(port, ca=ca, user="fleet", password="not-the-password")),
        ("an unknown user", _client_config(port, ca=ca, user="intruder", password="x")),
        ("plain TCP", _client_config(port, ca=None, proto="tcp")),
    ):
        with pytest.raises(zenoh.ZError):
            s = zenoh.open(conf)
            s.close()
            pytest.fail(f"a client with {what} could connect")


def test_a_viewer_watches_but_cannot_drive_and_the_fleet_can(secured):
    out, _, router, sim = secured
    viewer = open_session(TransportArgs(config=str(out / "members" / "viewer.json5")))
    fleet = open_session(TransportArgs(config=str(out / "members" / "fleet.json5")))
    try:
        seen = Odometry(viewer)
        wait_until(lambda: seen.count >= 3, 60, "the viewer to receive r0's odometry through the router")
        tokens = [str(r.ok.key_expr) for r in viewer.liveliness().get("rsal/r0/**", timeout=5.0) if r.ok]
        assert "rsal/r0/position2d/0" in tokens

        # The viewer commands a turn on the spot for 20 odometry messages: nothing moves.
        start, n0 = seen.last, seen.count
        turn = encode(VelocityCmd(0.3, 0.8))
        for _ in range(200):
            viewer.put(cmd_key(BASE), turn)
            if seen.count >= n0 + 20:
                break
            wait_until(lambda n=seen.count: seen.count > n, 10, "odometry to keep arriving at the viewer")
        assert seen.count >= n0 + 20
        assert _travel(start, seen.last) < 1e-3, "a viewer's command moved the robot"

        replies = list(viewer.get(rpc_key(BASE, "set_velocity"), payload=turn, timeout=2.0))
        assert [r for r in replies if r.ok] == [], "a viewer's rpc was answered"
        assert [r for r in viewer.get(rpc_key(BASE, "describe"), timeout=5.0) if r.ok], "a viewer cannot describe"

        # The fleet's rpc is answered and the same command moves the robot.
        answered = [r for r in fleet.get(rpc_key(BASE, "describe"), timeout=5.0) if r.ok]
        assert answered, "the fleet's rpc got no reply"
        start = seen.last

        def moved() -> bool:
            fleet.put(cmd_key(BASE), turn)
            return _travel(start, seen.last) > 0.05

        wait_until(moved, 20, "the fleet's command to move r0", interval=0.1)
        fleet.put(cmd_key(BASE), encode(VelocityCmd(0.0, 0.0)))
        assert router.alive() and sim.alive(), sim.output()
    finally:
        viewer.close()
        fleet.close()


def test_a_viewer_may_press_the_emergency_stop_and_only_the_fleet_releases_it(secured):
    from rsal.estop import estop

    out, _, router, sim = secured
    viewer = open_session(TransportArgs(config=str(out / "members" / "viewer.json5")))
    fleet = open_session(TransportArgs(config=str(out / "members" / "fleet.json5")))
    try:
        seen = Odometry(viewer)
        wait_until(lambda: seen.count >= 3, 60, "the viewer to receive r0's odometry through the router")
        turn = encode(VelocityCmd(0.3, 0.8))
        start = seen.last

        def moved() -> bool:
            fleet.put(cmd_key(BASE), turn)
            return _travel(start, seen.last) > 0.05

        wait_until(moved, 20, "the fleet's command to move r0", interval=0.1)
        pressed = wait_until(lambda: estop(viewer).robots, 20, "the viewer's emergency stop to be confirmed")
        assert pressed == ["r0"]
        assert estop(viewer, release=True).robots == [], "a viewer released the emergency stop"
        wait_until(lambda: seen.last.estop, 10, "r0 to report estop")
        start, n0 = seen.last, seen.count
        while seen.count < n0 + 10:  # the fleet commands on: r0 stays where it is
            fleet.put(cmd_key(BASE), turn)
            wait_until(lambda n=seen.count: seen.count > n, 10, "odometry to keep arriving")
        assert _travel(start, seen.last) < 1e-3, "a latched base moved"
        assert estop(fleet, release=True).robots == ["r0"]
        start = seen.last
        wait_until(moved, 20, "r0 to move again after the fleet's release", interval=0.1)
        fleet.put(cmd_key(BASE), encode(VelocityCmd(0.0, 0.0)))
        assert router.alive() and sim.alive(), sim.output()
    finally:
        viewer.close()
        fleet.close()
