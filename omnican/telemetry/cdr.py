"""ROS 2 messages as bytes: CDR serialization and message definitions through ``rosbags``
(a pure-Python ROS 2 type system; no ROS installation needed).

Messages go in and out as nested dicts with the ROS field names (:mod:`omnican.telemetry`
builds them); ``encode``/``decode`` convert through rosbags' message classes, so no byte
layout is written by hand. ``can_msgs/msg/Frame`` (ROS 2's socketcan message, not in
rosbags' store) is registered from its message definition.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from functools import cache, lru_cache
from typing import Any

import numpy as np

CAN_FRAME_MSG = """\
std_msgs/Header header
uint32 id
bool is_rtr
bool is_extended
bool is_error
uint8 dlc
uint8[8] data
"""

_DTYPES = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8,
           "uint8": np.uint8, "int16": np.int16, "uint16": np.uint16, "int32": np.int32,
           "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
           "float32": np.float32, "float64": np.float64}


@lru_cache(maxsize=1)
def typestore() -> Any:
    """ROS 2 Jazzy's message types, plus can_msgs/msg/Frame."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(CAN_FRAME_MSG, "can_msgs/msg/Frame"))
    return store


#: The encoding of a ROS 2 type's schema text (MCAP's and Foxglove's name for it).
SCHEMA_ENCODING = "ros2msg"


@cache
def msgdef(typename: str) -> str:
    """The ``ros2msg`` schema text of a type: its definition, then every type it uses."""
    text: str = typestore().generate_msgdef(typename, ros_version=2)[0]
    return text


Maker = Callable[[Any], Any]


@cache
def _builder(typename: str) -> Maker:
    """A function from a dict message to rosbags' message object of ``typename``. The
    field definitions are read once per type, not once per message (a state sample of
    a recording is a few hundred fields)."""
    store = typestore()
    cls = store.types[typename]
    _, fields = store.fielddefs[typename]
    makers = tuple((name, _field_maker(desc)) for name, desc in fields)

    def build(value: dict[str, Any]) -> Any:
        get = value.get
        return cls(**{name: make(get(name)) for name, make in makers})

    return build


def _field_maker(desc: tuple[Any, Any]) -> Maker:
    kind, spec = desc
    kind = int(kind)
    if kind == 1:  # base type
        typ = spec[0]
        default = "" if typ == "string" else _DTYPES[typ](0).item()
        return lambda value: default if value is None else value
    if kind == 2:  # a message
        sub_builder = _builder(spec)
        return lambda value: sub_builder(value or {})
    sub, _size = spec  # 3 = fixed array, 4 = sequence
    sub_kind, sub_spec = sub
    if int(sub_kind) == 1 and sub_spec[0] != "string":
        dtype = _DTYPES[sub_spec[0]]
        return lambda value: np.asarray([] if value is None else value, dtype=dtype)
    if int(sub_kind) == 1:
        return lambda value: [] if value is None else list(value)
    item_builder = _builder(sub_spec)
    return lambda value: [] if value is None else [item_builder(item) for item in value]


def encode(typename: str, message: dict[str, Any]) -> bytes:
    """CDR bytes (little endian, with the encapsulation header) of a dict message."""
    fast = _FAST.get(typename)
    if fast is not None:
        return fast(message)
    data: Any = typestore().serialize_cdr(_builder(typename)(message), typename)
    return bytes(data)


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if hasattr(value, "__dataclass_fields__"):
        return {k: _plain(getattr(value, k)) for k in value.__dataclass_fields__
                if k != "__msgtype__"}
    return value


def decode(typename: str, data: bytes) -> dict[str, Any]:
    """The dict of a CDR message."""
    out: dict[str, Any] = _plain(typestore().deserialize_cdr(data, typename))
    return out


# can_msgs/msg/Frame is written for every frame on the bus (thousands a second at 1 kHz),
# where the generic path costs ~25 us a frame. Its layout is fixed but for the channel
# name, so it is packed directly here; tests check it against encode()/decode() above.
_CDR_LE = b"\x00\x01\x00\x00"
_TIME = struct.Struct("<iII")  # sec, nanosec, string length (with its NUL)
_BODY = struct.Struct("<I???B8s")


def encode_can_frame(stamp_ns: int, can_id: int, data: bytes, channel: str = "", *,
                     extended: bool = False, remote: bool = False, error: bool = False) -> bytes:
    """CDR of can_msgs/msg/Frame; the same bytes as ``encode(CAN_FRAME, ...)``."""
    name = channel.encode("utf-8", "replace") + b"\x00"  # never raise on the writer
    payload = bytes(data[:8])
    pad = -(12 + len(name)) % 4
    return b"".join((_CDR_LE,
                     _TIME.pack(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000, len(name)),
                     name, b"\x00" * pad,
                     _BODY.pack(can_id, remote, extended, error, len(payload), payload)))


_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_POSE = struct.Struct("<7d")


def _encode_path(message: dict[str, Any]) -> bytes:
    """CDR of nav_msgs/msg/Path: the odometry's trail, hundreds of poses twice a second,
    where the generic path costs ~35 us a pose (and holds the GIL). The same bytes as
    the generic encoder (tests check)."""
    out = bytearray()

    def stamped(header: dict[str, Any]) -> None:
        out.extend(b"\x00" * (-len(out) % 4))
        stamp = header["stamp"]
        name = header["frame_id"].encode() + b"\x00"
        out.extend(_STAMP.pack(stamp["sec"], stamp["nanosec"]) + _U32.pack(len(name)) + name)

    stamped(message["header"])
    poses = message["poses"]
    out.extend(b"\x00" * (-len(out) % 4))
    out.extend(_U32.pack(len(poses)))
    for p in poses:
        stamped(p["header"])
        out.extend(b"\x00" * (-len(out) % 8))
        pos, q = p["pose"]["position"], p["pose"]["orientation"]
        out.extend(_POSE.pack(pos["x"], pos["y"], pos["z"], q["x"], q["y"], q["z"], q["w"]))
    return _CDR_LE + bytes(out)


_FAST: dict[str, Callable[[dict[str, Any]], bytes]] = {"nav_msgs/msg/Path": _encode_path}


def decode_can_frame(data: bytes) -> tuple[int, int, bytes, str, bool, bool, bool]:
    """(stamp ns, id, data, channel, extended, remote, error) of a CDR can_msgs/msg/Frame."""
    if data[:4] != _CDR_LE:
        raise ValueError("not little-endian CDR")
    sec, nanosec, length = _TIME.unpack_from(data, 4)
    start = 4 + _TIME.size
    name = data[start:start + length - 1].decode("utf-8", "replace")
    offset = start + length + (-(12 + length) % 4)
    can_id, remote, extended, error, dlc, payload = _BODY.unpack_from(data, offset)
    return (sec * 1_000_000_000 + nanosec, can_id, payload[:min(dlc, 8)], name, extended,
            remote, error)
