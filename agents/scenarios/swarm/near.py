"""The neighbourhood swarm's per-hub work before each re-watch (thesis 4.2.3 at 1000 robots; the
neighbourhood-scoped broadcasts of :mod:`agents.cells`).

With ``neighbourhood`` R > 0 a host's :class:`agents.hub.RobotHub` re-computes its agents' cells
every report period; just before, two things are done for all the host's robots at once instead of
once per agent and message (:attr:`agents.hub.RobotHub.before_rewatch`):

- :meth:`.ledger.NearLedger.flush`: what each agent received under its old cells;
- :meth:`Headings.update`: the disperse layer's headings (:func:`.behaviour.away_headings`, a k-d
  tree over the positions the host received).

:func:`near_hooks` makes both on a hub's first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from agents.hub import robot_xy

from .behaviour import away_headings
from .ledger import NearLedger

if TYPE_CHECKING:
    from agents.hub import RobotHub

__all__ = ["Headings", "near_hooks"]


class Headings:
    """The disperse headings of a neighbourhood hub's robots (agents of class ``kind``), all at once
    before each re-watch (:func:`away_headings` on the positions the host received), instead of
    one numpy call per agent and broadcast."""

    def __init__(self, hub: RobotHub, kind: type):
        self.hub = hub
        self.kind = kind
        self.of: dict[str, float | None] = {}

    def update(self) -> None:
        agents, mine = [], []
        for a in self.hub.agents.values():
            if isinstance(a, self.kind) and a.pioneer is not None and a.frame == "map":
                p = robot_xy(a.pioneer)
                if p is not None:
                    agents.append(a)
                    mine.append(p)
        if not agents:
            return
        xy, index = self.hub.received_positions()
        me = np.array(mine, dtype=float)
        radius = np.array([min(a.disperse_radius, a.neighbourhood or a.disperse_radius) for a in agents])
        own = np.array([index.get(a.robot, -1) for a in agents])
        h = away_headings(me, xy, radius, own)
        self.of = {a.robot: (None if np.isnan(v) else float(v)) for a, v in zip(agents, h.tolist(), strict=True)}


def near_hooks(hub: RobotHub, kind: type) -> tuple[NearLedger, Headings]:
    """The hub's :class:`.ledger.NearLedger` and :class:`Headings` for agents of class ``kind``
    (made on first use; both run before each re-watch)."""
    owners = [getattr(fn, "__self__", None) for fn in hub.before_rewatch]
    found = {type(o): o for o in owners if o is not None}
    if NearLedger not in found:
        found[NearLedger] = NearLedger(hub)
        hub.before_rewatch.append(found[NearLedger].flush)
    if Headings not in found:
        found[Headings] = Headings(hub, kind)
        hub.before_rewatch.append(found[Headings].update)
    return found[NearLedger], found[Headings]
