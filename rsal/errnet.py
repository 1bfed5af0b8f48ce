"""How an ``rsal`` command reports a failure: one line on stderr, never a traceback by default.

Every command (``rsal ls`` ... ``rsal demo``, and the processes they start such as agent hosts)
runs through :func:`run_guarded`, the central safety net: an exception that escapes a command is
written as ``<prog>: <what failed>; <what to do>`` and becomes the exit code. Commands that know
the context better catch their errors themselves and print a more specific line; the net is for
everything they did not foresee. The line per error type:

    BaseException
    ├── KeyboardInterrupt ........ "interrupted", exit 130
    └── Exception ................ exit 1
        ├── RsalError ............ (the platform's own tree, rsal/errors.py)
        │   ├── RpcError ......... timeout: "<key> did not answer within N s; is ... still starting?"
        │   │                      otherwise the device's code and message, and what to check
        │   └── the others ....... their message: it names the value, the place and a fix
        ├── TimeoutError ......... its message (the raising site names the device and a fix)
        ├── zenoh.ZError ......... Zenoh's text without Rust source locations, with a hint for
        │                          a port in use, a bad endpoint or a refused connection
        ├── OSError .............. the system's reason and the file or address
        ├── ValueError ........... its message: other user errors (argparse, a library's own
        │   LookupError            checks) are ValueErrors or LookupErrors that name the value
        └── anything else ........ a bug: "unexpected <Type>: <text> (run with -v for the traceback)"

``-v`` on the command line or ``RSAL_DEBUG=1`` in the environment (inherited by the processes a
command starts) prints the traceback before the line. The same rule holds for log records: a
record logged with an exception shows the exception on the record's one line, and the traceback
only in debug mode (:class:`OneLineFormatter`).
"""

from __future__ import annotations

import errno
import logging
import os
import re
import sys
import threading
import traceback
from collections.abc import Callable

from .errors import RsalError

__all__ = [
    "DEBUG_ENV",
    "OneLineFormatter",
    "debug_enabled",
    "describe",
    "exit_code",
    "install_thread_hook",
    "run_guarded",
    "zenoh_text",
]

DEBUG_ENV = "RSAL_DEBUG"
TRACEBACK_HINT = "run with -v (or RSAL_DEBUG=1) for the traceback"
ENDPOINT_FORM = "endpoints look like tcp/127.0.0.1:7447"

_RUST_LOCATION = re.compile(r"\s*\bat\s+\S+\.rs:\d+\.?")
_JSON5_MESSAGE = re.compile(r'Json5Err\(Message \{ msg: "(.*?)", location: .*?\}\)', re.S)
_WITHIN = re.compile(r"within ([0-9.]+) s")
_ENDPOINT = re.compile(r"\b((?:tcp|udp|tls|quic|ws|unixsock-stream)/[^\s\[\],;]+)")


def debug_enabled(verbosity: int = 0) -> bool:
    """True with ``-v`` or ``RSAL_DEBUG`` set to anything but empty, 0, false or no."""
    return verbosity > 0 or os.environ.get(DEBUG_ENV, "").strip().lower() not in ("", "0", "false", "no")


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def zenoh_text(e: BaseException | str) -> str:
    """Zenoh's error text on one line, without the Rust source locations and JSON5 wrappers."""
    text = str(e)
    m = _JSON5_MESSAGE.search(text)
    if m:
        text = m.group(1)
    text = _RUST_LOCATION.sub("", text)
    return _one_line(text).rstrip(". ")


def _endpoint_in(text: str) -> str | None:
    m = _ENDPOINT.search(text)
    return m.group(1).rstrip(":.)") if m else None


def zenoh_summary(text: str) -> str | None:
    """Our own words for a Zenoh transport error we recognise in its (cleaned) text: what failed
    and what to do; None for the others."""
    low = text.lower()
    where = _endpoint_in(text)
    on = f" on {where}" if where else ""
    if "address already in use" in low:
        return f"cannot listen{on}: the port is in use (another rsal server or router?); stop it or use another port"
    if "cannot assign requested address" in low:
        return f"cannot listen{on}: not an address of this host; use one of its own, e.g. tcp/127.0.0.1:7447"
    if "endpoints must be of the form" in low or "not supported for" in low:
        return f"bad endpoint ({text}); {ENDPOINT_FORM}"
    if "connection refused" in low:
        at = f" at {where}" if where else ""
        return f"nothing answers{at}; start a device server ('rsal sim maps/floor.world') or check --connect"
    return None


def _rpc_line(e) -> str:
    from .msgs import ErrorCode

    key = e.key or "the device"
    if e.code == ErrorCode.TIMEOUT:
        m = _WITHIN.search(e.message)
        within = f"within {m.group(1)} s" if m else "in time"
        return (
            f"{key} did not answer {within}; is its device server still starting, busy or gone? "
            f"retry, or check the server's output and 'rsal ls'"
        )
    if e.code == ErrorCode.UNAVAILABLE:
        return f"{e}; the device cannot do it now: retry, or check its required devices with 'rsal ls'"
    if e.code == ErrorCode.INTERNAL:
        return f"{e}; the driver failed: see the device server's log"
    return str(e)


def describe(e: BaseException) -> str:
    """One line naming what failed and, where we can tell, what to do (without the program name)."""
    from .msgs import RpcError

    if isinstance(e, KeyboardInterrupt):
        return "interrupted"
    if isinstance(e, RpcError):
        return _one_line(_rpc_line(e))
    if isinstance(e, RsalError):
        return _one_line(str(e)) or f"{type(e).__name__} without a message; {TRACEBACK_HINT}"
    if isinstance(e, TimeoutError):
        text = _one_line(str(e))
        return text or "timed out waiting for the fabric; is the device server running and reachable (--connect)?"
    try:
        import zenoh

        if isinstance(e, zenoh.ZError):
            text = zenoh_text(e)
            return zenoh_summary(text) or f"Zenoh: {text}"
    except ImportError:  # pragma: no cover - zenoh is a dependency
        pass
    if isinstance(e, OSError):
        if e.errno == errno.EADDRINUSE:
            return f"{e.strerror or e}: the port is in use; stop the other process or choose another port"
        if isinstance(e, BrokenPipeError):
            return "the output was closed (broken pipe)"
        what = e.strerror or str(e) or type(e).__name__
        where = e.filename or ""
        return _one_line(f"{where}: {what}" if where else what)
    if isinstance(e, (ValueError, LookupError)) and not isinstance(e, (KeyError, IndexError)):
        return _one_line(str(e)) or f"{type(e).__name__} without a message; {TRACEBACK_HINT}"
    text = _one_line(str(e))
    return f"unexpected {type(e).__name__}{': ' + text if text else ''} (a bug: {TRACEBACK_HINT}, and report it)"


def exit_code(e: BaseException) -> int:
    """130 for Ctrl-C, 1 for every other failure."""
    return 130 if isinstance(e, KeyboardInterrupt) else 1


def run_guarded(prog: str, fn: Callable[[], int | None], *, debug: bool | None = None) -> int:
    """Run ``fn()`` and return its exit code; an exception becomes one line ``<prog>: ...`` on
    stderr (after the traceback in debug mode) and exit 1, or 130 for Ctrl-C."""
    if debug is None:
        debug = debug_enabled()
    try:
        return int(fn() or 0)
    except (Exception, KeyboardInterrupt) as e:
        try:
            sys.stdout.flush()
        except Exception:
            pass
        if debug and not isinstance(e, KeyboardInterrupt):
            traceback.print_exc()
        print(f"{prog}: {describe(e)}", file=sys.stderr, flush=True)
        return exit_code(e)


class OneLineFormatter(logging.Formatter):
    """A formatter that writes a record with an exception on one line (``message: Type: text``)
    unless ``debug``, in which case the traceback follows as usual."""

    def __init__(self, *args, debug: bool = False, **kw) -> None:
        super().__init__(*args, **kw)
        self.debug = debug

    def format(self, record: logging.LogRecord) -> str:
        if self.debug or not (record.exc_info or record.stack_info):
            return super().format(record)
        r = logging.makeLogRecord(record.__dict__)
        exc = record.exc_info[1] if record.exc_info else None
        msg = record.getMessage()
        if exc is not None:
            msg = f"{msg}: {type(exc).__name__}: {_one_line(str(exc))} ({TRACEBACK_HINT})"
        r.msg, r.args, r.exc_info, r.exc_text, r.stack_info = msg, None, None, None, None
        return super().format(r)


def install_thread_hook(prog: str, *, debug: bool = False) -> None:
    """An exception that ends a thread prints one line ``<prog>: thread NAME: ...`` (the traceback
    too in debug mode) instead of Python's default traceback."""
    default = threading.excepthook

    def hook(a: threading.ExceptHookArgs) -> None:
        if debug:
            default(a)
            return
        if a.exc_type is SystemExit:
            return
        name = a.thread.name if a.thread is not None else "?"
        print(f"{prog}: thread {name}: {describe(a.exc_value)}", file=sys.stderr, flush=True)

    threading.excepthook = hook
