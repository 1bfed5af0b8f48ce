"""Child processes that die with their parent (Linux ``prctl(PR_SET_PDEATHSIG)``).

Commands and benchmarks that start other processes pass ``**die_with_parent()`` to
:class:`subprocess.Popen`: the child then receives SIGTERM when the thread that started it ends,
which is when its parent process exits, however it exits (SIGTERM, Ctrl-C, SIGKILL, a crash). A
child whose parent died before the request took effect exits at once. Elsewhere than on Linux
it returns no arguments and children are stopped by their parent's own clean-up only.

Start children from the main thread (or a thread that lives as long as the process): Linux sends
the signal when the *thread* that forked the child ends.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from typing import Any

__all__ = ["die_with_parent"]

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
