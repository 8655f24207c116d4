"""The ROS 2 bridge: a running :class:`~omnican.chassis.Chassis` on DDS.

``cmd_vel`` goes into :meth:`Chassis.set_velocity`, so the chassis watchdog stops the
base when commands stop. Commands are polled, not called back: a thread of the bridge
takes what arrived at most :data:`MAX_POLL_HZ` times a second (the control rate, if
lower), up to the reader's depth each time, and applies only the newest sample of each
publisher. A flood costs DDS's receive thread (C, without the GIL) and at most
``depth x rate`` samples a second here, whoever sends it. One publisher drives at a
time (:class:`~omnican.command.arbiter.CommandArbiter`, shared with Foxglove's clients when
``--foxglove-control`` is on): another is ignored, and told so in the log, until the
first has sent nothing for the command timeout. A publisher of another type on the
cmd_vel topic (DDS does not connect it) is named in the log once, from DDS discovery.

``odom``, ``tf``, ``joint_states``, ``diagnostics`` and the simulator's true pose are
the base's telemetry (:mod:`omnican.telemetry`), the same messages the live view and an
MCAP recording carry, published at the configured rates; the bridge builds none of its
own and adds no work to the control loop.

The DDS side is a :class:`Transport`: :class:`DdsTransport` (Cyclone DDS) in use, an
in-memory one in the unit tests.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import os
import sys
import tempfile
import threading
import time
import typing
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from omnican.command.arbiter import CommandArbiter
from omnican.core.kinematics import Twist
from omnican.errors import ConfigError, DriveError
from omnican.errors import quote as _quote
from omnican.log_throttle import Throttle
from omnican.ros2.settings import Ros2Settings, cyclone_config, dds_topic, resolve_name
from omnican.telemetry import Message
from omnican.telemetry.attach import feed_of

if TYPE_CHECKING:
    from cyclonedds.idl import IdlStruct

    from omnican.chassis import Chassis
    from omnican.sim import SimulatedBase

logger = logging.getLogger(__name__)

M = TypeVar("M", bound="IdlStruct")

#: tf2's history depth for /tf (its TransformListener subscribes with keep-last 100).
TF_DEPTH = 100
#: cmd_vel's reader keeps the newest this many samples between polls: enough that the
#: driving publisher's samples survive beside another's flood of 10 kHz (at 100 polls a
#: second about 100 samples arrive per poll), few enough that taking them is cheap.
CMD_VEL_DEPTH = 256
#: At most this many polls of cmd_vel and recover a second (fewer if the loop is slower).
MAX_POLL_HZ = 100.0
#: A Twist is 52 bytes on the wire, a TwistStamped 76 plus its frame id: a larger sample
#: is refused before it is parsed.
MAX_CMD_BYTES = 1024
#: Quoted values and texts from clients are cut to this many characters in the log.
QUOTE_CHARS = 60
#: At most this many samples are parsed a poll: the driver's, and while no one drives,
#: those of a few others that may take control (so many writers cost no more than few).
MAX_PARSED_PER_POLL = 4
#: At most this many writers of a wrong type are named (a hostile peer may make many).
MAX_NAMED_WRITERS = 100
CMD_VEL_SOURCE = "ROS 2 cmd_vel"  # what the other sources of commands are told


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


def quote(value: object, limit: int = QUOTE_CHARS) -> str:
    """``repr(value)`` cut to ``limit`` characters (:func:`omnican.errors.quote`)."""
    return _quote(value, limit)


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


class _Rate:
    """Counts what a stream published: overall and over the last window."""

    def __init__(self, now: float) -> None:
        self.count = 0
        self.start = now
        self._mark = (now, 0)
        self.recent = 0.0

    def tick(self) -> None:
        self.count += 1

    def sample(self, now: float) -> float:
        t0, n0 = self._mark
        if now - t0 >= 0.5:
            self.recent = (self.count - n0) / (now - t0)
            self._mark = (now, self.count)
        return self.recent

    def overall(self, now: float) -> float:
        return self.count / (now - self.start) if now > self.start else 0.0


@functools.cache
def _plan(msg_type: type[Any]) -> tuple[tuple[str, str, type[Any] | None], ...]:
    """How to make ``msg_type`` from a dict: (field, "struct" | "structs" | "plain", type)."""
    out: list[tuple[str, str, type[Any] | None]] = []
    for name, hint in typing.get_type_hints(msg_type, include_extras=True).items():
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out.append((name, "struct", hint))
            continue
        origin = getattr(hint, "__origin__", None)
        args = typing.get_args(origin) if origin is not None else ()
        if args and isinstance(args[0], type) and dataclasses.is_dataclass(args[0]):
            out.append((name, "structs", args[0]))
        else:
            out.append((name, "plain", None))
    return tuple(out)


def to_idl(msg_type: type[M], data: dict[str, Any]) -> M:
    """The DDS struct of a message that :mod:`omnican.telemetry.messages` built."""
    kwargs: dict[str, Any] = {}
    for name, kind, sub in _plan(msg_type):
        value = data[name]
        if kind == "struct":
            kwargs[name] = to_idl(sub, value)  # type: ignore[arg-type]
        elif kind == "structs":
            kwargs[name] = [to_idl(sub, v) for v in value]  # type: ignore[arg-type]
        else:
            kwargs[name] = value
    return msg_type(**kwargs)


class Bridge:
    """Publishes the base's telemetry over a :class:`Transport` and takes its commands.

    A :class:`~omnican.telemetry.Sink` of ``feed_of(base)``: the messages are the ones
    the live view and an MCAP recording carry, published here at the configured rates
    (every n-th sample). Use as a context manager (or :meth:`start` and :meth:`close`);
    it does not own the chassis or the transport."""

    def __init__(self, base: Chassis, settings: Ros2Settings, transport: Transport, *,
                 sim: SimulatedBase | None = None, arbiter: CommandArbiter | None = None,
                 poll_thread: bool = True) -> None:
        from omnican.ros2 import msgs

        self.base = base
        self.settings = settings
        self.sim = sim
        self._feed = feed = feed_of(base)
        if sim is not None:
            feed.truth = sim  # the simulator's ground truth goes along (~/sim/true_pose)
        self.joint_names = feed.settings.joint_names
        radii = feed.settings.wheel_radii
        self.wheel_radii: list[float] | None = list(radii) if radii is not None else None
        self._prefix = feed.settings.prefix
        state_rate = feed.settings.state_rate_hz
        self._every = {"odom": max(1, round(state_rate / settings.odom_rate_hz)),
                       "joint_states": max(1, round(state_rate / settings.joint_states_rate_hz)),
                       "battery_state": max(1, round(state_rate /
                                                     settings.battery_state_rate_hz))}
        self._seen = {"odom": 0, "joint_states": 0, "battery_state": 0}

        default = TopicQos()
        self._pub_odom = transport.publisher(settings.topic("odom"), msgs.Odometry, default)
        self._pub_tf = (transport.publisher(settings.topic("tf"), msgs.TFMessage,
                                            TopicQos(depth=TF_DEPTH))
                        if settings.publish_tf else None)
        self._pub_joints = (transport.publisher(settings.topic("joint_states"),
                                                msgs.JointState, default)
                            if self.wheel_radii is not None else None)
        self._pub_diag = transport.publisher(settings.topic("diagnostics"),
                                             msgs.DiagnosticArray, default)
        self._pub_battery = transport.publisher(settings.topic("battery_state"),
                                                msgs.BatteryState, default)
        self.true_pose_topic = resolve_name("~/sim/true_pose", settings.node_namespace,
                                            settings.node_name)
        self._pub_truth = (transport.publisher(self.true_pose_topic, msgs.PoseStamped, default)
                           if sim is not None else None)
        self.transport = transport
        self.cmd_type: type[Any] = msgs.TwistStamped if settings.cmd_vel_stamped else msgs.Twist
        self._cmd_topic = settings.topic("cmd_vel")
        self._take_cmd = transport.reader(self._cmd_topic, self.cmd_type,
                                          TopicQos(depth=CMD_VEL_DEPTH))
        self._take_recover = transport.reader(settings.topic("recover"), msgs.Empty,
                                              TopicQos(depth=1))
        cmd_timeout_s = base.cfg.chassis.cmd_timeout_s
        # One cmd_vel publisher drives at a time, as one Foxglove client does.
        self.arbiter = arbiter if arbiter is not None else CommandArbiter(cmd_timeout_s)
        self.poll_period_s = 1.0 / min(MAX_POLL_HZ, base.cfg.chassis.rate_hz)
        self._poll_thread: threading.Thread | None = None
        self._poll_on_thread = poll_thread
        self._stop_polling = threading.Event()
        self._poll_lock = threading.Lock()
        self._polls = 0
        self._writers: dict[int, str] = {}  # publication handle -> source name
        self._driver: str | None = None
        self._told_types: set[str] = set()
        self._throttle = Throttle(logger)
        self._wanted = {"/odom", "/diagnostics", "/battery_state"}
        if self._pub_tf is not None:
            self._wanted.add("/tf")
        if self._pub_joints is not None:
            self._wanted.add("/joint_states")
        if self._pub_truth is not None:
            self._wanted.add("/sim/true_pose")

        self.cmd_vel_count = 0  # samples taken from DDS
        self.cmd_vel_parsed = 0  # the newest of a publisher's samples, parsed
        self.cmd_vel_rejected = 0
        self.cmd_vel_refused = 0  # ignored: another source held control
        self.wrong_types: dict[str, str] = {}  # cmd_vel writers of another type: guid -> type
        self.recover_note: str | None = None
        self._recover_thread: threading.Thread | None = None
        self._recover_lock = threading.Lock()
        now = time.monotonic()
        self.rates = {name: _Rate(now) for name in ("odom", "joint_states", "diagnostics",
                                                     "battery_state")}
        self._started = False

    # ------------------------------------------------------------ inputs

    def poll(self) -> None:
        """Take what arrived on cmd_vel and recover and act on it: the newest sample of
        each cmd_vel publisher, the others dropped unparsed. The poll thread calls this;
        a test may call it instead."""
        with self._poll_lock:
            self._polls += 1
            if self._polls % 10 == 1:
                self._check_publications()
            received = self._take_cmd()
            self.cmd_vel_count += len(received)
            newest: dict[int, bytes] = {}
            for r in received:  # oldest first: the last of each writer stays
                newest.pop(r.writer, None)
                newest[r.writer] = r.data
            now = self.base.clock.now()
            holder = self.arbiter.holder(now)
            parsed = 0
            # The driver's sample first; another's only while no one drives (then it is
            # parsed to see whether it may take control), a few a poll at most.
            for writer in sorted(newest, key=lambda w: self._source(w) != holder):
                source = self._source(writer)
                other = self.arbiter.may_act(source, now)
                if other is not None:
                    self._refuse(source, other)
                elif parsed < MAX_PARSED_PER_POLL:
                    parsed += 1
                    self._on_cmd_vel(source, newest[writer])
            if self._take_recover():
                self._on_recover()

    def _source(self, writer: int) -> str:
        name = self._writers.get(writer)
        if name is None:
            guid = self.transport.writer_guid(self._cmd_topic, writer)
            name = f"{CMD_VEL_SOURCE} publisher {guid or hex(writer)}"
            if len(self._writers) > 1000:  # writers come and go; do not grow for ever
                self._writers.clear()
            self._writers[writer] = name
        return name

    def _on_cmd_vel(self, source: str, data: bytes) -> None:
        self.cmd_vel_parsed += 1
        if len(data) > MAX_CMD_BYTES:
            self._reject(source, f"a {len(data)}-byte sample, not read (more than the "
                         f"{MAX_CMD_BYTES} bytes a {self._type_name()} may have here)")
            return
        try:
            msg = self.cmd_type.deserialize(data)
        except Exception as exc:  # whatever a broken sample raises
            self._reject(source, f"cannot be read as a {self._type_name()}: {quote(str(exc))}")
            return
        twist = msg.twist if self.settings.cmd_vel_stamped else msg
        t = twist_from_msg((twist.linear.x, twist.linear.y, twist.linear.z),
                           (twist.angular.x, twist.angular.y, twist.angular.z))
        if not t.is_finite():
            self._reject(source, f"not finite: vx={quote(t.vx)} vy={quote(t.vy)} "
                         f"wz={quote(t.wz)}")
            return
        try:
            holder = self.arbiter.claim(source, self.base.clock.now(),
                                        lambda: self.base.set_velocity(t.vx, t.vy, t.wz))
        except ValueError as exc:
            self._reject(source, quote(str(exc), 200))
            return
        except DriveError:
            return  # closing
        if holder is not None:  # someone else drives (another publisher, a Foxglove client)
            self._refuse(source, holder)
            return
        if self._driver != source:
            self._driver = source
            logger.info("%s drives the base", source)

    def _refuse(self, source: str, holder: str) -> None:
        self.cmd_vel_refused += 1
        self._throttle.warning(("refused", source), "cmd_vel from %s ignored: %s is driving "
                               "the base (one publisher at a time; it drives once %s has "
                               "sent nothing for %g s)", source, holder, holder,
                               self.arbiter.timeout_s)

    def _reject(self, source: str, why: str) -> None:
        self.cmd_vel_rejected += 1
        self._throttle.warning(("rejected", source), "cmd_vel from %s ignored: %s",
                               source, why)

    def _type_name(self) -> str:
        return ros_type_name(self.cmd_type.__idl_typename__)

    def _check_publications(self) -> None:
        """Name once each cmd_vel writer of another type: DDS does not connect it, so
        nothing of it arrives, and without this nothing would say why the base stands."""
        ours = self._type_name()
        for pub in self.transport.publications():
            if pub.topic != self._cmd_topic or pub.type_name == ours:
                continue
            if pub.guid in self._told_types or len(self._told_types) >= MAX_NAMED_WRITERS:
                continue
            self._told_types.add(pub.guid)
            self.wrong_types[pub.guid] = pub.type_name
            if pub.type_name.endswith("/TwistStamped"):
                hint = "start with --cmd-vel-stamped (or [ros2] cmd_vel_stamped = true)"
            elif pub.type_name.endswith("/Twist"):
                hint = "start without --cmd-vel-stamped ([ros2] cmd_vel_stamped = false)"
            else:
                hint = ("it takes geometry_msgs/msg/Twist, or TwistStamped with "
                        "--cmd-vel-stamped")
            logger.warning("%s: publisher %s sends %s but this node reads %s: its commands "
                           "are not received; %s", self._cmd_topic, pub.guid,
                           quote(pub.type_name), ours, hint)

    def _on_recover(self) -> None:
        with self._recover_lock:
            if self._recover_thread is not None and self._recover_thread.is_alive():
                self._throttle.log(logging.INFO, "recover", "recover: already under way")
                return
            self._recover_thread = threading.Thread(target=self.recover,
                                                    name="omnican-ros2-recover", daemon=True)
            self._recover_thread.start()

    def recover(self, answered: bool = False) -> bool:
        """Clear a latched stop (what the recover topic does); True when it worked. A
        failure is logged as a warning, unless ``answered`` (the console prints it)."""
        logger.info("recover requested")
        ok = True
        try:
            self.base.recover()
            note = "ok"
        except DriveError as exc:
            ok, note = False, f"failed: {exc}"
        stamp = time.strftime("%H:%M:%S")
        self.recover_note = f"{note} ({stamp})"
        (logger.info if ok or answered else logger.warning)("recover %s", note)
        return ok

    # ------------------------------------------------------------ outputs (the sink)

    def wants(self, topic: str) -> bool:
        return topic in self._wanted

    def publish(self, messages: list[Message]) -> None:
        from omnican.ros2 import msgs

        for message in messages:
            topic, data = message.topic, message.decoded()
            if topic == "/odom":
                if self._due("odom"):
                    self._pub_odom(to_idl(msgs.Odometry, data))
                    self.rates["odom"].tick()
                    self._odom_sent = True
                else:
                    self._odom_sent = False
            elif topic == "/tf":
                if self._pub_tf is not None and self._odom_sent:
                    self._pub_tf(to_idl(msgs.TFMessage, data))
            elif topic == "/sim/true_pose":
                if self._pub_truth is not None and self._odom_sent:
                    self._pub_truth(to_idl(msgs.PoseStamped, data))
            elif topic == "/joint_states":
                if self._pub_joints is not None and self._due("joint_states"):
                    self._pub_joints(to_idl(msgs.JointState, data))
                    self.rates["joint_states"].tick()
            elif topic == "/battery_state":
                if self._due("battery_state"):
                    self._pub_battery(to_idl(msgs.BatteryState, data))
                    self.rates["battery_state"].tick()
            elif topic == "/diagnostics":
                # The base's statuses as every front end has them, and the bridge's own
                # after them (only the bridge knows it): one array, as a reader expects.
                self._pub_diag(to_idl(msgs.DiagnosticArray, {
                    "header": data["header"], "status": [*data["status"], self.bridge_status()]}))
                self.rates["diagnostics"].tick()

    _odom_sent = False

    def _due(self, stream: str) -> bool:
        self._seen[stream] += 1
        return (self._seen[stream] - 1) % self._every[stream] == 0

    def bridge_status(self) -> dict[str, Any]:
        """The bridge itself, as a diagnostic status: publish rates, cmd_vel received,
        the last recover (after the base's statuses in each diagnostics array)."""
        mono = time.monotonic()
        values = [{"key": f"{name}_hz", "value": f"{r.sample(mono):.1f}"}
                  for name, r in self.rates.items()]
        values += [{"key": "cmd_vel_received", "value": str(self.cmd_vel_count)},
                   {"key": "cmd_vel_rejected", "value": str(self.cmd_vel_rejected)},
                   {"key": "cmd_vel_parsed", "value": str(self.cmd_vel_parsed)},
                   {"key": "cmd_vel_polls", "value": str(self._polls)},
                   {"key": "cmd_vel_ignored", "value": str(self.cmd_vel_refused)},
                   {"key": "cmd_vel_last_driver", "value": self._driver or ""},
                   {"key": "last_recover", "value": self.recover_note or ""}]
        return {"level": 0, "name": f"{self._prefix}: ros2 bridge", "message": "running",
                "hardware_id": "", "values": values}

    # ------------------------------------------------------------ lifecycle

    def start(self) -> Bridge:
        """Publish the telemetry and (unless made with ``poll_thread=False``: then call
        :meth:`poll`) take commands on a thread of its own."""
        if not self._started:
            self._started = True
            self._feed.add(self)
            if self._poll_on_thread:
                self._stop_polling.clear()
                self._poll_thread = threading.Thread(target=self._poll_loop,
                                                     name="omnican-ros2-poll", daemon=True)
                self._poll_thread.start()
        return self

    def _poll_loop(self) -> None:
        period = self.poll_period_s
        next_t = time.monotonic()
        while not self._stop_polling.is_set():
            try:
                self.poll()
            except Exception:  # keep taking commands whatever one did
                logger.exception("handling ROS 2 commands failed")
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:  # fell behind: the next poll a period from now, no burst
                next_t, delay = time.monotonic() + period, period
            self._stop_polling.wait(delay)

    def close(self) -> None:
        """Stop publishing; wait for a recover under way. Idempotent."""
        if self._started:
            self._started = False
            self._feed.remove(self)
        self._stop_polling.set()
        poller = self._poll_thread
        if poller is not None:
            poller.join(timeout=5.0)
            self._poll_thread = None
        self._throttle.flush()
        worker = self._recover_thread
        if worker is not None:
            cfg = self.base.cfg.chassis
            worker.join(timeout=cfg.enable_timeout_s + cfg.boot_timeout_s + 1.0)

    def achieved_rates(self) -> dict[str, float]:
        """Messages per second each stream published since start."""
        now = time.monotonic()
        return {name: r.overall(now) for name, r in self.rates.items()}

    def __enter__(self) -> Bridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


def twist_from_msg(linear: Sequence[float], angular: Sequence[float]) -> Twist:
    """The planar part of a geometry_msgs/Twist (x, y linear; z angular)."""
    return Twist(float(linear[0]), float(linear[1]), float(angular[2]))
