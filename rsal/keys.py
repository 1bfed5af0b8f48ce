"""The key space: the one module that knows how RSAL addresses are laid out on Zenoh.

A device address is Player's ``host:port:interface:index`` with the host:port pair replaced by a
*node* name (usually the robot, e.g. ``r0``), thesis 3.6.2.3 (DeviceNode)::

    rsal/<node>/<iface>/<idx>/data        latest state, published at the driver's rate
    rsal/<node>/<iface>/<idx>/cmd         fire-and-forget commands (velocities)
    rsal/<node>/<iface>/<idx>/rpc/<op>    request/reply operations
    rsal/<node>/<iface>/<idx>/event       asynchronous events (goal done, gripper closed)
    liveliness token rsal/<node>/<iface>/<idx>   present while the device works
    agents/<agent_id>                     liveliness token of a running agent
    svc/<service>/<sender_id>             agent services
    liveliness token hosts/<name>         a host daemon (``rsal host``) that launches agent hosts
    hosts/<name>/rpc/<op>                 its launch/stop/status requests
    hosts/<name>/run/<run>/<what>         a launched agent host's output lines and exit (``out``,
                                          ``exit``) and the runner's token (``runner``)

In configuration files a device is written the Player way, ``[key::][node:]iface:idx`` (for
example ``odometry::r0:position2d:0`` or ``laser:0``), see :func:`parse_device`. The full contract
is in ``docs/protocol.md``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

__all__ = [
    "PREFIX",
    "INTERFACES",
    "DeviceAddr",
    "parse_device",
    "device_key",
    "data_key",
    "cmd_key",
    "rpc_key",
    "event_key",
    "parse_key",
    "template_to_keyexpr",
    "AGENTS_PREFIX",
    "SVC_PREFIX",
    "check_name",
    "is_name",
    "agent_key",
    "service_key",
    "HOSTS_PREFIX",
    "host_key",
    "host_rpc_key",
    "host_run_key",
]

PREFIX = "rsal"
PROTOCOL_VERSION = 1

# Player's interfaces that RSAL knows (thesis 3.6.2.3 and appendix A.2-A.4): ``INTERFACES`` is the
# registry's list (rsal/interfaces), read on first use because the interface modules import this one.
if TYPE_CHECKING:
    INTERFACES: tuple[str, ...]


def __getattr__(name: str):
    if name == "INTERFACES":
        from .interfaces import names

        value = globals()["INTERFACES"] = names()
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


_NAME = re.compile(r"^[A-Za-z0-9_\-.]+$")  # no '/', '*', '$', '?', '#', ':' and no spaces


def is_name(value: object) -> bool:
    """True when ``value`` is a valid name (:func:`check_name`'s rule), without raising."""
    return type(value) is str and _NAME.match(value) is not None


def check_name(kind: str, value: str) -> str:
    """A node, interface, key or agent name must be one key chunk: letters, digits, ``_ - .``."""
    if not isinstance(value, str) or not _NAME.match(value):
        raise ValueError(
            f"{kind} {value!r} must be letters, digits, '_', '-' or '.' (one key chunk: no '/', '*', ':' or spaces)"
        )
    return value


@dataclass(frozen=True, order=True)
class DeviceAddr:
    """``node/interface/index`` of one device; ``key`` is Player's optional role name
    (``odometry::``, ``laser::``) that tells a driver which required device is which."""

    node: str
    interface: str
    index: int = 0
    key: str = ""

    def __post_init__(self) -> None:
        check_name("node", self.node)
        check_name("interface", self.interface)
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 0:
            raise ValueError(f"device index {self.index!r} must be a non-negative integer")

    @property
    def path(self) -> str:
        """``node/iface/idx``, the part after the ``rsal/`` prefix."""
        return f"{self.node}/{self.interface}/{self.index}"

    def __str__(self) -> str:
        k = f"{self.key}::" if self.key else ""
        return f"{k}{self.node}:{self.interface}:{self.index}"

    def without_key(self) -> DeviceAddr:
        return DeviceAddr(self.node, self.interface, self.index)


def parse_device(text: str, default_node: str | None = None) -> DeviceAddr:
    """Parse ``[key::][node:]iface:idx``; ``default_node`` fills a missing node.

    >>> parse_device("odometry::r0:position2d:0")
    DeviceAddr(node='r0', interface='position2d', index=0, key='odometry')
    """
    if not isinstance(text, str):
        raise ValueError(f"device {text!r} must be a string like 'r0:laser:0'")
    s = text.strip()
    key = ""
    if "::" in s:
        key, s = s.split("::", 1)
        # Player allows "output:::position2d:1" (key, empty host): tolerate a leading ':'.
        s = s.lstrip(":")
    parts = s.split(":")
    if len(parts) == 2:
        if not default_node:
            raise ValueError(f"device {text!r} names no node; write it as 'node:{parts[0]}:{parts[1]}'")
        node, iface, idx = default_node, parts[0], parts[1]
    elif len(parts) == 3:
        node, iface, idx = parts
    else:
        raise ValueError(f"device {text!r} must look like '[key::][node:]interface:index', e.g. 'r0:laser:0'")
    try:
        index = int(idx)
    except ValueError:
        raise ValueError(f"device {text!r}: index {idx!r} is not an integer") from None
    try:
        if key:
            check_name("device key", key)
        return DeviceAddr(node, iface, index, key)
    except ValueError as e:
        raise ValueError(f"device {text!r}: {e}") from None


def device_key(addr: DeviceAddr) -> str:
    """The liveliness token key of a device."""
    return f"{PREFIX}/{addr.path}"


def data_key(addr: DeviceAddr) -> str:
    return f"{PREFIX}/{addr.path}/data"


def cmd_key(addr: DeviceAddr) -> str:
    return f"{PREFIX}/{addr.path}/cmd"


def rpc_key(addr: DeviceAddr, op: str) -> str:
    return f"{PREFIX}/{addr.path}/rpc/{check_name('operation', op)}"


def bases_rpc_keyexpr(op: str, node: str | None = None) -> str:
    """Every ``position2d``'s ``rpc/<op>`` of ``node`` (of every node if None): the emergency stop's
    one query to many bases."""
    n = "*" if node is None else check_name("node", node)
    return f"{PREFIX}/{n}/position2d/*/rpc/{check_name('operation', op)}"


def event_key(addr: DeviceAddr) -> str:
    return f"{PREFIX}/{addr.path}/event"


def parse_key(key: str) -> tuple[DeviceAddr, str, str] | None:
    """Split a full key into ``(device, channel, op)``: channel is ``""`` for a token key,
    ``data``/``cmd``/``event``, or ``rpc`` with ``op``. None if it is not a device key."""
    parts = str(key).split("/")
    if len(parts) < 4 or parts[0] != PREFIX:
        return None
    try:
        addr = DeviceAddr(parts[1], parts[2], int(parts[3]))
    except ValueError:
        return None
    rest = parts[4:]
    if not rest:
        return addr, "", ""
    if rest[0] in ("data", "cmd", "event") and len(rest) == 1:
        return addr, rest[0], ""
    if rest[0] == "rpc" and len(rest) == 2:
        return addr, "rpc", rest[1]
    return None


def template_to_keyexpr(template: str) -> str:
    """A device template in either form to a token key expression.

    Accepts key expressions (``rsal/r0/**``, ``rsal/*/ranger/*``, ``r0/**``) and Player-style
    patterns with ``*`` for any part (``r0:*:*``, ``*:laser:*``, ``r0``). An empty template or
    ``**`` means every device.
    """
    t = (template or "").strip()
    if t in ("", "*", "**"):
        return f"{PREFIX}/**"
    if ":" in t and "/" not in t:
        parts = t.split(":")
        if len(parts) == 2:
            parts = ["*", *parts]
        if len(parts) != 3:
            raise ValueError(f"template {template!r} must look like 'node:interface:index' with '*' wildcards")
        return f"{PREFIX}/" + "/".join(p or "*" for p in parts)
    if not t.startswith(PREFIX + "/") and t != PREFIX:
        t = f"{PREFIX}/{t}"
    if t.count("/") < 3 and not t.endswith("**"):
        t = t.rstrip("/") + "/**"
    return t


#: agents' liveliness tokens live under ``agents/<agent id>``; service messages under ``svc/``
AGENTS_PREFIX = "agents"
SVC_PREFIX = "svc"


def agent_key(agent_id: str) -> str:
    """The liveliness key of a running agent: ``agents/<agent_id>``."""
    return f"{AGENTS_PREFIX}/{check_name('agent id', agent_id)}"


def service_key(service: str, sender: str = "*") -> str:
    """``svc/<service>/<sender>`` (``*`` for every sender)."""
    s = check_name("service", service)
    return f"{SVC_PREFIX}/{s}/{sender if sender == '*' else check_name('sender id', sender)}"


#: host daemons (``rsal host``, :mod:`agents.hostd`): token ``hosts/<name>``, requests and runs under it
HOSTS_PREFIX = "hosts"
HOST_OPS = ("launch", "stop", "status")
RUN_PARTS = ("out", "exit", "runner")


def host_key(name: str) -> str:
    """The liveliness key of a host daemon: ``hosts/<name>`` (``*``: every daemon)."""
    return f"{HOSTS_PREFIX}/{name if name == '*' else check_name('host name', name)}"


def host_rpc_key(name: str, op: str = "*") -> str:
    """``hosts/<name>/rpc/<op>``: a host daemon's launch, stop and status requests."""
    if op != "*" and op not in HOST_OPS:
        raise ValueError(f"host operation {op!r}: one of {', '.join(HOST_OPS)}")
    return f"{host_key(name)}/rpc/{op}"


def host_run_key(name: str, run: str = "*", part: str = "*") -> str:
    """``hosts/<name>/run/<run>/<part>``: a launched agent host's ``out`` lines and ``exit``, and the
    ``runner`` token of whoever launched it (the daemon stops the run when that token goes)."""
    if part not in ("*", "**") and part not in RUN_PARTS:
        raise ValueError(f"run key part {part!r}: one of {', '.join(RUN_PARTS)}")
    r = run if run == "*" else check_name("run id", run)
    return f"{host_key(name)}/run/{r}/{part}"
