"""The player behind ``rsal play``: a recording's devices back on the fabric (Player's ``readlog``).

Reads a file written by :class:`rsal.record.Recorder` (layout: :mod:`rsal.record.format`) through
:class:`rsal.record.reading.Recording`: with the MCAP index when the file has one (``--start`` then
decompresses only the chunks from that moment on), front to back otherwise, so a file without its
index (a recorder killed with SIGKILL) or cut short plays as far as it is valid, and
:attr:`Recording.skipped` says what was not.

For each recorded device the player declares, in this order, a queryable on ``rpc/*`` answering
``describe`` with the recorded reply (other operations: ``unavailable``, a recording cannot act),
then its liveliness token, at the moment the recording saw it join; it withdraws the token when
the recording saw it leave. Samples are published on their recorded keys with their recorded bytes,
at their recorded receive times scaled by ``rate`` (0: as fast as it goes). ``remap`` renames nodes
(``r0=r5``) or key prefixes (``rsal/r0=rsal/ghost``); the ``node`` field of a replayed ``describe``
follows the rename, sample bytes never change.

With ``control`` (``rsal play`` sets node ``play``) the player is itself a device,
``rsal/<control>/player/0`` (docs/protocol.md) with the rpcs ``pause``, ``resume``, ``status`` and
``seek`` (it publishes no data: a subscriber to the replayed keys gets nothing else). The keyboard
and the rpcs go through the same :meth:`Player.pause`, :meth:`Player.resume` and
:meth:`Player.seek`; the playback clock stops while paused, so the recorded spacing of
the samples continues after a resume (no burst)."""

from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time
from collections.abc import Callable

import ormsgpack
import zenoh

from .. import keys
from ..msgs import ErrorCode, error_reply, ok_reply
from ..ownership import DeviceToken
from .format import RecordingError
from .reading import Recording, Sample
from .reading import alive as _alive

__all__ = ["Recording", "Sample", "Player", "PlayOptions", "PlayStats", "parse_remap", "CONTROL_OPS"]

#: the operations of the player's control device (``rsal/<node>/player/0``), ``describe`` first
CONTROL_OPS = ("describe", "pause", "resume", "status", "seek")

log = logging.getLogger(__name__)


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
    control: str | None = None  # node of the control device rsal/<control>/player/0 (None: none)
    paused: bool = False  # start paused: the devices come up, the samples wait for resume()
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
        self._lock = threading.Lock()
        self._seek_to: float | None = None
        self._delayed = False  # opts.delay is waited once, before the first sample
        self._control = None
        if self.opts.paused:
            self.pause()
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
        """What the recording holds (from its index when it has one): every device's ``describe``
        reply and the recording's length; returns the number of samples to play. Raises
        :class:`RecordingError` when there are none. Declares the control device."""
        c = self.rec.contents()
        for token_key, data in c.describes.items():
            self._device(token_key).describe = data
        for token_key in c.live_keys:
            self._device(token_key).has_tokens = True
        n = sum(
            k
            for (kind, key), k in c.counts.items()
            if kind in ("data", "event", "cmd", "svc") and self._wanted(kind, key)
        )
        if n == 0 or c.first_ns is None:
            what = f" of devices {self.opts.devices!r}" if self.opts.devices else ""
            raise RecordingError(f"{self.rec.path}: holds no recorded samples{what}; nothing to play")
        self._t0 = c.first_ns
        self.stats.duration = (c.last_ns - c.first_ns) / 1e9
        if self.opts.start > self.stats.duration:
            raise RecordingError(
                f"--start {self.opts.start:g} is past the end of {self.rec.path} ({self.stats.duration:.1f} s long)"
            )
        self.stats.position = self.opts.start
        if self.opts.control and self._control is None:
            self._declare_control(self.opts.control)
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
            dev.token = DeviceToken(self.session, self._map(token_key))
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

    def _answer(self, dev: _Device | None, query) -> None:
        try:
            if dev is None:
                self._answer_control(query)
                return
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
        start = self.opts.start
        while True:
            start = self._play_from(start, progress)
            if start is None:
                return

    def _play_from(self, start: float, progress) -> float | None:
        """Play from ``start`` s into the recording to its end; returns where to go on after a
        :meth:`seek`, None at the end or when stopped."""
        start_ns = self._t0 + int(start * 1e9)
        self._wall0: float | None = None
        next_report = 0.0
        for s in self.rec.samples(start_ns if start > 0 else None):
            if self._stop.is_set():
                return None
            if self._seek_to is not None:
                return self._take_seek()
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
                return self._take_seek() if self._seek_to is not None else None
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
        return self._take_seek() if self._seek_to is not None else None

    def _take_seek(self) -> float:
        with self._lock:
            t, self._seek_to = self._seek_to, None
        self.stats.position = t
        return t

    def _wait_for(self, log_time: int, start_ns: int) -> bool:
        """Sleep until ``log_time``'s moment of the playback; False when stopped or sought meanwhile."""
        if self._wall0 is None:
            if not self._delayed:
                self._delayed = True
                if self.opts.delay > 0 and self._stop.wait(self.opts.delay):
                    return False  # the devices are up; subscribers get the delay to find them
            self._wall0 = time.monotonic()
        while True:
            if not self._running.is_set():  # paused: the clock of the playback stops with it
                paused_at = time.monotonic()
                while not self._running.wait(0.05):
                    if self._stop.is_set() or self._seek_to is not None:
                        return False
                self._wall0 += time.monotonic() - paused_at
            if self._seek_to is not None:
                return False
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
        where it stopped, with the recorded timing. The keyboard and the ``pause`` rpc call this."""
        self._running.clear()
        self.stats.paused = True

    def resume(self) -> None:
        self._running.set()
        self.stats.paused = False

    def seek(self, t: float) -> None:
        """Go on from ``t`` seconds into the recording (read through the index where there is one);
        a paused playback stays paused there."""
        if not 0.0 <= t <= self.stats.duration:
            raise RecordingError(f"seek to {t:g} s: outside the recording (0 to {self.stats.duration:.1f} s)")
        with self._lock:
            self._seek_to = float(t)

    def status(self) -> dict:
        st = self.stats
        return {
            "position": round(st.position, 6),
            "duration": round(st.duration, 6),
            "rate": self.opts.rate,
            "paused": st.paused,
            "messages": st.messages,
            "passes": st.passes,
            "devices": st.alive,
        }

    # ------------------------------------------------------------------ the control device
    def _declare_control(self, node: str) -> None:
        keys.check_name("node", node)
        base = f"{keys.PREFIX}/{node}/player/0"
        self._control_describe = ok_reply(
            node=node,
            interface="player",
            index=0,
            driver="play",
            rate=0.0,
            geometry={"files": [str(p) for p in self.rec.paths], "duration": self.stats.duration},
            ops=list(CONTROL_OPS),
            cmd="",
            data="",
            protocol=keys.PROTOCOL_VERSION,
        )
        q = self.session.declare_queryable(f"{base}/rpc/*", lambda query: self._queries.put((None, query)))
        self._control = (base, q, DeviceToken(self.session, base))

    def _answer_control(self, query) -> None:
        base = self._control[0]
        op = str(query.key_expr).rsplit("/", 1)[-1]
        if op in ("describe", "*", "**"):
            query.reply(f"{base}/rpc/describe", self._control_describe)
            return
        if op not in CONTROL_OPS:
            query.reply_err(
                error_reply(ErrorCode.NOT_FOUND, f"{base}: no operation {op!r}; it has {', '.join(CONTROL_OPS)}")
            )
            return
        args = {}
        payload = query.payload.to_bytes() if query.payload is not None else b""
        if payload:
            try:
                args = ormsgpack.unpackb(payload)
            except Exception:
                args = None
            if not isinstance(args, dict):
                query.reply_err(
                    error_reply(ErrorCode.BAD_REQUEST, f"{base}/rpc/{op}: the arguments must be a msgpack map")
                )
                return
        if op == "pause":
            self.pause()
        elif op == "resume":
            self.resume()
        elif op == "seek":
            t = args.get("t")
            if isinstance(t, bool) or not isinstance(t, (int, float)):
                query.reply_err(
                    error_reply(ErrorCode.BAD_REQUEST, f"{base}/rpc/seek needs 't', seconds into the recording")
                )
                return
            try:
                self.seek(float(t))
            except RecordingError as e:
                query.reply_err(error_reply(ErrorCode.OUT_OF_RANGE, f"{base}: {e}"))
                return
            self.stats.position = float(t)
        query.reply(f"{base}/rpc/{op}", ok_reply(**self.status()))

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
        if self._control is not None:
            for ent in (self._control[2], self._control[1]):
                try:
                    ent.undeclare()
                except Exception:
                    pass
            self._control = None


def check_profile(rec: Recording) -> str | None:
    """A note when the file was not written by ``rsal record`` (played anyway, as far as it fits)."""
    return rec.profile_note()
