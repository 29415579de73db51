"""rmw_zenoh 1.x names (ros2/rmw_zenoh docs/design.md), pure functions and data.

* data key of a topic: ``<domain>/<fully qualified name without the leading />/<DDS type
  name>/<RIHS01 type hash>``, e.g. ``0/ubot1/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_...``;
* liveliness token of a node: ``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>``;
  of a publisher: ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/MP/<enclave>/<namespace>/<node>/<topic>/
  <type>/<hash>/<qos>``; names are mangled (``/`` written ``%``, an empty name ``%``);
* attachment of every sample (33 bytes): int64 LE sequence number, int64 LE source timestamp
  [ns since the epoch], one byte GID length (16), the 16-byte GID of the publisher.
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"
GID_LENGTH = 16
_ATTACHMENT = struct.Struct("<qqB16s")
ATTACHMENT_SIZE = _ATTACHMENT.size  # 33
DEFAULT_QOS = "::,10:,:,:,,"
"""rmw_zenoh's compact QoS of a reliable, volatile, keep-last-10 publisher (the defaults of
``rclcpp::QoS(10)``; ``qos_to_keyexpr``)."""
DOMAIN_MAX = 232
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class RosNameError(ValueError):
    """A ROS name, namespace or domain that ROS 2 would refuse."""


def dds_type(typename: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    package, kind, name = typename.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def ros_type(dds: str) -> str:
    """Inverse of :func:`dds_type`."""
    package, kind, dds_, name = dds.split("::")
    if dds_ != "dds_" or not name.endswith("_"):
        raise RosNameError(f"{dds!r} is no DDS type name")
    return f"{package}/{kind}/{name[:-1]}"


def mangle(name: str) -> str:
    """A name in a token: ``/`` as ``%``; an empty name is ``%``."""
    return name.replace("/", "%") if name else "%"


def demangle(chunk: str) -> str:
    return "" if chunk == "%" else chunk.replace("%", "/")


def robot_namespace(robot: str) -> str:
    """A robot's default ROS namespace, ``/<robot>`` (characters a ROS name lacks as ``_``)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", robot)
    return f"/{'_' if name[:1].isdigit() else ''}{name}"


def check_namespace(namespace: str) -> str:
    """A ROS namespace (``/`` or ``/a/b``); ``RosNameError`` naming what is wrong."""
    if namespace == "/":
        return namespace
    if not namespace.startswith("/") or namespace.endswith("/"):
        raise RosNameError(f"ROS namespace {namespace!r} must start with '/' and not end with one")
    for part in namespace[1:].split("/"):
        if not _NAME.match(part):
            raise RosNameError(f"ROS namespace {namespace!r}: {part!r} is not a ROS name "
                             "(letters, digits, '_', not starting with a digit)")
    return namespace


def check_domain(domain: int) -> int:
    if not 0 <= domain <= DOMAIN_MAX:
        raise RosNameError(f"ROS domain id {domain} is outside 0..{DOMAIN_MAX}")
    return domain


@dataclass(frozen=True)
class Node:
    """One ROS 2 node on one Zenoh session.

    Attributes:
        domain: ROS_DOMAIN_ID. namespace: ``/`` or ``/ubot1``. name: the node name.
        zid: the Zenoh session id (``str(session.info.zid())``). node_id: id in the session.
        enclave: SROS enclave (empty: none).
    """
    domain: int
    namespace: str
    name: str
    zid: str
    node_id: int = 0
    enclave: str = ""

    def __post_init__(self) -> None:
        check_domain(self.domain)
        check_namespace(self.namespace)
        if not _NAME.match(self.name):
            raise RosNameError(f"ROS node name {self.name!r} is not a ROS name")

    def topic(self, name: str) -> str:
        """Fully qualified name of a relative topic name."""
        if not _NAME.match(name):
            raise RosNameError(f"topic {name!r} is not a relative ROS name")
        return f"{self.namespace.rstrip('/')}/{name}"

    def data_key(self, topic: str, typename: str, type_hash: str) -> str:
        return f"{self.domain}/{self.topic(topic)[1:]}/{dds_type(typename)}/{type_hash}"

    def _head(self, entity_id: int, kind: str) -> str:
        ns = "" if self.namespace == "/" else self.namespace
        return (f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
                f"{mangle(self.enclave)}/{mangle(ns)}/{self.name}")

    def node_token(self) -> str:
        return self._head(self.node_id, "NN")

    def publisher_token(self, entity_id: int, topic: str, typename: str, type_hash: str,
                        qos: str = DEFAULT_QOS) -> str:
        return (f"{self._head(entity_id, 'MP')}/{mangle(self.topic(topic))}/{dds_type(typename)}/"
                f"{type_hash}/{qos}")


@dataclass(frozen=True)
class Token:
    """A parsed liveliness token (see :func:`parse_token`)."""
    domain: int
    zid: str
    node_id: int
    entity_id: int
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str = ""
    type_name: str = ""
    type_hash: str = ""
    qos: str = ""


def parse_token(key: str) -> Token:
    """Parse an rmw_zenoh liveliness token (node ``NN`` or entity ``MP``/``MS``/``SS``/``SC``).

    Raises:
        RosNameError: not a token in that format.
    """
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE:
        raise RosNameError(f"{key!r} is no rmw_zenoh liveliness token")
    kind = parts[5]
    try:
        head = dict(domain=int(parts[1]), zid=parts[2], node_id=int(parts[3]), entity_id=int(parts[4]),
                    kind=kind, enclave=demangle(parts[6]), namespace=demangle(parts[7]), node=parts[8])
    except ValueError as exc:
        raise RosNameError(f"{key!r}: domain, node and entity ids must be integers") from exc
    if kind == "NN" and len(parts) == 9:
        return Token(**head)
    if kind in ("MP", "MS", "SS", "SC") and len(parts) == 13:
        return Token(**head, topic=demangle(parts[9]), type_name=parts[10], type_hash=parts[11], qos=parts[12])
    raise RosNameError(f"{key!r}: entity kind {kind!r} with {len(parts)} chunks")


def attachment(sequence: int, timestamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment of a sample."""
    if len(gid) != GID_LENGTH:
        raise ValueError(f"a GID has {GID_LENGTH} bytes, got {len(gid)}")
    return _ATTACHMENT.pack(sequence, timestamp_ns, GID_LENGTH, gid)


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp [ns], GID) of an attachment."""
    if len(data) != ATTACHMENT_SIZE:
        raise ValueError(f"an rmw_zenoh attachment has {ATTACHMENT_SIZE} bytes, got {len(data)}")
    seq, stamp, n, gid = _ATTACHMENT.unpack(data)
    if n != GID_LENGTH:
        raise ValueError(f"GID length {n}, expected {GID_LENGTH}")
    return seq, stamp, gid
