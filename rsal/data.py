"""RSAL data types: positions and frame transforms, goals, the blackboard and blobfinder blobs.

Implements the *Data* component of the RSAL middle layer (thesis 3.6.2.1, figures 3.12-3.15):

- :func:`normalize_angle` is the thesis's ``getRelativeAngle``: an angle mapped to [-pi, pi)
  (:func:`rsal.geometry.wrap` for finite values, ValueError otherwise).
- :class:`Position` is a planar pose (x, y in metres, yaw in radians) with the frame transforms
  of equations (3.1) and (3.2), computed by :mod:`rsal.geometry`: :meth:`Position.to_global`
  takes a position given in a local frame (e.g. the robot's) into the frame that local frame is
  expressed in (e.g. the world), :meth:`Position.to_local` is the inverse.
- :class:`Goal` is a goal with a cost and an obsolete flag (figure 3.13).
- :class:`Board` is the blackboard of :class:`BoardObject` notes with topics and timeouts
  (figure 3.14). As in the thesis it has no thread: expired notes are removed whenever the board
  is used, from a heap ordered by expiry time, so a purge costs O(k log n) for k expired notes
  and O(1) when none has expired.
- :class:`BlobfinderBlob` is a coloured region seen by a blobfinder (figure 3.15).

All values are SI: metres, radians, seconds. Times are on a monotonic clock.
"""

from __future__ import annotations

import heapq
import itertools
import math
import numbers
import time
from collections.abc import Callable, Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar

from .geometry import compose, relative, wrap

__all__ = [
    "DEFAULT_TIMEOUT",
    "BlobfinderBlob",
    "Board",
    "BoardObject",
    "Goal",
    "Position",
    "normalize_angle",
]

DEFAULT_TIMEOUT = 60.0
"""Seconds a :class:`BoardObject` stays on a :class:`Board` unless it says otherwise."""


def normalize_angle(a: float) -> float:
    """Return ``a`` (radians) mapped to [-pi, pi); pi itself maps to -pi (thesis ``getRelativeAngle``).

    Raises ValueError if ``a`` is not finite.
    """
    a = float(a)
    if not math.isfinite(a):
        raise ValueError(f"cannot normalise angle {a!r}: it is not finite")
    return wrap(a)


def _finite(value: object, what: str) -> float:
    """``value`` as a float, or ValueError naming it and ``what`` it was meant to be."""
    if type(value) is float and math.isfinite(value):  # the common case, without the ABC check
        return value
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    return v


@dataclass(frozen=True, slots=True)
class Position:
    """A planar position: ``x``, ``y`` in metres and ``yaw`` in radians (figure 3.12).

    Equality is exact (the thesis's ``equals``); use :meth:`is_near_to` for a tolerance. The yaw
    is stored as given; the frame transforms return normalised yaws.
    """

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0

    def __post_init__(self) -> None:
        x, y, yaw = self.x, self.y, self.yaw
        if type(x) is float and type(y) is float and type(yaw) is float and math.isfinite(x + y + yaw):
            return  # already finite floats (every decoded pose): nothing to convert
        for name in ("x", "y", "yaw"):
            object.__setattr__(self, name, _finite(getattr(self, name), f"Position.{name}"))

    @classmethod
    def from_degrees(cls, x: float, y: float, yaw_deg: float) -> Position:
        """A position whose yaw is given in degrees."""
        return cls(x, y, math.radians(_finite(yaw_deg, "Position yaw in degrees")))

    @classmethod
    def from_seq(cls, seq: Iterable[float]) -> Position:
        """A position from ``(x, y)`` or ``(x, y, yaw)``; ValueError names a bad value."""
        if isinstance(seq, str | bytes) or not isinstance(seq, Iterable):
            raise ValueError(f"a position must be a sequence of 2 or 3 numbers (x, y[, yaw]), got {seq!r}")
        values = tuple(seq)
        if len(values) not in (2, 3):
            raise ValueError(f"a position must have 2 or 3 numbers (x, y[, yaw]), got {len(values)}: {values!r}")
        names = ("x", "y", "yaw")
        return cls(*(_finite(v, f"Position.{n} in {values!r}") for n, v in zip(names, values, strict=False)))

    def as_tuple(self) -> tuple[float, float, float]:
        """``(x, y, yaw)``."""
        return (self.x, self.y, self.yaw)

    @property
    def yaw_degrees(self) -> float:
        """The yaw in degrees."""
        return math.degrees(self.yaw)

    def distance_to(self, other: Position) -> float:
        """Planar Euclidean distance to ``other`` in metres."""
        return math.hypot(self.x - other.x, self.y - other.y)

    def is_near_to(self, other: Position, dist_tol: float, angle_tol: float | None = None) -> bool:
        """True if ``other`` is within ``dist_tol`` metres and, if ``angle_tol`` is given, its yaw
        within ``angle_tol`` radians (the shorter way round)."""
        if self.distance_to(other) > dist_tol:
            return False
        if angle_tol is None:
            return True
        return abs(normalize_angle(self.yaw - other.yaw)) <= angle_tol

    def to_global(self, frame: Position) -> Position:
        """This position, expressed in the local frame ``frame``, in the frame's parent frame.

        ``frame`` is the local frame's origin and orientation in the parent (e.g. the robot's
        pose in the world); equation (3.1) gives x and y, equation (3.2) the normalised yaw.
        """
        return Position(*compose(frame.as_tuple(), self.as_tuple()))

    def to_local(self, frame: Position) -> Position:
        """The inverse of :meth:`to_global`: this position, given in the parent frame, expressed
        in the local frame ``frame``."""
        return Position(*relative(frame.as_tuple(), self.as_tuple()))

    def cartesian(self) -> Position:
        """Read ``x`` as a range (m) and ``y`` as an angle (rad); return ``(r cos, r sin, 0)``.

        The thesis's ``getCartesianCoordinates``.
        """
        return Position(self.x * math.cos(self.y), self.x * math.sin(self.y), 0.0)


@dataclass(slots=True)
class Goal:
    """A goal of a scenario (figure 3.13).

    ``position`` is where the goal is, if it is at a place (world frame); ``cost`` the current cost
    of reaching it (inf while unknown); ``obsolete`` is set once it is reached; ``timestamp`` is
    when it was made (monotonic seconds); ``tag`` a free label.
    """

    position: Position | None = None
    cost: float = math.inf
    obsolete: bool = False
    timestamp: float = field(default_factory=time.monotonic)
    tag: str = ""

    def __post_init__(self) -> None:
        if math.isnan(self.cost):
            raise ValueError(f"Goal.cost must be a number or inf, got {self.cost!r}")

    def mark_obsolete(self) -> None:
        """Mark the goal reached (or otherwise no longer wanted)."""
        self.obsolete = True


@dataclass(slots=True)
class BoardObject:
    """A note on a :class:`Board` (figure 3.14b); every field is optional.

    ``timeout`` is its lifespan in seconds (``<= 0`` or ``inf``: never expires). ``created`` is
    when its lifespan started; :meth:`Board.put` sets it to the board's clock.
    """

    topic: str = ""
    position: Position | None = None
    goal: Goal | None = None
    data: Any = None
    timeout: float = DEFAULT_TIMEOUT
    created: float = field(default_factory=time.monotonic)
    done: bool = False

    def __post_init__(self) -> None:
        if math.isnan(self.timeout):
            raise ValueError(f"BoardObject.timeout must be seconds (<= 0 or inf for never), got {self.timeout!r}")
        if not math.isfinite(self.created):
            raise ValueError(f"BoardObject.created must be a finite time, got {self.created!r}")

    @property
    def expires(self) -> float:
        """The time at which it expires; inf if it never does."""
        if self.timeout <= 0 or math.isinf(self.timeout):
            return math.inf
        return self.created + self.timeout

    def is_expired(self, now: float) -> bool:
        """True if its timeout has elapsed at time ``now`` (same clock as ``created``)."""
        return now >= self.expires


def _topic_matches(pattern: str, topic: str) -> bool:
    if pattern.endswith("*"):
        return topic.startswith(pattern[:-1])
    return topic == pattern


class Board:
    """A blackboard: :class:`BoardObject` notes under keys, grouped by topic, with timeouts
    (figure 3.14a).

    No thread: every method first drops expired notes. Notes are indexed by expiry time in a
    heap, so that purge looks only at expired ones; heap entries left by replaced or removed
    notes are skipped when they surface and the heap is rebuilt once stale entries outnumber
    live ones, bounding its memory. ``clock`` returns monotonic seconds: by default the process's
    clock (:mod:`rsal.clock`, simulated seconds under ``use_sim_time``); inject a fake in tests.
    Not thread-safe: use it from one thread or loop.
    """

    __slots__ = ("_clock", "_entries", "_heap", "_seq")

    def __init__(self, clock: Callable[[], float] | None = None) -> None:
        if clock is None:
            from .clock import clock as process_clock

            def clock() -> float:
                return process_clock().now()

        self._clock = clock
        # key -> (object, expiry, sequence number of its put)
        self._entries: dict[Hashable, tuple[BoardObject, float, int]] = {}
        # (expiry, sequence number, key); a heap entry is live iff its sequence number is the key's.
        self._heap: list[tuple[float, int, Hashable]] = []
        self._seq = itertools.count()

    def put(self, key: Hashable, obj: BoardObject) -> None:
        """Put ``obj`` under ``key``, replacing any note there; its lifespan starts now.

        Sets ``obj.created`` to the board's clock.
        """
        if not isinstance(obj, BoardObject):
            raise TypeError(f"Board.put({key!r}, ...) takes a BoardObject, got {type(obj).__name__}")
        self.purge()
        now = self._clock()
        obj.created = now
        expires = obj.expires
        seq = next(self._seq)
        self._entries[key] = (obj, expires, seq)
        if expires != math.inf:
            heapq.heappush(self._heap, (expires, seq, key))
            self._maybe_compact()

    def get(self, key: Hashable, default: BoardObject | None = None) -> BoardObject | None:
        """The note under ``key``, or ``default`` if there is none (or it expired)."""
        self.purge()
        entry = self._entries.get(key)
        return default if entry is None else entry[0]

    def remove(self, key: Hashable) -> BoardObject | None:
        """Remove and return the note under ``key``; None if there is none."""
        self.purge()
        entry = self._entries.pop(key, None)
        if entry is None:
            return None
        self._maybe_compact()
        return entry[0]

    def __contains__(self, key: object) -> bool:
        self.purge()
        return key in self._entries

    def __len__(self) -> int:
        self.purge()
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Board({len(self)} objects)"

    def keys(self) -> list[Hashable]:
        """The keys of all live notes."""
        self.purge()
        return list(self._entries)

    def items(self, topic: str | None = None) -> list[tuple[Hashable, BoardObject]]:
        """``(key, note)`` pairs of live notes, all or those whose topic matches ``topic``.

        ``topic`` matches exactly, or, ending in ``*``, as a prefix (``"goal/*"``, ``"*"``).
        """
        self.purge()
        if topic is None:
            return [(k, e[0]) for k, e in self._entries.items()]
        return [(k, e[0]) for k, e in self._entries.items() if _topic_matches(topic, e[0].topic)]

    def values(self, topic: str | None = None) -> list[BoardObject]:
        """The live notes, all or those matching ``topic`` (as in :meth:`items`)."""
        return [obj for _, obj in self.items(topic)]

    def topics(self) -> list[str]:
        """The distinct topics of live notes, sorted."""
        self.purge()
        return sorted({e[0].topic for e in self._entries.values()})

    def clear(self) -> None:
        """Remove every note."""
        self._entries.clear()
        self._heap.clear()

    def purge(self) -> int:
        """Remove expired notes now; return how many were removed."""
        heap = self._heap
        if not heap:
            return 0
        now = self._clock()
        entries = self._entries
        removed = 0
        while heap and heap[0][0] <= now:
            _, seq, key = heapq.heappop(heap)
            entry = entries.get(key)
            if entry is not None and entry[2] == seq:
                del entries[key]
                removed += 1
        return removed

    def _maybe_compact(self) -> None:
        """Rebuild the heap from live notes when stale entries outnumber them (amortised O(1))."""
        if len(self._heap) > 2 * len(self._entries) + 64:
            self._heap = [(exp, seq, k) for k, (_, exp, seq) in self._entries.items() if exp != math.inf]
            heapq.heapify(self._heap)


_COLOR_NAMES: Mapping[int, str] = MappingProxyType(
    {
        0xFF0000: "red",
        0x00FF00: "green",
        0x0000FF: "blue",
        0xFFFF00: "yellow",
        0x00FFFF: "cyan",
        0xFF00FF: "magenta",
        0xFFA500: "orange",
        0xFFFFFF: "white",
        0x000000: "black",
    }
)


@dataclass(frozen=True, slots=True)
class BlobfinderBlob:
    """A coloured region seen by a blobfinder (figure 3.15).

    ``color`` is 0xRRGGBB; ``area`` in pixels; ``x``, ``y`` the centroid and ``left``, ``right``,
    ``top``, ``bottom`` the bounding box in image pixels; ``range`` the distance in metres and
    ``bearing`` the angle in radians (positive to the left) from the robot; ``discovered`` the
    world position where it was seen, if known.
    """

    COLOR_NAMES: ClassVar[Mapping[int, str]] = _COLOR_NAMES

    id: int
    color: int
    area: int
    x: int
    y: int
    left: int
    right: int
    top: int
    bottom: int
    range: float
    bearing: float
    discovered: Position | None = None

    def __post_init__(self) -> None:
        if isinstance(self.color, bool) or not isinstance(self.color, numbers.Integral):
            raise ValueError(f"BlobfinderBlob.color must be an integer 0xRRGGBB, got {self.color!r}")
        if not 0 <= self.color <= 0xFFFFFF:
            raise ValueError(f"BlobfinderBlob.color must be in 0x000000..0xFFFFFF, got {self.color!r}")
        rng = _finite(self.range, "BlobfinderBlob.range")
        if rng < 0:
            raise ValueError(f"BlobfinderBlob.range must be >= 0 m, got {self.range!r}")
        object.__setattr__(self, "range", rng)
        object.__setattr__(self, "bearing", _finite(self.bearing, "BlobfinderBlob.bearing"))

    @property
    def color_name(self) -> str:
        """The colour's name (``"green"`` for 0x00FF00), or ``"0xRRGGBB"`` if it has none."""
        return self.COLOR_NAMES.get(self.color, f"0x{self.color:06X}")

    @property
    def angle(self) -> float:
        """The bearing in radians (the thesis's ``getAngle``)."""
        return self.bearing

    def world_position(self, robot_pose: Position) -> Position:
        """The blob's world position, seen by a robot at ``robot_pose`` (world frame).

        Range and bearing are turned into cartesian robot-frame coordinates and then into world
        coordinates (equation 3.1); a blob has no orientation, so the yaw is the robot's.
        """
        return Position(self.range, self.bearing).cartesian().to_global(robot_pose)
