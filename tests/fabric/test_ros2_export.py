"""Multi-process integration of ``rsal ros2`` (docs/ros2.md): ``rsal sim`` + ``rsal ros2`` as real
processes on loopback, and stock Zenoh sessions playing the ROS 2 peer. The LaserScan is decoded
by a second CDR decoder written here with ``struct`` (not the library the exporter encodes with);
the Twist test judges r0 by the simulator's ground truth (``sim:simulation:0`` ``rpc/get_pose``).
"""

from __future__ import annotations

import math
import struct
import threading
import time

import numpy as np
import pytest
import zenoh

from mrs_bridge.ros2.wire import Attachment, Entity, Kind
from tests.conftest import MAPS, Proc, free_port, rsal_cmd, wait_until

WORLD = str(MAPS / "testroom.world")
SCAN_HASH = "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828"
TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
SCAN_KEY = f"0/r0/scan/sensor_msgs::msg::dds_::LaserScan_/{SCAN_HASH}"
TWIST_TYPE = "geometry_msgs::msg::dds_::Twist_"


def stock_session(port: int) -> zenoh.Session:
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
    cfg.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(cfg)


def decode_laser_scan(b: bytes) -> dict:
    """sensor_msgs/msg/LaserScan from CDR little-endian, by hand: alignment counts from the byte
    after the 4-byte encapsulation header."""
    assert b[:4] == b"\x00\x01\x00\x00", "CDR little-endian encapsulation"
    body = b[4:]
    o = 0

    def align(n):
        nonlocal o
        o += (-o) % n

    def take(fmt, size):
        nonlocal o
        align(size)
        v = struct.unpack_from("<" + fmt, body, o)
        o += struct.calcsize("<" + fmt)
        return v

    sec, nsec = take("iI", 4)
    (n,) = take("I", 4)
    frame = body[o : o + n - 1].decode()
    assert body[o + n - 1] == 0, "frame_id ends with NUL"
    o += n
    a0, a1, da, dt, st, r0, r1 = take("7f", 4)
    (k,) = take("I", 4)
    ranges = np.frombuffer(body, "<f4", k, o)
    o += 4 * k
    (ki,) = take("I", 4)
    o += 4 * ki
    assert o == len(body), "no trailing bytes"
    return dict(
        t=sec + nsec * 1e-9,
        frame=frame,
        angle_min=a0,
        angle_max=a1,
        angle_increment=da,
        scan_time=st,
        range_min=r0,
        range_max=r1,
        ranges=ranges,
    )


@pytest.fixture(scope="module")
def fleet():
    from rsal.client import Fabric
    from rsal.transport import TransportArgs

    port = free_port()
    started = [Proc(rsal_cmd("sim", WORLD, "--listen", f"tcp/127.0.0.1:{port}"))]
    fab = None
    try:
        started.append(Proc(rsal_cmd("ros2", "--connect", f"tcp/127.0.0.1:{port}")))
        fab = Fabric.connect(TransportArgs(connect=[f"tcp/127.0.0.1:{port}"]))
        fab.node("r0:*:*").wait_for("r0:laser:0", timeout=30)
        fab.node("sim:*:*").wait_for("sim:simulation:0", timeout=30)
        exp = started[1]
        wait_until(
            lambda: "r0 (scan sonar_0..7 odom tf cmd_vel); fleet: /map /clock" in exp.output() or not exp.alive(),
            30,
            "rsal ros2 to export r0, the map and the clock",
        )
        assert exp.alive(), exp.output()
        yield port, fab, exp
    finally:
        if fab is not None:
            fab.close()
        for p in reversed(started):
            p.close()


def test_a_stock_subscriber_on_the_exact_key_receives_laser_scans(fleet):
    port, fab, _ = fleet
    laser = fab.device("r0:laser:0")
    sensor = laser.describe().geometry["sensors"][0]
    rsal_scans: dict[float, np.ndarray] = {}
    laser.add_listener(lambda m: rsal_scans.__setitem__(round(m.t, 6), np.array(m.ranges)), inline=True)
    got: list[tuple[bytes, bytes | None]] = []
    lock = threading.Lock()

    def on_sample(s):
        with lock:
            got.append((s.payload.to_bytes(), None if s.attachment is None else s.attachment.to_bytes()))

    with stock_session(port) as s, s.declare_subscriber(SCAN_KEY, on_sample):
        wait_until(lambda: len(got) >= 5, 15, "five LaserScans on " + SCAN_KEY)
    with lock:
        samples = list(got)
    seqs = []
    for payload, att in samples:
        a = Attachment.from_bytes(att)  # 33 bytes, GID length 16
        seqs.append(a.sequence)
        assert abs(a.timestamp_ns / 1e9 - time.time()) < 60
        m = decode_laser_scan(payload)
        assert m["frame"] == "r0/laser"
        assert len(m["ranges"]) == sensor["samples"]
        assert m["angle_min"] == pytest.approx(-sensor["fov"] / 2, abs=1e-5)
        assert m["angle_max"] - m["angle_min"] == pytest.approx(sensor["fov"], abs=1e-4)
        assert m["angle_increment"] == pytest.approx(sensor["fov"] / (sensor["samples"] - 1), rel=1e-4)
        assert (m["range_min"], m["range_max"]) == pytest.approx((sensor["range_min"], sensor["range_max"]), rel=1e-6)
        assert m["scan_time"] == pytest.approx(0.1, rel=1e-3)
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), f"sequence numbers must grow: {seqs}"
    # the very ranges the RSAL laser published with the same stamp
    m = decode_laser_scan(samples[-1][0])
    same = rsal_scans.get(round(m["t"], 6))
    assert same is not None, "an RSAL scan with the ROS scan's stamp"
    np.testing.assert_array_equal(m["ranges"], same)


def test_graph_tokens_show_the_node_its_publishers_and_subscription(fleet):
    port, _, _ = fleet
    want = {
        (Kind.NODE, "", ""),
        (Kind.PUBLISHER, "/r0/scan", "sensor_msgs::msg::dds_::LaserScan_"),
        (Kind.PUBLISHER, "/r0/odom", "nav_msgs::msg::dds_::Odometry_"),
        (Kind.PUBLISHER, "/tf", "tf2_msgs::msg::dds_::TFMessage_"),
        (Kind.PUBLISHER, "/tf_static", "tf2_msgs::msg::dds_::TFMessage_"),
        (Kind.SUBSCRIPTION, "/r0/cmd_vel", TWIST_TYPE),
        *((Kind.PUBLISHER, f"/r0/sonar_{k}", "sensor_msgs::msg::dds_::Range_") for k in range(8)),
    }
    seen: list = []
    with stock_session(port) as s:

        def graph():  # a new session sees the exporter's tokens once its routes are in
            seen[:] = [Entity.parse(str(r.ok.key_expr)) for r in s.liveliness().get("@ros2_lv/0/**", timeout=2)]
            return {(e.kind, e.topic, e.type) for e in seen if e.namespace == "/r0" and e.node == "rsal"} == want

        wait_until(graph, 15, "r0's node, publishers and subscription in the graph", interval=0.2)
    ents = list(seen)
    scan = next(e for e in ents if e.topic == "/r0/scan")
    assert scan.type_hash == SCAN_HASH and scan.qos.reliability == 2 and scan.qos.depth == 5
    grid = next(e for e in ents if e.topic == "/map")
    assert (grid.kind, grid.namespace, grid.node) == (Kind.PUBLISHER, "/", "rsal")
    assert (grid.qos.reliability, grid.qos.durability, grid.qos.depth) == (1, 1, 1)  # transient local
    assert str(grid.token).endswith("/:1:,1:,:,:,,")


def true_pose(fab) -> tuple[float, float, float]:
    return tuple(fab.device("sim:simulation:0").rpc("get_pose", name="r0")["pose"])


def moved(a, b, eps: float = 1e-4) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) > eps or abs(a[2] - b[2]) > eps


def still(fab, window: float = 0.3) -> bool:
    """r0's true pose does not change over ``window`` s of wall time (three simulation steps)."""
    a = true_pose(fab)
    time.sleep(window)
    return not moved(a, true_pose(fab))


def twist_cdr(v: float, w: float, vy: float = 0.0) -> bytes:
    return b"\x00\x01\x00\x00" + struct.pack("<6d", v, vy, 0.0, 0.0, 0.0, w)


@pytest.mark.parametrize(
    ("type_hash", "w", "vy"),
    [(TWIST_HASH, 0.8, 0.0), ("TypeHashNotSupported", 50.0, 0.2)],
    ids=["jazzy", "humble-over-the-limits"],
)
def test_a_twist_on_cmd_vel_moves_r0_and_r0_stops_when_the_twists_stop(fleet, type_hash, w, vy):
    """A Twist over the base's max_speed is clipped and its sideways speed dropped, not refused."""
    port, fab, exp = fleet
    key = f"0/r0/cmd_vel/{TWIST_TYPE}/{type_hash}"
    gid = bytes(range(16))
    with stock_session(port) as s:
        seq = 0

        def put_for(seconds: float) -> None:
            nonlocal seq
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                seq += 1
                s.put(key, twist_cdr(0.0, w, vy), attachment=Attachment(seq, time.time_ns(), gid).to_bytes())
                time.sleep(0.1)  # the commander's own 10 Hz rate, as teleop_twist_keyboard's

        start = true_pose(fab)
        put_for(1.5)
        turned = true_pose(fab)
        assert abs(math.remainder(turned[2] - start[2], math.tau)) > 0.3, f"r0 turned: {start} -> {turned}"
    # no more Twists: the server's command timeout (0.5 s) stops r0
    t0 = time.monotonic()
    last, settled = true_pose(fab), None
    while time.monotonic() - t0 < 3.0:
        time.sleep(0.1)
        p = true_pose(fab)
        if moved(p, last):
            settled = None
        elif settled is None:
            settled = time.monotonic() - t0
        last = p
    assert settled is not None and settled < 1.5, f"r0 still moving {time.monotonic() - t0:.1f} s after the last Twist"
    if vy:
        assert "over the base's max_speed" in exp.output() and "linear.y 0.2 m/s ignored" in exp.output()


def test_a_twist_without_the_attachment_or_with_another_hash_is_dropped(fleet):
    port, fab, exp = fleet
    with stock_session(port) as s:
        start = true_pose(fab)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            s.put(f"0/r0/cmd_vel/{TWIST_TYPE}/{TWIST_HASH}", twist_cdr(0.0, 0.8))  # no attachment
            s.put(
                f"0/r0/cmd_vel/{TWIST_TYPE}/RIHS01_{'0' * 64}",
                twist_cdr(0.0, 0.8),
                attachment=Attachment(1, time.time_ns(), bytes(16)).to_bytes(),
            )
            time.sleep(0.1)
        assert not moved(start, true_pose(fab), eps=1e-3)
    wait_until(lambda: "attachment must be 33 bytes" in exp.output(), 5, "the exporter to log the dropped Twist")
    assert "is not RIHS01_9c45" in exp.output()


def r0_entities(port: int) -> set[tuple[Kind, str]]:
    with stock_session(port) as s:
        ents = [Entity.parse(str(r.ok.key_expr)) for r in s.liveliness().get("@ros2_lv/0/**", timeout=3)]
    return {(e.kind, e.topic) for e in ents if e.namespace == "/r0"}


def test_robots_that_join_are_exported_and_robots_that_leave_take_their_topics(procs):
    sim_port, exp_port = free_port(), free_port()
    exp = procs(
        rsal_cmd(
            "ros2", "--connect", f"tcp/127.0.0.1:{sim_port}", "--listen", f"tcp/127.0.0.1:{exp_port}", "--robots", "r0"
        )
    )
    wait_until(lambda: "looking for robots matching r0" in exp.output(), 30, "rsal ros2 to start")
    assert r0_entities(exp_port) == set()
    sim = procs(rsal_cmd("sim", WORLD, "--listen", f"tcp/127.0.0.1:{sim_port}"))
    wait_until(
        lambda: "r0 (scan sonar_0..7 odom tf cmd_vel)" in exp.output(), 60, "r0 exported once the simulator runs"
    )
    wait_until(lambda: (Kind.SUBSCRIPTION, "/r0/cmd_vel") in r0_entities(exp_port), 10, "r0's graph tokens")
    sim.stop()
    wait_until(lambda: "0 robot(s) exported: none yet" in exp.output(), 30, "r0 withdrawn when its server stops")
    wait_until(lambda: r0_entities(exp_port) == set(), 10, "r0's graph tokens to go")
    assert exp.alive(), exp.output()


def pose_stamped_cdr(frame: str, x: float, y: float, yaw: float) -> bytes:
    """geometry_msgs/msg/PoseStamped by hand: stamp, frame_id, then 7 float64 aligned on 8."""
    f = frame.encode() + b"\x00"
    body = struct.pack("<iII", 0, 0, len(f)) + f
    body += b"\x00" * ((-len(body)) % 8)
    body += struct.pack("<7d", x, y, 0.0, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    return b"\x00\x01\x00\x00" + body


def decode_pose_with_covariance_stamped(b: bytes) -> tuple[str, tuple[float, float, float], np.ndarray]:
    body = b[4:]
    (n,) = struct.unpack_from("<I", body, 8)
    frame = body[12 : 12 + n - 1].decode()
    o = 12 + n
    o += (-o) % 8
    x, y, _, qx, qy, qz, qw = struct.unpack_from("<7d", body, o)
    cov = np.frombuffer(body, "<f8", 36, o + 56).reshape(6, 6)
    assert o + 56 + 288 == len(body)
    return frame, (x, y, math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))), cov


@pytest.fixture
def nav_fleet(procs):
    from rsal.client import Fabric
    from rsal.transport import TransportArgs

    port = free_port()
    procs(rsal_cmd("sim", WORLD, "--nav", "vfh", "--listen", f"tcp/127.0.0.1:{port}"))
    exp = procs(rsal_cmd("ros2", "--connect", f"tcp/127.0.0.1:{port}"))
    fab = Fabric.connect(TransportArgs(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        fab.node("sim:*:*").wait_for("sim:simulation:0", timeout=30)
        wait_until(
            lambda: "r0 (scan sonar_0..7 odom tf cmd_vel amcl_pose goal_pose plan)" in exp.output(),
            60,
            "rsal ros2 to export r0 with its navigation stack",
        )
        yield port, fab
    finally:
        fab.close()


def test_amcl_pose_follows_the_robot_and_goal_pose_drives_it_there_with_a_plan(nav_fleet):
    from mrs_bridge.ros2 import types

    port, fab = nav_fleet
    amcl_key = "0/r0/amcl_pose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/" + types.type_hash(
        "geometry_msgs/msg/PoseWithCovarianceStamped"
    )
    plan_key = "0/r0/plan/nav_msgs::msg::dds_::Path_/" + types.type_hash("nav_msgs/msg/Path")
    goal_key = "0/r0/goal_pose/geometry_msgs::msg::dds_::PoseStamped_/" + types.type_hash(
        "geometry_msgs/msg/PoseStamped"
    )
    poses, plans = [], []
    goal = (-0.5, -2.0, 0.0)
    with (
        stock_session(port) as s,
        s.declare_subscriber(amcl_key, lambda m: poses.append(m.payload.to_bytes())),
        s.declare_subscriber(plan_key, lambda m: plans.append(m.payload.to_bytes())),
    ):
        wait_until(lambda: poses, 20, "an amcl_pose")
        frame, est, cov = decode_pose_with_covariance_stamped(poses[-1])
        truth = true_pose(fab)
        assert frame == "map" and math.hypot(est[0] - truth[0], est[1] - truth[1]) < 0.5
        assert cov[0, 0] > 0 and cov[1, 1] > 0 and cov[5, 5] > 0 and cov[2, 2] == 0
        s.put(goal_key, pose_stamped_cdr("map", *goal), attachment=Attachment(1, time.time_ns(), bytes(16)).to_bytes())
        wait_until(
            lambda: math.hypot(true_pose(fab)[0] - goal[0], true_pose(fab)[1] - goal[1]) < 0.5,
            60,
            "r0 at the goal_pose (ground truth)",
        )
        wait_until(lambda: plans, 5, "a plan")
    paths = [types.decode(p, "nav_msgs/msg/Path") for p in plans]
    assert all(p.header.frame_id == "map" for p in paths)
    ends = [p.poses[-1].pose.position for p in paths if p.poses]
    assert any(math.hypot(e.x - goal[0], e.y - goal[1]) < 0.3 for e in ends), "a plan that ends at the goal"


def test_the_map_is_published_transient_local_and_a_late_subscriber_gets_it(fleet):
    import zenoh.ext as zext

    from mrs_bridge.ros2 import types

    port, fab, _ = fleet
    grid = fab.device("sim:map:0").get_map()
    key = "0/map/nav_msgs::msg::dds_::OccupancyGrid_/" + types.type_hash("nav_msgs/msg/OccupancyGrid")
    got = []
    # the exporter published the map once, long before this subscriber: the publisher's cache answers
    with stock_session(port) as s:
        sub = zext.declare_advanced_subscriber(
            s, key, lambda m: got.append(m.payload.to_bytes()), history=zext.HistoryConfig(detect_late_publishers=True)
        )
        wait_until(lambda: got, 10, "the map from the publisher's cache")
        sub.undeclare()
    body = got[0][4:]
    (n,) = struct.unpack_from("<I", body, 8)
    assert body[12 : 12 + n - 1] == b"map"
    o = 12 + n
    o += (-o) % 4
    _, _, res, w, h = struct.unpack_from("<iIfII", body, o)
    o += 20
    o += (-o) % 8
    ox, oy = struct.unpack_from("<2d", body, o)
    o += 56
    (k,) = struct.unpack_from("<I", body, o)
    cells = np.frombuffer(body, np.int8, k, o + 4)
    assert (w, h, k) == (grid.width, grid.height, grid.width * grid.height)
    assert res == pytest.approx(grid.resolution) and (ox, oy) == pytest.approx(grid.origin)
    player = np.asarray(grid.cells, dtype=np.int8).reshape(-1)
    assert np.array_equal(cells == 100, player > 0) and np.array_equal(cells == 0, player < 0)
    assert np.array_equal(cells == -1, player == 0) and (cells == 100).any() and (cells == 0).any()


GHOST = """
[server]
node = "ghost"

[[driver]]
name = "ros2"
provides = ["position2d:0", "laser:0"]
namespace = "/r0"
laser_pose = [0.13, 0, 0]
"""


def test_import_loop_sim_export_import_drives_the_simulated_robot(procs, tmp_path):
    """sim -> rsal ros2 (export r0) -> ros2 driver (import /r0 as ghost) -> RSAL client: the
    ghost's laser is r0's laser, and the ghost's velocity commands move r0 (ground truth)."""
    from rsal.client import Fabric
    from rsal.transport import TransportArgs

    port = free_port()
    cfg = tmp_path / "ghost.toml"
    cfg.write_text(GHOST)
    ep = f"tcp/127.0.0.1:{port}"
    procs(rsal_cmd("sim", WORLD, "--listen", ep))
    procs(rsal_cmd("ros2", "--robots", "r0", "--connect", ep))
    procs(rsal_cmd("serve", str(cfg), "--listen", f"tcp/127.0.0.1:{free_port()}", "--connect", ep))
    with Fabric.connect(TransportArgs(connect=[ep])) as fab:
        fab.node("ghost:*:*").wait_for("ghost:*:*", count=2, timeout=60)
        fab.node("sim:*:*").wait_for("sim:simulation:0", timeout=30)
        real, ghost = fab.device("r0:laser:0"), fab.device("ghost:laser:0")
        scans: dict[float, np.ndarray] = {}
        real.add_listener(lambda m: scans.__setitem__(round(m.t, 6), np.array(m.ranges)), inline=True)
        g = ghost.wait_for_data(10)
        wait_until(lambda: round(ghost.latest.t, 6) in scans, 5, "the ghost's scan among r0's")
        g = ghost.latest
        np.testing.assert_array_equal(g.ranges, scans[round(g.t, 6)])
        sensor = real.describe().geometry["sensors"][0]
        gs = ghost.describe().geometry
        assert gs["sensors"][0]["samples"] == sensor["samples"] and gs["pose"][0] == pytest.approx(0.13)
        assert g.angle_min == pytest.approx(-sensor["fov"] / 2, abs=1e-5)

        base = fab.device("ghost:position2d:0")
        start = true_pose(fab)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.5:
            base.set_velocity(0.0, 0.8, hold=False)
            time.sleep(0.1)
        turned = true_pose(fab)
        assert abs(math.remainder(turned[2] - start[2], math.tau)) > 0.3, f"r0 turned: {start} -> {turned}"
        # the ghost's odometry is r0's, through ROS
        odo = base.wait_for_data(5)
        r0odo = fab.device("r0:position2d:0").wait_for_data(5)
        assert abs(math.remainder(odo.pose[2] - r0odo.pose[2], math.tau)) < 0.2
        # commands stop: the ghost's own command timeout reports it, and r0 stops
        wait_until(lambda: base.latest.timed_out, 5, "the ghost base to report its command timeout")
        wait_until(lambda: still(fab), 5, "r0 to stop (ground truth)")


def test_a_recording_becomes_a_rosbag2_bag_that_a_stock_mcap_reader_decodes(procs, tmp_path):
    from mcap.reader import make_reader

    from rsal.client import Fabric
    from rsal.transport import TransportArgs

    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    procs(rsal_cmd("sim", WORLD, "--listen", ep))
    with Fabric.connect(TransportArgs(connect=[ep])) as fab:
        fab.node("r0:*:*").wait_for("r0:position2d:0", timeout=30)
    run = tmp_path / "run.mcap"
    rec = procs(rsal_cmd("record", "r0:*:*", "-o", str(run), "--duration", "2", "--connect", ep))
    wait_until(lambda: not rec.alive(), 60, "rsal record to finish")
    assert rec.p.returncode == 0, rec.output()
    bag = tmp_path / "bag"
    conv = procs(rsal_cmd("rosbag2", str(run), "-o", str(bag)))
    wait_until(lambda: not conv.alive(), 60, "rsal rosbag2 to finish")
    assert conv.p.returncode == 0 and "/r0/scan" in conv.output(), conv.output()
    meta = (bag / "metadata.yaml").read_text()
    assert "storage_identifier: mcap" in meta and "sensor_msgs/msg/LaserScan" in meta
    assert SCAN_HASH in meta  # rosbag2 v9 keeps each topic's type hash
    with open(next(bag.glob("*.mcap")), "rb") as f:
        msgs = list(make_reader(f).iter_messages(topics=["/r0/scan"]))
    assert len(msgs) >= 10
    schema, channel, message = msgs[-1]
    assert (schema.name, schema.encoding, channel.message_encoding) == ("sensor_msgs/msg/LaserScan", "ros2msg", "cdr")
    m = decode_laser_scan(message.data)
    assert m["frame"] == "r0/laser" and len(m["ranges"]) == 682
    assert message.log_time == pytest.approx(m["t"] * 1e9, abs=1e3)  # bag time = the scan's own time
    # a second conversion to the same place is refused with one line
    again = procs(rsal_cmd("rosbag2", str(run), "-o", str(bag)))
    wait_until(lambda: not again.alive(), 60, "rsal rosbag2 to refuse")
    assert again.p.returncode == 1 and "exists; rosbag2 writes a new directory" in again.output()


def test_clock_carries_the_simulation_time_the_stamps_are_in(fleet):
    from mrs_bridge.ros2 import types

    port, fab, _ = fleet
    clock_key = "0/clock/rosgraph_msgs::msg::dds_::Clock_/" + types.type_hash("rosgraph_msgs/msg/Clock")
    ticks: list[float] = []
    with (
        stock_session(port) as s,
        s.declare_subscriber(
            clock_key,
            lambda m: ticks.append(
                sum(x * k for x, k in zip(struct.unpack_from("<iI", m.payload.to_bytes(), 4), (1, 1e-9), strict=True))
            ),
        ),
    ):
        wait_until(lambda: len(ticks) >= 3, 10, "three /clock messages")
    sim_t = fab.device("sim:simulation:0").wait_for_data(5).t
    assert ticks == sorted(ticks) and abs(ticks[-1] - sim_t) < 2.0
    odom_t = fab.device("r0:position2d:0").wait_for_data(5).t
    assert abs(odom_t - sim_t) < 2.0  # the robots' stamps are on the same clock


SERVER_WITH_EXPORT = """
[server]
node = "sim"

[[driver]]
name = "simulation"
provides = ["simulation:0"]
worldfile = "{world}"

[[driver]]
name = "sim"
model = "r0"
provides = ["r0:position2d:0", "r0:laser:0"]

[[driver]]
name = "ros2_export"
robots = ["r0"]
"""


def test_the_exporter_as_a_driver_in_the_robots_own_server(procs, tmp_path):
    from rsal.client import Fabric
    from rsal.transport import TransportArgs

    cfg = tmp_path / "r0-ros2.toml"
    cfg.write_text(SERVER_WITH_EXPORT.format(world=WORLD))
    port = free_port()
    srv = procs(rsal_cmd("serve", str(cfg), "--listen", f"tcp/127.0.0.1:{port}"))
    wait_until(lambda: "r0 (scan odom tf cmd_vel)" in srv.output() or not srv.alive(), 60, "the server to export r0")
    got: list[bytes] = []
    with Fabric.connect(TransportArgs(connect=[f"tcp/127.0.0.1:{port}"])) as fab, stock_session(port) as s:
        with s.declare_subscriber(SCAN_KEY, lambda m: got.append(m.payload.to_bytes())):
            wait_until(lambda: got, 15, "a LaserScan from the server's exporter")
        assert decode_laser_scan(got[-1])["frame"] == "r0/laser"
        start, seq = true_pose(fab), 0
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.5:
            seq += 1
            s.put(
                f"0/r0/cmd_vel/{TWIST_TYPE}/{TWIST_HASH}",
                twist_cdr(0.0, 0.8),
                attachment=Attachment(seq, time.time_ns(), bytes(16)).to_bytes(),
            )
            time.sleep(0.1)
        assert abs(math.remainder(true_pose(fab)[2] - start[2], math.tau)) > 0.3, "r0 turned (ground truth)"


def test_the_sonar_ring_is_one_range_topic_per_transducer(fleet):
    from mrs_bridge.ros2 import types

    port, fab, _ = fleet
    sonar = fab.device("r0:sonar:0")
    fov = sonar.describe().geometry["sensors"][3]["fov"]
    rsal: dict[float, float] = {}
    sonar.add_listener(lambda m: rsal.__setitem__(round(m.t, 6), float(m.ranges[3])), inline=True)
    got: list[bytes] = []
    key = "0/r0/sonar_3/sensor_msgs::msg::dds_::Range_/" + types.type_hash("sensor_msgs/msg/Range")
    with stock_session(port) as s, s.declare_subscriber(key, lambda m: got.append(m.payload.to_bytes())):
        wait_until(lambda: len(got) >= 3, 15, "Range messages of transducer 3")
    body = got[-1][4:]
    sec, nsec, n = struct.unpack_from("<iII", body, 0)
    assert body[12 : 12 + n - 1] == b"r0/sonar_3"
    o = 12 + n
    kind = body[o]
    o += 1
    o += (-o) % 4
    f, lo, hi, r, var = struct.unpack_from("<5f", body, o)
    assert o + 20 == len(body)
    assert kind == 0 and f == pytest.approx(fov, rel=1e-6) and lo <= r <= hi  # ULTRASOUND
    wait_until(lambda: round(sec + nsec * 1e-9, 6) in rsal or len(rsal) > 50, 5, "the RSAL sonar reading")
    assert r == pytest.approx(rsal[round(sec + nsec * 1e-9, 6)], rel=1e-6)


def decode_tf_message(b: bytes) -> list[tuple[str, str, float, float, float]]:
    """tf2_msgs/msg/TFMessage, CDR little-endian, read by hand: (parent, child, x, y, yaw) each."""
    body, o, out = b[4:], 0, []

    def string(o: int) -> tuple[str, int]:
        o += (-o) % 4
        (n,) = struct.unpack_from("<I", body, o)
        return body[o + 4 : o + 4 + n - 1].decode(), o + 4 + n

    (count,) = struct.unpack_from("<I", body, o)
    o += 4
    for _ in range(count):
        o += (-o) % 4 + 8  # stamp: int32 sec, uint32 nanosec
        parent, o = string(o)
        child, o = string(o)
        o += (-o) % 8
        x, y, _z, _qx, _qy, qz, qw = struct.unpack_from("<7d", body, o)
        o += 56
        out.append((parent, child, x, y, 2.0 * math.atan2(qz, qw)))
    return out


def test_sensor_mounts_are_on_tf_static_for_a_late_listener(fleet):
    """``base_link -> laser`` and ``-> sonar_<k>`` go out once on /tf_static, transient local as tf2's
    static broadcaster publishes them; a listener that starts long after gets them from the cache."""
    import zenoh.ext as zext

    from mrs_bridge.ros2 import types

    port, fab, _ = fleet
    mount = fab.device("r0:laser:0").describe().geometry["pose"][:3]
    key = "0/tf_static/tf2_msgs::msg::dds_::TFMessage_/" + types.type_hash("tf2_msgs/msg/TFMessage")
    got: list[bytes] = []
    with stock_session(port) as s:
        sub = zext.declare_advanced_subscriber(
            s, key, lambda m: got.append(m.payload.to_bytes()), history=zext.HistoryConfig(detect_late_publishers=True)
        )
        wait_until(lambda: got, 10, "/tf_static from the publisher's cache")
        sub.undeclare()
    tfs = {(p, c): (x, y, yaw) for p, c, x, y, yaw in decode_tf_message(got[-1])}
    assert tfs[("r0/base_link", "r0/laser")] == pytest.approx(tuple(mount), abs=1e-9)
    assert {c for p, c in tfs if p == "r0/base_link"} == {"r0/laser", *(f"r0/sonar_{k}" for k in range(8))}
