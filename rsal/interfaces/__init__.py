"""The interfaces the platform knows: one module per Player interface, one registry.

Each module (``position2d``, ``ranger`` with ``laser``/``sonar``, ``localize``, ``planner``,
``map``, ``gripper``, ``blobfinder``, ``simulation``, ``crowd``, ``power``, ``dio``, ``actarray``,
``bumper``, ``fiducial``) holds that interface's wire messages (``docs/protocol.md``), its typed
geometry where it has one and its client proxy, and names them in an :class:`Interface` record.
This registry collects the records; everything else derives from it:

- the key space's interface list (:data:`rsal.keys.INTERFACES`);
- the proxy class the ``device()`` factory builds (:func:`proxy_class`);
- the device server's typed decoding of ``cmd`` payloads and of driver inputs
  (:func:`decode_data`, :func:`cmd_types`);
- the live view's decoding and one-line summaries (``rsal watch``).

Adding an interface = one module here plus its line in :data:`MODULES`; the recipe with the
exact files is ``docs/contributing.md``.
"""

from __future__ import annotations

from typing import Any

from . import (
    actarray,
    blobfinder,
    bumper,
    crowd,
    dio,
    fiducial,
    gripper,
    localize,
    map,
    planner,
    position2d,
    power,
    ranger,
    simulation,
)
from .base import Device, Interface, decode_as

__all__ = [
    "Interface",
    "Device",
    "REGISTRY",
    "MODULES",
    "names",
    "get",
    "proxy_class",
    "message_class",
    "messages",
    "decode_data",
    "cmd_types",
    "decode_as",
]

#: the interface modules, in key-space order: a new interface adds its module here (and its import above)
MODULES = (
    position2d,
    ranger,
    localize,
    planner,
    map,
    gripper,
    blobfinder,
    simulation,
    crowd,
    power,
    dio,
    actarray,
    bumper,
    fiducial,
)

#: Player's ``audio``: known to the key space, no typed messages yet (data travel as plain maps).
_AUDIO = Interface("audio", doc="sound playback and recording (plain maps)")


def _collect() -> dict[str, Interface]:
    out: dict[str, Interface] = {}
    for mod in MODULES:
        records = getattr(mod, "INTERFACES", None) or (mod.INTERFACE,)
        for rec in records:
            if rec.name in out:
                raise RuntimeError(f"interface {rec.name!r} is registered twice ({mod.__name__})")
            out[rec.name] = rec
    out[_AUDIO.name] = _AUDIO
    return out


#: name -> :class:`Interface`, in the order of the key space's interface list
REGISTRY: dict[str, Interface] = _collect()


def _messages() -> dict[str, type]:
    out: dict[str, type] = {}
    for mod in MODULES:
        for name in getattr(mod, "__all__", ()):
            obj = getattr(mod, name)
            if isinstance(obj, type) and hasattr(obj, "from_dict") and hasattr(obj, "to_msgpack"):
                out[name] = obj
    return out


_MESSAGES = _messages()


def names() -> tuple[str, ...]:
    """Every interface name, registry order."""
    return tuple(REGISTRY)


def get(name: str) -> Interface | None:
    """The record of interface ``name`` (None for an interface the platform does not know)."""
    return REGISTRY.get(name)


def proxy_class(interface: str) -> type[Device]:
    """The client proxy class of ``interface`` (the generic :class:`Device` for an unknown one)."""
    rec = REGISTRY.get(interface)
    return rec.proxy if rec is not None else Device


def message_class(name: str) -> type | None:
    """A wire message class by its name (``"VelocityCmd"``), None if there is none."""
    return _MESSAGES.get(name.strip())


def messages() -> dict[str, type]:
    """Every wire message class of the interface modules, by name."""
    return dict(_MESSAGES)


def decode_data(interface: str, payload: bytes | bytearray | memoryview | None) -> Any:
    """A ``data`` payload of ``interface`` to its message (a plain map for an interface without
    a data type, or an unknown one); raises :class:`~rsal.msgs.MessageError` for a malformed one."""
    rec = REGISTRY.get(interface)
    if rec is None or rec.data is None:
        from ..msgs import decode_map

        return decode_map(payload)
    return rec.data.from_bytes(payload)


def cmd_types(interface: str, declared: str = "") -> tuple[type, ...]:
    """The message classes a ``cmd`` of ``interface`` is decoded to: those a driver declares
    (``"GoalCmd | VelocityCmd"``, its ``cmd_types``) when every name is a known message, else the
    interface's own. Empty: the command stays a plain map."""
    if declared:
        found = tuple(message_class(n) for n in declared.split("|"))
        if all(c is not None for c in found):
            return found  # type: ignore[return-value]
        return ()  # a driver's own command type: it decodes the map itself
    rec = REGISTRY.get(interface)
    return rec.cmds if rec is not None else ()
