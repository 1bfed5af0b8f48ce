"""Ranger sensor layouts: every shape the loaders accept reads what the geometry says.

A ranger is a list of sensors. A sensor with ``samples > 1`` gives one reading per beam; a
single-sample sensor (a sonar transducer) gives one reading, the minimum over the rays cast across
its cone. Rangers may mix both (two half-lasers in one Stage ranger, a YAML sonar sensor with many
samples beside ordinary transducers). Each test puts a robot at a known pose in a 10 m x 8 m room
and compares every reading with the ray-rectangle intersection worked out here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from simulator.loader import load_world
from simulator.raycast import segment_min
from simulator.spec import RangerSpec
from simulator.world import SONAR_SUBRAYS, World

X_WALL, Y_WALL = 4.85, 3.85  # inner wall faces of room.png, m
TOL = 1e-3  # m: walls are cell boundaries, hit exactly up to float32 rounding


def room_png(d: Path) -> Path:
    """10 x 8 m at 0.05 m/px, centred on the origin, 3-pixel walls: inner faces x = +-4.85, y = +-3.85."""
    img = np.full((160, 200), 255, dtype=np.uint8)
    img[:3, :] = img[-3:, :] = 0
    img[:, :3] = img[:, -3:] = 0
    p = d / "room.png"
    Image.fromarray(img).save(p)
    return p


def wall_range(x: float, y: float, a: np.ndarray, rmin: float, rmax: float) -> np.ndarray:
    """Distance from (x, y) along heading(s) ``a`` to the room's walls, clipped to [rmin, rmax]."""
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (X_WALL - x) / c, np.where(c < 0, (-X_WALL - x) / c, np.inf))
        ty = np.where(s > 0, (Y_WALL - y) / s, np.where(s < 0, (-Y_WALL - y) / s, np.inf))
    return np.clip(np.minimum(tx, ty), rmin, rmax)


def expected(ranger: RangerSpec, pose: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """What the ranger should read from ``pose``, from the geometry alone, sensor by sensor, and
    the tolerance of each reading (4 standard deviations of the sensor's noise)."""
    rx, ry, ra = pose
    mx, my, ma = ranger.pose
    out: list[float] = []
    tol: list[float] = []
    for s in ranger.sensors:
        sx, sy, sa = s.pose
        # sensor in the world = robot pose ∘ mount pose ∘ sensor pose
        dx, dy = mx + math.cos(ma) * sx - math.sin(ma) * sy, my + math.sin(ma) * sx + math.cos(ma) * sy
        x, y = rx + math.cos(ra) * dx - math.sin(ra) * dy, ry + math.sin(ra) * dx + math.cos(ra) * dy
        a = ra + ma + sa
        if s.samples > 1:
            beams = a - s.fov / 2 + np.arange(s.samples) * s.fov / (s.samples - 1)
            out.extend(wall_range(x, y, beams, s.range_min, s.range_max))
        else:
            cone = a - s.fov / 2 + np.arange(SONAR_SUBRAYS) * s.fov / (SONAR_SUBRAYS - 1)
            out.append(wall_range(x, y, cone, s.range_min, s.range_max).min())
        tol.extend([TOL + 4 * s.noise] * (len(out) - len(tol)))
    return np.asarray(out), np.asarray(tol)


def check_readings(w: World, robot: str, pose: tuple[float, float, float]) -> list[np.ndarray]:
    """Every ranger of ``robot`` reads its geometry; returns the readings."""
    got = []
    for i, rs in enumerate(w.rangers(robot)):
        r = w.ranger(robot, i)
        assert r is not None, f"ranger {i} has no reading"
        want, tol = expected(rs, pose)
        assert r.ranges.shape == want.shape, f"ranger {i} ({rs.name})"
        assert r.ranges.dtype == np.float32
        bad = np.nonzero(np.abs(r.ranges - want) > tol)[0]
        assert bad.size == 0, f"ranger {i} ({rs.name}) readings {bad}: {r.ranges[bad]} != {want[bad]}"
        got.append(r.ranges)
    return got


HALF_LASERS_STAGE = """
model( name "room" bitmap "room.png" size [ 10 8 1 ] pose [ 0 0 0 0 ] )
position
(
  name "r0"
  pose [ 1.0 0.5 0 30 ]
  # two half-lasers in one ranger: left half and right half, 181 beams each
  ranger
  (
    pose [ 0.1 0 0 0 ]
    sensor( pose [ 0 0.05 0 90 ] range [ 0.02 5.6 ] fov 180 samples 181 )
    sensor( pose [ 0 -0.05 0 -90 ] range [ 0.02 5.6 ] fov 180 samples 181 )
  )
)
"""


def test_stage_ranger_of_two_half_lasers(tmp_path):
    room_png(tmp_path)
    (tmp_path / "halves.world").write_text(HALF_LASERS_STAGE)
    w = World(load_world(tmp_path / "halves.world"))
    w.step()
    (z,) = check_readings(w, "r0", (1.0, 0.5, math.radians(30)))
    assert z.shape == (362,)
    # Spot check by hand: the left half's middle beam points at 30 + 90 = 120 degrees from
    # (1.0, 0.5) + R(30)(0.1, 0.05); it meets the north wall y = 3.85.
    sy = 0.5 + math.sin(math.radians(30)) * 0.1 + math.cos(math.radians(30)) * 0.05
    assert z[90] == pytest.approx((3.85 - sy) / math.sin(math.radians(120)), abs=TOL)


def test_stage_ranger_mixing_a_laser_and_sonar_transducers(tmp_path):
    room_png(tmp_path)
    (tmp_path / "mixed.world").write_text("""
model( name "room" bitmap "room.png" size [ 10 8 1 ] pose [ 0 0 0 0 ] )
position
(
  name "r0"
  pose [ -2.0 -1.0 0 -20 ]
  ranger
  (
    sensor( pose [ 0.2 0.1 0 45 ] range [ 0 5 ] fov 15 )
    sensor( pose [ 0.2 0 0 0 ] range [ 0.05 8 ] fov 120 samples 61 )
    sensor( pose [ 0.2 -0.1 0 -45 ] range [ 0 5 ] fov 15 )
    sensor( pose [ -0.2 0 0 180 ] range [ 0 5 ] fov 30 )
  )
)
""")
    w = World(load_world(tmp_path / "mixed.world"))
    w.step()
    (z,) = check_readings(w, "r0", (-2.0, -1.0, math.radians(-20)))
    assert z.shape == (1 + 61 + 1 + 1,)


YAML_HALVES = """
floorplan: {bitmap: room.png, resolution: 0.05, origin: [-5.0, -4.0]}
robots:
  - name: r0
    pose: [-1.5, 1.0, 135]
    sonar: false
    devices:
      - type: sonar
        name: halves
        pose: [0.1, 0, 0]
        sensors:
          - {pose: [0, 0.05, 90], fov: 180, samples: 91, range: [0.02, 5.6]}
          - {pose: [0, -0.05, -90], fov: 180, samples: 91, range: [0.02, 5.6]}
"""


def test_yaml_ranger_of_two_half_lasers(tmp_path):
    room_png(tmp_path)
    (tmp_path / "halves.yaml").write_text(YAML_HALVES)
    w = World(load_world(tmp_path / "halves.yaml"))
    w.step()
    (z,) = check_readings(w, "r0", (-1.5, 1.0, math.radians(135)))
    assert z.shape == (182,)


def test_yaml_sonar_sensor_with_many_samples(tmp_path):
    room_png(tmp_path)
    (tmp_path / "s.yaml").write_text("""
floorplan: {bitmap: room.png, resolution: 0.05, origin: [-5.0, -4.0]}
robots:
  - name: r0
    pose: [3.0, 0.0, 0]
    sonar: false
    devices:
      - type: sonar
        sensors:
          - {pose: [0.2, 0, 0], fov: 40, samples: 9, range: [0, 5]}
""")
    w = World(load_world(tmp_path / "s.yaml"))
    w.step()
    (z,) = check_readings(w, "r0", (3.0, 0.0, 0.0))
    assert z.shape == (9,)
    # The middle beam faces the east wall head on, 4.85 - 3.2 m away; the others are 5 degrees apart.
    assert z[4] == pytest.approx(4.85 - 3.2, abs=TOL)
    assert z[0] == pytest.approx((4.85 - 3.2) / math.cos(math.radians(20)), abs=TOL)


def test_yaml_mixed_rangers_with_different_intervals(tmp_path):
    """Two robots: the preset sonar ring, a mixed ranger scanning every 3rd step and a laser; the
    rangers not due keep their last reading, the due ones read the geometry."""
    room_png(tmp_path)
    (tmp_path / "m.yaml").write_text("""
floorplan: {bitmap: room.png, resolution: 0.05, origin: [-5.0, -4.0]}
robots:
  - name: r0
    pose: [2.0, -1.0, 60]
    devices:
      - type: sonar
        name: mixed
        interval: 0.3
        sensors:
          - {pose: [0.1, 0.1, 30], fov: 20}
          - {pose: [0.15, 0, 0], fov: 90, samples: 19, range: [0.05, 8]}
          - {pose: [0.1, -0.1, -30], fov: 20, samples: 1}
      - {type: laser, fov: 270, samples: 271, range: [0.1, 6]}
  - name: r1
    pose: [-4.2, 3.2, 135]
    sonar: false
    devices:
      - type: sonar
        sensors:
          - {pose: [0, 0, 0], fov: 60, samples: 13}
          - {pose: [0, 0, 180], fov: 15}
""")
    w = World(load_world(tmp_path / "m.yaml"))
    p0 = (2.0, -1.0, math.radians(60))
    p1 = (-4.2, 3.2, math.radians(135))
    w.step()
    sonar, mixed, laser = check_readings(w, "r0", p0)
    assert (sonar.shape, mixed.shape, laser.shape) == ((8,), (1 + 19 + 1,), (271,))
    check_readings(w, "r1", p1)
    first_mixed = w.ranger("r0", 1)
    w.step()  # the mixed ranger is not due: its reading is the same object
    assert w.ranger("r0", 1) is first_mixed
    assert w.ranger("r0", 0).time > first_mixed.time
    check_readings(w, "r0", p0)
    check_readings(w, "r1", p1)
    w.step(2)  # due again
    assert w.ranger("r0", 1).time > first_mixed.time
    check_readings(w, "r0", p0)


def test_segment_min_matches_numpy():
    rng = np.random.default_rng(3)
    values = rng.uniform(0, 10, 500).astype(np.float32)
    counts = rng.integers(1, 8, 120)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    keep = counts.cumsum() <= values.size
    starts, counts = starts[keep], counts[keep]
    got = segment_min(values, starts, counts)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, [values[s : s + c].min() for s, c in zip(starts, counts, strict=True)])
