"""Hunt and Prey (thesis 4.2.1): hunters that navigate to a broadcasting prey and catch it.

:mod:`.agents`: :class:`FollowAgent` (the hunter, alone or sharing out the prey by contract net).
Notes: ``docs/scenarios/hunt_prey.md``; scenario file ``deploy/scenarios/hunt_prey.yaml``.
"""

from .agents import FollowAgent, NavAgent

__all__ = ["FollowAgent", "NavAgent"]
