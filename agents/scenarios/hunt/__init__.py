"""Hunt and Prey (thesis 4.2.1): hunters that navigate to a broadcasting prey and catch it.

:mod:`.agents`: :class:`FollowAgent` (the hunter, alone or sharing out the prey by contract net,
and with a finite ``sight`` waiting at the energy stations) and :class:`EscapeAgent` (the prey);
:mod:`.energy`: :class:`EnergyEscapeAgent` (the prey that recharges at energy stations);
:mod:`.stations`: where the stations are and which one a robot goes to; :mod:`.messages`: the
hunters' contract-net service. The hunter is a
:class:`agents.navigation.NavAgent`, the prey a :class:`agents.classes.WallfollowAgent`.
Notes: ``docs/scenarios/hunt_prey.md``; scenario file ``deploy/scenarios/hunt_prey.yaml``.
"""

from agents.navigation import NavAgent  # named ``agents.hunt:NavAgent`` in older scenario files

from .agents import EscapeAgent, FollowAgent
from .energy import EnergyEscapeAgent
from .messages import HUNT_SERVICE

__all__ = ["HUNT_SERVICE", "EnergyEscapeAgent", "EscapeAgent", "FollowAgent", "NavAgent"]
