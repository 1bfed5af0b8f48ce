"""The agent classes that scenario files and ``rsal agent CLASS`` can name (thesis fig. 3.9).

A class is named either by its registered name (``FollowAgent``) or as ``package.module:Class`` for
classes outside this package. Modules are imported when a class is first asked for, so naming one
class does not load every scenario's code.
"""

from __future__ import annotations

import importlib

from rsal.errors import RsalError

__all__ = ["CLASS_MODULES", "AgentClassError", "known_classes", "resolve"]

#: registered class name -> the module that defines it
CLASS_MODULES: dict[str, str] = {
    "WallfollowAgent": "agents.classes",
    "EscapeAgent": "agents.classes",
    "NavAgent": "agents.hunt",
    "FollowAgent": "agents.hunt",
    "ExploreAgent": "agents.collect",
    "CollectAgent": "agents.collect",
    "MasterAgent": "agents.collect",
    "SwarmAgent": "agents.swarm",
    "SwarmMonitor": "agents.swarm",
    "DispersionAgent": "agents.distribution",
    "ViewAgent": "agents.mixed",
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
