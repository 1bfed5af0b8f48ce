"""The recorder behind ``rsal record``: every sample of the matching devices into an MCAP file.

Player's ``writelog`` driver and ROS 2's ``rosbag2 record`` in the fabric's terms: subscriptions on
the devices' ``data`` and ``event`` keys (``cmd`` and agents' ``svc/**`` on request), a liveliness
subscriber for joins and leaves, and each device's ``describe`` reply asked for when it appears.
The layout of the file is :mod:`rsal.record.format`.

Zenoh's threads only stamp the receive time and append ``(kind, key, bytes, t_ns)`` to a bounded
deque (no lock, no zenoh call, never blocking); when it is full the sample is counted as dropped.
One writer thread drains the deque into the MCAP writer (the ``mcap`` package), asks for the
``describe`` replies, and flushes the file after every batch, so a recorder killed with SIGKILL
leaves every finished chunk readable; a chunk is closed when it reaches ``chunk_size`` bytes or
``chunk_seconds`` of age, which bounds what such a kill loses.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import os
import threading
import time
from pathlib import Path

import zenoh
from mcap.writer import CompressionType, Writer

from .. import keys
from .format import ENCODING, FORMAT_VERSION, META_NAME, PROFILE, liveliness_message, source_time_ns
from .format import channel_meta as _channel_meta

__all__ = ["Recorder", "RecordOptions", "RecordStats"]

log = logging.getLogger(__name__)


@dataclasses.dataclass
class RecordOptions:
    templates: list[str] = dataclasses.field(default_factory=lambda: ["**"])
    commands: bool = False
    services: bool = False
    chunk_size: int = 256 * 1024  # bytes of a chunk before it is compressed and written
    chunk_seconds: float = 1.0  # a chunk older than this is closed (bounds what a SIGKILL loses)
    split_size: int | None = None  # bytes: start a new file once one is this big
    split_duration: float | None = None  # s: start a new file once one spans this long
    queue_max: int = 200_000  # samples waiting for the writer; beyond, they are dropped and counted
    describe_timeout: float = 5.0


@dataclasses.dataclass
class RecordStats:
    messages: int = 0
    bytes: int = 0  # wire bytes of the recorded messages
    dropped: int = 0
    channels: int = 0
    devices: set = dataclasses.field(default_factory=set)  # token keys seen alive
    alive: int = 0
    started: float = dataclasses.field(default_factory=time.monotonic)


class Recorder:
    """Record the fabric into ``path`` until :meth:`stop`; ``stats`` is updated as it goes."""

    def __init__(self, session: zenoh.Session, path: str | os.PathLike, opts: RecordOptions | None = None):
        self.session = session
        self.opts = opts or RecordOptions()
        self.base = Path(path)
        self.splitting = bool(self.opts.split_size or self.opts.split_duration)
        self.path = self._part(0) if self.splitting else self.base
        self.files: list[Path] = []  # every file written, in order
        self.stats = RecordStats()
        self.kes = _dedupe([keys.template_to_keyexpr(t) for t in (self.opts.templates or ["**"])])
        self._q: collections.deque = collections.deque()
        self._stop = threading.Event()
        self._drop_lock = threading.Lock()
        self._subs: list = []
        self._channels: dict[str, int] = {}  # key -> channel id in the current file
        self._keys: set[str] = set()  # every key recorded
        self._alive: set[str] = set()
        self._describes: dict[str, bytes] = {}  # rpc key -> reply, written again at the top of each part
        self._opened = 0.0
        self._closed_bytes = 0
        self._file = None
        self._writer: Writer | None = None
        self._thread: threading.Thread | None = None
        self._chunk_open_since: float | None = None
        self.error: BaseException | None = None

    # ------------------------------------------------------------------ zenoh side (never blocks)
    def _put(self, kind: str, key: str, payload: bytes) -> None:
        if len(self._q) >= self.opts.queue_max:
            with self._drop_lock:  # only on overflow: the normal path takes no lock
                self.stats.dropped += 1
            return
        self._q.append((kind, key, payload, time.time_ns()))

    def _on_sample(self, kind: str):
        return lambda smp: self._put(kind, str(smp.key_expr), smp.payload.to_bytes())

    def _on_token(self, smp) -> None:
        self._put("liveliness", str(smp.key_expr), b"\x01" if smp.kind == zenoh.SampleKind.PUT else b"")

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        """Open the file and subscribe; raises ``OSError`` when the file cannot be created."""
        self.base.parent.mkdir(parents=True, exist_ok=True)
        self._open(self.path)
        s = self.session
        for ke in self.kes:  # tokens first: a device's join is usually recorded before its data
            self._subs.append(s.liveliness().declare_subscriber(ke, self._on_token, history=True))
            self._subs.append(s.declare_subscriber(f"{ke}/data", self._on_sample("data")))
            self._subs.append(s.declare_subscriber(f"{ke}/event", self._on_sample("event")))
            if self.opts.commands:
                self._subs.append(s.declare_subscriber(f"{ke}/cmd", self._on_sample("cmd")))
        if self.opts.services:
            self._subs.append(s.declare_subscriber(f"{keys.SVC_PREFIX}/**", self._on_sample("svc")))
        self._thread = threading.Thread(target=self._run, name="rsal-record-writer", daemon=True)
        self._thread.start()

    def _part(self, n: int) -> Path:
        return self.base.with_name(f"{self.base.stem}_{n:03d}{self.base.suffix}")

    def _open(self, path: Path, at_ns: int | None = None) -> None:
        """Start a file: header, metadata, and (for a later part) the devices alive and their
        ``describe`` replies, so that each part plays on its own."""
        self.path = path
        self._file = open(path, "wb")
        self.files.append(path)
        self._opened = time.monotonic()
        self._channels = {}
        self._writer = Writer(self._file, chunk_size=self.opts.chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library="rsal record")
        self._writer.add_metadata(
            META_NAME,
            {
                "format_version": FORMAT_VERSION,
                "protocol_version": str(keys.PROTOCOL_VERSION),
                "templates": " ".join(self.opts.templates or ["**"]),
                "commands": str(self.opts.commands).lower(),
                "services": str(self.opts.services).lower(),
                "started_unix_ns": str(time.time_ns()),
                "part": str(len(self.files) - 1),
            },
        )
        now = at_ns or time.time_ns()  # restated at the cut's time: the next samples come after it
        for key in sorted(self._alive):
            self._write("liveliness", key, liveliness_message(True), now, now)
        for key, reply in self._describes.items():
            self._write("rpc", key, reply, now, now)
        self._file.flush()

    def _split_due(self) -> bool:
        o = self.opts
        return bool(
            (o.split_size and self._file.tell() >= o.split_size)
            or (o.split_duration and time.monotonic() - self._opened >= o.split_duration)
        )

    def _rotate(self, at_ns: int) -> None:
        self._writer.finish()
        self._file.close()
        self._closed_bytes += self.path.stat().st_size
        self._chunk_open_since = None
        self._open(self._part(len(self.files)), at_ns)

    def stop(self) -> None:
        """Stop subscribing, write what is queued, finish the file (index and summary)."""
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # already closed with the session
                pass
        self._subs.clear()
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._writer is not None:
            self._writer.finish()
            self._file.close()
            self._writer = None
        if self.error is not None:
            raise self.error

    def __enter__(self) -> Recorder:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def size(self) -> int:
        """Bytes written so far (every part)."""
        try:
            return self._closed_bytes + self.path.stat().st_size
        except OSError:
            return self._closed_bytes

    # ------------------------------------------------------------------ the writer thread
    def _run(self) -> None:
        try:
            while True:
                stopping = self._stop.is_set()
                n = self._drain()
                self._age_chunk()
                if n:
                    self._file.flush()
                elif stopping:
                    return
                else:
                    time.sleep(0.005)
        except BaseException as e:  # the file cannot be written (disk full, ...): stop() raises it
            self.error = e
            self._stop.set()

    def _drain(self) -> int:
        q, st = self._q, self.stats
        n = 0
        while q and n < 10_000:
            kind, key, payload, t_ns = q.popleft()
            n += 1
            if kind == "liveliness":
                alive = payload == b"\x01"
                if alive == (key in self._alive):
                    continue
                (self._alive.add if alive else self._alive.discard)(key)
                st.alive = len(self._alive)
                if alive:
                    st.devices.add(key)
                    self._ask_describe(key)
                payload, src = liveliness_message(alive), t_ns
            elif kind == "rpc":
                src = t_ns
            else:
                src = source_time_ns(payload, t_ns)
            if kind == "rpc":
                self._describes[key] = payload
            self._write(kind, key, payload, t_ns, src)
            if self.splitting and self._split_due():
                self._rotate(t_ns)
        return n

    def _write(self, kind: str, key: str, payload: bytes, t_ns: int, src: int) -> None:
        st = self.stats
        ch = self._channels.get(key)
        if ch is None:
            ch = self._channels[key] = self._writer.register_channel(key, ENCODING, 0, _channel_meta(kind, key))
            self._keys.add(key)
            st.channels = len(self._keys)
        self._writer.add_message(ch, t_ns, payload, src, sequence=st.messages & 0xFFFFFFFF)
        if self._chunk_open_since is None:
            self._chunk_open_since = time.monotonic()
        st.messages += 1
        st.bytes += len(payload)

    def _age_chunk(self) -> None:
        """Close the open chunk once it is ``chunk_seconds`` old (the writer closes it by size)."""
        since = self._chunk_open_since
        if since is None or time.monotonic() - since < self.opts.chunk_seconds:
            return
        # The mcap writer closes a chunk by size only; its one close step is private (name-mangled).
        finalize = getattr(self._writer, "_Writer__finalize_chunk", None)
        if finalize is not None:
            finalize()
            self._file.flush()
        self._chunk_open_since = None

    def _ask_describe(self, token_key: str) -> None:
        """Query the device's ``describe`` without blocking; the reply joins the queue."""
        parsed = keys.parse_key(token_key)
        if parsed is None:
            return
        rkey = keys.rpc_key(parsed[0], "describe")

        def on_reply(reply) -> None:
            if reply.ok is not None:
                self._put("rpc", rkey, reply.ok.payload.to_bytes())

        try:
            self.session.get(rkey, on_reply, timeout=self.opts.describe_timeout)
        except Exception as e:  # the session is closing
            log.debug("describe of %s not asked: %s", token_key, e)


def _dedupe(kes: list[str]) -> list[str]:
    """Drop key expressions another one already includes (a sample would be recorded twice)."""
    out: list[str] = []
    for ke in dict.fromkeys(kes):
        k = zenoh.KeyExpr(ke)
        if not any(zenoh.KeyExpr(o).includes(k) for o in kes if o != ke):
            out.append(ke)
    return out
