"""The navigation stack on the fabric, multi-process: ``rsal sim WORLD --nav PLANNER`` serves amcl,
a local planner and wavefront per robot; a client in this process (and ``rsal goto``) sends goals.
The simulator runs at ``SPEEDUP_NAV`` (the navigation drivers work on each odometry message, so they
follow it; only they command the base). Each planner's drive gets a simulator of its own; the
invalid goals (which move nothing) and ``rsal goto`` share one ``vfh`` simulator.

Test room (maps/testroom.world): walls at x = ±4.8, y = ±3.8, a box at x 2..3, y -0.5..0.5, r0
starts at (-2, 0, 0).
"""

from __future__ import annotations

import math
import time

import pytest

from tests.conftest import ROOT, SPEEDUP, SPEEDUP_NAV, Proc, free_port, rsal_cmd, wait_until

WORLD = str(ROOT / "maps" / "testroom.world")


def nav_cmd(port: int, planner: str) -> list[str]:
    return rsal_cmd("sim", WORLD, "--nav", planner, "--speedup", SPEEDUP_NAV, "--listen", f"tcp/127.0.0.1:{port}")


def start_nav(procs, port: int, planner: str):
    return procs(nav_cmd(port, planner))


@pytest.fixture(scope="module")
def vfh_port():
    """One ``rsal sim --nav vfh`` for the tests that leave r0 where a goal puts it (or where it is)."""
    port = free_port()
    server = Proc(nav_cmd(port, "vfh"))
    try:
        yield port
    finally:
        server.close()


def nav_robot(fab, timeout: float = 30.0):
    from rsal.robot import NavRobot, robot_devices

    node = fab.node("r0:*:*", "sim:*:*")
    node.wait_for("r0:planner:0", 1, timeout)
    node.wait_for("r0:localize:0", 1, timeout)
    # amcl's two devices (localize:0, position2d:2) are two tokens: wait for both, not the first
    node.wait_for("r0:position2d:*", 3, timeout)
    devs = robot_devices(node, "r0")
    robot = NavRobot(devs)
    sim = fab.device("sim:simulation:0")
    # the planner publishes once the map is in and amcl has a pose
    wait_until(lambda: robot.planner.latest is not None, timeout, "planner data")
    wait_until(
        lambda: robot.localize.latest is not None or robot.planner.latest.pose != (0.0, 0.0, 0.0),
        timeout,
        "a localized pose",
    )
    return robot, sim


@pytest.mark.parametrize("planner", ["vfh", "nd", "snd"])
def test_goto_reaches_the_goal_around_the_box(procs, port, fabric_factory, planner):
    from rsal.data import Position

    server = start_nav(procs, port, planner)
    fab = fabric_factory(port)
    robot, sim = nav_robot(fab)
    # Goal behind the box: the straight line from (-2, 0) to (4, 0) crosses it.
    goal = Position(4.0, 0.0, 0.0)
    fut = robot.goto(goal)
    # the planner publishes its new plan at its own rate (10 Hz of wall time), after the goal's reply
    wait_until(lambda: robot.planner.waypoint_count >= 3 or fut.done(), 5, "a plan around the box (3+ waypoints)")
    try:
        result = fut.result(timeout=90)
    except TimeoutError:
        pytest.fail(f"not done in 90 s: planner {robot.planner.latest}\n{server.output()[-3000:]}")
    assert result == "done"
    truth = sim.get_pose("r0")
    assert math.hypot(truth.x - goal.x, truth.y - goal.y) < 0.6  # wavefront distance_epsilon 0.4 + drift
    est = robot.localize.get_position()
    assert math.hypot(est.x - truth.x, est.y - truth.y) < 0.3, (est, truth)
    assert robot.localized is not None and robot.localized.addr.index == 2  # amcl's position2d, map frame
    pos = robot.position
    assert math.hypot(pos.x - truth.x, pos.y - truth.y) < 0.3, (pos, truth)
    assert server.alive()


def test_invalid_goals_are_reported_at_once(vfh_port, fabric_factory):
    from rsal.data import Position
    from rsal.msgs import ErrorCode, RpcError

    fab = fabric_factory(vfh_port)
    robot, _ = nav_robot(fab)
    for goal, why in ((Position(2.5, 0.0, 0.0), "obstacle"), (Position(30.0, 0.0, 0.0), "outside")):
        t0 = time.monotonic()
        fut = robot.goto(goal)
        with pytest.raises(RpcError) as e:
            fut.result(timeout=5)
        assert time.monotonic() - t0 < 1.0
        assert e.value.code == ErrorCode.NOT_FOUND
        assert why in str(e.value).lower() or "map" in str(e.value).lower(), str(e.value)
    wait_until(lambda: robot.planner.status == "invalid", 2.0, "the planner to report the goal invalid")
    assert "map" in robot.planner.latest.message or "obstacle" in robot.planner.latest.message


def test_localize_takes_known_obstacles_and_names_a_bad_one(vfh_port, fabric_factory):
    from rsal.msgs import ErrorCode, RpcError

    fab = fabric_factory(vfh_port)
    robot, _ = nav_robot(fab)
    assert (
        robot.localize.set_obstacles([(0.0, 1.0, 0.4), (1.0, -1.0, 0.4)], ttl=2.0).result(timeout=5)["obstacles"] == 2
    )
    assert robot.localize.rpc("set_obstacles", obstacles=[])["obstacles"] == 0
    with pytest.raises(RpcError) as e:
        robot.localize.rpc("set_obstacles", obstacles=[[0.0, 1.0, 0.4], [1.0, "near", 0.4]])
    assert e.value.code == ErrorCode.BAD_REQUEST and "obstacles[1]" in str(e.value), str(e.value)
    with pytest.raises(RpcError) as e:
        robot.localize.rpc("set_obstacles", obstacles=[[0.0, 1.0, 0.4]], ttl=0)
    assert e.value.code == ErrorCode.BAD_REQUEST and "ttl" in str(e.value), str(e.value)


def test_localize_takes_known_obstacles_as_a_command(vfh_port, fabric_factory):
    fab = fabric_factory(vfh_port)
    robot, _ = nav_robot(fab)
    loc = robot.localize

    def held():  # describe's geometry, asked afresh (the proxy caches describe)
        return loc.rpc("describe")["geometry"].get("obstacles")

    assert held() == 0
    loc.declare_obstacles([(0.0, 1.0, 0.4), (1.0, -1.0, 0.4)], ttl=30.0)
    wait_until(lambda: held() == 2, 10, "the declared obstacles to be held")
    fab.send(loc.addr, {"obstacles": [[0.0, 1.0, -0.4]]})  # malformed: dropped in the intake with a warning
    loc.declare_obstacles([(2.0, 0.5, 0.4)], ttl=30.0)  # sent after it: replaces them once it arrives
    wait_until(lambda: held() == 1, 10, "the next declaration to replace them")


def test_rsal_goto_command(procs, vfh_port):
    endpoint = f"tcp/127.0.0.1:{vfh_port}"
    bad = procs(rsal_cmd("goto", "r0", "2.5", "0", "--connect", endpoint, "--wait", "30"))
    wait_until(lambda: not bad.alive(), 60, "rsal goto (invalid goal) to exit")
    assert bad.p.returncode == 1
    err = [ln for ln in bad.output().splitlines() if ln.startswith("rsal goto:")]
    assert len(err) == 1 and "Traceback" not in bad.output(), bad.output()
    ok = procs(rsal_cmd("goto", "r0", "-1", "-2", "90", "--connect", endpoint, "--progress", "1"))
    wait_until(lambda: not ok.alive(), 90, "rsal goto to arrive")
    out = ok.output()
    assert ok.p.returncode == 0, out
    assert "[goto] r0:planner:0: done after" in out
    assert out.count("m to go") >= 1


def test_the_stack_in_another_server_reaches_the_goal(procs, port, fabric_factory):
    """``--nav-servers 1`` leaves the stack out of the simulator's server; ``--nav-part 0/1`` runs it
    in a second process that requires r0's devices and the map over the fabric (Player's
    planner_6666.cfg requiring 6665:position2d:0)."""
    from rsal.data import Position

    ep = f"tcp/127.0.0.1:{port}"
    sim = procs(rsal_cmd("sim", WORLD, "--nav", "vfh", "--nav-servers", "1", "--speedup", SPEEDUP, "--listen", ep))
    nav = procs(rsal_cmd("sim", WORLD, "--nav", "vfh", "--nav-part", "0/1", "--connect", ep))
    fab = fabric_factory(port)
    robot, simdev = nav_robot(fab, timeout=60.0)
    wait_until(lambda: "[nav]" in nav.output() and "part 0/1" in nav.output(), 10, "the nav server's banner")
    assert "[serve]" in nav.output() and "robots (r0)" not in nav.output()
    goal = Position(4.0, 0.0, 0.0)
    try:
        assert robot.goto(goal).result(timeout=90) == "done"
    except TimeoutError:
        pytest.fail(f"not done in 90 s: planner {robot.planner.latest}\n{nav.output()[-3000:]}")
    truth = simdev.get_pose("r0")
    assert math.hypot(truth.x - goal.x, truth.y - goal.y) < 0.6
    # the planner was the nav server's: stopping it withdraws r0:planner:0, the simulator runs on
    nav.stop()
    node = fab.node("r0:*:*")
    wait_until(
        lambda: not any(d.interface == "planner" for d in node.devices()), 20, "r0:planner:0 to go with its server"
    )
    assert sim.alive()


def test_nav_part_needs_nav(procs, port):
    p = procs(rsal_cmd("sim", WORLD, "--nav-part", "0/2", "--listen", f"tcp/127.0.0.1:{port}"))
    wait_until(lambda: not p.alive(), 30, "rsal sim to exit")
    assert p.p.returncode == 1 and "--nav" in p.output() and "Traceback" not in p.output()
