"""``rsal play`` (rsal/record/player.py, reading.py): the control device, ``--start`` through the MCAP
index, and files of another format version.

The recordings here are written with the ``mcap`` package in the layout of docs/recording.md (a
laser at 10 Hz for two minutes in small chunks), so they are long without a simulator; the
recorder's own files are tested in test_record.py.
"""

from __future__ import annotations

import os
import shutil
import threading
import time

import msgpack
import pytest
import zenoh
from mcap.writer import CompressionType, Writer

from rsal.record import Player, PlayOptions, Recording
from tests.conftest import Proc, free_port, rsal_cmd, stock_session, wait_until

LASER = "rsal/r0/laser/0"
SECONDS, HZ = 120, 10
T0 = 1_700_000_000 * 10**9  # ns: the recording's first receive time


def write_recording(path, *, seconds=SECONDS, version="1", chunk_size=4096) -> int:
    """A laser scan every 0.1 s for ``seconds``, its join and describe first; returns the scans."""
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        w.start(profile="rsal", library="test")
        w.add_metadata("rsal.recording", {"format_version": version, "protocol_version": "1"})
        ids = {}
        for kind, key in (("liveliness", LASER), ("rpc", f"{LASER}/rpc/describe"), ("data", f"{LASER}/data")):
            ids[kind] = w.register_channel(key, "msgpack", 0, {"kind": kind, "device": "r0:laser:0"})
        w.add_message(ids["liveliness"], T0, msgpack.packb({"alive": True}), T0)
        desc = {"ok": True, "node": "r0", "interface": "laser", "index": 0, "driver": "test", "rate": 10.0}
        w.add_message(ids["rpc"], T0, msgpack.packb(desc), T0)
        n = seconds * HZ
        for i in range(n):
            t = T0 + i * 10**9 // HZ
            scan = {"t": i / HZ, "ranges": bytes(range(256)) * 4, "i": i}
            w.add_message(ids["data"], t, msgpack.packb(scan), t, sequence=i)
        w.finish()
    return n


@pytest.fixture(scope="module")
def long_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("play") / "long.mcap"
    write_recording(path)
    return path


def test_a_start_near_the_end_reads_a_few_chunks_through_the_index(long_file):
    from mcap.reader import make_reader

    with open(long_file, "rb") as f:
        index = make_reader(f).get_summary().chunk_indexes
    chunks = len(index)
    assert chunks >= 100, "a long file of many chunks"
    start = SECONDS - 5.0
    tail = sum(1 for ci in index if ci.message_end_time >= T0 + int(start * 1e9))  # the last 5 s
    assert tail < chunks / 10
    want = sum(1 for i in range(SECONDS * HZ) if i / HZ >= start)
    with stock_session(listen=f"tcp/127.0.0.1:{free_port()}") as s:
        rec = Recording(long_file)
        player = Player(s, rec, PlayOptions(rate=0, start=start))
        st = player.run()
        assert st.messages == want
        assert "rsal/r0/laser/0" in st.devices, "the device that joined before --start is up"
        # the last 5 s and the first chunk (join, describe; read once to prepare, once to play)
        assert rec.chunks_read <= tail + 2, f"{rec.chunks_read} of {chunks} chunks decompressed, {tail} needed"
        # the same playback from the front decompresses every chunk
        rec2 = Recording(long_file)
        st2 = Player(s, rec2, PlayOptions(rate=0, start=0.05)).run()
        assert st2.messages == SECONDS * HZ - 1 and rec2.chunks_read >= chunks
    assert rec.skipped is None


def test_start_without_an_index_reads_from_the_front_and_says_so(long_file, tmp_path):
    cut = tmp_path / "cut.mcap"
    shutil.copy(long_file, cut)
    os.truncate(cut, cut.stat().st_size * 3 // 4)  # no summary: sequential, up to the cut
    rec = Recording(cut)
    assert not rec.indexed()
    with stock_session(listen=f"tcp/127.0.0.1:{free_port()}") as s:
        st = Player(s, rec, PlayOptions(rate=0, start=30.0)).run()
    assert 0 < st.messages < (SECONDS - 30) * HZ
    assert rec.skipped and "skipped the rest" in rec.skipped and "\n" not in rec.skipped


def test_another_format_version_plays_with_one_line_saying_so(tmp_path):
    old = tmp_path / "old.mcap"
    n = write_recording(old, seconds=2, version="0", chunk_size=1024)
    cut = tmp_path / "old_cut.mcap"
    shutil.copy(old, cut)
    os.truncate(cut, cut.stat().st_size // 2)  # and cut short: both in the one line
    for path, parts in ((old, ["format version '0'"]), (cut, ["format version '0'", "skipped the rest"])):
        p = Proc(rsal_cmd("play", str(path), "--rate", "0", "--listen", f"tcp/127.0.0.1:{free_port()}"))
        try:
            p.p.wait(30)
            out = p.output()
        finally:
            p.close()
        assert p.p.returncode == 0, out
        lines = [ln for ln in out.splitlines() if ln.startswith("rsal play:")]
        assert len(lines) == 1 and all(x in lines[0] for x in parts), out
        assert "Traceback" not in out
        if path == old:
            assert f"{n} messages" in out, out


def rpc(s: zenoh.Session, op: str, args: dict | None = None) -> dict:
    key = f"rsal/play/player/0/rpc/{op}"
    replies = list(s.get(key, payload=msgpack.packb(args or {}), timeout=5.0))
    assert len(replies) == 1, (op, replies)
    r = replies[0]
    return msgpack.unpackb(r.ok.payload.to_bytes() if r.ok else r.err.payload.to_bytes())


def test_the_control_device_pauses_seeks_and_resumes_a_running_rsal_play(long_file):
    ep = f"tcp/127.0.0.1:{free_port()}"
    got: list[tuple[float, int]] = []  # (arrival, scan index)
    lock = threading.Lock()

    def on_scan(smp):
        with lock:
            got.append((time.monotonic(), msgpack.unpackb(smp.payload.to_bytes())["i"]))

    with stock_session(listen=ep) as s:
        sub = s.declare_subscriber(f"{LASER}/data", on_scan)
        play = Proc(rsal_cmd("play", str(long_file), "--connect", ep, "--rate", "1"))
        try:
            wait_until(
                lambda: any(r.ok for r in s.liveliness().get("rsal/play/player/0", timeout=1.0)),
                20,
                "the control device's token",
            )
            d = rpc(s, "describe")
            assert (
                d["ok"] and d["interface"] == "player" and d["ops"] == ["describe", "pause", "resume", "status", "seek"]
            )
            wait_until(lambda: len(got) >= 5, 10, "the first scans")
            st = rpc(s, "pause")
            assert st["ok"] and st["paused"] is True and st["duration"] == pytest.approx(SECONDS - 0.1)
            time.sleep(0.3)  # in flight before the pause took effect
            with lock:
                held = len(got)
            time.sleep(1.0)
            assert len(got) == held, "nothing is published while paused"
            st = rpc(s, "seek", {"t": 100.0})
            assert st["ok"] and st["paused"] is True
            wait_until(lambda: rpc(s, "status")["position"] == pytest.approx(100.0), 5, "the position after seek")
            assert len(got) == held, "a paused seek publishes nothing"
            bad = rpc(s, "seek", {"t": 1e6})
            assert bad["ok"] is False and bad["code"] == "out_of_range" and "outside the recording" in bad["message"]
            bad = rpc(s, "jump")
            assert bad["ok"] is False and bad["code"] == "not_found"
            resumed = time.monotonic()
            assert rpc(s, "resume")["paused"] is False
            wait_until(lambda: len(got) >= held + 15, 10, "scans after the resume")
            with lock:
                after = [(t - resumed, i) for t, i in got[held:]]
            assert after[0][1] == 1000, "the playback went on from 100 s: scan 1000"
            # the recorded 10 Hz continue: no burst of what the pause held back
            early = [i for t, i in after if t < 0.5]
            assert len(early) <= 6, f"{len(early)} scans in the first 0.5 s after resuming"
            span = after[14][0] - after[0][0]
            assert 1.2 <= span <= 1.6, f"15 scans over {span:.2f} s at the recorded 10 Hz"
            st = rpc(s, "status")
            assert st["rate"] == 1.0 and st["position"] >= 100.5 and not st["paused"]
        finally:
            play.close()
        sub.undeclare()
