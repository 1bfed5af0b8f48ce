"""simulator/warmup.py: the tiny world compiles every kernel the real worlds use, with their types."""

from __future__ import annotations

from pathlib import Path

from simulator.loader import load_world
from simulator.warmup import kernels, warm_up
from simulator.world import World

FLOOR = Path(__file__).resolve().parents[2] / "maps" / "floor.world"


def test_after_warm_up_a_real_world_compiles_nothing_new():
    warm_up()
    before = {k.__name__: len(k.signatures) for k in kernels()}
    assert all(n >= 1 for n in before.values()), before
    w = World(load_world(FLOOR))
    for name in w.robot_names:
        w.set_velocity(name, 0.3, 0.2)
    for _ in range(3):
        w.step()
    assert {k.__name__: len(k.signatures) for k in kernels()} == before
