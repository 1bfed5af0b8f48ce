"""Swarm (thesis 4.2.3): a crowd of wall-following robots that broadcast their positions.

:mod:`.agents`: :class:`SwarmAgent`, :class:`SwarmMonitor`, :func:`crowd_world`. Notes:
``docs/scenarios/swarm.md``; scenario file ``deploy/scenarios/swarm.yaml``.
"""

from .agents import LatencyHistogram, SwarmAgent, SwarmMonitor, crowd_world, write_crowd_world

__all__ = ["LatencyHistogram", "SwarmAgent", "SwarmMonitor", "crowd_world", "write_crowd_world"]
