"""Swarm (thesis 4.2.3): a crowd of wall-following robots that broadcast their positions.

- :mod:`.behaviour`: :class:`Disperse` (the wall-following behaviour with a disperse layer),
  :func:`away_from`, :func:`away_headings`;
- :mod:`.agents`: :class:`SwarmAgent` (one robot: wall-following with the :class:`Disperse` layer,
  broadcasting, accounting what it receives), on the host's shared :class:`agents.hub.RobotHub`;
- :mod:`.monitor`: :class:`SwarmMonitor`, the verdict from the simulation's ground truth;
- :mod:`.ledger`: what the agents of a neighbourhood hub received, accounted per hub (:class:`.ledger.NearLedger`);
- :mod:`.near`: the neighbourhood hub's work before each re-watch (the ledger's flush, the headings);
- :mod:`.metrics`: delivery and latency figures (:class:`LatencyHistogram`);
- :mod:`.delivery`: delivery within a neighbourhood radius on ground truth (:class:`NeighbourhoodDelivery`);
- :mod:`.messages`: the ``swarm_stats`` service;
- :mod:`.world`: :func:`crowd_world`, the Stage world of a crowd (``maps/swarm.world``).

Notes: ``docs/scenarios/swarm.md``; scenario file ``deploy/scenarios/swarm.yaml``.
"""

from .agents import SwarmAgent
from .behaviour import Disperse, SwarmPioneer, away_from, away_headings
from .delivery import Delivery, NeighbourhoodDelivery, expand_ranges
from .messages import STATS_SERVICE
from .metrics import LATENCY_EDGES, LatencyHistogram, latency_bin, latency_bins, sequence
from .monitor import SwarmMonitor
from .world import crowd_world, write_crowd_world

__all__ = [
    "LATENCY_EDGES",
    "Delivery",
    "NeighbourhoodDelivery",
    "STATS_SERVICE",
    "Disperse",
    "LatencyHistogram",
    "SwarmAgent",
    "SwarmMonitor",
    "SwarmPioneer",
    "away_from",
    "away_headings",
    "crowd_world",
    "expand_ranges",
    "latency_bin",
    "latency_bins",
    "sequence",
    "write_crowd_world",
]
