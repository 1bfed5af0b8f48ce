"""Find and Collect (thesis 4.2.2): explorers report blobs, a master hands them to collectors.

- :mod:`.explorer`: :class:`ExploreAgent` (wall-following with a blobfinder, reports blobs);
- :mod:`.collector`: :class:`CollectAgent` (navigation and gripper, fetches blobs home);
- :mod:`.fleet`: :class:`FleetCollectAgent` (a collector that works for the fleet dispatcher);
- :mod:`.master`: :class:`MasterAgent` (the blackboard; direct or contract-net allocation);
- :mod:`.messages`: the ``blob`` / ``collect`` / ``collected`` services.

Notes: ``docs/scenarios/find_collect.md``; scenario file ``deploy/scenarios/find_collect.yaml``.
"""

from .collector import CollectAgent, FetchResult
from .explorer import ExploreAgent
from .fleet import FleetCollectAgent
from .master import MasterAgent
from .messages import BLOB, COLLECT, COLLECTED, BlobReport

__all__ = [
    "BLOB",
    "COLLECT",
    "COLLECTED",
    "BlobReport",
    "CollectAgent",
    "ExploreAgent",
    "FetchResult",
    "FleetCollectAgent",
    "MasterAgent",
]
