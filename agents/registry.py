"""The agent classes that scenario files and ``rsal agent CLASS`` can name (thesis fig. 3.9).

A class is named either by its registered name (``FollowAgent``) or as ``package.module:Class`` for
classes outside this package. Modules are imported when a class is first asked for, so naming one
class does not load every scenario's code.
"""

from __future__ import annotations

import importlib

from rsal.errors import RsalError

__all__ = ["CLASS_MODULES", "MOVED_MODULES", "AgentClassError", "known_classes", "resolve"]

#: registered class name -> the module that defines it
CLASS_MODULES: dict[str, str] = {
    "WallfollowAgent": "agents.classes",
    "EscapeAgent": "agents.scenarios.hunt.agents",
    "NavAgent": "agents.navigation",
    "FollowAgent": "agents.scenarios.hunt.agents",
    "ExploreAgent": "agents.scenarios.collect.collector",
    "CollectAgent": "agents.scenarios.collect.collector",
    "MasterAgent": "agents.scenarios.collect.collector",
    "SwarmAgent": "agents.scenarios.swarm.agents",
    "SwarmMonitor": "agents.scenarios.swarm.monitor",
    "DispersionAgent": "agents.scenarios.distribution.agents",
    "ViewAgent": "agents.scenarios.mixed.agents",
}

#: modules that scenario files named before the scenarios moved to ``agents.scenarios`` -> the package
#: that now holds their classes (``agents.hunt:FollowAgent`` keeps working)
MOVED_MODULES: dict[str, str] = {
    "agents.hunt": "agents.scenarios.hunt",
    "agents.collect": "agents.scenarios.collect",
    "agents.swarm": "agents.scenarios.swarm",
    "agents.distribution": "agents.scenarios.distribution",
    "agents.mixed": "agents.scenarios.mixed",
}


class AgentClassError(RsalError, LookupError):
    """An agent class name that names no known class."""


def known_classes() -> list[str]:
    """The registered class names whose module imports, sorted."""
    out = []
    for name, mod in CLASS_MODULES.items():
        try:
            if hasattr(importlib.import_module(mod), name):
                out.append(name)
        except ImportError:
            continue
    return sorted(out)


def resolve(name: str) -> type:
    """The agent class ``name`` (registered name or ``module:Class``); raises :class:`AgentClassError`."""
    from .runtime import Agent

    if ":" in name:
        mod_name, _, cls_name = name.partition(":")
        mod_name = MOVED_MODULES.get(mod_name, mod_name)
    else:
        mod_name, cls_name = CLASS_MODULES.get(name, ""), name
        if not mod_name:
            raise AgentClassError(f"unknown agent class {name!r}; classes: {', '.join(known_classes())}")
    try:
        mod = importlib.import_module(mod_name)
    except ImportError as e:
        raise AgentClassError(f"agent class {name!r}: cannot import module {mod_name!r} ({e})") from None
    cls = getattr(mod, cls_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Agent)):
        raise AgentClassError(f"agent class {name!r}: {mod_name} has no Agent subclass {cls_name!r}")
    return cls
