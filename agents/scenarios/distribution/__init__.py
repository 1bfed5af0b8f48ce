"""Distribution (thesis 4.2.4 and its "advanced" variant): spread the navigating robots over the map.

:mod:`.agents`: :func:`target_points` (farthest-point sampling of the drivable space),
:func:`assign` and :class:`DispersionAgent`. Notes: ``docs/scenarios/distribution.md``; scenario
file ``deploy/scenarios/distribution.yaml``.
"""

from .agents import DispersionAgent, assign, target_points

__all__ = ["DispersionAgent", "assign", "target_points"]
