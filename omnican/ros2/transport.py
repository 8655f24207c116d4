"""The DDS side of the ROS 2 bridge: a :class:`Transport` gives publishers and readers
of topics by their full ROS 2 name (``/odom``); :class:`DdsTransport` is Cyclone DDS's
(one domain and participant, ROS 2's topic and type names, XCDR1), an in-memory one
stands in for it in the unit tests. Readers hand over samples unparsed, with the writer
each came from, so that the bridge parses only what it uses.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from omnican.errors import ConfigError
from omnican.ros2.settings import Ros2Settings, cyclone_config, dds_topic

if TYPE_CHECKING:
    from cyclonedds.idl import IdlStruct

logger = logging.getLogger(__name__)

M = TypeVar("M", bound="IdlStruct")


@dataclass(frozen=True)
class TopicQos:
    """The QoS of one topic: ROS 2's default is reliable, volatile, keep-last 10."""

    reliable: bool = True
    depth: int = 10


@dataclass(frozen=True)
class Received:
    """One sample as it arrived, not yet parsed: its writer (DDS's publication handle) and
    its serialised data (CDR with its encapsulation header)."""

    writer: int
    data: bytes


@dataclass(frozen=True)
class Publication:
    """A writer DDS discovered: its GUID (hex), its topic (``/cmd_vel``) and ROS 2 type
    name (``geometry_msgs/msg/TwistStamped``)."""

    guid: str
    topic: str
    type_name: str


class Transport(Protocol):
    """Where messages go and come from: topics by their full ROS 2 name (``/odom``)."""

    def publisher(self, topic: str, msg_type: type[M], qos: TopicQos) -> Callable[[M], None]:
        ...

    def reader(self, topic: str, msg_type: type[M], qos: TopicQos
               ) -> Callable[[], list[Received]]:
        """A reader; calling it takes what arrived since (at most ``qos.depth``, the
        newest; oldest first), unparsed."""
        ...

    def writer_guid(self, topic: str, writer: int) -> str:
        """The GUID (hex) of the writer a sample on ``topic`` came from ("" if gone)."""
        ...

    def publications(self) -> list[Publication]:
        """Writers DDS discovered since the last call (on any topic)."""
        ...

    def close(self) -> None:
        ...


def _read_text(path: str) -> str:
    with open(path, encoding="utf-8") as f:  # as Cyclone reads it: bytes, mostly ASCII
        return f.read()


class DdsTransport:
    """Cyclone DDS: one domain and participant; topics ``rt/<name>`` with ROS 2's
    type names; data in XCDR1, the representation ROS 2's middlewares use."""

    def __init__(self, settings: Ros2Settings, env_uri: str | None = None) -> None:
        from cyclonedds.core import DDSException
        from cyclonedds.domain import Domain, DomainParticipant

        self.config = cyclone_config(settings, env_uri, _read_text)
        said: list[str] = []
        try:
            with _c_stderr_to(said):
                self._domain = Domain(settings.domain_id, self.config)
                self._participant = DomainParticipant(settings.domain_id)
        except DDSException as exc:
            # Cyclone explains on stderr (e.g. 'failed to find interfaces for "udp"'); the
            # exception only says "Non specific error".
            why = "; ".join(_cyclone_words(line) for line in said) or str(exc)
            raise ConfigError(f"cannot start DDS on domain {settings.domain_id} "
                              f"({_network_words(settings)}): {why}") from None
        for line in said:  # nothing failed: pass on whatever was said
            sys.stderr.write(line + "\n")
        self._topics: dict[str, Any] = {}
        self._entities: list[Any] = []
        self._readers: dict[str, Any] = {}
        self._discovery: Any = None
        self._closed = False

    def _topic(self, name: str, msg_type: type[Any]) -> Any:
        from cyclonedds.topic import Topic

        dds_name = dds_topic(name)
        if dds_name not in self._topics:
            self._topics[dds_name] = Topic(self._participant, dds_name, msg_type)
        return self._topics[dds_name]

    @staticmethod
    def _qos(qos: TopicQos) -> Any:
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.util import duration

        reliability = (Policy.Reliability.Reliable(duration(milliseconds=100)) if qos.reliable
                       else Policy.Reliability.BestEffort)
        return Qos(reliability, Policy.Durability.Volatile, Policy.History.KeepLast(qos.depth),
                   Policy.DataRepresentation(use_cdrv0_representation=True))

    def publisher(self, topic: str, msg_type: type[M], qos: TopicQos) -> Callable[[M], None]:
        from cyclonedds.pub import DataWriter

        writer = DataWriter(self._participant, self._topic(topic, msg_type), qos=self._qos(qos))
        self._entities.append(writer)
        write: Callable[[M], None] = writer.write
        return write

    def reader(self, topic: str, msg_type: type[M], qos: TopicQos
               ) -> Callable[[], list[Received]]:
        from cyclonedds.core import DDSException
        from cyclonedds.sub import DataReader

        reader = DataReader(self._participant, self._topic(topic, msg_type), qos=self._qos(qos))
        self._entities.append(reader)
        self._readers[topic] = reader
        take_raw = _raw_take()
        depth = qos.depth

        def take() -> list[Received]:
            if self._closed:
                return []
            try:
                if take_raw is not None:  # parse nothing here: the caller picks what to parse
                    got = take_raw(reader, depth)
                    if isinstance(got, int):
                        raise DDSException(got, "take")
                    return [Received(info.publication_handle, bytes(data))
                            for data, info in got if info.valid_data]
                return [Received(m.sample_info.publication_handle,  # type: ignore[attr-defined]
                                 m.serialize(use_version_2=False))
                        for m in reader.take(depth) if isinstance(m, msg_type)]
            except DDSException as exc:
                if not self._closed:  # else: deleted meanwhile
                    logger.warning("reading %s failed: %s", topic, exc)
                return []

        return take

    def writer_guid(self, topic: str, writer: int) -> str:
        from cyclonedds.core import DDSException

        reader = self._readers.get(topic)
        if reader is None or self._closed:
            return ""
        try:
            endpoint = reader.get_matched_publication_data(writer)
        except DDSException:
            return ""
        return "" if endpoint is None else endpoint.key.hex

    def publications(self) -> list[Publication]:
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
        from cyclonedds.core import DDSException

        if self._closed:
            return []
        if self._discovery is None:
            self._discovery = BuiltinDataReader(self._participant, BuiltinTopicDcpsPublication)
            self._entities.append(self._discovery)
        try:
            found = self._discovery.take(64)
        except DDSException:
            return []
        out = []
        for ep in found:
            topic = getattr(ep, "topic_name", None)
            if isinstance(topic, str) and topic.startswith("rt/"):  # ROS 2 topics only
                out.append(Publication(ep.key.hex, topic[2:], ros_type_name(ep.type_name)))
        return out

    def close(self) -> None:
        """Delete the participant and the domain; DDS stops calling back before it returns."""
        if self._closed:
            return
        self._closed = True
        for entity in [*reversed(self._entities), *self._topics.values(), self._participant,
                       self._domain]:
            entity.__del__()  # dds_delete now, not whenever the garbage collector runs
        self._entities.clear()
        self._topics.clear()
        self._readers.clear()
        self._discovery = None


def _raw_take() -> Callable[[Any, int], Any] | None:
    """Cyclone's take without parsing (serialised data and sample info), which its Python
    binding's ``DataReader.take`` uses and parses every sample after: parsing costs some
    15 us a Twist, taking about 1 us. None if this binding lacks it (then every sample is
    parsed: slower, not wrong)."""
    try:
        from cyclonedds._clayer import ddspy_take  # type: ignore[import-not-found]
        from cyclonedds.core import InstanceState, SampleState, ViewState
    except ImportError:
        return None
    mask = SampleState.Any | ViewState.Any | InstanceState.Any

    def take(reader: Any, n: int) -> Any:
        return ddspy_take(reader._ref, mask, n)
    return take


def ros_type_name(dds_name: str) -> str:
    """A ROS 2 type's DDS name in ROS 2's form: ``geometry_msgs::msg::dds_::Twist_`` ->
    ``geometry_msgs/msg/Twist``; other names as they are."""
    parts = dds_name.split("::")
    if len(parts) == 4 and parts[2] == "dds_" and parts[3].endswith("_"):
        return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"
    return dds_name


@contextlib.contextmanager
def _c_stderr_to(lines: list[str]) -> Iterator[None]:
    """Collect what C code writes to file descriptor 2 meanwhile into ``lines``."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines += [ln for ln in tmp.read().decode(errors="replace").splitlines() if ln]


def _cyclone_words(line: str) -> str:
    """A Cyclone log line without its timestamp, domain and thread: '... [0] main: x' -> 'x'."""
    head, sep, rest = line.partition("]")
    return rest.split(":", 1)[-1].strip() if sep and head.split(" ")[0][:1].isdigit() else line


def _network_words(s: Ros2Settings) -> str:
    from omnican.ros2.settings import describe_network

    return describe_network(s)
