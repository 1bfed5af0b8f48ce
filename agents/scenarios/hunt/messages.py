"""The services of Hunt and Prey (thesis 4.2.1) beyond the shared ones of :mod:`agents.services`.

The hunters allocate prey with the contract net of :mod:`agents.contractnet` on their own service
:data:`HUNT_SERVICE` (task: ``{"prey": robot id, "x": m, "y": m}``); the catch is an
:class:`agents.services.Outcome` ``caught`` whose subject is the prey's robot.
"""

__all__ = ["HUNT_SERVICE"]

HUNT_SERVICE = "hunt_cnp"  # the contract-net service the hunters allocate prey on
