"""The ``rsal watch`` command: flags, the Rerun sinks (native viewer, web viewer, ``.rrd`` file)
and the life of one :class:`~rsal.watch.app.Watcher` from the first device to Ctrl-C. User
errors (bad flags, no display, nothing to watch) are one line on stderr and exit status 1.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from ..cliutil import stop_on_signals
from ..transport import TransportArgs, add_transport_args, open_session
from .app import Watcher
from .state import WatchOptions

__all__ = ["register", "run_watch"]


def _blueprint():
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(origin="world", name="fleet"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="plots", name="plots"),
                rrb.TextLogView(origin="log", name="log"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=False,
    )


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def run_watch(args: argparse.Namespace) -> int:
    opts = WatchOptions(
        template=args.template,
        rate=args.rate,
        scan_rate=args.scan_rate,
        max_beams=args.max_beams,
        truth_rate=args.truth_rate,
        plot_rate=args.plot_rate,
        particles=args.particles,
        particles_rate=args.particles_rate,
        services=not args.no_services,
        report_every=args.report_every,
        task_hold=args.task_hold,
    )
    try:
        opts.check()
    except ValueError as e:
        print(f"rsal watch: {e}", file=sys.stderr)
        return 1
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        print(f"rsal watch: --duration {args.duration:g} must be a positive number of seconds", file=sys.stderr)
        return 1
    if not (args.save or args.serve or _has_display()):
        print(
            "rsal watch: no display ($DISPLAY and $WAYLAND_DISPLAY are unset): record with --save FILE.rrd or "
            "open the web viewer with --serve",
            file=sys.stderr,
        )
        return 1
    if args.save and not str(args.save).endswith(".rrd"):
        print(f"rsal watch: --save {args.save!r} must name an .rrd file", file=sys.stderr)
        return 1
    if args.save and not os.path.isdir(os.path.dirname(os.path.abspath(args.save))):
        print(f"rsal watch: --save {args.save!r}: the directory does not exist", file=sys.stderr)
        return 1
    stop, got = stop_on_signals()
    try:
        session = open_session(TransportArgs.from_namespace(args))
    except ValueError as e:
        print(f"rsal watch: {e}", file=sys.stderr)
        return 1
    watcher = None
    rec = None
    try:
        import rerun as rr

        rec = rr.RecordingStream("rsal_watch")
        watcher = Watcher(session, rec, opts)
        watcher.start()
        if not watcher.wait_for_devices(args.wait, stop):
            if stop.is_set():
                return 0
            print(
                f"rsal watch: no devices match {opts.template!r} within {args.wait:g} s (is a device server running? "
                f"try 'rsal sim maps/testroom.world', or check --connect)",
                file=sys.stderr,
            )
            return 1
        sinks = []
        if args.save:
            sinks.append(rr.FileSink(args.save))
        if args.serve:
            try:
                server = rr.GrpcServerSink("127.0.0.1", args.grpc_port)
            except Exception as e:
                print(f"rsal watch: cannot serve gRPC on port {args.grpc_port}: {e} (try --grpc-port)", file=sys.stderr)
                return 1
            sinks.append(server)
        if sinks:
            rec.set_sinks(*sinks, default_blueprint=_blueprint())
        else:
            try:
                rec.spawn(default_blueprint=_blueprint())
            except Exception as e:
                print(f"rsal watch: cannot start the Rerun viewer: {e} (record with --save FILE.rrd)", file=sys.stderr)
                return 1
        if args.serve:
            uri = server.uri
            try:
                rr.serve_web_viewer(web_port=args.web_port, open_browser=False, connect_to=uri)
            except Exception as e:
                print(
                    f"rsal watch: cannot serve the web viewer on port {args.web_port}: {e} (try --web-port)",
                    file=sys.stderr,
                )
                return 1
            print(f"[watch] web viewer: http://127.0.0.1:{args.web_port}/?url={uri}", flush=True)
        if args.save:
            print(f"[watch] recording to {args.save}", flush=True)
        watcher.setup()
        watcher.run(stop, args.duration)
    finally:
        if watcher is not None:
            watcher.close()
        if rec is not None:
            try:
                rec.flush(timeout_sec=10.0)
                rec.disconnect()
            except Exception as e:
                print(f"rsal watch: could not finish the recording: {e}", file=sys.stderr)
        session.close()
    s = watcher.stats
    print(
        f"[watch] stopped ({got[0] if got else 'done'}): {s.n_in} samples and {s.n_text} messages in, {s.taken} "
        f"samples taken, {s.logged} logged, "
        f"{s.downsampled} scans downsampled, {s.text_dropped} text entries dropped, {s.malformed} malformed, "
        f"{s.late} late ticks",
        flush=True,
    )
    return 0


def register(sub) -> None:
    p = sub.add_parser("watch", help="live view of the fleet in Rerun (viewer, web viewer or .rrd file)")
    p.add_argument("template", nargs="?", default="**", help="devices to watch, e.g. 'r0:*:*' (default: all)")
    p.add_argument("--save", metavar="FILE.rrd", help="record to this file instead of spawning a viewer")
    p.add_argument("--serve", action="store_true", help="serve the web viewer on loopback and print its URL")
    p.add_argument("--web-port", type=int, default=9090, help="web viewer HTTP port with --serve (default 9090)")
    p.add_argument("--grpc-port", type=int, default=9876, help="gRPC port with --serve (default 9876)")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--wait", type=float, default=10.0, help="seconds to wait for the first device (default 10)")
    p.add_argument("--rate", type=float, default=10.0, help="logger ticks per second (default 10)")
    p.add_argument("--scan-rate", type=float, default=5.0, help="scans logged per second per device (default 5)")
    p.add_argument("--max-beams", type=int, default=180, help="beams per logged scan, every k-th (default 180)")
    p.add_argument("--truth-rate", type=float, default=1.0, help="ground-truth polls per robot per second (default 1)")
    p.add_argument("--plot-rate", type=float, default=2.0, help="time-series points per robot per second (default 2)")
    p.add_argument("--particles", action="store_true", help="also log AMCL particles (rpc get_particles)")
    p.add_argument("--particles-rate", type=float, default=1.0, help="particle polls per second (default 1)")
    p.add_argument("--no-services", action="store_true", help="do not log agent service messages")
    p.add_argument(
        "--task-hold", type=float, default=5.0, help="seconds an ended dispatcher task stays on the map (default 5)"
    )
    p.add_argument("--report-every", type=float, default=5.0, help="seconds between progress lines (default 5)")
    add_transport_args(p)
    p.set_defaults(func=run_watch)
