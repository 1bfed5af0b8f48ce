"""``rsal record`` and ``rsal play``: the command-line side of :mod:`rsal.record`.

``rsal play`` pauses and resumes with the space bar when run in a terminal, and by the rpcs of its
control device ``rsal/play/player/0`` (``--control NODE``). Progress goes to stderr
at most once a second (one line rewritten in place on a terminal, a new line otherwise), a summary
line at the end; SIGTERM and Ctrl-C end a recording cleanly (the file gets its index). See
``docs/recording.md``.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from ..transport import TransportArgs, add_transport_args, open_session
from .format import RecordingError

__all__ = ["register", "run_record", "run_play"]


def _progress_line(text: str, final: bool = False) -> None:
    if sys.stderr.isatty():
        sys.stderr.write("\r" + text.ljust(79) + ("\n" if final else ""))
    else:
        sys.stderr.write(text + "\n")
    sys.stderr.flush()


def _stop_on_sigterm(stop: threading.Event) -> None:
    try:
        signal.signal(signal.SIGTERM, lambda *_: stop.set())
    except ValueError:  # not the main thread (tests calling run_* directly)
        pass


def run_record(args: argparse.Namespace) -> int:
    from .recorder import Recorder, RecordOptions

    out = Path(args.output)
    if out.suffix != ".mcap":
        raise RecordingError(f"-o {args.output!r}: a recording is an MCAP file; name it with .mcap, e.g. -o run.mcap")
    if args.duration is not None and args.duration <= 0:
        raise RecordingError(f"--duration {args.duration:g} must be > 0 seconds")
    for flag, v in (("--split-size", args.split_size), ("--split-duration", args.split_duration)):
        if v is not None and v <= 0:
            raise RecordingError(f"{flag} {v:g} must be > 0")
    if args.chunk_size <= 0:
        raise RecordingError(f"--chunk-size {args.chunk_size:g} must be > 0 KB")
    opts = RecordOptions(
        templates=list(args.template) or ["**"],
        commands=args.commands,
        services=args.services,
        chunk_size=int(args.chunk_size * 1024),
        split_size=int(args.split_size * 1e6) if args.split_size else None,
        split_duration=args.split_duration,
    )
    stop = threading.Event()
    _stop_on_sigterm(stop)
    with open_session(TransportArgs.from_namespace(args)) as session:
        rec = Recorder(session, out, opts)
        try:
            rec.start()
        except OSError as e:
            raise RecordingError(f"-o {args.output}: cannot create the file: {e.strerror or e}") from None
        t0 = time.monotonic()
        st = rec.stats
        last = (t0, 0)
        try:
            while not stop.wait(1.0):
                now = time.monotonic()
                rate = (st.messages - last[1]) / max(now - last[0], 1e-9)
                last = (now, st.messages)
                drops = f"  {st.dropped} dropped" if st.dropped else ""
                _progress_line(
                    f"[record] {now - t0:6.1f} s  {st.messages} msgs  {rec.size / 1e6:.2f} MB  "
                    f"{rate:.0f} msg/s  {st.alive} devices{drops}"
                )
                if args.duration is not None and now - t0 >= args.duration:
                    break
                if rec.error is not None:
                    break
        except KeyboardInterrupt:
            pass
        finally:
            rec.stop()
    elapsed = time.monotonic() - t0
    drops = (
        f"; {st.dropped} samples DROPPED (the writer fell behind: record fewer devices or use a faster disk)"
        if st.dropped
        else ", none dropped"
    )
    where = str(out) if len(rec.files) == 1 else f"{rec.files[0]} .. {rec.files[-1].name} ({len(rec.files)} files)"
    _progress_line(
        f"[record] {where}: {st.messages} messages on {st.channels} channels from {len(st.devices)} devices "
        f"in {elapsed:.1f} s, {rec.size / 1e6:.2f} MB{drops}",
        final=True,
    )
    if st.messages == 0:
        print(
            f"rsal record: nothing matched {' '.join(opts.templates)!r}; is a device server running "
            "(rsal ls) and the endpoint right (--connect)?",
            file=sys.stderr,
        )
        return 1
    return 0


def _keyboard(player, stop: threading.Event) -> None:
    """Space pauses and resumes the playback when stdin is a terminal (the terminal is restored
    at exit); without a terminal there are no keys to read."""
    if not sys.stdin.isatty():
        return
    import atexit
    import select
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    atexit.register(termios.tcsetattr, fd, termios.TCSADRAIN, saved)
    tty.setcbreak(fd)

    def read() -> None:
        while not stop.is_set():
            if select.select([fd], [], [], 0.2)[0] and sys.stdin.read(1) == " ":
                (player.resume if player.stats.paused else player.pause)()
                _progress_line("[play] paused (space resumes)" if player.stats.paused else "[play] resumed")

    threading.Thread(target=read, name="rsal-play-keys", daemon=True).start()


def run_play(args: argparse.Namespace) -> int:
    from .player import Player, PlayOptions, Recording, check_profile, parse_remap

    if args.rate < 0:
        raise RecordingError(f"--rate {args.rate:g} must be >= 0 (1: recorded speed, 0: as fast as it goes)")
    if args.delay < 0:
        raise RecordingError(f"--delay {args.delay:g} must be >= 0 seconds")
    if args.start < 0:
        raise RecordingError(f"--start {args.start:g} must be >= 0 seconds into the recording")
    remap = parse_remap(args.remap)  # the flags first, then the files
    if args.control:
        from ..keys import check_name

        check_name("--control node", args.control)
    rec = Recording(*args.file)
    opts = PlayOptions(
        rate=args.rate,
        start=args.start,
        loop=args.loop,
        remap=remap,
        devices=args.devices,
        delay=args.delay,
        commands=args.commands,
        services=args.services,
        control=None if args.control == "" else args.control,
        paused=args.paused,
    )
    stop = threading.Event()
    _stop_on_sigterm(stop)
    with open_session(TransportArgs.from_namespace(args)) as session:
        player = Player(session, rec, opts)
        n = player.prepare()
        resume = "space" + (f" or rsal/{opts.control}/player/0/rpc/resume" if opts.control else "")
        notes = [x for x in (check_profile(rec), rec.skipped) if x]
        if notes:  # one line for whatever was not read as recorded
            print(f"rsal play: {'; '.join(notes)}", file=sys.stderr, flush=True)
        _progress_line(
            f"[play] {rec.path}: {n} samples, {player.stats.duration:.1f} s, "
            f"{len(player._devices)} devices; rate {args.rate:g}"
            + (f"; paused (resume: {resume})" if args.paused else "")
        )
        threading.Thread(target=lambda: (stop.wait(), player.stop()), daemon=True).start()
        _keyboard(player, stop)
        t0 = time.monotonic()
        try:
            st = player.run(
                lambda s: _progress_line(
                    f"[play] {s.position:6.1f}/{s.duration:.1f} s  {s.messages} msgs  {s.alive} devices"
                )
            )
        except KeyboardInterrupt:
            player.stop()
            player.close()
            raise
    lag = f", at most {st.lag_max * 1000:.0f} ms behind" if args.rate > 0 else ""
    _progress_line(
        f"[play] {rec.path}: {st.messages} messages from {len(st.devices)} devices in "
        f"{time.monotonic() - t0:.1f} s ({st.passes} pass{'es' if st.passes != 1 else ''}){lag}",
        final=True,
    )
    return 0


def register(sub) -> None:
    r = sub.add_parser(
        "record",
        help="record the devices' samples into an MCAP file",
        description="Record every data and event sample of the matching devices (and their describe "
        "replies, joins and leaves) into an MCAP file, until Ctrl-C, SIGTERM or --duration.",
    )
    r.add_argument("template", nargs="*", help="device templates, e.g. 'r0:*:*' 'rsal/*/laser/*' (default: all)")
    r.add_argument("-o", "--output", required=True, metavar="RUN.mcap", help="the file to write")
    r.add_argument("--commands", action="store_true", help="also record the devices' commands (cmd)")
    r.add_argument("--services", action="store_true", help="also record agent service messages (svc/**)")
    r.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds (default: Ctrl-C)")
    r.add_argument(
        "--chunk-size", type=float, default=256, metavar="KB", help="chunk size before compression (default 256)"
    )
    r.add_argument(
        "--split-size", type=float, metavar="MB", help="start a new file (RUN_001.mcap, ...) every MB megabytes"
    )
    r.add_argument("--split-duration", type=float, metavar="S", help="start a new file every S seconds")
    add_transport_args(r)
    r.set_defaults(func=run_record)

    p = sub.add_parser(
        "play",
        help="play an MCAP recording back onto the fabric",
        description="Re-create the recorded devices (tokens, describe) and publish their samples with the "
        "recorded timing.",
    )
    p.add_argument(
        "file", metavar="RUN.mcap", nargs="+", help="a recording made with 'rsal record' (or its split parts, in order)"
    )
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1; 0: as fast as it goes)")
    p.add_argument("--start", type=float, default=0.0, metavar="T", help="start T seconds into the recording")
    p.add_argument(
        "--delay", type=float, default=0.0, metavar="S", help="wait S seconds before the first sample (default 0)"
    )
    p.add_argument("--loop", action="store_true", help="play again from the start at the end, until Ctrl-C")
    p.add_argument(
        "--remap", action="append", default=[], metavar="OLD=NEW", help="rename a node (r0=r5) or key prefix"
    )
    p.add_argument("--devices", metavar="TEMPLATE", help="play only these devices, e.g. 'r0:*:*'")
    p.add_argument("--commands", action="store_true", help="also publish recorded commands (they move live robots)")
    p.add_argument("--services", action="store_true", help="also publish recorded agent service messages")
    p.add_argument(
        "--paused",
        action="store_true",
        help="start paused: the devices come up, the samples wait for the space bar or the resume rpc",
    )
    p.add_argument(
        "--control",
        default="play",
        metavar="NODE",
        help="node of the control device rsal/NODE/player/0 (pause, resume, status, seek; default 'play', '' for none)",
    )
    add_transport_args(p)
    p.set_defaults(func=run_play)
