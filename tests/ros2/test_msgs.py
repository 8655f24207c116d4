"""omnican's ROS 2 message structs against the ROS 2 Jazzy message definitions that
rosbags ships: the same fields in the same order, the same DDS type names, and byte for
byte the same CDR for any values."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("cyclonedds", reason="needs the ros2 extra: pip install '.[ros2]'")
rosbags_typesys = pytest.importorskip("rosbags.typesys", reason="needs rosbags (test extra)")

from omnican.ros2 import msgs  # noqa: E402

STORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
NAME, BASE, ARRAY, SEQUENCE = 2, 1, 3, 4  # rosbags' Nodetype values

# rosbags packs "byte" (DiagnosticStatus.level) as signed; 0-127 is the same on both sides.
_INT_RANGES = {"int8": (-(2**7), 2**7 - 1), "uint8": (0, 255), "octet": (0, 255),
               "byte": (0, 127), "int32": (-(2**31), 2**31 - 1), "uint32": (0, 2**32 - 1)}
_NUMPY = {"float64": np.float64, "float32": np.float32, "uint8": np.uint8, "int32": np.int32,
          "uint32": np.uint32}


def _base_strategy(kind: str) -> st.SearchStrategy[Any]:
    if kind in ("float64", "float32"):
        return st.floats(allow_nan=False, width=64 if kind == "float64" else 32)
    if kind == "bool":
        return st.booleans()
    if kind == "string":
        return st.text(st.characters(blacklist_characters="\x00",
                                     blacklist_categories=("Cs",)), max_size=12)
    lo, hi = _INT_RANGES[kind]
    return st.integers(lo, hi)


def _node_strategy(node: tuple[int, Any]) -> st.SearchStrategy[Any]:
    kind, detail = node
    if kind == BASE:
        return _base_strategy(detail[0])
    if kind == NAME:
        return message_strategy(detail)
    sub, length = detail
    if kind == ARRAY:
        return st.lists(_node_strategy(sub), min_size=length, max_size=length)
    return st.lists(_node_strategy(sub), max_size=3)


def message_strategy(ros_type: str) -> st.SearchStrategy[dict[str, Any]]:
    """Values for every field of ``ros_type`` (nested dicts and lists)."""
    fields = STORE.fielddefs[ros_type][1]
    return st.fixed_dictionaries({name: _node_strategy(node) for name, node in fields})


def to_omnican(ros_type: str, values: dict[str, Any]) -> Any:
    cls = msgs.ROS_TYPES[ros_type]
    kwargs = {}
    for name, (kind, detail) in STORE.fielddefs[ros_type][1]:
        v = values[name]
        if kind == NAME:
            v = to_omnican(detail, v)
        elif kind in (ARRAY, SEQUENCE) and detail[0][0] == NAME:
            v = [to_omnican(detail[0][1], item) for item in v]
        kwargs[name] = v
    return cls(**kwargs)


def to_rosbags(ros_type: str, values: dict[str, Any]) -> Any:
    kwargs = {}
    for name, (kind, detail) in STORE.fielddefs[ros_type][1]:
        v = values[name]
        if kind == NAME:
            v = to_rosbags(detail, v)
        elif kind in (ARRAY, SEQUENCE):
            sub_kind, sub = detail[0]
            if sub_kind == NAME:
                v = [to_rosbags(sub, item) for item in v]
            elif sub[0] in _NUMPY:
                v = np.array(v, dtype=_NUMPY[sub[0]])
        kwargs[name] = v
    return STORE.types[ros_type](**kwargs)


@pytest.mark.parametrize("ros_type", sorted(msgs.ROS_TYPES))
def test_fields_and_type_names_follow_the_message_definitions(ros_type: str) -> None:
    cls = msgs.ROS_TYPES[ros_type]
    ours = [f.name for f in dataclasses.fields(cls)]
    assert ours == [name for name, _ in STORE.fielddefs[ros_type][1]]
    assert cls.__idl_typename__ == msgs.dds_type_name(ros_type)


@pytest.mark.parametrize("ros_type", sorted(msgs.ROS_TYPES))
def test_defaults_serialise_like_ros(ros_type: str) -> None:
    """A default-constructed message is what ROS 2 sends for an empty one (quaternions
    default to the identity, as in ROS 2)."""
    ours = msgs.ROS_TYPES[ros_type]().serialize(use_version_2=False)
    values = STORE.deserialize_cdr(ours, ros_type)
    assert STORE.serialize_cdr(values, ros_type) == ours


@st.composite
def typed_message(draw: st.DrawFn) -> tuple[str, dict[str, Any]]:
    ros_type = draw(st.sampled_from(sorted(msgs.ROS_TYPES)))
    return ros_type, draw(message_strategy(ros_type))


@settings(max_examples=300, deadline=None)
@given(typed_message())
def test_cdr_is_byte_for_byte_that_of_ros(case: tuple[str, dict[str, Any]]) -> None:
    ros_type, values = case
    ours = to_omnican(ros_type, values).serialize(use_version_2=False)
    theirs = bytes(STORE.serialize_cdr(to_rosbags(ros_type, values), ros_type))
    # CDR pads the end to 4 bytes on the wire; the writer does that for omnican's data.
    assert ours.ljust(len(theirs), b"\0") == theirs
    back = msgs.ROS_TYPES[ros_type].deserialize(theirs)
    assert back.serialize(use_version_2=False) == ours


def test_dds_type_name() -> None:
    assert msgs.dds_type_name("nav_msgs/msg/Odometry") == "nav_msgs::msg::dds_::Odometry_"
