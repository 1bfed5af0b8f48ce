"""The scenarios of the thesis's chapter 4, one package each: its agents, its messages, its notes.

Each ``agents.scenarios.<name>`` package holds what only that scenario uses; what several share
(the agent runtime, services, the contract net, the robot agents, the per-host robot hub) stays at
the top of :mod:`agents`. Nothing here is imported until a class of the scenario is named
(:mod:`agents.registry`), so this package's ``__init__`` imports none of them.
"""
