"""The player behind ``rsal play``: a recording's devices back on the fabric (Player's ``readlog``).

Reads a file written by :class:`rsal.record.Recorder` (layout: :mod:`rsal.record.format`) with the
``mcap`` package's sequential reader, so a file without its index (a recorder killed with SIGKILL)
or cut short plays as far as it is valid, and :attr:`Recording.skipped` says what was not.

For each recorded device the player declares, in this order, a queryable on ``rpc/*`` answering
``describe`` with the recorded reply (other operations: ``unavailable``, a recording cannot act),
then its liveliness token, at the moment the recording saw it join; it withdraws the token when
the recording saw it leave. Samples are published on their recorded keys with their recorded bytes,
at their recorded receive times scaled by ``rate`` (0: as fast as it goes). ``remap`` renames nodes
(``r0=r5``) or key prefixes (``rsal/r0=rsal/ghost``); the ``node`` field of a replayed ``describe``
follows the rename, sample bytes never change.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import ormsgpack
import zenoh
from mcap.stream_reader import StreamReader

from .. import keys
from ..msgs import ErrorCode, error_reply
from .format import MAGIC, PROFILE, RecordingError

__all__ = ["Recording", "Sample", "Player", "PlayOptions", "parse_remap"]

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Sample:
    kind: str  # format.KINDS
    key: str
    data: bytes
    log_time: int  # ns, receive time
    publish_time: int  # ns, source time


class Recording:
    """A recording: one file, or the parts of a split one in order, read sequentially;
    :attr:`skipped` says what was not valid (a file cut short or without its index)."""

    def __init__(self, *paths: str | os.PathLike):
        if not paths:
            raise RecordingError("no recording given; name the .mcap file 'rsal record -o' wrote")
        self.paths = [Path(p) for p in paths]
        for path in self.paths:
            _check_file(path)
        self.path = self.paths[0] if len(self.paths) == 1 else Path(f"{self.paths[0]} (+{len(self.paths) - 1} parts)")
        self._skipped: list[str] = []
        self.profile: str | None = None

    @property
    def skipped(self) -> str | None:
        return "; ".join(self._skipped) if self._skipped else None

    def samples(self) -> Iterator[Sample]:
        """Every recorded message in file order, part after part; a part is read up to its first
        invalid record, noted in :attr:`skipped`."""
        self._skipped = []
        for path in self.paths:
            yield from self._file_samples(path)

    def _file_samples(self, path: Path) -> Iterator[Sample]:
        channels: dict[int, tuple[str, str]] = {}
        size = path.stat().st_size
        with open(path, "rb") as f:
            it = iter(StreamReader(f, validate_crcs=True).records)
            good = 0  # the file offset after the last complete record
            while True:
                try:
                    rec = next(it)
                    good = _tell(f)
                except StopIteration:
                    return
                except Exception as e:  # truncated or corrupt: play what came before
                    left = max(size - good, 0)
                    if left == 0:
                        self._skipped.append(
                            f"{path}: ends without its index (the recorder was stopped abruptly); "
                            "read every complete chunk, the chunk it was writing is lost"
                        )
                    else:
                        self._skipped.append(
                            f"{path}: read up to the last complete chunk; skipped the rest "
                            f"({left / 1024:.1f} KB of {size / 1024:.0f} KB: {_why(e)})"
                        )
                    return
                name = type(rec).__name__
                if name == "Header":
                    self.profile = rec.profile
                elif name == "Channel":
                    channels[rec.id] = (rec.topic, rec.metadata.get("kind", "data"))
                elif name == "Message":
                    ch = channels.get(rec.channel_id)
                    if ch is not None:
                        yield Sample(ch[1], ch[0], rec.data, rec.log_time, rec.publish_time)
                elif name in ("DataEnd", "Footer"):
                    return  # the summary section repeats what came before


def _check_file(path: Path) -> None:
    try:
        with open(path, "rb") as f:
            head = f.read(len(MAGIC))
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file; give the .mcap file 'rsal record -o' wrote") from None
    except OSError as e:
        raise RecordingError(f"{path}: cannot be read: {e.strerror or e}") from None
    if not head:
        raise RecordingError(f"{path}: the file is empty (not a recording); record one with 'rsal record'")
    if head != MAGIC:
        raise RecordingError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")


def _alive(data: bytes) -> bool:
    try:
        m = ormsgpack.unpackb(data)
    except Exception:
        return False
    return isinstance(m, dict) and m.get("alive") is True


def _tell(f) -> int:
    try:
        return f.tell()
    except (OSError, ValueError):
        return 0


def _why(e: BaseException) -> str:
    text = str(e).strip().splitlines()[0] if str(e).strip() else ""
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def parse_remap(items: list[str]) -> list[tuple[str, str]]:
    """``OLD=NEW`` pairs: node names (``r0=r5``) or key prefixes (``rsal/r0=rsal/ghost``)."""
    out = []
    for item in items or []:
        old, sep, new = item.partition("=")
        if not sep or not old or not new:
            raise RecordingError(f"--remap {item!r} must be OLD=NEW, e.g. --remap r0=r5 or --remap rsal/r0=rsal/ghost")
        if "/" in old or "/" in new:
            out.append((old.rstrip("/"), new.rstrip("/")))
        else:
            keys.check_name("node", old)
            keys.check_name("node", new)
            out.append((f"{keys.PREFIX}/{old}", f"{keys.PREFIX}/{new}"))
    return out


@dataclasses.dataclass
class PlayOptions:
    rate: float = 1.0  # 0: as fast as it goes
    start: float = 0.0  # seconds into the recording
    loop: bool = False
    remap: list[tuple[str, str]] = dataclasses.field(default_factory=list)
    devices: str | None = None  # template of the devices to play
    delay: float = 0.0  # s to wait before the first sample (subscribers connect meanwhile)
    commands: bool = False  # also publish recorded commands (they would move live robots)
    services: bool = False  # also publish recorded agent service messages


@dataclasses.dataclass
class PlayStats:
    messages: int = 0
    devices: set = dataclasses.field(default_factory=set)
    alive: int = 0
    passes: int = 0
    position: float = 0.0  # seconds into the recording
    duration: float = 0.0
    lag_max: float = 0.0  # s, the latest a sample went out after its time
    paused: bool = False


class _Device:
    def __init__(self, token_key: str):
        self.token_key = token_key
        self.describe: bytes | None = None
        self.has_tokens = False  # its joins and leaves were recorded
        self.queryable = None
        self.token = None


class Player:
    """Publish a :class:`Recording` on ``session``; :meth:`run` returns when done or stopped."""

    def __init__(self, session: zenoh.Session, recording: Recording, opts: PlayOptions | None = None):
        self.session = session
        self.rec = recording
        self.opts = opts or PlayOptions()
        self.stats = PlayStats()
        self._stop = threading.Event()
        self._running = threading.Event()  # cleared while paused
        self._running.set()
        self._devices: dict[str, _Device] = {}
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._filter = zenoh.KeyExpr(keys.template_to_keyexpr(self.opts.devices)) if self.opts.devices else None
        self._remap_cache: dict[str, str] = {}
        self._queries: queue.SimpleQueue = queue.SimpleQueue()
        self._answerer = threading.Thread(target=self._answer_queries, name="rsal-play-rpc", daemon=True)
        self._answerer.start()

    def stop(self) -> None:
        self._stop.set()

    # ------------------------------------------------------------------ names
    def _map(self, key: str) -> str:
        out = self._remap_cache.get(key)
        if out is None:
            out = key
            for old, new in self.opts.remap:
                if out == old or out.startswith(old + "/"):
                    out = new + out[len(old) :]
                    break
            self._remap_cache[key] = out
        return out

    def _wanted(self, kind: str, key: str) -> bool:
        if kind == "cmd" and not self.opts.commands:
            return False
        if kind == "svc":
            return self.opts.services and self._filter is None
        if self._filter is None:
            return True
        parsed = keys.parse_key(key)
        return parsed is not None and self._filter.includes(zenoh.KeyExpr(keys.device_key(parsed[0])))

    # ------------------------------------------------------------------ playing
    def prepare(self) -> int:
        """First pass: every device's ``describe`` reply and the recording's length; returns the
        number of samples to play. Raises :class:`RecordingError` when there are none."""
        first = last = None
        n = 0
        for s in self.rec.samples():
            if s.kind == "rpc" and s.key.endswith("/rpc/describe"):
                self._device(s.key.rsplit("/rpc/", 1)[0]).describe = s.data
            elif s.kind == "liveliness":
                self._device(s.key).has_tokens = True
            elif s.kind in ("data", "event", "cmd", "svc") and self._wanted(s.kind, s.key):
                n += 1
            first = s.log_time if first is None else first
            last = s.log_time
        if n == 0:
            what = f" of devices {self.opts.devices!r}" if self.opts.devices else ""
            raise RecordingError(f"{self.rec.path}: holds no recorded samples{what}; nothing to play")
        self._t0 = first
        self.stats.duration = (last - first) / 1e9
        if self.opts.start > self.stats.duration:
            raise RecordingError(
                f"--start {self.opts.start:g} is past the end of {self.rec.path} ({self.stats.duration:.1f} s long)"
            )
        return n

    def _device(self, token_key: str) -> _Device:
        dev = self._devices.get(token_key)
        if dev is None:
            dev = self._devices[token_key] = _Device(token_key)
        return dev

    def _set_alive(self, token_key: str, alive: bool) -> None:
        dev = self._device(token_key)
        if alive and dev.token is None:
            if dev.queryable is None:  # answers before its token says it is there
                dev.queryable = self.session.declare_queryable(
                    f"{self._map(token_key)}/rpc/*", lambda q, d=dev: self._queries.put((d, q))
                )
            dev.token = self.session.liveliness().declare_token(self._map(token_key))
            self.stats.devices.add(token_key)
        elif not alive and dev.token is not None:
            dev.token.undeclare()
            dev.token = None
        self.stats.alive = sum(1 for d in self._devices.values() if d.token is not None)

    def _answer_queries(self) -> None:
        """The answering thread: Zenoh's threads only queue the queries (they never call Zenoh)."""
        while True:
            item = self._queries.get()
            if item is None:
                return
            self._answer(*item)

    def _answer(self, dev: _Device, query) -> None:
        try:
            op = str(query.key_expr).rsplit("/", 1)[-1]
            if op in ("describe", "*", "**") and dev.describe is not None:
                query.reply(f"{self._map(dev.token_key)}/rpc/describe", self._describe_bytes(dev))
            else:
                query.reply_err(
                    error_reply(ErrorCode.UNAVAILABLE, f"{self._map(dev.token_key)} is a replay: no operation {op!r}")
                )
        except Exception as e:  # a closed query must not end the player
            log.debug("reply failed: %s", e)
        finally:
            query.drop()

    def _describe_bytes(self, dev: _Device) -> bytes:
        if not self.opts.remap or self._map(dev.token_key) == dev.token_key:
            return dev.describe
        m = ormsgpack.unpackb(dev.describe)
        parsed = keys.parse_key(self._map(dev.token_key))
        if isinstance(m, dict) and parsed is not None:
            m["node"] = parsed[0].node
        return ormsgpack.packb(m)

    def _publisher(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._pubs[key] = self.session.declare_publisher(self._map(key))
        return pub

    def run(self, progress: Callable[[PlayStats], None] | None = None) -> PlayStats:
        """Play (again and again with ``loop``) until the end or :meth:`stop`."""
        if not hasattr(self, "_t0"):
            self.prepare()
        try:
            while not self._stop.is_set():
                self._one_pass(progress)
                self.stats.passes += 1
                if not self.opts.loop or self._stop.is_set():
                    break
        finally:
            self.close()
        return self.stats

    def _one_pass(self, progress) -> None:
        start_ns = self._t0 + int(self.opts.start * 1e9)
        self._wall0: float | None = None
        next_report = 0.0
        for s in self.rec.samples():
            if self._stop.is_set():
                return
            if s.kind == "rpc":
                continue
            live = s.kind == "liveliness"
            if not self._wanted("data" if live else s.kind, s.key):
                continue
            if s.log_time < start_ns or (live and self._wall0 is None):
                if live:  # before --start or the first sample: devices come up before any data
                    self._set_alive(s.key, _alive(s.data))
                continue
            if not self._wait_for(s.log_time, start_ns):
                return
            if live:
                self._set_alive(s.key, _alive(s.data))
                continue
            parsed = keys.parse_key(s.key) if s.kind != "svc" else None
            if parsed is not None:
                dev = self._device(keys.device_key(parsed[0]))
                if not dev.has_tokens and dev.token is None:
                    self._set_alive(dev.token_key, True)  # recorded without its token: up with its first sample
            self._publisher(s.key).put(s.data)
            self.stats.messages += 1
            self.stats.position = (s.log_time - self._t0) / 1e9
            now = time.monotonic()
            if progress is not None and now >= next_report:
                next_report = now + 1.0
                progress(self.stats)

    def _wait_for(self, log_time: int, start_ns: int) -> bool:
        """Sleep until ``log_time``'s moment of the playback; False when stopped meanwhile."""
        if self._wall0 is None:
            if self.stats.passes == 0 and self.opts.delay > 0 and self._stop.wait(self.opts.delay):
                return False  # the devices are up; subscribers get the delay to find them
            self._wall0 = time.monotonic()
        while True:
            if not self._running.is_set():  # paused: the clock of the playback stops with it
                paused_at = time.monotonic()
                while not self._running.wait(0.05):
                    if self._stop.is_set():
                        return False
                self._wall0 += time.monotonic() - paused_at
            if self.opts.rate <= 0:
                return not self._stop.is_set()
            wait = self._wall0 + (log_time - start_ns) / 1e9 / self.opts.rate - time.monotonic()
            if wait <= 0:
                self.stats.lag_max = max(self.stats.lag_max, -wait)
                return True
            if self._stop.wait(min(wait, 0.05)):  # short naps: a pause takes effect at once
                return False

    def pause(self) -> None:
        """Hold the playback (the devices stay up and answer ``describe``); :meth:`resume` goes on
        where it stopped, with the recorded timing."""
        self._running.clear()
        self.stats.paused = True

    def resume(self) -> None:
        self._running.set()
        self.stats.paused = False

    def close(self) -> None:
        self._queries.put(None)
        for dev in self._devices.values():
            for ent in (dev.token, dev.queryable):
                if ent is not None:
                    try:
                        ent.undeclare()
                    except Exception:
                        pass
            dev.token = dev.queryable = None
        for pub in self._pubs.values():
            try:
                pub.undeclare()
            except Exception:
                pass
        self._pubs.clear()


def check_profile(rec: Recording) -> str | None:
    """A note when the file was not written by ``rsal record`` (played anyway, as far as it fits)."""
    if rec.profile not in (None, PROFILE):
        return f"{rec.path}: written with MCAP profile {rec.profile!r}, not {PROFILE!r}; playing the keys it holds"
    return None
