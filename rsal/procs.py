"""Child processes: started, relayed, judged and stopped by one supervisor; and children that die
with their parent (Linux ``prctl(PR_SET_PDEATHSIG)``).

:class:`Child` is the one process supervisor of the commands that start others (``rsal run``,
``rsal control``, ``rsal demo``): it starts a child in its own session and process group
(``start_new_session=True``) that dies with its parent, reads its output on a thread (so a pipe never
fills), keeps the last lines, forwards each line with ``[name]`` in front (or to a callback), states
its exit in one line (:meth:`Child.exit_reason`) and stops it with escalating signals and deadlines,
SIGINT, then SIGTERM, then SIGKILL (:func:`stop_all` stops several at once so their deadlines run
together). Signals go to the child's PID only, never to a name or a group.

Commands and benchmarks that start other processes pass ``**die_with_parent()`` to
:class:`subprocess.Popen`: the child then receives SIGTERM when the thread that started it ends,
which is when its parent process exits, however it exits (SIGTERM, Ctrl-C, SIGKILL, a crash). A
child whose parent died before the request took effect exits at once. Elsewhere than on Linux
it returns no arguments and children are stopped by their parent's own clean-up only.

Linux sends the signal when the *thread* that forked the child ends, so a child must be started by
the main thread or a thread that lives as long as the process: :func:`spawn` does that for code
that runs on short-lived threads (an HTTP server's request threads).
"""

from __future__ import annotations

import collections
import ctypes
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_STEPS", "Child", "die_with_parent", "python_env", "spawn", "stop_all"]

log = logging.getLogger(__name__)

#: the repository root: children of a checkout import its packages from here
REPO_ROOT = Path(__file__).resolve().parent.parent

_PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int = signal.SIGTERM) -> dict[str, Any]:
    """Keyword arguments for :class:`subprocess.Popen` that make the child get ``sig`` when its
    parent dies (empty when the platform cannot)."""
    if not sys.platform.startswith("linux"):
        return {}
    parent = os.getpid()

    def preexec() -> None:  # in the child, between fork and exec
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:  # the parent died before prctl: nobody will signal us
            os.kill(os.getpid(), sig)

    return {"preexec_fn": preexec}


_launcher: ThreadPoolExecutor | None = None
_launcher_lock = threading.Lock()


def spawn(args, **kw: Any) -> subprocess.Popen:
    """:class:`subprocess.Popen` with :func:`die_with_parent`, forked by the main thread when called on
    it, else by one launcher thread that lives as long as the process (so the child is not signalled
    when the calling thread ends)."""
    global _launcher
    kw.update(die_with_parent())
    if threading.current_thread() is threading.main_thread():
        return subprocess.Popen(args, **kw)
    with _launcher_lock:
        if _launcher is None:
            _launcher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rsal-launcher")
    return _launcher.submit(subprocess.Popen, args, **kw).result()


def python_env(*paths: str | os.PathLike) -> dict[str, str]:
    """The environment of a Python child of ours: ``paths``, the working directory and the
    repository root in front of ``PYTHONPATH`` (so ``module:Class`` names next to a file import),
    and unbuffered output (so its lines are relayed as they are written)."""
    env = dict(os.environ)
    front = [str(p) for p in paths] + [os.getcwd(), str(REPO_ROOT)]
    if env.get("PYTHONPATH"):
        front.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(front))
    env["PYTHONUNBUFFERED"] = "1"
    return env


#: how :meth:`Child.stop` escalates: each signal with the seconds it gets, then SIGKILL
DEFAULT_STEPS: tuple[tuple[int, float], ...] = ((signal.SIGINT, 10.0), (signal.SIGTERM, 5.0))
#: seconds to wait for a child after SIGKILL
KILL_WAIT = 5.0


class Child:
    """One supervised child process.

    ``argv`` runs in its own session (process group) with stdin closed; it dies with this process.
    Its output is read line by line on reader threads: the last ``keep`` lines are kept in
    :attr:`lines`; each line goes to ``forward`` (if given) with ``[name] `` in front unless the
    line already starts with ``[`` (children that name themselves), to ``on_line`` and to
    ``on_output(line, is_stderr)`` (called on the reader thread; an exception there is logged,
    never raised). With ``stderr_apart`` the
    standard error is read separately and its last line is what :meth:`exit_reason` quotes;
    otherwise both streams are merged. ``kind`` and ``shown`` (the command as a user would type
    it) are labels for whoever lists children.
    """

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        *,
        kind: str = "",
        shown: str = "",
        env: dict | None = None,
        cwd: Any = None,
        forward: Callable[[str], None] | None = None,
        on_line: Callable[[str], None] | None = None,
        on_output: Callable[[str, bool], None] | None = None,
        stderr_apart: bool = False,
        keep: int = 40,
    ):
        self.name = name
        self.kind = kind
        self.argv = list(argv)
        self.shown = shown or " ".join(self.argv)
        self.forward = forward
        self.on_line = on_line
        self.on_output = on_output
        self.lines: collections.deque[str] = collections.deque(maxlen=keep)
        self.errors: collections.deque[str] = collections.deque(maxlen=5)
        self.stderr_apart = stderr_apart
        self.started = time.time()
        self.stopping = False  # a stop was asked for
        self.stopped_by_user = False  # and it was this supervisor's stop() that ended it
        self.reported = False  # for the owner: its exit was reported
        self.p = spawn(  # forked by a long-lived thread, so it dies with this process only
            self.argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE if stderr_apart else subprocess.STDOUT,
            env=env,
            cwd=cwd,
            start_new_session=True,
            text=True,
            errors="replace",
        )
        pipes = [(self.p.stdout, False)] + ([(self.p.stderr, True)] if stderr_apart else [])
        self._readers = [
            threading.Thread(target=self._read, args=pp, name=f"child-{name}-{self.p.pid}", daemon=True) for pp in pipes
        ]
        for t in self._readers:
            t.start()

    @property
    def pid(self) -> int:
        return self.p.pid

    @property
    def returncode(self) -> int | None:
        return self.p.poll()

    def poll(self) -> int | None:
        return self.p.poll()

    def alive(self) -> bool:
        return self.p.poll() is None

    def _read(self, pipe, is_err: bool) -> None:
        for raw in pipe:
            line = raw.rstrip("\n")
            if not line:
                continue
            self.lines.append(line)
            if is_err or not self.stderr_apart:
                self.errors.append(line)
            if self.forward is not None:
                self.forward(line if line.startswith("[") else f"[{self.name}] {line}")
            for handler, hargs in ((self.on_line, (line,)), (self.on_output, (line, is_err))):
                if handler is not None:
                    try:
                        handler(*hargs)
                    except Exception:
                        log.exception("%s: line handler failed", self.name)
        pipe.close()

    @property
    def state(self) -> str:
        """running, stopping, stopped (by :meth:`stop`), finished (exit 0) or failed."""
        rc = self.p.poll()
        if rc is None:
            return "stopping" if self.stopping else "running"
        return "stopped" if self.stopped_by_user else ("finished" if rc == 0 else "failed")

    def drained(self, timeout: float = 2.0) -> None:
        """Wait (briefly) until its output is read, after it exited."""
        for t in self._readers:
            t.join(timeout)

    def last_error(self) -> str:
        """Its last error line (with merged output: its last line)."""
        return self.errors[-1] if self.errors else "(no error output)"

    def exit_reason(self) -> str:
        """One line: how it ended and its last error line (``running`` while it runs)."""
        rc = self.p.poll()
        if rc is None:
            return "running"
        if rc < 0:
            try:
                how = f"was ended by {signal.Signals(-rc).name}"
            except ValueError:
                how = f"was ended by signal {-rc}"
        else:
            how = f"exited with code {rc}"
        return f"{how}: {self.last_error()}"

    def signal(self, sig: int) -> None:
        """Send ``sig`` to its PID if it still runs."""
        if self.p.poll() is None:
            try:
                os.kill(self.p.pid, sig)
            except ProcessLookupError:
                pass

    def stop(self, steps: Sequence[tuple[int, float]] = DEFAULT_STEPS, on_kill=None) -> int | None:
        """Stop it (see :func:`stop_all`); returns its exit code."""
        stop_all([self], steps, on_kill)
        return self.p.returncode

    def info(self) -> dict:
        """What a listing shows: name, pid, state, exit code, command, start time, last lines."""
        return {
            "name": self.name,
            "pid": self.pid,
            "state": self.state,
            "exit_code": self.p.poll(),
            "command": self.shown,
            "started": self.started,
            "lines": list(self.lines),
        }


def stop_all(
    children: Iterable[Child],
    steps: Sequence[tuple[int, float]] = DEFAULT_STEPS,
    on_kill: Callable[[Child, float], None] | None = None,
) -> None:
    """Stop ``children`` together: send each step's signal to every child still running, wait for
    them up to the step's seconds (one deadline for all), go on to the next step for those left,
    and SIGKILL whatever outlived every step (``on_kill(child, seconds_waited)`` is called first;
    by default a line is added to its kept lines). Waits until their output is read."""
    children = list(children)
    left = [c for c in children if c.poll() is None]
    for c in left:
        c.stopping = True
        c.stopped_by_user = True
    waited = 0.0
    for sig, seconds in steps:
        if not left:
            break
        for c in left:
            c.signal(sig)
        deadline = time.monotonic() + seconds
        for c in left:
            try:
                c.p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        waited += seconds
        left = [c for c in left if c.poll() is None]
    for c in left:
        if on_kill is not None:
            on_kill(c, waited)
        else:
            c.lines.append(f"[supervisor] pid {c.pid} did not stop within {waited:g} s; killed")
        c.signal(signal.SIGKILL)
        try:
            c.p.wait(KILL_WAIT)
        except subprocess.TimeoutExpired:
            log.warning("%s (pid %d) outlived SIGKILL by %g s", c.name, c.pid, KILL_WAIT)
    for c in children:
        c.drained()
