"""The device server: Player's server role on Zenoh (thesis 2.2.1, 3.5; DESIGN "Processes").

A :class:`DeviceServer` hosts the drivers of one configuration. For each provided device it
declares, per the key space of :mod:`rsal.keys`:

- a liveliness token ``rsal/<node>/<iface>/<idx>`` (present while the device works),
- a ``data`` publisher and an ``event`` publisher,
- a ``cmd`` subscriber and an ``rpc/*`` queryable (``rpc/describe`` on every device).

Ready means ready: a device's token is declared only once its driver is set up (compiled kernels
included, see :mod:`simulator.warmup`) and has run its first ``update()`` (drivers without a rate
publish on their own events: after the first scheduler pass), so a client that sees the token can
query, command and receive data at once, on the first run of a fresh checkout as on every other.

Concurrency: Zenoh callbacks only put raw items on one in-memory queue; a single scheduler loop
(:meth:`DeviceServer.run`) takes them off, decodes and validates them, hands them to drivers and
replies, and runs every driver's ``update()`` at its own rate. A driver that raises is logged, its
devices' tokens are withdrawn (clients see them as lost) and the other drivers keep running.
Bad input (not msgpack, wrong fields or types, NaN/inf, out of range, unknown op) gets an error
reply on ``rpc`` and a rate-limited warning on ``cmd``, and changes nothing.

Typed hand-over: where the interface is known (:mod:`rsal.interfaces`), a ``cmd`` reaches the
driver's ``on_cmd`` as its message (the types the driver declares in ``cmd_types``, else the
interface's: ``VelocityCmd``, ``GoalCmd``, ``GripperCmd``, ``DioCmd``) and a required device's
``data`` reaches ``on_input`` as the interface's data message (``Position2dData``,
``RangerData``, ...), decoded and validated once, here. Events and interfaces without a message
type arrive as plain maps.

Required devices may live on other servers: a driver with ``requires`` waits for their tokens
(liveliness subscriber with history) up to ``require_timeout`` seconds, then fails with a message
that names the missing devices.

The package's modules: :mod:`.core` (:class:`DeviceServer`: driver slots, lifecycle, the
scheduler), :mod:`.devices` (declaring devices, readiness tokens, publishing), :mod:`.intake` (the
bounded inbox, Zenoh's callbacks, typed decoding of ``cmd`` and inputs) and :mod:`.rpc` (queries,
typed replies, long operations). The server logs under the one name ``mrs_bridge.server``.
"""

from .core import WARN_INTERVAL, DeviceServer, ServerError, make_driver_config
from .intake import INBOX_MAX, MAX_INPUT, MAX_PAYLOAD

__all__ = [
    "INBOX_MAX",
    "MAX_INPUT",
    "MAX_PAYLOAD",
    "WARN_INTERVAL",
    "DeviceServer",
    "ServerError",
    "make_driver_config",
]
