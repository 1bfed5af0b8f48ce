"""``rsal watch`` (rsal/watch/): the pure conversions, the latest-wins logger against an in-memory
recording, and the command as a real process against ``rsal sim`` whose ``.rrd`` file is read back."""

from __future__ import annotations

import collections
import math
import signal
import time
from types import SimpleNamespace

import msgpack
import numpy as np
import pytest

from rsal import interfaces
from rsal.interfaces.bumper import BumperData
from rsal.interfaces.fiducial import FiducialData, FiducialItem
from rsal.keys import DeviceAddr
from rsal.msgs import Position2dData, RangerData, encode
from rsal.watch import (
    Watcher,
    WatchOptions,
    beam_layout,
    cov_ellipse,
    draw,
    ellipse_points,
    footprint,
    map_image,
    map_transform,
    scan_to_world,
)
from rsal.watch.convert import RED
from tests.conftest import MAPS, free_port, rsal_cmd, wait_until

LASER_GEO = {  # r0:laser:0 of maps/testroom.world: a URG 0.13 m ahead of the centre
    "kind": "laser",
    "pose": [0.13, 0.0, 0.0],
    "sensors": [{"pose": [0.0, 0.0, 0.0], "fov": 4.18879, "samples": 682, "range_min": 0.02, "range_max": 5.6}],
}


# ---------------------------------------------------------------------------- pure conversions
def test_laser_scan_lands_on_the_testroom_walls_in_the_world_frame():
    # r0 at (-2, 0) facing +x: beam 0 deg hits the box's west face x = 2.0 (range 3.87 m), beam +90
    # the north wall y = 3.8 (range 3.80 m); docs in maps/testroom.world.
    n, amin = 5, -math.pi / 2
    origins, angles = beam_layout(LASER_GEO, n, amin, math.pi / 4)
    assert np.allclose(origins, [[0.13, 0.0]] * n) and np.allclose(angles[[0, 2, 4]], [-math.pi / 2, 0, math.pi / 2])
    ranges = np.array([3.8, 5.6, 3.87, 5.6, 3.8], dtype=np.float32)  # 5.6 = range_max: no hit
    pts = scan_to_world(ranges, origins, angles, (-2.0, 0.0, 0.0), 0.02, 5.6)
    assert pts.shape == (3, 2)  # the two beams at range_max are dropped
    assert np.allclose(pts, [[-1.87, -3.8], [2.0, 0.0], [-1.87, 3.8]], atol=1e-5)
    # the same scan seen from a robot turned by 90 degrees: rotated about the robot
    pts90 = scan_to_world(ranges, origins, angles, (0.0, 0.0, math.pi / 2), 0.02, 5.6)
    assert np.allclose(pts90[1], [0.0, 4.0], atol=1e-5)


def test_scan_stride_keeps_every_kth_beam():
    origins, angles = beam_layout(LASER_GEO, 682, -2.0944, 0.0061509)
    ranges = np.full(682, 2.0, dtype=np.float32)
    pts = scan_to_world(ranges, origins, angles, (0.0, 0.0, 0.0), 0.02, 5.6, stride=4)
    assert len(pts) == math.ceil(682 / 4)
    assert np.allclose(np.hypot(pts[:, 0] - 0.13, pts[:, 1]), 2.0, atol=1e-5)


def test_sonar_ring_uses_each_transducer_pose():
    geo = {
        "kind": "sonar",
        "pose": [0.0, 0.0, 0.0],
        "sensors": [{"pose": [0.1, 0.1, math.pi / 2]}, {"pose": [0.1, -0.1, -math.pi / 2]}],
    }
    origins, angles = beam_layout(geo, 2, 0.0, 0.0)
    assert np.allclose(origins, [[0.1, 0.1], [0.1, -0.1]]) and np.allclose(angles, [math.pi / 2, -math.pi / 2])
    pts = scan_to_world(np.array([1.0, 2.0]), origins, angles, (1.0, 0.0, 0.0), 0.0, 5.0)
    assert np.allclose(pts, [[1.1, 1.1], [1.1, -2.1]])


def test_covariance_to_ellipse_half_axes_and_angle():
    a, b, ang = cov_ellipse([0.04, 0, 0, 0, 0.01, 0, 0, 0, 0.1])  # sigma x 0.2 m, y 0.1 m
    assert a == pytest.approx(0.4) and b == pytest.approx(0.2)
    assert math.sin(ang) == pytest.approx(0.0, abs=1e-9)  # major axis along x
    th = math.radians(30)
    r = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    c = r @ np.diag([0.09, 0.01]) @ r.T
    a, b, ang = cov_ellipse(c, sigma=1.0)
    assert (a, b) == pytest.approx((0.3, 0.1))
    assert math.tan(ang) == pytest.approx(math.tan(th))  # the axis, either direction
    poly = ellipse_points((1.0, 2.0), a, b, ang, n=36)
    assert poly.shape == (37, 2) and np.allclose(poly[0], poly[-1])
    assert np.allclose(poly[0], [1.0 + 0.3 * math.cos(ang), 2.0 + 0.3 * math.sin(ang)])


def test_footprint_is_the_rotated_rectangle_and_heading():
    rect, head = footprint((1.0, 1.0, math.pi / 2), (0.4, 0.2))
    assert rect.shape == (5, 2) and np.allclose(rect[0], rect[-1])
    assert np.allclose(sorted(map(tuple, rect[:4].round(6))), sorted([(0.9, 1.2), (0.9, 0.8), (1.1, 1.2), (1.1, 0.8)]))
    assert np.allclose(head, [[1.0, 1.0], [1.0, 1.2]])


def test_map_grid_to_image_and_transform():
    cells = np.array([[-1, 0, 1], [1, 1, -1]], dtype=np.int8)  # row 0 = bottom row
    img = map_image(cells)
    assert img.dtype == np.uint8 and img.shape == (2, 3)
    assert img.tolist() == [[255, 160, 0], [0, 0, 255]]
    tr, sc = map_transform((-5.0, -4.0), 0.05)
    # pixel (col 2, row 1) -> world (-5 + 2 * 0.05, -4 + 1 * 0.05), shown with y flipped like world/robots
    x = tr[0] + sc[0] * 2
    y = tr[1] + sc[1] * 1
    assert (x, -y) == pytest.approx((-4.9, -3.95))


# ---------------------------------------------------------------------------- logger, in memory
class FakeRec:
    """Records ``log`` calls as (path, archetype name)."""

    def __init__(self):
        self.logs: list[tuple[str, str, object]] = []

    def log(self, path, archetype, static=False):
        self.logs.append((path, type(archetype).__name__, archetype))

    def set_time(self, *a, **kw):
        pass

    def paths(self):
        return collections.Counter(p for p, _, _ in self.logs)


def _sample(key: str, msg) -> SimpleNamespace:
    data = encode(msg)
    return SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: data))


def test_callbacks_keep_only_the_latest_sample_per_key_and_the_tick_logs_it():
    rec = FakeRec()
    w = Watcher(session=None, rec=rec, opts=WatchOptions())
    odom = "rsal/r0/position2d/0/data"
    amcl = "rsal/r0/position2d/2/data"
    for i in range(50):  # a burst between two ticks: only the last one is kept
        w._on_data(_sample(odom, Position2dData(float(i), (0.01 * i, 0.0, 0.0), (0.3, 0.0, 0.0))))
        w._on_data(_sample(amcl, Position2dData(float(i), (1.0 + 0.01 * i, 2.0, 0.0), (0.3, 0.0, 0.0))))
    assert len(w._pending) == 2 and w.stats.n_in == 100
    w.tick()
    assert w.stats.taken == 2
    r0 = w._robots["r0"]
    assert r0.odom == pytest.approx((0.49, 0.0, 0.0)) and r0.loc == pytest.approx((1.49, 2.0, 0.0))
    kinds = collections.Counter((p, k) for p, k, _ in rec.logs)
    # the outline once (robot frame), then one transform per move: the latest pose only
    assert kinds[("world/robots/r0/pose", "LineStrips2D")] == 1 and kinds[("world/robots/r0/pose", "Transform3D")] == 1
    assert r0.shown["pose"] == pytest.approx((1.49, 2.0, 0.0)) and kinds[("plots/r0/speed", "Scalars")] == 1
    # ground truth arrives by rpc (get_pose) and is carried forward by odometry
    w._on_reply("truth:robot:r0", DeviceAddr("sim", "simulation", 0), {"name": "r0", "pose": [5.0, 5.0, 0.0]})
    w._on_data(_sample(odom, Position2dData(60.0, (0.59, 0.0, 0.0), (0.3, 0.0, 0.0))))
    w.tick()
    assert r0.truth() == pytest.approx(np.array([5.1, 5.0, 0.0]))
    assert r0.shown["truth"] == pytest.approx((5.1, 5.0, 0.0))
    n_pose = len(rec.logs)
    w.tick()  # nothing new: nothing logged (a robot standing still costs nothing)
    assert len(rec.logs) == n_pose


def test_scans_are_downsampled_and_placed_from_the_robot_pose():
    rec = FakeRec()
    w = Watcher(session=None, rec=rec, opts=WatchOptions(scan_rate=1.0, max_beams=100))
    laser = DeviceAddr("r0", "laser", 0)
    w._alive.add(laser)
    w._geometry[laser] = LASER_GEO
    w._on_data(_sample("rsal/r0/position2d/2/data", Position2dData(0.0, (-2.0, 0.0, 0.0), (0.0, 0.0, 0.0))))
    scan = RangerData(0.1, np.full(682, 3.0, dtype=np.float32), -2.0944, 0.0061509, 0.02, 5.6)
    w._on_data(_sample("rsal/r0/laser/0/data", scan))
    w.tick()
    logged = [a for p, _, a in rec.logs if p == "world/robots/r0/laser"]
    assert len(logged) == 1
    w._on_data(_sample("rsal/r0/laser/0/data", scan))
    w.tick()  # within 1 s of the last logged scan: skipped and counted
    assert len([p for p, _, _ in rec.logs if p == "world/robots/r0/laser"]) == 1 and w.stats.downsampled == 1


BUMPER_GEO = {  # two front segments 0.1 m long, facing forward, left and right of the axis
    "pose": [0.0, 0.0, 0.0],
    "segments": [{"pose": [0.25, 0.05, 0.0], "length": 0.1}, {"pose": [0.25, -0.05, 0.0], "length": 0.1}],
}
FIDUCIAL_GEO = {"pose": [0.1, 0.0, 0.0], "fov": math.pi, "range_min": 0.0, "range_max": 8.0, "range_max_id": 5.0}


def _located_watcher(rec, **opts) -> Watcher:
    """A watcher that knows r0 at (1, 2) facing +y from its localized position2d."""
    w = Watcher(session=None, rec=rec, opts=WatchOptions(**opts))
    w._on_data(_sample("rsal/r0/position2d/2/data", Position2dData(0.0, (1.0, 2.0, math.pi / 2), (0.0, 0.0, 0.0))))
    w.tick()
    return w


def test_bumper_segments_are_drawn_in_the_robot_frame_red_while_pressed():
    rec = FakeRec()
    w = _located_watcher(rec)
    addr = DeviceAddr("r0", "bumper", 0)
    w._alive.add(addr)
    w._geometry[addr] = BUMPER_GEO
    path = "world/robots/r0/pose/bumper"  # under the localized footprint: moves with the robot
    w._on_data(_sample("rsal/r0/bumper/0/data", BumperData(0.1, (0, 1))))
    w.tick()
    (strips,) = [a for p, _, a in rec.logs if p == path]
    ends = strips.strips.as_arrow_array().to_pylist()
    # each segment lies across its facing (+x), centred at its pose, in the robot frame
    assert np.allclose(ends, [[[0.25, 0.0], [0.25, 0.1]], [[0.25, -0.1], [0.25, 0.0]]])
    colors = strips.colors.as_arrow_array().to_pylist()
    assert colors[1] == RED and colors[0] != RED
    w._on_data(_sample("rsal/r0/bumper/0/data", BumperData(0.2, (0, 1))))
    w.tick()  # the same contacts: nothing logged again
    assert len([p for p, _, _ in rec.logs if p == path]) == 1
    w._on_data(_sample("rsal/r0/bumper/0/data", BumperData(0.3, (0, 0))))
    w.tick()
    last = [a for p, _, a in rec.logs if p == path][-1]
    assert RED not in last.colors.as_arrow_array().to_pylist()
    # data that does not fit the geometry is counted and dropped, not drawn
    w._on_data(_sample("rsal/r0/bumper/0/data", BumperData(0.4, (1, 1, 1))))
    w.tick()
    assert w.stats.malformed == 1 and len([p for p, _, _ in rec.logs if p == path]) == 2


def test_fiducials_are_lines_from_the_finder_labelled_with_their_ids():
    rec = FakeRec()
    w = _located_watcher(rec)
    addr = DeviceAddr("r0", "fiducial", 0)
    w._alive.add(addr)
    w._geometry[addr] = FIDUCIAL_GEO
    seen = FiducialData(0.1, [FiducialItem.at(7, (1.0, 1.0, 0.0)), FiducialItem.at(-1, (2.0, 0.0, 0.0))])
    w._on_data(_sample("rsal/r0/fiducial/0/data", seen))
    w.tick()
    path = "world/robots/r0/pose/fiducial"
    (lines,) = [a for p, _, a in rec.logs if p == path]
    # from the finder (0.1 m ahead of the centre) to each marker, robot frame; an unread id is "?"
    assert np.allclose(lines.strips.as_arrow_array().to_pylist(), [[[0.1, 0.0], [1.1, 1.0]], [[0.1, 0.0], [2.1, 0.0]]])
    assert lines.labels.as_arrow_array().to_pylist() == ["#7", "?"]
    w._on_data(_sample("rsal/r0/fiducial/0/data", FiducialData(0.2, [])))
    w.tick()  # nothing in view: the lines are cleared
    assert [k for p, k, _ in rec.logs if p == path] == ["LineStrips2D", "Clear"]


def test_every_interface_has_a_view_hook_from_the_registry():
    for name in interfaces.names():
        assert callable(draw.hook(name))
    drawn = {n for n in interfaces.names() if draw.hook(n) is not draw.draw_summary}
    assert {"position2d", "laser", "sonar", "ranger", "bumper", "fiducial", "planner", "blobfinder"} <= drawn
    assert draw.hook("dio") is draw.draw_summary  # not drawn: its summary text is logged
    with pytest.raises(RuntimeError, match="'bumpr' is not an interface"):
        draw.draws("bumpr")(lambda w, a, m: None)


def test_service_messages_become_text_log_entries():
    rec = FakeRec()
    w = Watcher(session=None, rec=rec, opts=WatchOptions())
    body = {"sender": "hunter1", "conversation": "c1", "time": 1.0, "event": "caught", "subject": "r0", "ok": True}
    data = msgpack.packb(body)
    w._on_text(SimpleNamespace(key_expr="svc/outcome/hunter1", payload=SimpleNamespace(to_bytes=lambda: data)))
    w.tick()
    entries = [a for p, kind, a in rec.logs if p == "log/services/outcome"]
    assert len(entries) == 1 and rec.logs[-1][1] == "TextLog"


# ---------------------------------------------------------------------------- the command, real processes
def _read_rrd(path) -> collections.Counter:
    from rerun.chunk import RrdReader

    rows: collections.Counter = collections.Counter()
    for c in RrdReader(str(path)).stream():
        rows[c.entity_path.lstrip("/")] += c.num_rows
    return rows


def _start_sim(procs):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    sim = procs(rsal_cmd("sim", str(MAPS / "testroom.world"), "--nav", "vfh", "--listen", ep))
    return sim, ep


@pytest.mark.timeout(240)
def test_watch_records_map_robot_laser_path_and_services(procs, tmp_path):
    sim, ep = _start_sim(procs)
    out = tmp_path / "out.rrd"
    flags = ["--duration", "12", "--wait", "60", "--report-every", "2", "--connect", ep]
    watch = procs(rsal_cmd("watch", "--save", str(out), *flags))
    wait_until(lambda: "[watch] recording" in watch.output() or not watch.alive(), 70, "watch to start recording")
    goto = procs(rsal_cmd("goto", "r0", "0", "-2", "--connect", ep, "--wait", "30", "--timeout", "60"))
    wait_until(lambda: "driving" in goto.output() or not goto.alive(), 60, "the robot to drive to its goal")
    assert "driving" in goto.output(), goto.output()
    from rsal.transport import TransportArgs, open_session

    with open_session(TransportArgs(connect=[ep])) as session:  # an agent's outcome message
        # the sim and the watcher (found by gossip) must be connected before a put can reach the watcher
        wait_until(lambda: len(list(session.info.peers_zid())) >= 2, 30, "the test's session to join the fabric")
        body = {"sender": "tester", "conversation": "c1", "time": time.time(), "event": "arrived", "subject": "r0"}
        for _ in range(3):  # a few, a tick apart: one put right after connecting may precede routing
            session.put("svc/outcome/tester", msgpack.packb(body))
            time.sleep(0.1)
    wait_until(lambda: not watch.alive(), 90, "watch to stop after --duration")
    text = watch.output()
    assert watch.p.returncode == 0, text
    assert "msg/s" in text and "robots 1" in text  # progress lines
    rows = _read_rrd(out)
    for path in (
        "world/map",
        "world/robots/r0/truth",
        "world/robots/r0/pose",
        "world/robots/r0/pose/covariance",
        "world/robots/r0/laser",
        "world/robots/r0/sonar",
        "world/robots/r0/path",
        "world/robots/r0/goal",
        "world/blobs/blob0",
        "plots/r0/speed",
        "plots/r0/loc_error",
        "plots/r0/battery",
        "log/services/outcome",
        "log/planner/r0",
        "log/devices/r0",
    ):
        assert rows[path] > 0, f"{path} missing from {sorted(rows)}"
    assert rows["world/robots/r0/laser"] >= 20  # ~5 scans/s for most of 12 s


CONTACT_WORLD = """\
interval_sim 100
position
(
  name "r0"
  size [ 0.44 0.38 0.22 ]
  bumper( bcount 2 blength 0.15 bpose[0] [ 0.235 0.08 0 0 ] bpose[1] [ 0.235 -0.08 0 0 ] )
  fiducial( range_max 6 fov 180 )
)
model( name "box" pose [ 0.40 0 0 0 ] size [ 0.3 0.3 0.3 ] mass 1000 )
model( name "beacon" pose [ 2 1.5 0 0 ] size [ 0.1 0.1 0.1 ] obstacle_return 0 fiducial_return 3 )
"""


def test_a_stage_worlds_bumper_and_fiducial_reach_the_live_view(procs, tmp_path):
    """End to end: Stage world file -> simulator -> rsal sim's devices -> rsal watch -> .rrd."""
    world = tmp_path / "contact.world"
    world.write_text(CONTACT_WORLD)
    ep = f"tcp/127.0.0.1:{free_port()}"
    sim = procs(rsal_cmd("sim", str(world), "--listen", ep))
    wait_until(lambda: "device(s) up" in sim.output() or not sim.alive(), 90, "rsal sim to serve")
    assert "not simulated" not in sim.output(), sim.output()
    out = tmp_path / "contact.rrd"
    watch = procs(rsal_cmd("watch", "--save", str(out), "--duration", "8", "--wait", "60", "--connect", ep))
    wait_until(lambda: not watch.alive(), 90, "watch to stop after --duration")
    assert watch.p.returncode == 0, watch.output()
    rows = _read_rrd(out)
    for path in ("world/robots/r0/truth/bumper", "world/robots/r0/truth/fiducial"):
        assert rows[path] > 0, f"{path} missing from {sorted(rows)}"


@pytest.mark.timeout(120)
def test_sigint_exits_0_with_a_complete_file(procs, tmp_path):
    sim, ep = _start_sim(procs)
    out = tmp_path / "sigint.rrd"
    watch = procs(rsal_cmd("watch", "--save", str(out), "--wait", "60", "--report-every", "1", "--connect", ep))
    wait_until(
        lambda: "(1 with ground truth)  maps 1" in watch.output() or not watch.alive(), 60, "map and robot logged"
    )
    watch.signal(signal.SIGINT)
    wait_until(lambda: not watch.alive(), 30, "watch to exit on SIGINT")
    assert watch.p.returncode == 0, watch.output()
    assert "stopped (SIGINT)" in watch.output()
    rows = _read_rrd(out)
    assert rows["world/map"] > 0 and rows["world/robots/r0/truth"] > 0


def _one_line_error(p) -> str:
    wait_until(lambda: not p.alive(), 60, "the command to exit")
    lines = [ln for ln in p.output().splitlines() if ln.strip()]
    assert p.p.returncode == 1 and len(lines) == 1, p.output()
    assert "Traceback" not in lines[0]
    return lines[0]


def test_bad_flags_give_one_line_and_exit_1(procs, tmp_path):
    line = _one_line_error(procs(rsal_cmd("watch", "--save", str(tmp_path / "x.rrd"), "--rate", "0")))
    assert line.startswith("rsal watch: --rate")
    line = _one_line_error(procs(rsal_cmd("watch", "--save", str(tmp_path / "x.txt"))))
    assert ".rrd" in line
    line = _one_line_error(procs(rsal_cmd("watch"), env={"DISPLAY": "", "WAYLAND_DISPLAY": ""}))
    assert "--save" in line and "--serve" in line


def test_nothing_to_connect_gives_one_line_and_exit_1(procs, tmp_path):
    t = time.monotonic()
    ep = f"tcp/127.0.0.1:{free_port()}"
    line = _one_line_error(procs(rsal_cmd("watch", "--save", str(tmp_path / "x.rrd"), "--wait", "2", "--connect", ep)))
    assert "no devices match" in line and time.monotonic() - t < 60
    assert not (tmp_path / "x.rrd").exists()


def test_a_malformed_sample_is_counted_and_dropped():
    rec = FakeRec()
    w = Watcher(session=None, rec=rec, opts=WatchOptions())
    bad = msgpack.packb({"t": 1.0, "pose": "here"})
    w._on_data(SimpleNamespace(key_expr="rsal/r0/position2d/0/data", payload=SimpleNamespace(to_bytes=lambda: bad)))
    w._on_data(_sample("rsal/r1/position2d/2/data", Position2dData(0.0, (1.0, 1.0, 0.0), (0.0, 0.0, 0.0))))
    w.tick()
    assert w.stats.malformed == 1 and w._robots["r1"].loc == (1.0, 1.0, 0.0)
