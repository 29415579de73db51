"""A ROS 2 node on the agent's Zenoh session, in rmw_zenoh 1.x's format (``names``): a node
liveliness token, and per topic of ``messages.TOPICS`` a publisher on its data key with its
``MP`` token; every sample carries the 33-byte attachment (sequence number from 1, source
timestamp strictly increasing, the publisher's GID). ``ros2 topic list/echo`` on a machine
running rmw_zenoh against the same router sees it (docs/ros2.md)."""
from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import dataclass, field

import zenoh

from ersac_hil.ros2 import messages, names
from ersac_hil.ros2.options import Ros2Options

log = logging.getLogger(__name__)


@dataclass
class _Publisher:
    publisher: zenoh.Publisher
    token: zenoh.LivelinessToken
    gid: bytes
    sequence: int = 0
    last_ns: int = 0

    def put(self, data: bytes) -> None:
        self.sequence += 1
        self.last_ns = max(time.time_ns(), self.last_ns + 1)
        self.publisher.put(data, attachment=names.attachment(self.sequence, self.last_ns, self.gid))


@dataclass
class Ros2Node:
    """The node's tokens and publishers on ``session`` (``close()`` withdraws them; the
    session stays the caller's)."""
    session: zenoh.Session
    node: names.Node
    publishers: dict[str, _Publisher] = field(default_factory=dict)

    @classmethod
    def declare(cls, session: zenoh.Session, options: Ros2Options, robot: str) -> "Ros2Node":
        node = names.Node(options.domain, options.namespace_for(robot), options.node, str(session.info.zid()))
        self = cls(session, node)
        self._node_token = session.liveliness().declare_token(node.node_token())
        for entity_id, (topic, typename) in enumerate(messages.TOPICS.items(), start=1):
            type_hash = messages.type_hash(typename)
            token_key = node.publisher_token(entity_id, topic, typename, type_hash)
            self.publishers[topic] = _Publisher(
                session.declare_publisher(node.data_key(topic, typename, type_hash)),
                session.liveliness().declare_token(token_key),
                hashlib.sha256(token_key.encode()).digest()[:names.GID_LENGTH])
        log.info("ROS 2 node %s%s on domain %d: %s", node.namespace.rstrip("/") + "/", node.name,
                 node.domain, ", ".join(node.topic(t) for t in messages.TOPICS))
        return self

    def put(self, topic: str, data: bytes) -> None:
        self.publishers[topic].put(data)

    def close(self) -> None:
        for p in self.publishers.values():
            for entity in (p.token, p.publisher):
                try:
                    entity.undeclare()
                except Exception as exc:  # the session may be closing
                    log.debug("undeclare: %s", exc)
        self.publishers = {}
        try:
            self._node_token.undeclare()
        except Exception as exc:
            log.debug("undeclare: %s", exc)
