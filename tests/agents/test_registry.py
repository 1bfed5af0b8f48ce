"""The agent class registry (agents/registry.py): decorators, the lazy index, old names."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pytest

import agents
from agents.registry import CLASS_MODULES, MOVED_MODULES, AgentClassError, agent_class, registered, resolve
from agents.runtime import Agent
from tests.conftest import ROOT


def all_agent_modules() -> list[str]:
    """Every module of the agents package (importing one only defines things)."""
    return ["agents"] + [m.name for m in pkgutil.walk_packages(agents.__path__, "agents.")]


def test_the_index_lists_exactly_the_decorated_classes():
    for name in all_agent_modules():
        importlib.import_module(name)
    found = {name: cls.__module__ for name, cls in registered().items()}
    assert found == CLASS_MODULES
    for name, cls in registered().items():
        assert issubclass(cls, Agent) and cls.__name__ == name


def test_each_registered_name_resolves_to_its_class():
    for name, mod in CLASS_MODULES.items():
        cls = resolve(name)
        assert cls.__module__ == mod and cls is registered()[name]


def test_old_module_names_of_scenario_files_still_resolve():
    for old, new in MOVED_MODULES.items():
        assert importlib.util.find_spec(old) is None, f"{old} should no longer exist as a module"
        assert importlib.import_module(new)
    assert resolve("agents.hunt:FollowAgent") is resolve("FollowAgent")
    assert resolve("agents.hunt:NavAgent") is resolve("NavAgent")
    assert resolve("agents.collect:MasterAgent") is resolve("MasterAgent")
    assert resolve("agents.swarm:SwarmMonitor") is resolve("SwarmMonitor")
    assert resolve("agents.distribution:DispersionAgent") is resolve("DispersionAgent")
    assert resolve("agents.mixed:ViewAgent") is resolve("ViewAgent")
    assert resolve("agents.classes:EscapeAgent") is resolve("EscapeAgent")


def test_naming_one_class_imports_only_its_scenario():
    code = (
        "import sys\n"
        "from agents.registry import resolve\n"
        "resolve('ViewAgent')\n"
        "print(sorted(m for m in sys.modules if m.startswith('agents.scenarios.')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['agents.scenarios.mixed', 'agents.scenarios.mixed.agents']"


def test_unknown_and_clashing_names_are_clear_errors():
    with pytest.raises(AgentClassError, match=r"unknown agent class 'Folow'; classes: .*FollowAgent"):
        resolve("Folow")
    with pytest.raises(AgentClassError, match="cannot import module 'agents.nowhere'"):
        resolve("agents.nowhere:Thing")
    with pytest.raises(AgentClassError, match="has no Agent subclass 'Outcome'"):
        resolve("agents.services:Outcome")

    class FollowAgent(Agent):  # another class under a taken name
        pass

    with pytest.raises(
        AgentClassError, match="'FollowAgent': .* would replace agents.scenarios.hunt.agents.FollowAgent"
    ):
        agent_class("FollowAgent")(FollowAgent)
    assert resolve("FollowAgent").__module__ == "agents.scenarios.hunt.agents"
