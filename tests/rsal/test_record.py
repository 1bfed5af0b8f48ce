"""``rsal record`` / ``rsal play`` (rsal/record) against real processes on loopback.

One ``rsal sim maps/testroom.world`` serves the module; two recorders run against it at once: one
stops by itself (``--duration``) and writes a finished MCAP file, the other is killed with SIGKILL
once it has written a few chunks. Then (a) the finished file is a valid, indexed MCAP file with the
layout docs/recording.md describes; (b) ``rsal play`` at rate 1 (the simulator stopped) gives a
stock Zenoh subscriber every recorded data sample byte for byte, on time, and answers ``describe``
with the recorded reply; (c) the killed recorder's file plays as far as its last chunk, with one
line saying what was skipped; (d) bad inputs get one line and exit 1.
"""

from __future__ import annotations

import os
import shutil
import threading
import time

import msgpack
import pytest
from mcap.writer import Writer

from rsal.cli import build_parser
from rsal.errnet import run_guarded
from rsal.record import Recording
from tests.conftest import MAPS, SPEEDUP, Proc, free_port, rsal_cmd, stock_session, wait_until

WORLD = str(MAPS / "testroom.world")
RECORD_S = 3.0


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """(finished.mcap, killed.mcap, recorder output, split parts) from one simulator run."""
    d = tmp_path_factory.mktemp("rec")
    ep = f"tcp/127.0.0.1:{free_port()}"
    started: list[Proc] = []
    try:
        sim = Proc(rsal_cmd("sim", WORLD, "--listen", ep, "--no-map", "--speedup", SPEEDUP))
        started.append(sim)
        with stock_session(connect=ep) as s:

            def alive():
                return {"rsal/r0/laser/0", "rsal/r0/position2d/0"} <= {
                    str(r.ok.key_expr) for r in s.liveliness().get("rsal/**", timeout=1.0) if r.ok
                }

            wait_until(alive, 60, "the simulated robot's devices")
        fin, killed = d / "run.mcap", d / "killed.mcap"
        rec = Proc(rsal_cmd("record", "r0:*:*", "-o", str(fin), "--connect", ep, "--duration", str(RECORD_S)))
        kil = Proc(rsal_cmd("record", "-o", str(killed), "--connect", ep, "--chunk-size", "8"))
        split = Proc(
            rsal_cmd("record", "r0:*:*", "-o", str(d / "split.mcap"), "--connect", ep, "--split-duration", "1")
        )
        started += [rec, kil, split]
        # killed once a few chunks are on disk (each is at most 8 KB before compression)
        wait_until(lambda: killed.exists() and killed.stat().st_size > 20_000, 30, "the second recorder's chunks")
        kil.kill()
        rec.p.wait(RECORD_S + 30)
        out = rec.output()
        assert rec.p.returncode == 0, out
        # Cut by the recorder's own clock, from its start: on a loaded machine it may start late,
        # so it runs until its third part is open rather than for as long as the first recorder.
        wait_until(lambda: (d / "split_002.mcap").exists(), 30, "the split recorder's third part")
        split.stop()  # SIGTERM: a clean end, the last part gets its index
        assert split.p.returncode == 0, split.output()
        sim.close()  # the recordings are made: the players run alone
        yield fin, killed, out, sorted(d.glob("split_*.mcap"))
    finally:
        for p in started:
            p.close()


def messages(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        return summary, reader.get_header(), list(reader.iter_messages(log_time_order=False))


def test_the_file_is_indexed_mcap_in_the_documented_layout(recordings):
    fin, _, out, _ = recordings
    summary, header, msgs = messages(fin)
    assert summary is not None and summary.statistics.message_count == len(msgs) > 0
    assert header.profile == "rsal"
    topics = {ch.topic: ch for _, ch, _ in msgs}
    kinds = {ch.metadata["kind"] for ch in topics.values()}
    assert {"data", "rpc", "liveliness"} <= kinds
    assert all(t.startswith("rsal/r0/") for t in topics), "only the template's devices"
    laser = topics["rsal/r0/laser/0/data"]
    assert laser.message_encoding == "msgpack" and laser.metadata["device"] == "r0:laser:0"
    # each sample: its wire bytes (a valid message), receive time as log_time, its own t as publish_time
    scans = [(m.log_time, m.publish_time, msgpack.unpackb(m.data)) for _, ch, m in msgs if ch is laser]
    assert len(scans) >= 5
    for _log, pub, scan in scans:
        assert pub == int(scan["t"] * 1e9)
    assert all(a[0] <= b[0] for a, b in zip(scans, scans[1:], strict=False))
    assert abs(scans[-1][0] - scans[0][0]) / 1e9 <= RECORD_S + 0.5
    # the describe reply as the device gave it, and the device's join
    desc = [msgpack.unpackb(m.data) for _, ch, m in msgs if ch.topic == "rsal/r0/laser/0/rpc/describe"]
    assert desc and desc[0]["ok"] and desc[0]["driver"] == "sim" and desc[0]["interface"] == "laser"
    joins = [msgpack.unpackb(m.data) for _, ch, m in msgs if ch.topic == "rsal/r0/laser/0"]
    assert joins == [{"alive": True}]
    assert "none dropped" in out and "[record]" in out


def test_play_gives_a_stock_subscriber_every_sample_byte_identical_and_on_time(recordings):
    fin, _, _, _ = recordings
    recorded: dict[str, list[bytes]] = {}
    rec_times: list[tuple[str, int]] = []
    for s in Recording(fin).samples():
        if s.kind == "data":
            recorded.setdefault(s.key, []).append(s.data)
            rec_times.append((s.key, s.log_time))
    ep = f"tcp/127.0.0.1:{free_port()}"
    got: dict[str, list[bytes]] = {}
    got_times: list[tuple[str, float]] = []
    lock = threading.Lock()

    def on_data(smp):
        t = time.monotonic()
        with lock:
            got.setdefault(str(smp.key_expr), []).append(smp.payload.to_bytes())
            got_times.append((str(smp.key_expr), t))

    with stock_session(listen=ep) as s:
        sub = s.declare_subscriber("rsal/**/data", on_data)
        play = Proc(rsal_cmd("play", str(fin), "--connect", ep, "--rate", "1", "--delay", "1"))
        try:

            def tokens():
                return {str(r.ok.key_expr) for r in s.liveliness().get("rsal/**", timeout=1.0) if r.ok}

            wait_until(lambda: "rsal/r0/laser/0" in tokens(), 20, "the replayed laser's token")
            rep = [r for r in s.get("rsal/r0/laser/0/rpc/describe", timeout=5.0) if r.ok]
            want = next(x.data for x in Recording(fin).samples() if x.key == "rsal/r0/laser/0/rpc/describe")
            assert len(rep) == 1 and rep[0].ok.payload.to_bytes() == want
            play.p.wait(RECORD_S + 30)
            assert play.p.returncode == 0, play.output()
        finally:
            play.close()
        sub.undeclare()
    assert got == recorded, "every recorded data sample, byte-identical, in order, and nothing else"
    # timing: each sample's offset from the first, against the recorded one (rate 1)
    errs = sorted(
        abs((tg - got_times[0][1]) - (tr - rec_times[0][1]) / 1e9)
        for (_, tg), (_, tr) in zip(got_times, rec_times, strict=True)
    )
    # Paced, not flushed: an unpaced replay puts its samples up to the recording's length early.
    # On a quiet machine p95 is under 5 ms; the bounds leave room for the subscriber's own
    # scheduling on a loaded one (p95 8.7 ms measured under a full test suite beside it).
    p95, worst = errs[int(0.95 * (len(errs) - 1))], errs[-1]
    assert p95 <= 0.02, f"95 % of samples within 20 ms of their recorded time; p95 {p95 * 1e3:.1f} ms"
    assert worst <= 0.1, f"worst sample {worst * 1e3:.1f} ms off its recorded time"


def test_a_sigkilled_recorders_file_plays_up_to_its_last_chunk(recordings, tmp_path):
    _, killed, _, _ = recordings
    rec = Recording(killed)
    got = list(rec.samples())
    assert len([s for s in got if s.kind == "data"]) > 10
    # killed between two writes (the usual case) or in the middle of one
    assert rec.skipped and ("without its index" in rec.skipped or "skipped the rest" in rec.skipped)
    ep = f"tcp/127.0.0.1:{free_port()}"
    play = Proc(rsal_cmd("play", str(killed), "--rate", "0", "--listen", ep))
    try:
        play.p.wait(30)
        out = play.output()
        assert play.p.returncode == 0, out
        lines = [ln for ln in out.splitlines() if ln.startswith("rsal play:")]
        assert lines == [f"rsal play: {rec.skipped}"] and "Traceback" not in out
    finally:
        play.close()
    # cut in the middle of a chunk: read up to it, say how much was skipped
    cut = tmp_path / "cut.mcap"
    shutil.copy(killed, cut)
    os.truncate(cut, cut.stat().st_size // 2)
    rec = Recording(cut)
    n = sum(1 for _ in rec.samples())
    assert 0 < n < len(got) and rec.skipped and "skipped the rest" in rec.skipped


def test_split_parts_each_play_alone_and_together_lose_nothing(recordings):
    *_, parts = recordings
    assert len(parts) >= 3 and parts[0].name == "split_000.mcap"
    for part in parts:
        summary, _, msgs = messages(part)
        assert summary is not None, f"{part.name} is finished with its index"
        first = {}  # topic -> its first message's place in the file
        for i, (_, ch, _) in enumerate(msgs):
            first.setdefault(ch.topic, i)
        # each part opens with the laser's describe reply and its join: it plays on its own
        assert "rsal/r0/laser/0/rpc/describe" in first and "rsal/r0/laser/0" in first, part.name
        if part != parts[0]:  # restated at the cut, before any later sample
            assert first["rsal/r0/laser/0"] < first.get("rsal/r0/laser/0/data", len(msgs)), part.name
    # together: the same scans as the unsplit recording made at the same time, none lost or repeated
    fin = recordings[0]

    def scans(rec):
        return [msgpack.unpackb(s.data)["t"] for s in rec.samples() if s.key == "rsal/r0/laser/0/data"]

    split_ts, fin_ts = scans(Recording(*parts)), scans(Recording(fin))
    lo, hi = max(split_ts[0], fin_ts[0]), min(split_ts[-1], fin_ts[-1])
    window = [t for t in fin_ts if lo <= t <= hi]
    assert len(window) >= 10 and [t for t in split_ts if lo <= t <= hi] == window


def test_source_time_and_remap_rules():
    from rsal.record.format import source_time_ns
    from rsal.record.player import parse_remap

    assert source_time_ns(msgpack.packb({"t": 1.5, "ranges": b"\0" * 8}), 7) == 1_500_000_000  # fast path
    assert source_time_ns(msgpack.packb({"x": 1, "t": 2}), 7) == 2_000_000_000
    for no_t in ({"x": 1}, {"t": True}, {"t": -1.0}, {"t": float("nan")}, [1, 2]):
        assert source_time_ns(msgpack.packb(no_t), 7) == 7, no_t
    assert source_time_ns(b"\xc1 not msgpack", 7) == 7
    assert parse_remap(["r0=r5", "rsal/r1/=rsal/ghost"]) == [("rsal/r0", "rsal/r5"), ("rsal/r1", "rsal/ghost")]


def test_bad_files_and_flags_get_one_line_and_exit_1(tmp_path, capsys):
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    nothing = tmp_path / "nothing.mcap"  # a finished MCAP file without a sample
    with open(nothing, "wb") as f:
        w = Writer(f)
        w.start(profile="rsal")
        w.finish()
    cases = [
        (["play", str(nothing), "--listen", f"tcp/127.0.0.1:{free_port()}"], "holds no recorded samples"),
        (["play", str(text)], "not an MCAP file"),
        (["play", str(empty)], "the file is empty"),
        (["play", str(tmp_path / "missing.mcap")], "no such file"),
        (["play", str(text), "--rate", "-1"], "--rate -1 must be >= 0"),
        (["play", str(text), "--remap", "r0"], "must be OLD=NEW"),
        (["record", "-o", str(tmp_path / "run.bag")], "name it with .mcap"),
        (["record", "-o", str(tmp_path / "r.mcap"), "--split-size", "0"], "--split-size 0 must be > 0"),
    ]
    for argv, want in cases:
        args = build_parser().parse_args(argv)
        assert run_guarded(f"rsal {argv[0]}", lambda a=args: a.func(a)) == 1, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and want in err[0], (argv, err)
    # the real command line too: one line naming the file, no traceback
    p = Proc(rsal_cmd("play", str(text)))
    try:
        p.p.wait(30)
        out = p.output().strip().splitlines()
        want = f"rsal play: {text}: not an MCAP file (it does not start with the MCAP magic bytes)"
        assert p.p.returncode == 1 and out == [want]
    finally:
        p.close()


def test_rsal_clients_use_a_remapped_looping_replay_as_a_live_device(recordings, fabric_factory, procs, port):
    fin, *_ = recordings
    play = procs(rsal_cmd("play", str(fin), "--listen", f"tcp/127.0.0.1:{port}", "--remap", "r0=ghost", "--loop"))
    fab = fabric_factory(port)
    node = fab.node("ghost:*:*")
    node.wait_for("ghost:laser:0", timeout=20)
    d = fab.device("ghost:laser:0").describe()  # answered by the session that owns the token
    assert (d.node, d.interface, d.driver) == ("ghost", "laser", "sim")
    laser = node.device("ghost:laser:0")
    scan = laser.wait_for_data(10)
    assert scan.ranges.shape == (d.geometry["sensors"][0]["samples"],)
    assert not [a for a in fab.node("r0:*:*").devices()], "nothing under the old name"
    # past the end of the recording it starts again: more scans than the recording holds
    n_rec = sum(1 for s in Recording(fin).samples() if s.key == "rsal/r0/laser/0/data")
    wait_until(lambda: laser.count > n_rec, 2 * RECORD_S + 10, "a second pass of the recording")
    play.stop()  # SIGTERM: a clean end with its summary
    assert play.p.returncode == 0 and " passes)" in play.output(), play.output()


def test_start_and_devices_choose_what_is_played(recordings):
    from rsal.record import Player, PlayOptions

    fin, *_ = recordings
    samples = [s for s in Recording(fin).samples()]
    t0 = samples[0].log_time
    data = [s for s in samples if s.kind in ("data", "event")]
    cases = [
        (PlayOptions(rate=0, start=1.5), [s for s in data if s.log_time >= t0 + 1_500_000_000]),
        (PlayOptions(rate=0, devices="r0:laser:*"), [s for s in data if s.key.startswith("rsal/r0/laser/")]),
    ]
    with stock_session(listen=f"tcp/127.0.0.1:{free_port()}") as s:
        for opts, want in cases:
            st = Player(s, Recording(fin), opts).run()
            assert st.messages == len(want) > 0, opts
    assert len(cases[1][1]) < len(data)


def test_pause_holds_the_playback_and_resume_keeps_the_recorded_timing(recordings):
    from rsal.record import Player, PlayOptions

    fin, *_ = recordings
    samples = list(Recording(fin).samples())
    laser = [s.log_time for s in samples if s.key == "rsal/r0/laser/0/data"]
    want, span = len(laser), (laser[-1] - samples[0].log_time) / 1e9  # s from the start to the last scan
    with stock_session(listen=f"tcp/127.0.0.1:{free_port()}") as s:
        player = Player(s, Recording(fin), PlayOptions(rate=1.0, devices="r0:laser:0"))
        t0 = time.monotonic()
        runner = threading.Thread(target=player.run)
        runner.start()
        try:
            wait_until(lambda: player.stats.messages >= 3, 10, "the first scans")
            player.pause()
            held = player.stats.messages
            time.sleep(1.0)  # the pause being measured
            assert player.stats.messages == held, "nothing is published while paused"
            player.resume()
            runner.join(RECORD_S + 10)
        finally:
            player.stop()
            runner.join(5)
    elapsed = time.monotonic() - t0
    assert player.stats.messages == want
    assert elapsed >= span + 0.95, "the pause added its second to the playback"
    assert player.stats.lag_max < 0.05, "after resuming, the samples kept their recorded spacing"
