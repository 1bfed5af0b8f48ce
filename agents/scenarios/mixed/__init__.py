"""Mixed reality (thesis 4.3, 3.6.2.3): real robots mirrored into a virtual world by a ViewAgent.

:mod:`.agents`: :class:`ViewAgent`. Notes: ``docs/mixed_reality.md``; scenario file
``deploy/scenarios/mixed_hunt.yaml``.
"""

from .agents import ViewAgent

__all__ = ["ViewAgent"]
