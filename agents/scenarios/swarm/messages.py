"""The Swarm scenario's own service (thesis 4.2.3), beyond ``send_position`` of :mod:`agents.services`.

:data:`STATS_SERVICE` (``swarm_stats``): every ``stats_every`` seconds a
:class:`~agents.scenarios.swarm.agents.SwarmAgent` publishes a dict (no schema in
:mod:`agents.services`; the monitor checks the fields it reads): ``robot`` str, ``sent`` int
(positions broadcast), ``received`` and ``expected`` int (numbered positions received, and the ones
the sequence numbers say were sent: the difference is the losses), ``senders`` int, ``board`` int
(poses on its blackboard), ``latency`` (:meth:`.metrics.LatencyHistogram.to_dict`: ``bins``,
``counts``, ``max``, ``sum``). With a neighbourhood also ``since`` and ``t`` (wall times:
reception began; the figures are complete up to ``t``), ``part`` (int, 0, 1, 2, ... per agent) and
``new_ranges``: sender id -> the sequence numbers received since the previous part, as flat
inclusive ranges ``[first0, last0, first1, last1, ...]``; the parts together are everything the
agent received (a report costs what is new, not the whole run). An agent on a host's shared
control loop adds ``loop``: ``id`` (host:pid), ``cycles`` and ``overruns`` of that loop so far. A
``send_position`` broadcast's conversation id is ``p<sequence>``.
"""

__all__ = ["STATS_SERVICE"]

STATS_SERVICE = "swarm_stats"
