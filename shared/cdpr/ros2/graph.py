"""ROS 2's names on Zenoh, as rmw_zenoh (ROS 2's Zenoh middleware) writes them. Pure, no I/O.

* Data: a topic's messages are put on ``<domain>/<topic without its leading />/<dds type>/<type hash>``,
  e.g. ``0/cdpr/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_a13e…``, each with an
  :func:`attachment` (sequence number, source timestamp, the publisher's GID).
* Graph: every node and every endpoint holds a liveliness token (:func:`node_token`,
  :func:`endpoint_token`) below ``@ros2_lv/<domain>/``; ``ros2 node list`` and ``ros2 topic list`` read
  them. Names inside a token are mangled: each ``/`` becomes ``%`` (:func:`mangle`).
* Type hashes: RIHS01 (REP 2011) of the ROS 2 Jazzy definitions, as ``ros2 interface`` and rmw_zenoh
  compute them (tests check each against the ``rosbags`` library's own computation).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"

# ROS 2 type -> RIHS01 hash (Jazzy and later: the standard messages have not changed since)
TYPE_HASHES: dict[str, str] = {
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "sensor_msgs/msg/Imu": "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    "geometry_msgs/msg/PointStamped": "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "geometry_msgs/msg/TwistStamped": "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
    "geometry_msgs/msg/AccelStamped": "RIHS01_ef1df9eabae0a708cc049a061ebcddc4e2a5f745730100ba680e086a9698b165",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "std_msgs/msg/Float64MultiArray": "RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f",
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
}


def dds_type(ros_type: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def data_key(domain: int, topic: str, ros_type: str) -> str:
    """The key expression of a topic's messages (``topic`` fully qualified: ``/cdpr/joint_states``)."""
    return f"{domain}/{topic.strip('/')}/{dds_type(ros_type)}/{TYPE_HASHES[ros_type]}"


def mangle(name: str) -> str:
    """A name inside a liveliness token: every ``/`` becomes ``%`` (the root namespace ``/`` is ``%``)."""
    return name.replace("/", "%") if name else "%"


def qualify(namespace: str, topic: str) -> str:
    """``topic`` below ``namespace`` unless absolute: ("/cdpr", "joint_states") -> "/cdpr/joint_states"."""
    if topic.startswith("/"):
        return topic
    return f"{namespace.rstrip('/')}/{topic}"


@dataclass(frozen=True)
class Qos:
    """The QoS of an endpoint as its token spells it (rmw_zenoh: reliability:durability:history,depth and
    the deadline, lifespan and liveliness, left empty: their defaults)."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = 10

    def key(self) -> str:
        return f"{1 if self.reliable else 2}:{1 if self.transient_local else 2}:1,{self.depth}:,:,:,,"


@dataclass(frozen=True)
class NodeName:
    domain: int
    zid: str  # the Zenoh session's id
    node_id: int
    namespace: str  # "/" or "/cdpr"
    name: str
    enclave: str = "%"


def node_token(node: NodeName) -> str:
    """``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>``."""
    return (f"{ADMIN_SPACE}/{node.domain}/{node.zid}/{node.node_id}/{node.node_id}/NN/{node.enclave}/"
            f"{mangle(node.namespace)}/{mangle(node.name)}")


def endpoint_token(node: NodeName, entity_id: int, kind: str, topic: str, ros_type: str, qos: Qos) -> str:
    """``…/<eid>/<MP|MS>/<enclave>/<namespace>/<node>/<topic>/<dds type>/<type hash>/<qos>``."""
    return (f"{ADMIN_SPACE}/{node.domain}/{node.zid}/{node.node_id}/{entity_id}/{kind}/{node.enclave}/"
            f"{mangle(node.namespace)}/{mangle(node.name)}/{mangle(topic)}/{dds_type(ros_type)}/"
            f"{TYPE_HASHES[ros_type]}/{qos.key()}")


@dataclass(frozen=True)
class Endpoint:
    """An endpoint read back from its liveliness token."""

    zid: str
    node_id: str
    kind: str  # NN, MP, MS, SS, SC
    namespace: str
    node: str
    topic: str = ""
    dds_type: str = ""


def parse_token(key: str) -> Endpoint | None:
    """The endpoint (or node) a ``@ros2_lv/…`` key names; None for a key of another shape."""
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE:
        return None
    zid, nid, kind = parts[2], parts[3], parts[5]
    namespace, node = parts[7].replace("%", "/"), parts[8].replace("%", "/")
    if kind == "NN":
        return Endpoint(zid, nid, kind, namespace, node)
    if len(parts) < 12:
        return None
    return Endpoint(zid, nid, kind, namespace, node, parts[9].replace("%", "/"), parts[10])


_ATTACHMENT = struct.Struct("<qqB16s")


def attachment(sequence: int, timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment of a message, zenoh-ext serialised: int64 sequence number (from 1), int64 source
    timestamp (ns since the epoch), the publisher's 16-byte GID (its length first, as a varint: 16)."""
    return _ATTACHMENT.pack(sequence, timestamp_ns, 16, gid)


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence, timestamp_ns, gid) of an :func:`attachment`; ValueError for another layout."""
    if len(data) != _ATTACHMENT.size:
        raise ValueError(f"an attachment of {len(data)} bytes, expected {_ATTACHMENT.size}")
    seq, ts, n, gid = _ATTACHMENT.unpack(data)
    if n != 16:
        raise ValueError(f"a GID of {n} bytes, expected 16")
    return seq, ts, gid
