"""A minimal ROS 2 participant on a Zenoh session: nodes, publishers and subscriptions that
rmw_zenoh peers (``ros2 topic echo``, rviz2, Nav2) see and talk to.

Each entity declares its graph token (:class:`mrs_bridge.ros2.wire.Entity`); a publisher puts
CDR with the 33-byte attachment and a sequence number that starts at 1 and grows per publisher,
as ``rmw_publisher_data.cpp`` does; a subscription listens on the topic with any hash chunk and
accepts the type's RIHS01 hash or Humble's ``TypeHashNotSupported`` (another hash is another
definition of the type: logged once and dropped), decodes the CDR and hands the message to its
callback on Zenoh's thread (the callback must not block).

A transient-local publisher (``/map``) is Zenoh's advanced publisher with a cache of ``depth``
samples and publisher detection, plus sample-miss heartbeats when reliable, as rmw_zenoh declares
it: a late subscriber (rmw_zenoh's advanced subscriber with history) gets the cached messages.

:class:`Outbox` is the hand-off from Zenoh's threads: the latest message per publisher (latest
wins), built, encoded and put by one thread of its own.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
import zenoh.ext as zext

from . import types
from .wire import DEFAULT_QOS, Attachment, Entity, Kind, QoS, WireError, topic_key, topic_keyexpr_any_hash

__all__ = ["Participant", "Node", "Publisher", "Subscription", "Outbox"]

log = logging.getLogger(__name__)


class Participant:
    """The ROS side of one Zenoh session: the domain and the entity numbering."""

    def __init__(self, session: zenoh.Session, domain: int = 0, enclave: str = "/"):
        self.session = session
        self.domain = int(domain)
        self.enclave = enclave
        self.zid = str(session.zid())
        self._ids = itertools.count()
        self._lock = threading.Lock()

    def next_id(self) -> int:
        with self._lock:
            return next(self._ids)

    def node(self, namespace: str, name: str) -> Node:
        return Node(self, namespace, name)


def _fq(namespace: str, topic: str) -> str:
    """Fully qualified topic: relative names resolve in the node's namespace."""
    if topic.startswith("/"):
        return topic
    return f"{namespace.rstrip('/')}/{topic}"


class Node:
    """A ROS node: its ``NN`` token, and the publishers and subscriptions it declares."""

    def __init__(self, part: Participant, namespace: str, name: str):
        self.part = part
        self.namespace = namespace
        self.name = name
        self.nid = part.next_id()
        self.entity = Entity(part.domain, part.zid, self.nid, self.nid, Kind.NODE, namespace, name, part.enclave)
        self._token = part.session.liveliness().declare_token(self.entity.token)
        self._children: list[Publisher | Subscription] = []
        self.closed = False

    def _entity(self, kind: Kind, topic: str, ros_type: str, qos: QoS) -> Entity:
        return Entity(
            self.part.domain,
            self.part.zid,
            self.nid,
            self.part.next_id(),
            kind,
            self.namespace,
            self.name,
            self.part.enclave,
            topic=_fq(self.namespace, topic),
            type=types.dds_name(ros_type),
            type_hash=types.type_hash(ros_type),
            qos=qos,
        )

    def publisher(self, topic: str, ros_type: str, qos: QoS = DEFAULT_QOS) -> Publisher:
        p = Publisher(self, self._entity(Kind.PUBLISHER, topic, ros_type, qos), ros_type)
        self._children.append(p)
        return p

    def subscription(
        self, topic: str, ros_type: str, callback: Callable[[Any, Attachment], None], qos: QoS = DEFAULT_QOS
    ) -> Subscription:
        s = Subscription(self, self._entity(Kind.SUBSCRIPTION, topic, ros_type, qos), ros_type, callback)
        self._children.append(s)
        return s

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for c in self._children:
            c.close()
        _undeclare(self._token)


def _undeclare(x) -> None:
    try:
        x.undeclare()
    except Exception:  # the session closed first: its entities went with it
        pass


class Publisher:
    """Puts messages of one type on one topic, each with its attachment."""

    def __init__(self, node: Node, entity: Entity, ros_type: str):
        self.entity = entity
        self.ros_type = ros_type
        self.key = topic_key(entity.domain, entity.topic, entity.type, entity.type_hash)
        self.gid = entity.gid
        self.sequence = 0  # the number of the last message put; the first is 1
        s = node.part.session
        q = entity.qos
        if q.durability == 1:  # transient local
            self._pub = zext.declare_advanced_publisher(
                s,
                self.key,
                encoding=zenoh.Encoding.APPLICATION_CDR,
                congestion_control=zenoh.CongestionControl.DROP,
                cache=zext.CacheConfig(max(1, q.depth)),
                publisher_detection=True,
                sample_miss_detection=zext.MissDetectionConfig(sporadic_heartbeat=0.5) if q.reliability == 1 else None,
            )
        else:
            self._pub = s.declare_publisher(
                self.key, encoding=zenoh.Encoding.APPLICATION_CDR, congestion_control=zenoh.CongestionControl.DROP
            )
        self._token = s.liveliness().declare_token(entity.token)
        self._lock = threading.Lock()
        self.closed = False

    def publish(self, msg: Any) -> None:
        self.publish_cdr(types.encode(msg, self.ros_type))

    def publish_cdr(self, payload: bytes) -> None:
        with self._lock:
            if self.closed:
                return
            self.sequence += 1
            att = Attachment(self.sequence, time.time_ns(), self.gid).to_bytes()
            self._pub.put(payload, attachment=att)

    def close(self) -> None:
        with self._lock:
            if self.closed:
                return
            self.closed = True
        _undeclare(self._token)
        _undeclare(self._pub)


class Subscription:
    """Receives one topic's messages (from rmw_zenoh peers of Jazzy or Humble)."""

    def __init__(self, node: Node, entity: Entity, ros_type: str, callback: Callable[[Any, Attachment], None]):
        self.entity = entity
        self.ros_type = ros_type
        self.callback = callback
        self.accepted = {entity.type_hash, types.HASH_NOT_SUPPORTED}
        self.dropped = 0
        s = node.part.session
        self.keyexpr = topic_keyexpr_any_hash(entity.domain, entity.topic, entity.type)
        self._sub = s.declare_subscriber(self.keyexpr, self._on_sample)
        self._token = s.liveliness().declare_token(entity.token)
        self.closed = False

    def _drop(self, key: str, why: str) -> None:
        self.dropped += 1
        if self.dropped in (1, 10, 100) or self.dropped % 1000 == 0:
            log.warning("%s: dropped a message (%d so far): %s", key, self.dropped, why)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        h = key.rsplit("/", 1)[-1]
        if h not in self.accepted:
            self._drop(key, f"type hash {h} is not {self.entity.type_hash} (another definition of {self.ros_type})")
            return
        try:
            att = Attachment.from_bytes(None if sample.attachment is None else sample.attachment.to_bytes())
        except WireError as e:
            self._drop(key, f"{e}; rmw_zenoh publishers always attach one")
            return
        try:
            msg = types.decode(sample.payload.to_bytes(), self.ros_type)
        except Exception as e:  # malformed CDR: the library's errors are of several kinds
            self._drop(key, f"not a {self.ros_type} in CDR: {e}")
            return
        try:
            self.callback(msg, att)
        except Exception:
            log.exception("%s: the subscription's callback failed", key)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        _undeclare(self._token)
        _undeclare(self._sub)


class Outbox:
    """The latest (build, data) per publisher and slot; one thread builds, encodes and puts them
    (a build that returns None puts nothing)."""

    def __init__(self):
        self._pending: dict[tuple[Publisher, int], tuple[Callable[[Any], Any], Any]] = {}
        self._cond = threading.Condition()
        self._closed = False
        self.sent = 0
        self._thread = threading.Thread(target=self._run, name="ros2-export", daemon=True)
        self._thread.start()

    def post(self, pub: Publisher, build: Callable[[Any], Any], data: Any, slot: int = 0) -> None:
        with self._cond:
            self._pending[(pub, slot)] = (build, data)
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                batch, self._pending = self._pending, {}
            for (pub, _), (build, data) in batch.items():
                try:
                    msg = build(data)
                    if msg is not None:
                        pub.publish(msg)
                        self.sent += 1
                except Exception:
                    log.exception("%s: could not publish", pub.entity.topic)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(5.0)
