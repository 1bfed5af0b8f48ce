"""The platform's exceptions: one tree with :class:`RsalError` at its root (httpx's shape).

Every exception the product raises on purpose is a subclass, defined next to the code that raises
it and importable from there, as before. Where callers (or Python conventions) catch a builtin
category, the class also derives from it, so ``except ValueError`` still works::

    RsalError                                   anything the platform refuses or fails at, on purpose
    ├── MessageError (ValueError)               rsal.msgs: a payload does not match its schema
    │   ├── OutOfRange                          mrs_bridge.driver: well-formed but outside the device's range
    │   ├── Latched                             mrs_bridge.baseguard: the base's emergency stop is latched
    │   └── SenderMismatch                      agents.services: envelope sender is not the key's sender
    ├── RpcError                                rsal.msgs: a device answered with a typed error, or not at all
    ├── RobotError (ValueError)                 rsal.robot: a robot cannot be built from these devices
    ├── ConfigError (ValueError)                mrs_bridge.config: a driver configuration file is wrong
    ├── ServerError (RuntimeError)              mrs_bridge.server: the server cannot start or run
    ├── ScipError (ValueError)                  mrs_bridge.hw.scip: a malformed SCIP 2.0 frame
    ├── PlanError                               mrs_bridge.nav.wavefront: no plan (outside the map, ...)
    ├── ScenarioError (ValueError)              agents.scenario: a scenario file is wrong (file:line)
    ├── HostError (ValueError)                  agents.hostproc: a host group or an agent that cannot be built
    ├── HostConfigError (ValueError)            agents.hostd: a host daemon's configuration that cannot be used
    ├── _Refusal                                agents.hostd: a request the host daemon refuses (private)
    ├── RemoteError (ValueError)                agents.remote: a launch on a machine's daemon that could not be made
    ├── AgentClassError (LookupError)           agents.registry: no such agent class
    ├── TaskRefused (ValueError)                agents.dispatch.tasks: a task the dispatcher refuses (typed reason)
    ├── ApiError (ValueError)                   agents.control.api: a bad request to the control center
    ├── SecureError (ValueError)                rsal.secure: a fleet folder or identity that cannot be made
    ├── RecordingError (ValueError)             rsal.record: a recording that cannot be written or read
    ├── MapFileError (ValueError)               rsal.mapping.mapyaml: a map file that cannot be read or written
    ├── MapError (ValueError)                   rsal.mapping.cli: a bad ``rsal map`` argument
    ├── MapInputError (ValueError)              rsal.mapping.reader: a recording no map can be built from
    ├── TourError (ValueError)                  rsal.mapping.tour: a tour that cannot be made
    ├── RehearseError                           mrs_bridge.rehearse: a rehearsal that cannot start
    ├── WireError (ValueError)                  mrs_bridge.ros2.wire: a key, attachment or token not in rmw_zenoh's form
    └── _Failure                                agents.demo: the demo cannot go on (private)

    SimulatorError                              simulator.errors: a root of its own, see below
    ├── WorldFileError                          a world file is malformed: names file:line
    └── ModelError                              no such model, or it cannot do that
        └── OutOfWorld                          a pose outside the world's bounds

``str(error)`` is one line that names the value, the place and a fix: the command-line net
(:mod:`rsal.errnet`) prints it as it is, for every ``RsalError``. The simulator is a library that
imports nothing of ours (docs/concepts.md, "Layers"), so its errors cannot derive from
``RsalError``; ``rsal sim`` and the ``sim``/``mapfile`` drivers catch ``SimulatorError`` where they
load a world and re-raise it as a ``ConfigError`` or print its line.
"""

from __future__ import annotations

__all__ = ["RsalError"]


class RsalError(Exception):
    """Base class of every error the platform raises on purpose; ``str()`` is one line for a user."""
