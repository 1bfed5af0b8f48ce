"""One exception tree (rsal/errors.py): every exception class of rsal, mrs_bridge and agents derives
from RsalError, keeps the builtin category its callers catch, is drawn in the tree, and the
command-line net prints its one line."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import rsal.errors
from rsal.errnet import describe
from rsal.errors import RsalError

PACKAGES = ("rsal", "mrs_bridge", "agents")


def _product_exceptions() -> dict[str, type[BaseException]]:
    """Every exception class defined in a product module, by ``module.Class``."""
    found: dict[str, type[BaseException]] = {}
    for name in PACKAGES:
        pkg = importlib.import_module(name)
        for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{name}."):
            mod = importlib.import_module(info.name)
            for cls_name, cls in vars(mod).items():
                if inspect.isclass(cls) and issubclass(cls, BaseException) and cls.__module__ == mod.__name__:
                    found[f"{mod.__name__}.{cls_name}"] = cls
    return found


EXCEPTIONS = _product_exceptions()


def test_the_walk_finds_the_known_exceptions():
    for name in ("rsal.msgs.RpcError", "mrs_bridge.config.ConfigError", "agents.scenario.ScenarioError"):
        assert name in EXCEPTIONS
    assert len(EXCEPTIONS) >= 14


@pytest.mark.parametrize("name", sorted(EXCEPTIONS))
def test_every_product_exception_is_an_rsal_error_drawn_in_the_tree(name):
    cls = EXCEPTIONS[name]
    assert issubclass(cls, RsalError), f"{name} is not a subclass of rsal.errors.RsalError"
    assert f" {cls.__name__} " in rsal.errors.__doc__, f"{name} is missing from the tree in rsal/errors.py"


@pytest.mark.parametrize(
    ("name", "builtin"),
    [
        ("rsal.msgs.MessageError", ValueError),
        ("rsal.robot.RobotError", ValueError),
        ("mrs_bridge.config.ConfigError", ValueError),
        ("mrs_bridge.driver.OutOfRange", ValueError),
        ("mrs_bridge.baseguard.Latched", ValueError),
        ("mrs_bridge.hw.scip.ScipError", ValueError),
        ("mrs_bridge.server.core.ServerError", RuntimeError),
        ("agents.scenario.ScenarioError", ValueError),
        ("agents.hostproc.HostError", ValueError),
        ("agents.control.api.ApiError", ValueError),
        ("agents.registry.AgentClassError", LookupError),
    ],
)
def test_the_builtin_categories_callers_catch_are_kept(name, builtin):
    assert issubclass(EXCEPTIONS[name], builtin)


def test_the_net_prints_an_rsal_errors_own_line():
    from mrs_bridge.nav.wavefront import PlanError
    from mrs_bridge.server import ServerError

    assert describe(PlanError("unreachable", "no path from (0, 0) to (9, 9); pick a goal in open space")) == (
        "no path from (0, 0) to (9, 9); pick a goal in open space"
    )
    # a RuntimeError outside the tree would be reported as a bug; in the tree it is a user's line
    assert describe(ServerError("no driver started;\n  fix the config")) == "no driver started; fix the config"
    assert describe(RuntimeError("boom")).startswith("unexpected RuntimeError: boom")
    assert describe(RsalError()).startswith("RsalError without a message")


def test_the_simulator_keeps_its_own_root():
    """The simulator imports nothing of ours: its root is not under RsalError (rsal/errors.py says why)."""
    from simulator.errors import SimulatorError

    assert not issubclass(SimulatorError, RsalError)
    assert " SimulatorError " in rsal.errors.__doc__
