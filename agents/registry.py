"""The agent classes that scenario files and ``rsal agent CLASS`` can name (thesis fig. 3.9).

A class registers itself where it is defined, with the :func:`agent_class` decorator::

    @agent_class("FollowAgent")
    class FollowAgent(NavAgent): ...

and is then named either by that registered name (``FollowAgent``) or as ``package.module:Class``
(any :class:`agents.runtime.Agent` subclass, also outside this package). Modules are imported when
one of their classes is first asked for, so naming one class does not load every scenario's code:
for that the registry keeps an index, :data:`CLASS_MODULES` (registered name -> the module that
defines it). ``tests/agents/test_registry.py`` imports every module of :mod:`agents` and checks
that the index lists exactly the decorated classes; a new class needs its decorator and its line
in the index (``docs/contributing.md``, "A new scenario").

Scenario files written before the scenarios moved to ``agents.scenarios`` name classes as
``agents.hunt:FollowAgent``; :data:`MOVED_MODULES` maps such old module paths to the packages that
now hold the classes, so those names keep working without a module left at the old path.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TypeVar

from rsal.errors import RsalError

__all__ = ["CLASS_MODULES", "MOVED_MODULES", "AgentClassError", "agent_class", "known_classes", "registered", "resolve"]

T = TypeVar("T", bound=type)

#: registered class name -> the module that defines it (kept in sync with the decorators by a test)
CLASS_MODULES: dict[str, str] = {
    "WallfollowAgent": "agents.classes",
    "NavAgent": "agents.navigation",
    "EscapeAgent": "agents.scenarios.hunt.agents",
    "FollowAgent": "agents.scenarios.hunt.agents",
    "EnergyEscapeAgent": "agents.scenarios.hunt.energy",
    "ExploreAgent": "agents.scenarios.collect.explorer",
    "CollectAgent": "agents.scenarios.collect.collector",
    "MasterAgent": "agents.scenarios.collect.master",
    "FleetCollectAgent": "agents.scenarios.collect.fleet",
    "SwarmAgent": "agents.scenarios.swarm.agents",
    "SwarmMonitor": "agents.scenarios.swarm.monitor",
    "ThesisSwarmAgent": "agents.scenarios.swarm.thesis",
    "ThesisSwarmMonitor": "agents.scenarios.swarm.thesis",
    "DispersionAgent": "agents.scenarios.distribution.agents",
    "ViewAgent": "agents.scenarios.mixed.agents",
    "DispatcherAgent": "agents.dispatch.agent",
    "FleetAgent": "agents.dispatch.agent",
    "PatrolAgent": "agents.dispatch.patrol",
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

_REGISTERED: dict[str, type] = {}  # registered name -> class, filled as modules are imported


class AgentClassError(RsalError, LookupError):
    """An agent class name that names no known class."""


def agent_class(name: str) -> Callable[[T], T]:
    """Class decorator: register the class under ``name`` (give it a line in :data:`CLASS_MODULES`
    too, so that the name finds its module before the module is imported)."""

    def register(cls: T) -> T:
        prev = _REGISTERED.get(name)
        same = prev is not None and (prev.__module__, prev.__qualname__) == (cls.__module__, cls.__qualname__)
        if prev is not None and not same:  # a re-imported module registers its class again: fine
            raise AgentClassError(
                f"agent class name {name!r}: {cls.__module__}.{cls.__qualname__} would replace "
                f"{prev.__module__}.{prev.__qualname__}; give one of them another name"
            )
        _REGISTERED[name] = cls
        return cls

    return register


def registered() -> dict[str, type]:
    """The classes registered so far (by the modules imported so far): name -> class."""
    return dict(_REGISTERED)


def known_classes() -> list[str]:
    """The registered class names whose module imports, sorted."""
    out = []
    for name, mod in CLASS_MODULES.items():
        try:
            importlib.import_module(mod)
        except ImportError:
            continue
        if name in _REGISTERED:
            out.append(name)
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
    cls = getattr(mod, cls_name, None) if ":" in name else _REGISTERED.get(cls_name)
    if not (isinstance(cls, type) and issubclass(cls, Agent)):
        raise AgentClassError(f"agent class {name!r}: {mod_name} has no Agent subclass {cls_name!r}")
    return cls
