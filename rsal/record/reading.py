"""Reading a fabric recording (layout: :mod:`rsal.record.format`): sequentially, or through the MCAP index.

A finished MCAP file ends with a summary section (MCAP specification, "Summary Section"): the
channels, statistics (message count and first/last ``log_time``, per-channel counts) and one
*chunk index* per chunk (its offset, its first and last ``log_time``, the channels it holds).
:class:`Recording` uses it when it is there:

- :meth:`Recording.contents` (what the player needs before playing: length, sample counts, each
  device's ``describe`` reply, which devices have recorded joins) comes from the statistics and
  from the few chunks that hold ``rpc`` and ``liveliness`` channels, not from every chunk;
- :meth:`Recording.samples` with ``start_ns`` (``rsal play --start T``) decompresses only the
  chunks that end at or after ``start_ns``, plus the ``liveliness`` messages of earlier chunks that
  hold any (the devices alive at ``T``): a start near the end of a long file reads a few chunks.

A file without its summary (a recorder killed with SIGKILL) or cut short is read front to back with
the ``mcap`` package's stream reader up to its first invalid record; :attr:`Recording.skipped`
says, in one line, what was not read, and also when the file was written with another format
version or another MCAP profile. :attr:`Recording.chunks_read` counts the chunks decompressed by
indexed reads (a measure for tests and benchmarks).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from pathlib import Path

import ormsgpack
from mcap.records import Chunk
from mcap.stream_reader import StreamReader, breakup_chunk

from .format import FORMAT_VERSION, MAGIC, META_NAME, PROFILE, RecordingError

__all__ = ["Sample", "Recording", "Contents"]

LIVE_KINDS = ("rpc", "liveliness")  # what is read from the chunks before --start


@dataclasses.dataclass(frozen=True)
class Sample:
    kind: str  # format.KINDS
    key: str
    data: bytes
    log_time: int  # ns, receive time
    publish_time: int  # ns, source time


@dataclasses.dataclass
class Contents:
    """What a recording holds, for the player's preparation."""

    first_ns: int | None = None
    last_ns: int | None = None
    counts: dict = dataclasses.field(default_factory=dict)  # (kind, key) -> samples
    describes: dict = dataclasses.field(default_factory=dict)  # token key -> describe reply bytes
    live_keys: set = dataclasses.field(default_factory=set)  # token keys with recorded joins/leaves


class Recording:
    """A recording: one file, or the parts of a split one in order; :attr:`skipped` says what was
    not valid (a file cut short or without its index, another format version)."""

    def __init__(self, *paths: str | os.PathLike):
        if not paths:
            raise RecordingError("no recording given; name the .mcap file 'rsal record -o' wrote")
        self.paths = [Path(p) for p in paths]
        for path in self.paths:
            _check_file(path)
        self.path = self.paths[0] if len(self.paths) == 1 else Path(f"{self.paths[0]} (+{len(self.paths) - 1} parts)")
        self._skipped: dict[str, None] = {}  # ordered, each note once
        self.profile: str | None = None
        self.format_version: str | None = None
        self.chunks_read = 0
        self._summaries: dict[Path, object] = {}

    @property
    def skipped(self) -> str | None:
        return "; ".join(self._skipped) if self._skipped else None

    def _note(self, text: str) -> None:
        self._skipped[text] = None

    # ------------------------------------------------------------------ the index
    def summary(self, path: Path):
        """The file's MCAP summary (channels, statistics, chunk indexes), or None without one."""
        if path not in self._summaries:
            self._summaries[path] = _read_summary(path)
            s = self._summaries[path]
            if s is not None:
                self._read_head(path, s)
        return self._summaries[path]

    def _read_head(self, path: Path, summary) -> None:
        with open(path, "rb") as f:
            header = next(StreamReader(f).records, None)
            if type(header).__name__ == "Header":
                self.profile = header.profile
            for mi in summary.metadata_indexes:
                if mi.name == META_NAME:
                    f.seek(mi.offset)
                    self._metadata(path, next(StreamReader(f, skip_magic=True).records))

    def _metadata(self, path: Path, rec) -> None:
        if getattr(rec, "name", None) != META_NAME:
            return
        self.format_version = rec.metadata.get("format_version")
        if self.format_version != FORMAT_VERSION:
            self._note(
                f"{path}: written with recording format version {self.format_version!r}, this player reads "
                f"{FORMAT_VERSION!r}; playing the samples whose layout it knows"
            )

    def _read_chunk(self, f, ci, channels: dict, only: set | None) -> Iterator[Sample]:
        f.seek(ci.chunk_start_offset)
        chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
        if not isinstance(chunk, Chunk):
            raise RecordingError(f"{f.name}: the index points at a {type(chunk).__name__}, not a chunk")
        self.chunks_read += 1
        for rec in breakup_chunk(chunk, validate_crc=True):
            if type(rec).__name__ == "Message":
                ch = channels.get(rec.channel_id)
                if ch is not None and (only is None or rec.channel_id in only):
                    yield Sample(ch[1], ch[0], rec.data, rec.log_time, rec.publish_time)

    def indexed(self) -> bool:
        """Every part has its summary with chunk indexes (else the reads are sequential)."""
        return all(self.summary(p) is not None for p in self.paths)

    # ------------------------------------------------------------------ reading
    def contents(self) -> Contents:
        """Length, sample counts, ``describe`` replies and recorded joins; from the index when every
        part has one, else by reading every sample."""
        c = Contents()
        if not self.indexed():
            for s in self.samples():
                _add(c, s)
            return c
        for path in self.paths:
            summ = self.summary(path)
            channels = _channels(summ)
            st = summ.statistics
            if st is not None and st.message_count:
                c.first_ns = st.message_start_time if c.first_ns is None else min(c.first_ns, st.message_start_time)
                c.last_ns = st.message_end_time if c.last_ns is None else max(c.last_ns, st.message_end_time)
                for cid, n in st.channel_message_counts.items():
                    if cid in channels and channels[cid][1] not in LIVE_KINDS:
                        k = (channels[cid][1], channels[cid][0])
                        c.counts[k] = c.counts.get(k, 0) + n
            wanted = {cid for cid, (_, kind) in channels.items() if kind in LIVE_KINDS}
            with open(path, "rb") as f:
                for ci in summ.chunk_indexes:
                    if wanted & set(ci.message_index_offsets):
                        for s in self._read_chunk(f, ci, channels, wanted):
                            _add(c, s, count=False)
        return c

    def samples(self, start_ns: int | None = None) -> Iterator[Sample]:
        """Every recorded message in file order, part after part. With ``start_ns`` and an index,
        chunks that end before it are not decompressed, except for their ``liveliness`` messages
        (what comes before ``start_ns`` is for the caller to skip). Without an index a part is read
        front to back up to its first invalid record, noted in :attr:`skipped`."""
        for path in self.paths:
            summ = self.summary(path) if start_ns is not None else None
            if summ is not None and summ.chunk_indexes:
                yield from self._indexed_samples(path, summ, start_ns)
            else:
                yield from self._file_samples(path)

    def _indexed_samples(self, path: Path, summ, start_ns: int) -> Iterator[Sample]:
        channels = _channels(summ)
        live = {cid for cid, (_, kind) in channels.items() if kind == "liveliness"}
        with open(path, "rb") as f:
            for ci in sorted(summ.chunk_indexes, key=lambda c: c.chunk_start_offset):
                if ci.message_end_time >= start_ns:
                    yield from self._read_chunk(f, ci, channels, None)
                elif live & set(ci.message_index_offsets):
                    yield from self._read_chunk(f, ci, channels, live)

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
                        self._note(
                            f"{path}: ends without its index (the recorder was stopped abruptly); "
                            "read every complete chunk, the chunk it was writing is lost"
                        )
                    else:
                        self._note(
                            f"{path}: read up to the last complete chunk; skipped the rest "
                            f"({left / 1024:.1f} KB of {size / 1024:.0f} KB: {_why(e)})"
                        )
                    return
                name = type(rec).__name__
                if name == "Header":
                    self.profile = rec.profile
                elif name == "Metadata":
                    self._metadata(path, rec)
                elif name == "Channel":
                    channels[rec.id] = (rec.topic, rec.metadata.get("kind", "data"))
                elif name == "Message":
                    ch = channels.get(rec.channel_id)
                    if ch is not None:
                        yield Sample(ch[1], ch[0], rec.data, rec.log_time, rec.publish_time)
                elif name in ("DataEnd", "Footer"):
                    return  # the summary section repeats what came before

    def profile_note(self) -> str | None:
        """A note when the file was not written by ``rsal record`` (played anyway, as far as it fits)."""
        if self.profile not in (None, PROFILE):
            return (
                f"{self.path}: written with MCAP profile {self.profile!r}, not {PROFILE!r}; playing the keys it holds"
            )
        return None


def _add(c: Contents, s: Sample, count: bool = True) -> None:
    if s.kind == "rpc" and s.key.endswith("/rpc/describe"):
        c.describes[s.key.rsplit("/rpc/", 1)[0]] = s.data
    elif s.kind == "liveliness":
        c.live_keys.add(s.key)
    elif count:
        c.counts[(s.kind, s.key)] = c.counts.get((s.kind, s.key), 0) + 1
    if count:
        c.first_ns = s.log_time if c.first_ns is None else c.first_ns
        c.last_ns = s.log_time


def _channels(summary) -> dict[int, tuple[str, str]]:
    return {cid: (ch.topic, ch.metadata.get("kind", "data")) for cid, ch in summary.channels.items()}


def _read_summary(path: Path):
    from mcap.reader import SeekingReader

    try:
        with open(path, "rb") as f:
            return SeekingReader(f, validate_crcs=True).get_summary()
    except Exception:  # no footer (killed recorder, file cut short): read sequentially
        return None


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


def alive(data: bytes) -> bool:
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
