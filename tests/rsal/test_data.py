"""RSAL data types (thesis 3.6.2.1): angles, positions and frames, goals, the board, blobs."""

from __future__ import annotations

import dataclasses
import math
import random

import pytest

from rsal.data import (
    DEFAULT_TIMEOUT,
    BlobfinderBlob,
    Board,
    BoardObject,
    Goal,
    Position,
    normalize_angle,
)

PI = math.pi
SQRT3 = math.sqrt(3.0)


def approx_pos(p: Position, x: float, y: float, yaw: float, tol: float = 1e-9) -> None:
    assert p.x == pytest.approx(x, abs=tol)
    assert p.y == pytest.approx(y, abs=tol)
    assert normalize_angle(p.yaw - yaw) == pytest.approx(0.0, abs=tol)


class FakeClock:
    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


# --- normalize_angle -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("a", "expected"),
    [
        (0.0, 0.0),
        (PI, -PI),
        (-PI, -PI),
        (3 * PI, -PI),
        (-3 * PI, -PI),
        (2 * PI, 0.0),
        (-2 * PI, 0.0),
        (PI / 2, PI / 2),
        (-PI / 2, -PI / 2),
        (3 * PI / 2, -PI / 2),
        (-3 * PI / 2, PI / 2),
        (7.0, 7.0 - 2 * PI),
        (-7.0, -7.0 + 2 * PI),
    ],
)
def test_normalize_angle_edges(a: float, expected: float) -> None:
    assert normalize_angle(a) == pytest.approx(expected, abs=1e-12)


def test_normalize_angle_just_below_pi_stays() -> None:
    a = math.nextafter(PI, 0.0)
    assert normalize_angle(a) == a


def test_normalize_angle_range_random() -> None:
    rng = random.Random(1234)
    for _ in range(10_000):
        a = rng.uniform(-1e4, 1e4)
        r = normalize_angle(a)
        assert -PI <= r < PI
        # Same direction as a.
        assert math.cos(r) == pytest.approx(math.cos(a), abs=1e-9)
        assert math.sin(r) == pytest.approx(math.sin(a), abs=1e-9)


@pytest.mark.parametrize("a", [math.inf, -math.inf, math.nan])
def test_normalize_angle_rejects_non_finite(a: float) -> None:
    with pytest.raises(ValueError, match="not finite"):
        normalize_angle(a)


# --- Position --------------------------------------------------------------------------------


def test_position_defaults_and_floats() -> None:
    p = Position()
    assert p.as_tuple() == (0.0, 0.0, 0.0)
    q = Position(1, 2, 3)
    assert all(type(v) is float for v in q.as_tuple())


def test_position_is_frozen_and_hashable() -> None:
    p = Position(1.0, 2.0, 0.5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.x = 3.0  # type: ignore[misc]
    assert p == Position(1.0, 2.0, 0.5)
    assert p != Position(1.0, 2.0, 0.5000001)
    assert len({p, Position(1.0, 2.0, 0.5)}) == 1


@pytest.mark.parametrize(
    ("args", "bad"),
    [
        ((math.nan, 0.0, 0.0), "nan"),
        ((0.0, math.inf, 0.0), "inf"),
        ((0.0, 0.0, -math.inf), "-inf"),
        (("1", 0.0, 0.0), "'1'"),
        ((None, 0.0, 0.0), "None"),
        ((True, 0.0, 0.0), "True"),
    ],
)
def test_position_validation(args: tuple[object, ...], bad: str) -> None:
    with pytest.raises(ValueError) as exc:
        Position(*args)  # type: ignore[arg-type]
    assert bad in str(exc.value)


def test_position_fast_path_keeps_the_checks() -> None:
    """Finite floats skip the conversion; anything else still goes through it."""
    big = Position(1e308, 1e308, 0.0)  # finite, though their sum is not
    assert big.as_tuple() == (1e308, 1e308, 0.0)
    import numpy as np

    q = Position(np.float64(1.5), np.float32(2.0), 0)
    assert q.as_tuple() == (1.5, 2.0, 0.0) and all(type(v) is float for v in q.as_tuple())
    with pytest.raises(ValueError, match="Position.y"):
        Position(0.0, math.nan, 0.0)


def test_distance_to() -> None:
    assert Position(1, 1).distance_to(Position(4, 5, 2.0)) == pytest.approx(5.0)
    assert Position(1, 1).distance_to(Position(1, 1)) == 0.0


def test_is_near_to_distance_only() -> None:
    a = Position(0, 0, 0)
    assert a.is_near_to(Position(0.3, 0.4, 3.0), 0.5)
    assert not a.is_near_to(Position(0.3, 0.41, 0.0), 0.5)


def test_is_near_to_with_angle() -> None:
    a = Position(0, 0, 0.0)
    assert a.is_near_to(Position(0.1, 0, 0.05), 0.2, 0.1)
    assert not a.is_near_to(Position(0.1, 0, 0.2), 0.2, 0.1)
    assert not a.is_near_to(Position(1.0, 0, 0.0), 0.2, 0.1)


def test_is_near_to_angle_wraps_around() -> None:
    a = Position(0, 0, 3.1)
    b = Position(0, 0, -3.1)  # 2*pi - 6.2 = 0.083 rad apart the short way
    assert a.is_near_to(b, 0.01, 0.1)
    assert b.is_near_to(a, 0.01, 0.1)
    assert not a.is_near_to(b, 0.01, 0.05)
    assert a.is_near_to(b, 0.01)  # no angle tolerance: yaw ignored


def test_to_global_hand_computed() -> None:
    # Robot at (1, 2) facing +y; an object 1 m ahead of it is at (1, 3), facing +y too.
    approx_pos(Position(1, 0, 0).to_global(Position(1, 2, PI / 2)), 1.0, 3.0, PI / 2)
    # Robot at (2, -1) with yaw pi/6; object at (3, 4, pi) local:
    # x = cos30*3 - sin30*4 + 2 = 3*sqrt3/2, y = sin30*3 + cos30*4 - 1 = 0.5 + 2*sqrt3,
    # yaw = norm(pi/6 + pi) = -5pi/6.
    g = Position(3, 4, PI).to_global(Position(2, -1, PI / 6))
    approx_pos(g, 3 * SQRT3 / 2, 0.5 + 2 * SQRT3, -5 * PI / 6)
    assert -PI <= g.yaw < PI
    # Identity frame.
    approx_pos(Position(1.5, -2.5, 0.3).to_global(Position()), 1.5, -2.5, 0.3)


def test_to_global_yaw_is_normalised() -> None:
    g = Position(0, 0, 3.0).to_global(Position(0, 0, 3.0))
    assert g.yaw == pytest.approx(6.0 - 2 * PI)


def test_to_local_hand_computed() -> None:
    approx_pos(Position(1, 3, PI / 2).to_local(Position(1, 2, PI / 2)), 1.0, 0.0, 0.0)
    l = Position(3 * SQRT3 / 2, 0.5 + 2 * SQRT3, -5 * PI / 6).to_local(Position(2, -1, PI / 6))
    approx_pos(l, 3.0, 4.0, PI)
    assert -PI <= l.yaw < PI


def test_frame_round_trips_random() -> None:
    rng = random.Random(20110)
    for _ in range(2_000):
        frame = Position(rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-10, 10))
        p = Position(rng.uniform(-50, 50), rng.uniform(-50, 50), rng.uniform(-PI, PI))
        back = p.to_global(frame).to_local(frame)
        approx_pos(back, p.x, p.y, p.yaw, tol=1e-9)
        back2 = p.to_local(frame).to_global(frame)
        approx_pos(back2, p.x, p.y, p.yaw, tol=1e-9)
        # A rigid transform keeps distances.
        q = Position(rng.uniform(-50, 50), rng.uniform(-50, 50))
        assert p.to_global(frame).distance_to(q.to_global(frame)) == pytest.approx(p.distance_to(q))


def test_cartesian() -> None:
    approx_pos(Position(2.0, PI / 2, 1.0).cartesian(), 0.0, 2.0, 0.0)
    approx_pos(Position(2.0, PI, 0.0).cartesian(), -2.0, 0.0, 0.0)
    approx_pos(Position(SQRT3 * 2, PI / 6).cartesian(), 3.0, SQRT3, 0.0)
    assert Position(2.0, 1.0, 1.0).cartesian().yaw == 0.0


def test_degrees() -> None:
    p = Position.from_degrees(1, 2, 90)
    assert p.yaw == pytest.approx(PI / 2)
    assert p.yaw_degrees == pytest.approx(90.0)
    assert Position(0, 0, -PI).yaw_degrees == pytest.approx(-180.0)
    with pytest.raises(ValueError, match="nan"):
        Position.from_degrees(0, 0, math.nan)


def test_as_tuple_from_seq_round_trip() -> None:
    p = Position(1.0, -2.0, 0.25)
    assert Position.from_seq(p.as_tuple()) == p
    assert Position.from_seq([1, 2]) == Position(1.0, 2.0, 0.0)
    assert Position.from_seq(iter((1.0, 2.0, 3.0))) == Position(1.0, 2.0, 3.0)


@pytest.mark.parametrize(
    ("seq", "bad"),
    [
        ([1.0], "got 1"),
        ([1.0, 2.0, 3.0, 4.0], "got 4"),
        ([], "got 0"),
        ([1.0, math.nan], "nan"),
        ([1.0, 2.0, math.inf], "inf"),
        ([1.0, "a"], "'a'"),
        ([None, 1.0], "None"),
        ("12", "'12'"),
        (5, "5"),
    ],
)
def test_from_seq_validation(seq: object, bad: str) -> None:
    with pytest.raises(ValueError) as exc:
        Position.from_seq(seq)  # type: ignore[arg-type]
    assert bad in str(exc.value)


# --- Goal and BoardObject ----------------------------------------------------------------------


def test_goal_defaults_and_obsolete() -> None:
    g = Goal(Position(1, 2))
    assert g.cost == math.inf
    assert not g.obsolete
    assert g.tag == ""
    assert isinstance(g.timestamp, float)
    g.mark_obsolete()
    assert g.obsolete
    assert Goal().position is None
    with pytest.raises(ValueError, match="nan"):
        Goal(cost=math.nan)


def test_board_object_is_expired() -> None:
    o = BoardObject(topic="t", timeout=5.0, created=100.0)
    assert not o.is_expired(104.9)
    assert o.is_expired(105.0)
    assert BoardObject().timeout == DEFAULT_TIMEOUT
    for never in (math.inf, 0.0, -1.0):
        assert not BoardObject(timeout=never, created=0.0).is_expired(1e12)
    with pytest.raises(ValueError, match="nan"):
        BoardObject(timeout=math.nan)


# --- Board -----------------------------------------------------------------------------------


def test_board_basic_operations() -> None:
    clock = FakeClock()
    b = Board(clock=clock)
    a = BoardObject(topic="goal/a", data=1)
    b.put("a", a)
    assert a.created == clock.t
    assert b.get("a") is a
    assert b.get("missing") is None
    default = BoardObject()
    assert b.get("missing", default) is default
    assert "a" in b and "missing" not in b
    assert len(b) == 1
    assert b.keys() == ["a"]
    assert b.items() == [("a", a)]
    assert b.remove("a") is a
    assert b.remove("a") is None
    assert len(b) == 0
    with pytest.raises(TypeError, match="BoardObject"):
        b.put("x", {"not": "a board object"})  # type: ignore[arg-type]


def test_board_put_replaces() -> None:
    b = Board(clock=FakeClock())
    first, second = BoardObject(data=1), BoardObject(data=2)
    b.put("k", first)
    b.put("k", second)
    assert b.get("k") is second
    assert len(b) == 1


def test_board_expired_objects_never_returned() -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    short = BoardObject(topic="t", timeout=5.0)
    long = BoardObject(topic="t", timeout=50.0)
    b.put("short", short)
    b.put("long", long)
    clock.t = 4.999
    assert len(b) == 2
    clock.t = 5.0
    assert b.get("short") is None
    assert "short" not in b
    assert len(b) == 1
    assert b.keys() == ["long"]
    assert b.items() == [("long", long)]
    assert b.items("t") == [("long", long)]
    assert b.values() == [long]
    clock.t = 1e6
    assert b.get("long") is None
    assert b.items() == [] and b.keys() == [] and len(b) == 0 and b.topics() == []


@pytest.mark.parametrize("accessor", ["get", "contains", "len", "keys", "items", "topics", "remove"])
def test_every_accessor_drops_expired(accessor: str) -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    b.put("k", BoardObject(topic="t", timeout=1.0))
    clock.t = 2.0
    result = {
        "get": lambda: b.get("k"),
        "contains": lambda: "k" in b,
        "len": lambda: len(b),
        "keys": lambda: b.keys(),
        "items": lambda: b.items("t"),
        "topics": lambda: b.topics(),
        "remove": lambda: b.remove("k"),
    }[accessor]()
    assert result in (None, False, 0, [])
    assert b.purge() == 0  # already gone


def test_board_replacing_resets_expiry() -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    o = BoardObject(timeout=10.0)
    b.put("k", o)
    clock.t = 8.0
    b.put("k", o)  # the same object again: its lifespan restarts
    assert o.created == 8.0
    clock.t = 12.0
    assert b.get("k") is o  # the stale heap entry of the first put (expiry 10) must not remove it
    clock.t = 17.9
    assert "k" in b
    clock.t = 18.0
    assert "k" not in b


def test_board_replacement_with_never_expiring() -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    b.put("k", BoardObject(timeout=1.0))
    forever = BoardObject(timeout=math.inf)
    b.put("k", forever)
    clock.t = 1e9
    assert b.get("k") is forever


def test_board_remove_then_put_same_key() -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    b.put("k", BoardObject(timeout=1.0))
    b.remove("k")
    clock.t = 0.5
    o = BoardObject(timeout=1.0)
    b.put("k", o)
    clock.t = 1.2  # the removed note's expiry has passed, the new one's has not
    assert b.get("k") is o
    assert b.purge() == 0


def test_board_no_expiry_for_inf_or_non_positive_timeout() -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    b.put("inf", BoardObject(timeout=math.inf))
    b.put("zero", BoardObject(timeout=0.0))
    b.put("default", BoardObject())
    clock.t = DEFAULT_TIMEOUT - 0.001
    assert len(b) == 3
    clock.t = DEFAULT_TIMEOUT
    assert sorted(b.keys()) == ["inf", "zero"]
    clock.t = 1e12
    assert sorted(b.keys()) == ["inf", "zero"]


def test_board_topic_filter_and_prefix() -> None:
    b = Board(clock=FakeClock())
    b.put("g1", BoardObject(topic="goal/red"))
    b.put("g2", BoardObject(topic="goal/green"))
    b.put("p", BoardObject(topic="pose"))
    b.put("n", BoardObject())
    assert [k for k, _ in b.items("goal/red")] == ["g1"]
    assert sorted(k for k, _ in b.items("goal/*")) == ["g1", "g2"]
    assert b.items("goal") == []
    assert sorted(k for k, _ in b.items("go*")) == ["g1", "g2"]
    assert len(b.items("*")) == 4
    assert b.items("nothing*") == []
    assert [k for k, _ in b.items("")] == ["n"]
    assert b.topics() == ["", "goal/green", "goal/red", "pose"]
    assert len(b.values("goal/*")) == 2


def test_board_clear() -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    for i in range(10):
        b.put(i, BoardObject(timeout=1.0 + i))
    b.clear()
    assert len(b) == 0
    clock.t = 100.0
    assert b.purge() == 0


def test_board_purge_of_few_among_many() -> None:
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    n = 100_000
    for i in range(n):
        # Ten notes expire at t = 1..10, the rest at t = 1000 + i.
        b.put(i, BoardObject(timeout=float(i + 1) if i < 10 else 1000.0 + i))
    assert len(b) == n
    clock.t = 10.0
    assert b.purge() == 10
    assert len(b) == n - 10
    assert len(b._heap) == n - 10  # private: only the ten expired heap entries were popped
    assert all(i not in b for i in range(10))
    assert 10 in b
    assert b.purge() == 0


def test_board_heap_stays_bounded_under_replacement() -> None:
    # Memory footprint (thesis 3.6.2.1): replacing one key many times must not grow the heap.
    clock = FakeClock(0.0)
    b = Board(clock=clock)
    for i in range(10_000):
        clock.t = i * 1e-3
        b.put("k", BoardObject(timeout=60.0))
    assert len(b) == 1
    assert len(b._heap) <= 2 * len(b) + 65  # private: the bound _maybe_compact keeps


# --- BlobfinderBlob --------------------------------------------------------------------------


def blob(color: int = 0x00FF00, range_: float = 2.0, bearing: float = 0.0) -> BlobfinderBlob:
    return BlobfinderBlob(
        id=1,
        color=color,
        area=120,
        x=40,
        y=30,
        left=30,
        right=50,
        top=25,
        bottom=35,
        range=range_,
        bearing=bearing,
    )


def test_blob_color_name_and_angle() -> None:
    assert blob(0x00FF00).color_name == "green"
    assert blob(0xFF0000).color_name == "red"
    assert blob(0x123ABC).color_name == "0x123ABC"
    assert blob(bearing=0.3).angle == 0.3
    assert BlobfinderBlob.COLOR_NAMES[0x0000FF] == "blue"
    with pytest.raises(TypeError):
        BlobfinderBlob.COLOR_NAMES[0x1] = "x"  # type: ignore[index]


def test_blob_world_position() -> None:
    # Robot at (1, 2) facing +y; a blob 2 m away, 90 degrees to the left, is at (-1, 2).
    approx_pos(blob(range_=2.0, bearing=PI / 2).world_position(Position(1, 2, PI / 2)), -1.0, 2.0, PI / 2)
    # Straight ahead of a robot at the origin facing +x.
    approx_pos(blob(range_=3.0).world_position(Position()), 3.0, 0.0, 0.0)
    # Robot at (2, -1), yaw pi/6, blob 2 m at bearing pi/6: world bearing pi/3.
    w = blob(range_=2.0, bearing=PI / 6).world_position(Position(2, -1, PI / 6))
    approx_pos(w, 2 + 1.0, -1 + SQRT3, PI / 6)


def test_blob_discovered_and_frozen() -> None:
    b = blob()
    assert b.discovered is None
    seen = dataclasses.replace(b, discovered=b.world_position(Position(1, 1)))
    approx_pos(seen.discovered, 3.0, 1.0, 0.0)  # type: ignore[arg-type]
    with pytest.raises(dataclasses.FrozenInstanceError):
        b.range = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("kwargs", "bad"),
    [
        ({"color": -1}, "-1"),
        ({"color": 0x1000000}, "16777216"),
        ({"range_": -0.5}, "-0.5"),
        ({"range_": math.nan}, "nan"),
        ({"bearing": math.inf}, "inf"),
    ],
)
def test_blob_validation(kwargs: dict[str, float], bad: str) -> None:
    with pytest.raises(ValueError) as exc:
        blob(**kwargs)  # type: ignore[arg-type]
    assert bad in str(exc.value)
