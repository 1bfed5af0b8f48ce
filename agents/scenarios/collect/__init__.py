"""Find and Collect (thesis 4.2.2): explorers report blobs, a master hands them to collectors.

:mod:`.collector`: :class:`ExploreAgent`, :class:`CollectAgent`, :class:`MasterAgent` and the
``blob`` / ``collect`` / ``collected`` services. Notes: ``docs/scenarios/find_collect.md``; scenario
file ``deploy/scenarios/find_collect.yaml``.
"""

from .collector import BLOB, COLLECT, COLLECTED, BlobReport, CollectAgent, ExploreAgent, MasterAgent

__all__ = ["BLOB", "COLLECT", "COLLECTED", "BlobReport", "CollectAgent", "ExploreAgent", "MasterAgent"]
