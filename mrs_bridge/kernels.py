"""The compiled kernels a device server needs, prepared before it announces anything.

Two groups of numba kernels exist: the simulator's ray caster (:mod:`simulator.warmup`) and the
navigation drivers' AMCL and Wavefront kernels (:mod:`mrs_bridge.nav.warmup`). numba compiles them
on first use and caches the machine code on disk (``__pycache__`` beside the modules, or
``NUMBA_CACHE_DIR``): tens of seconds on a fresh checkout, well under a second afterwards.

:func:`prepare` compiles or loads one group once per process, printing a progress line when it
takes long (``[sim] compiling kernels (first run only) ...``); drivers call it from their set-up,
before the server declares their devices. ``rsal warmup`` (run by the project's set-up) prepares
every group ahead of time, so that the first run starts as fast as every later one.
"""

from __future__ import annotations

import sys
import threading
import time

__all__ = ["GROUPS", "prepare"]

#: group name -> (module path, what it holds)
GROUPS = {
    "simulator": ("simulator.warmup", "the simulator's ray caster"),
    "nav": ("mrs_bridge.nav.warmup", "AMCL and Wavefront"),
}
NOTICE_AFTER = 1.0  # s: a warm cache loads faster than this; slower means numba is compiling

_lock = threading.Lock()
_ready: set[str] = set()


def prepare(group: str, *, label: str = "serve", out=None, notice_after: float | None = NOTICE_AFTER) -> float:
    """Compile or load the kernels of ``group`` (once per process); returns the seconds it took.

    A line ``[label] compiling kernels of ... (first run only) ...`` goes to ``out`` (stdout by
    default) if it takes longer than ``notice_after`` seconds (None: no such line), and
    ``... ready in N s`` after it.
    """
    import importlib

    with _lock:
        if group in _ready:
            return 0.0
        module, what = GROUPS[group]
        stream = out if out is not None else sys.stdout
        done = threading.Event()
        shown: list[bool] = []

        def notice() -> None:
            if not done.wait(notice_after):
                shown.append(True)
                print(f"[{label}] compiling kernels of {what} (first run only) ...", file=stream, flush=True)

        t0 = time.perf_counter()
        watcher = threading.Thread(target=notice, name="kernel-notice", daemon=True)
        if notice_after is not None:
            watcher.start()
        try:
            importlib.import_module(module).warm_up()
        finally:
            done.set()
            if notice_after is not None:
                watcher.join()
        dt = time.perf_counter() - t0
        if shown:
            print(f"[{label}] kernels of {what} ready in {dt:.1f} s (cached for later runs)", file=stream, flush=True)
        _ready.add(group)
        return dt
