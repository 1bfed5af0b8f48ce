"""Child processes that die with their parent (Linux ``prctl(PR_SET_PDEATHSIG)``).

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

import ctypes
import os
import signal
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

__all__ = ["die_with_parent", "spawn"]

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
