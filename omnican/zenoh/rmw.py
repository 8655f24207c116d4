"""rmw_zenoh's wire format, so that ROS 2 nodes on ``rmw_zenoh_cpp`` see the base: key
expressions of data, liveliness tokens of the ROS graph, the QoS string in them, and the
attachment every publication carries. Pure: strings and bytes, no Zenoh, no I/O.

The format is rmw_zenoh's design document (``docs/design.md``, "Topic and Service name
mapping to Zenoh key expressions", "Graph Cache") and its ``attachment_helpers.cpp``:

- data: ``<domain>/<fully qualified name without its leading slash>/<DDS type name>/
  RIHS01_<type hash>``, e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``;
- liveliness: ``@ros2_lv/<domain>/<session id>/<node id>/<entity id>/<kind>/<enclave>/
  <namespace>/<node name>[/<name>/<type>/<hash>/<qos>]`` with every ``/`` inside a name
  written ``%`` (an empty namespace is ``%``);
- attachment: int64 sequence number, int64 source timestamp (ns), then the 16-byte GID
  as a sequence: its length (LEB128, one byte ``0x10``) and the bytes; little endian.

Type hashes (REP 2011's RIHS01) come from the message definitions rosbags ships for ROS 2
Jazzy (:func:`type_hash`): no ROS installation is needed.
"""

from __future__ import annotations

import functools
import hashlib
import re
import struct
from dataclasses import dataclass
from enum import Enum
from typing import Any

ADMIN_SPACE = "@ros2_lv"
GID_BYTES = 16
#: rmw_zenoh's QoS defaults: a field equal to its default is left empty in the token.
DEFAULT_DEPTH = 42
_HEAD = struct.Struct("<qq")  # sequence number, source timestamp (ns)
_TYPE_NAME = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(msg|srv)/([A-Za-z][A-Za-z0-9_]*)$")


class Kind(str, Enum):
    """An entity in a liveliness token (rmw_zenoh's two-letter kinds)."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


def mangle(name: str) -> str:
    """A name as one chunk of a key expression: ``/`` -> ``%``; empty -> ``%``."""
    return name.replace("/", "%") or "%"


def unmangle(chunk: str) -> str:
    """The inverse of :func:`mangle` (``%`` -> ``/``)."""
    return chunk.replace("%", "/")


def dds_type_name(type_name: str) -> str:
    """``nav_msgs/msg/Odometry`` -> ``nav_msgs::msg::dds_::Odometry_`` (ROS 2's DDS name)."""
    m = _TYPE_NAME.match(type_name)
    if m is None:
        raise ValueError(f"not a ROS 2 type name (package/msg/Name): {type_name!r}")
    package, kind, name = m.groups()
    return f"{package}::{kind}::dds_::{name}_"


def ros_type_name(dds_name: str) -> str:
    """The inverse of :func:`dds_type_name`."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        raise ValueError(f"not a ROS 2 DDS type name: {dds_name!r}")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def type_hash(type_name: str) -> str:
    """``RIHS01_<sha256>`` of a type ROS 2 Jazzy ships (or omnican registers)."""
    from omnican.telemetry.cdr import typestore

    value: str = typestore().hash_rihs01(type_name)
    return value


#: ROS 2's service_msgs/msg/ServiceEventInfo as its type description has it: rosidl
#: writes ``char`` as uint8, where rosbags' store keeps ``char`` (and so hashes it apart).
_EVENT_INFO = ("uint8 event_type\nbuiltin_interfaces/Time stamp\nuint8[16] client_gid\n"
               "int64 sequence_number")


@functools.cache
def service_type_hash(name: str, request: str, response: str) -> str:
    """``RIHS01_<sha256>`` of the service ``name`` (``std_srvs/srv/Trigger``) whose request
    and response have the message definitions ``request`` and ``response``: REP 2011's
    service description (request_message, response_message, event_message; the event
    holds ServiceEventInfo and at most one request and one response)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if _TYPE_NAME.match(name) is None or "/srv/" not in name:
        raise ValueError(f"not a ROS 2 service name (package/srv/Name): {name!r}")
    short = name.rsplit("/", 1)[1]
    types: dict[str, Any] = {}
    for text, typename in (
            ("int32 sec\nuint32 nanosec", "builtin_interfaces/msg/Time"),
            (_EVENT_INFO, "service_msgs/msg/ServiceEventInfo"),
            (request, f"{name}_Request"), (response, f"{name}_Response"),
            (f"service_msgs/ServiceEventInfo info\n{short}_Request[<=1] request\n"
             f"{short}_Response[<=1] response", f"{name}_Event"),
            (f"{short}_Request request_message\n{short}_Response response_message\n"
             f"{short}_Event event_message", name)):
        types.update(get_types_from_msg(text, typename))
    store = get_typestore(Stores.EMPTY)
    # rosbags files a service's parts under <package>/srv/msg/; ROS 2 names them
    # <package>/srv/<Name>_Request (the names are part of what is hashed).
    store.register({_srv_name(k): _srv_names(v) for k, v in types.items()})
    value: str = store.hash_rihs01(name)
    return value


def _srv_name(name: str) -> str:
    return name.replace("/srv/msg/", "/srv/")


def _srv_names(value: Any) -> Any:
    if isinstance(value, str):
        return _srv_name(value)
    if isinstance(value, (list, tuple)):
        return type(value)(_srv_names(v) for v in value)
    return value


def fully_qualified(namespace: str, name: str) -> str:
    """``/ns`` + ``odom`` -> ``/ns/odom``; an absolute name (``/odom``) stays as it is."""
    if name.startswith("/"):
        return name
    ns = namespace.strip("/")
    return f"/{ns}/{name}" if ns else f"/{name}"


def data_key(domain_id: int, fq_name: str, type_name: str, hash_: str) -> str:
    """The key expression a topic's (or service's) data travel on."""
    if not fq_name.startswith("/") or fq_name == "/":
        raise ValueError(f"not a fully qualified name: {fq_name!r}")
    return f"{domain_id}/{fq_name[1:]}/{dds_type_name(type_name)}/{hash_}"


def topic_of(key: str) -> str:
    """The fully qualified name a data key (:func:`data_key`) carries: its chunks between
    the domain and the type. ValueError for a key with no name in it."""
    parts = key.split("/")
    if len(parts) < 4:
        raise ValueError(f"not an rmw_zenoh data key: {key!r}")
    return "/" + "/".join(parts[1:-2])


class Reliability(Enum):
    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(Enum):
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


@dataclass(frozen=True)
class Qos:
    """What a liveliness token says of an endpoint's QoS. Keep-last history; deadline,
    lifespan and liveliness lease are infinite and liveliness automatic (rmw_zenoh
    implements no other)."""

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    depth: int = 10

    def encode(self) -> str:
        """rmw_zenoh's ``qos_to_keyexpr``: ``<rel>:<dur>:<kind>,<depth>:<deadline>:
        <lifespan>:<liveliness>``, a default left empty (``::,10:,:,:,,``)."""
        rel = "" if self.reliability is Reliability.RELIABLE else str(self.reliability.value)
        dur = "" if self.durability is Durability.VOLATILE else str(self.durability.value)
        depth = "" if self.depth == DEFAULT_DEPTH else str(self.depth)
        return f"{rel}:{dur}:,{depth}:,:,:,,"

    @staticmethod
    def decode(text: str) -> Qos:
        """The inverse of :meth:`encode`; ValueError for what it does not describe."""
        parts = text.split(":")
        if len(parts) != 6 or parts[3:] != [",", ",", ",,"]:
            raise ValueError(f"not a QoS string with infinite durations: {text!r}")
        rel, dur, hist = parts[:3]
        kind, comma, depth = hist.partition(",")
        if kind not in ("", "1") or not comma:
            raise ValueError(f"not a keep-last history: {hist!r}")
        try:
            return Qos(Reliability(int(rel)) if rel else Reliability.RELIABLE,
                       Durability(int(dur)) if dur else Durability.VOLATILE,
                       int(depth) if depth else DEFAULT_DEPTH)
        except ValueError:
            raise ValueError(f"not a QoS string: {text!r}") from None


@dataclass(frozen=True)
class RosNode:
    """A ROS 2 node as the ROS graph sees it (not a CANopen node): ``session_id`` is the
    Zenoh session's id (hex)."""

    domain_id: int
    session_id: str
    node_id: int
    name: str
    namespace: str = ""
    enclave: str = ""

    def token(self) -> str:
        """The node's liveliness token (kind ``NN``; its entity id is its node id)."""
        return self._prefix(self.node_id, Kind.NODE)

    def _prefix(self, entity_id: int, kind: Kind) -> str:
        return (f"{ADMIN_SPACE}/{self.domain_id}/{self.session_id}/{self.node_id}/"
                f"{entity_id}/{kind.value}/{mangle(self.enclave)}/{mangle(self.namespace)}/"
                f"{mangle(self.name)}")

    def endpoint_token(self, entity_id: int, kind: Kind, fq_name: str, type_name: str,
                       hash_: str, qos: Qos) -> str:
        """The liveliness token of a publisher, subscription, service or client."""
        if kind is Kind.NODE:
            raise ValueError("a node's token is RosNode.token()")
        return (f"{self._prefix(entity_id, kind)}/{mangle(fq_name)}/"
                f"{dds_type_name(type_name)}/{hash_}/{qos.encode()}")


def gid_of(token: str) -> bytes:
    """A fixed 16-byte GID for the endpoint that ``token`` announces: the same token, the
    same GID (rmw_zenoh hashes the token too; any stable 16 bytes will do for a peer)."""
    return hashlib.sha256(token.encode()).digest()[:GID_BYTES]


@dataclass(frozen=True)
class Attachment:
    """What rides along with every publication (and service request and reply)."""

    sequence: int
    timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        if len(self.gid) != GID_BYTES:
            raise ValueError(f"a GID is {GID_BYTES} bytes, not {len(self.gid)}")
        return _HEAD.pack(self.sequence, self.timestamp_ns) + bytes((GID_BYTES,)) + self.gid

    @staticmethod
    def decode(data: bytes) -> Attachment:
        """ValueError for bytes that are not an attachment with a 16-byte GID."""
        if len(data) != _HEAD.size + 1 + GID_BYTES or data[_HEAD.size] != GID_BYTES:
            raise ValueError(f"not an rmw_zenoh attachment ({len(data)} bytes)")
        seq, stamp = _HEAD.unpack_from(data)
        return Attachment(seq, stamp, bytes(data[_HEAD.size + 1:]))


_KINDS = {k.value: k for k in Kind}
_HASH = re.compile(r"^RIHS01_[0-9a-f]{64}$")


@dataclass(frozen=True)
class Token:
    """A liveliness token read back into its fields (:func:`parse_token`): the node that
    declared it and, for an endpoint, what it announces. ``name`` is the endpoint's fully
    qualified name (``/robot1/base_summary``) and ``type_name`` its ROS 2 type."""

    node: RosNode
    entity_id: int
    kind: Kind
    name: str = ""
    type_name: str = ""
    hash_: str = ""
    qos: Qos | None = None

    @property
    def node_name(self) -> str:
        """The node's fully qualified name (``/robot1/omnican``)."""
        return fully_qualified(self.node.namespace, self.node.name)


def parse_token(key: str) -> Token:
    """The inverse of :meth:`RosNode.token` and :meth:`RosNode.endpoint_token`: a token's key
    expression in, its fields out (an empty namespace or enclave reads back as ``/``,
    which writes the same ``%``). ValueError for a key that is not such a token."""
    chunks = key.split("/")
    if len(chunks) not in (9, 13) or chunks[0] != ADMIN_SPACE:
        raise ValueError(f"not an rmw_zenoh liveliness token: {key!r}")
    domain, session, node_id, entity_id, kind_text, enclave, namespace, name = chunks[1:9]
    kind = _KINDS.get(kind_text)
    if kind is None or (kind is Kind.NODE) != (len(chunks) == 9):
        raise ValueError(f"not an rmw_zenoh liveliness token (kind {kind_text!r}): {key!r}")
    if not all(c.isdigit() for c in (domain, node_id, entity_id)) or not session \
            or not name or "%" in name:
        raise ValueError(f"not an rmw_zenoh liveliness token: {key!r}")
    node = RosNode(int(domain), session, int(node_id), name, namespace=unmangle(namespace),
                enclave=unmangle(enclave))
    if kind is Kind.NODE:
        return Token(node, int(entity_id), kind)
    fq_name, dds_name, hash_, qos = chunks[9:]
    if not fq_name.startswith("%") or _HASH.match(hash_) is None:
        raise ValueError(f"not an rmw_zenoh endpoint token: {key!r}")
    return Token(node, int(entity_id), kind, unmangle(fq_name), ros_type_name(dds_name),
                 hash_, Qos.decode(qos))
