"""Multi-process integration: a robot stops when its controller dies (command timeout), and a latched
emergency stop overrides every commander. Verdicts come from the simulator's ground truth
(``sim:simulation:0`` ``rpc/get_pose``), sampled on the wall clock. The tests of r0's base alone
share one simulator (fixture ``sim``: r0 reset to a fresh simulator's state before each); the tests of
several commanders, or of another world, start their own.
"""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import time

import pytest

from rsal.client import Fabric
from rsal.data import Position
from rsal.msgs import ErrorCode, RpcError
from rsal.transport import TransportArgs
from tests.conftest import MAPS, Proc, free_port, rsal_cmd, wait_until

WORLD = str(MAPS / "testroom.world")
CMD_TIMEOUT = 0.5  # the bases' default

# A controller that keeps commanding: puts a velocity at 10 Hz on every robot named, refreshing it
# itself (hold=False), until killed.
DRIVER = """
import sys, time
from rsal.client import Fabric
from rsal.transport import TransportArgs
fab = Fabric.connect(TransportArgs(connect=[sys.argv[1]]))
bases = [fab.device(f"{r}:position2d:0") for r in sys.argv[3].split(",")]
v, w = float(sys.argv[2]), 0.6
print("driving", flush=True)
while True:
    for b in bases:
        b.set_velocity(v, w, hold=False)
    time.sleep(0.1)
"""


def true_pose(fab, name: str) -> tuple[float, float, float]:
    return tuple(fab.device("sim:simulation:0").rpc("get_pose", name=name)["pose"])


def moved(a, b, eps: float = 1e-4) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) > eps or abs(a[2] - b[2]) > eps


def moving(fab, names, window: float = 0.25) -> dict[str, bool]:
    """Whether each robot's true pose changes over ``window`` s of wall time (two simulation steps)."""
    before = {n: true_pose(fab, n) for n in names}
    time.sleep(window)
    return {n: moved(before[n], true_pose(fab, n)) for n in names}


def stop_time(fab, name: str, t0: float, horizon: float = 2.0, period: float = 0.02) -> float:
    """Seconds after ``t0`` of the last change of ``name``'s true pose seen within ``horizon`` s
    (sampled every ``period`` s); the robot did not move after that."""
    last = true_pose(fab, name)
    last_change = t0
    while time.monotonic() - t0 < horizon:
        p = true_pose(fab, name)
        if moved(p, last):
            last_change = time.monotonic()
        last = p
        time.sleep(period)
    return last_change - t0


@pytest.fixture(scope="module")
def sim_server():
    """One ``rsal sim testroom.world`` for the module's tests of r0's base (started and stopped here
    by PID): its port, a client fabric and r0's true start pose."""
    port = free_port()
    proc = Proc(rsal_cmd("sim", WORLD, "--listen", f"tcp/127.0.0.1:{port}"))
    fab = None
    try:
        fab = Fabric.connect(TransportArgs(connect=[f"tcp/127.0.0.1:{port}"]))
        fab.node("r0:*:*").wait_for("r0:position2d:0", timeout=30)
        fab.node("sim:*:*").wait_for("sim:simulation:0", timeout=30)
        yield port, fab, true_pose(fab, "r0")
    finally:
        if fab is not None:
            fab.close()
        proc.close()


@pytest.fixture
def sim(sim_server):
    """The shared simulator with r0 as a fresh one has it (the reset): emergency stop released,
    motors on, stopped, at its start pose and standing still (ground truth)."""
    _, fab, (x, y, a) = sim_server
    pos = fab.device("r0:position2d:0")
    pos.release_estop()
    assert pos.set_motor_power(True) is True
    pos.stop()
    fab.device("sim:simulation:0").set_pose("r0", Position(x, y, a))
    wait_until(lambda: not moving(fab, ["r0"])["r0"], 5, "r0 to stand still after the reset")
    assert math.hypot(true_pose(fab, "r0")[0] - x, true_pose(fab, "r0")[1] - y) < 0.01
    return fab


@pytest.fixture
def sim_port(sim_server) -> int:
    return sim_server[0]


def start_driver(procs, port, robots: str = "r0", v: float = 0.3):
    p = procs([sys.executable, "-c", DRIVER, f"tcp/127.0.0.1:{port}", str(v), robots])
    wait_until(lambda: "driving" in p.output(), 30, "the commanding process to start")
    return p


def test_a_robot_stops_when_its_commanding_process_is_killed(sim, procs, sim_port):
    fab = sim
    driver = start_driver(procs, sim_port)
    wait_until(lambda: moving(fab, ["r0"])["r0"], 10, "r0 to move (ground truth)")
    pos = fab.device("r0:position2d:0")
    assert not pos.wait_for_data(5).timed_out
    t0 = time.monotonic()
    driver.signal(signal.SIGKILL)
    latency = stop_time(fab, "r0", t0)
    print(f"deadman: r0 stopped {latency:.2f} s after its controller was killed (cmd_timeout {CMD_TIMEOUT} s)")
    assert latency <= CMD_TIMEOUT + 0.3
    wait_until(lambda: pos.latest is not None and pos.latest.timed_out, 2, "the data to say timed_out")
    # the next command clears the flag and moves it again
    pos.set_velocity(0.2, 0.0)
    wait_until(lambda: not pos.latest.timed_out, 2, "timed_out to clear with the next command")
    wait_until(lambda: moving(fab, ["r0"])["r0"], 5, "r0 to move again")
    pos.stop()


def test_a_velocity_set_once_holds_while_its_client_lives(sim):
    fab = sim
    pos = fab.device("r0:position2d:0")
    pos.set_velocity(0.0, 0.4)  # once: the fabric refreshes it
    wait_until(lambda: moving(fab, ["r0"])["r0"], 10, "r0 to turn")
    time.sleep(3 * CMD_TIMEOUT)  # several timeouts long: a held command must not time out
    assert moving(fab, ["r0"])["r0"] and not pos.latest.timed_out
    pos.stop()
    wait_until(lambda: not moving(fab, ["r0"])["r0"], 3, "r0 to stop")


def test_cmd_timeout_zero_is_refused_when_negative(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(
        f'[[driver]]\nname = "simulation"\nprovides = ["sim:simulation:0"]\nworldfile = "{WORLD}"\n\n'
        '[[driver]]\nname = "sim"\nmodel = "r0"\nprovides = ["r0:position2d:0"]\ncmd_timeout = -1\n'
    )
    r = subprocess.run(
        rsal_cmd("serve", str(cfg), "--listen", "tcp/127.0.0.1:0"), capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 1
    assert "cmd_timeout = -1 must be a number of seconds >= 0" in r.stderr and "Traceback" not in r.stderr


def test_velocity_rpc_while_latched_is_a_typed_error(sim):
    fab = sim
    pos = fab.device("r0:position2d:0")
    assert pos.estop() == {"ok": True, "estop": True}
    with pytest.raises(RpcError) as e:
        pos.rpc("set_velocity", v=0.2, w=0.0)
    assert e.value.code == ErrorCode.ESTOP and "rsal estop r0 --release" in e.value.message
    wait_until(lambda: pos.latest is not None and pos.latest.estop, 2, "the data to say estop")
    pos.release_estop()
    assert pos.rpc("set_velocity", v=0.2, w=0.0) == {"ok": True}
    wait_until(lambda: moving(fab, ["r0"])["r0"], 5, "r0 to move after the release")
    pos.stop()


def estop_cli(port, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        rsal_cmd("estop", *args, "--connect", f"tcp/127.0.0.1:{port}"), capture_output=True, text=True, timeout=60
    )


def test_estop_all_stops_every_robot_while_their_controllers_keep_commanding(procs, port, fabric_factory):
    from rsal.estop import estop

    procs(rsal_cmd("sim", str(MAPS / "arena.world"), "--listen", f"tcp/127.0.0.1:{port}"))
    fab = fabric_factory(port)
    node = fab.node("*:position2d:0", "sim:simulation:0")
    node.wait_for("sim:simulation:0", timeout=30)
    names = fab.device("sim:simulation:0").rpc("models")["robots"]
    assert len(names) >= 3
    node.wait_for("*:position2d:0", count=len(names), timeout=30)
    start_driver(procs, port, ",".join(names), v=0.2)
    wait_until(lambda: all(moving(fab, names).values()), 10, "every robot to move (ground truth)")

    # the fabric-wide query, timed from the moment it is sent
    t0 = time.monotonic()
    res = estop(fab.session)
    confirmed = time.monotonic() - t0  # every base answered: each had stopped its robot before answering
    assert sorted(res.robots) == sorted(names) and not res.failed, res
    latency = max(confirmed, *(stop_time(fab, n, t0, horizon=1.5) for n in names))
    print(
        f"estop --all: {len(names)} robots confirmed in {confirmed:.3f} s, no true pose changed after {latency:.3f} s"
    )
    assert latency <= 0.5
    assert not any(moving(fab, names).values())  # still commanded, still stopped
    bases = [fab.device(f"{n}:position2d:0") for n in names]
    wait_until(lambda: all(b.latest is not None and b.latest.estop for b in bases), 2, "every base to report estop")

    # the same from a shell
    r = estop_cli(port, "--all", "--release")
    assert r.returncode == 0 and r.stdout.startswith("released: ") and all(n in r.stdout for n in names), r.stderr
    wait_until(lambda: all(moving(fab, names).values()), 5, "the robots to move again after the release")
    r = estop_cli(port, "--all")
    assert r.returncode == 0 and r.stdout.startswith("latched: ") and all(n in r.stdout for n in names), r.stderr
    assert not any(moving(fab, names).values())
    assert estop_cli(port, "--all", "--release").returncode == 0
    wait_until(lambda: all(moving(fab, names).values()), 5, "the robots to move again")

    # one robot: only that one stops
    r = estop_cli(port, names[0])
    assert r.returncode == 0 and r.stdout.strip() == f"latched: {names[0]} (position2d:0)", r.stdout + r.stderr
    m = moving(fab, names)
    assert not m[names[0]] and all(m[n] for n in names[1:]), m
    assert estop_cli(port, names[0], "--release").returncode == 0


def test_estop_overrides_the_worlds_own_wander_controller(procs, port, fabric_factory):
    world = MAPS.parent / "tests" / "simulator" / "fixtures" / "stage" / "stage4" / "wander.world"
    procs(rsal_cmd("sim", str(world), "--listen", f"tcp/127.0.0.1:{port}"))
    fab = fabric_factory(port)
    node = fab.node("w0:position2d:0", "sim:simulation:0")
    node.wait_for("sim:simulation:0", timeout=30)
    node.wait_for("w0:position2d:0", timeout=30)
    names = ["w0", "w1"]
    wait_until(lambda: all(moving(fab, names).values()), 10, "the wander controller to move the robots")
    base = fab.device("w0:position2d:0")
    assert base.rpc("estop")["estop"] is True
    wait_until(lambda: not moving(fab, ["w0"])["w0"], 2, "w0 to stop (ground truth)")
    for _ in range(3):  # the controller keeps commanding every scan; the latch wins each time
        m = moving(fab, names)
        assert not m["w0"] and m["w1"], m
    assert base.rpc("release")["estop"] is False
    wait_until(lambda: moving(fab, ["w0"])["w0"], 5, "w0 to wander again after the release")


def test_estop_cli_errors_are_one_line(port):
    r = estop_cli(port, "--wait", "1", "nobody")
    assert r.returncode == 1 and "no base of nobody answered" in r.stderr and "Traceback" not in r.stderr
    r = estop_cli(port)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "--all" in r.stderr


def test_motor_power_from_the_client(sim):
    fab = sim
    pos = fab.device("r0:position2d:0")
    assert pos.set_motor_power(False) is False
    pos.set_velocity(0.0, 0.5)
    assert not moving(fab, ["r0"])["r0"]  # motors off: commands are ignored
    assert pos.set_motor_power(True) is True
    wait_until(lambda: moving(fab, ["r0"])["r0"], 5, "r0 to turn with its motors on (the held command)")
    pos.stop()
