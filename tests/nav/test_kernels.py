"""mrs_bridge/nav/warmup.py and mrs_bridge/kernels.py: every navigation kernel is compiled for the
types the drivers use, once per process, with a progress line only when it is slow."""

from __future__ import annotations

import io
import math

import numpy as np

from mrs_bridge import kernels as kernel_groups
from mrs_bridge.nav.amcl import Amcl, AmclParams
from mrs_bridge.nav.grid import NavGrid
from mrs_bridge.nav.warmup import kernels, warm_up
from mrs_bridge.nav.wavefront import Wavefront


def test_after_warm_up_the_drivers_paths_compile_nothing_new():
    warm_up()
    before = {k.__name__: len(k.signatures) for k in kernels()}
    assert all(n >= 1 for n in before.values()), before
    occ = np.zeros((200, 300), dtype=bool)  # another map size and origin than the warm-up's
    occ[:3, :] = occ[-3:, :] = occ[:, :3] = occ[:, -3:] = True
    grid = NavGrid.from_occupancy(occ, 0.05, (-7.5, -5.0))
    pf = Amcl(grid, AmclParams(init_pose=(0.0, 0.0, 0.0)))
    pf.odometry((0.0, 0.0, 0.0))
    b = np.linspace(-2.0, 2.0, 682)
    pf.sensor(np.full(682, 3.0, dtype=np.float32), b, np.tile([0.13, 0.0], (682, 1)), 0.02, 5.6)
    sonar = np.radians([90, 50, 30, 10, -10, -30, -50, -90])
    pf._due = True
    pf.sensor(np.full(8, 2.0), sonar, np.zeros((8, 2)), 0.0, 5.0, beam_width=math.radians(15))
    Wavefront(grid).plan((-6.0, -4.0), (6.0, 4.0))
    assert {k.__name__: len(k.signatures) for k in kernels()} == before


def test_prepare_runs_once_per_process_and_is_quiet_when_fast():
    out = io.StringIO()
    kernel_groups._ready.discard("nav")
    kernel_groups.prepare("nav", label="t", out=out, notice_after=60.0)  # cached by now: well under 60 s
    assert out.getvalue() == ""
    assert kernel_groups.prepare("nav", label="t", out=out, notice_after=0.0) == 0.0  # done already
    assert out.getvalue() == ""


def test_prepare_says_so_when_it_takes_long():
    out = io.StringIO()
    kernel_groups._ready.discard("nav")
    kernel_groups.prepare("nav", label="t", out=out, notice_after=0.0)
    lines = out.getvalue().splitlines()
    assert lines[0] == "[t] compiling kernels of AMCL and Wavefront (first run only) ..."
    assert lines[1].startswith("[t] kernels of AMCL and Wavefront ready in ")
