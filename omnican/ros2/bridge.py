"""The ROS 2 bridge: a running :class:`~omnican.chassis.Chassis` on DDS.

``cmd_vel`` goes straight into :meth:`Chassis.set_velocity`, so the chassis watchdog
stops the base when commands stop. ``odom``, ``tf``, ``joint_states``, ``diagnostics`` and
the simulator's true pose are the base's telemetry (:mod:`omnican.telemetry`), the same
messages the live view and an MCAP recording carry, published at the configured rates;
the bridge builds none of its own and adds no work to the control loop.

The DDS side is a :class:`Transport`: :class:`DdsTransport` (Cyclone DDS) in use, an
in-memory one in the unit tests.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import math
import os
import sys
import tempfile
import threading
import time
import typing
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from omnican.arbiter import CommandArbiter
from omnican.errors import ConfigError, DriveError
from omnican.kinematics import Twist
from omnican.ros2.settings import Ros2Settings, cyclone_config, dds_topic, resolve_name
from omnican.telemetry import Message

if TYPE_CHECKING:
    from cyclonedds.idl import IdlStruct

    from omnican.chassis import Chassis
    from omnican.sim import SimulatedBase

logger = logging.getLogger(__name__)

M = TypeVar("M", bound="IdlStruct")

#: tf2's history depth for /tf (its TransformListener subscribes with keep-last 100).
TF_DEPTH = 100
CMD_VEL_SOURCE = "ROS 2 cmd_vel"  # its name to the other sources of commands


@dataclass(frozen=True)
class TopicQos:
    """The QoS of one topic: ROS 2's default is reliable, volatile, keep-last 10."""

    reliable: bool = True
    depth: int = 10


class Transport(Protocol):
    """Where messages go: topics by their full ROS 2 name (``/odom``)."""

    def publisher(self, topic: str, msg_type: type[M], qos: TopicQos) -> Callable[[M], None]:
        ...

    def subscribe(self, topic: str, msg_type: type[M], qos: TopicQos,
                  callback: Callable[[M], None]) -> None:
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

    def subscribe(self, topic: str, msg_type: type[M], qos: TopicQos,
                  callback: Callable[[M], None]) -> None:
        from cyclonedds.core import DDSException, Listener
        from cyclonedds.sub import DataReader

        readers: list[Any] = []  # the reader itself: DDS may call back while it is deleted

        def on_data_available(_: Any) -> None:
            if self._closed or not readers:
                return
            try:
                samples = readers[0].take(16)
            except DDSException as exc:
                if not self._closed:  # else: deleted meanwhile
                    logger.warning("reading %s failed: %s", topic, exc)
                return
            for sample in samples:
                if isinstance(sample, msg_type):  # invalid samples (disposals) carry no data
                    try:
                        callback(sample)
                    except Exception:  # a bad message must not kill DDS's listener thread
                        logger.exception("handling a message on %s failed", topic)

        reader = DataReader(self._participant, self._topic(topic, msg_type),
                            qos=self._qos(qos),
                            listener=Listener(on_data_available=on_data_available))
        readers.append(reader)
        self._entities.append(reader)

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

    A :class:`~omnican.telemetry.Sink` of ``base.telemetry``: the messages are the ones
    the live view and an MCAP recording carry, published here at the configured rates
    (every n-th sample). Use as a context manager (or :meth:`start` and :meth:`close`);
    it does not own the chassis or the transport."""

    def __init__(self, base: Chassis, settings: Ros2Settings, transport: Transport, *,
                 sim: SimulatedBase | None = None, arbiter: CommandArbiter | None = None
                 ) -> None:
        from omnican.ros2 import msgs

        self.base = base
        self.arbiter = arbiter  # shared with other sources of commands (Foxglove), if any
        self.settings = settings
        self.sim = sim
        feed = base.telemetry
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
        cmd_type: type[Any] = msgs.TwistStamped if settings.cmd_vel_stamped else msgs.Twist
        transport.subscribe(settings.topic("cmd_vel"), cmd_type, default, self._on_cmd_vel)
        transport.subscribe(settings.topic("recover"), msgs.Empty, default, self._on_recover)
        self._wanted = {"/odom", "/diagnostics", "/battery_state"}
        if self._pub_tf is not None:
            self._wanted.add("/tf")
        if self._pub_joints is not None:
            self._wanted.add("/joint_states")
        if self._pub_truth is not None:
            self._wanted.add("/sim/true_pose")

        self.cmd_vel_count = 0
        self.cmd_vel_rejected = 0
        self.cmd_vel_refused = 0  # ignored: another source held control
        self._last_reject_log = -math.inf
        self._last_refused_log = -math.inf
        self.recover_note: str | None = None
        self._recover_thread: threading.Thread | None = None
        self._recover_lock = threading.Lock()
        now = time.monotonic()
        self.rates = {name: _Rate(now) for name in ("odom", "joint_states", "diagnostics",
                                                     "battery_state")}
        self._started = False

    # ------------------------------------------------------------ inputs

    def _on_cmd_vel(self, msg: Any) -> None:
        twist = msg.twist if self.settings.cmd_vel_stamped else msg
        self.cmd_vel_count += 1
        t = twist_from_msg((twist.linear.x, twist.linear.y, twist.linear.z),
                           (twist.angular.x, twist.angular.y, twist.angular.z))
        try:
            if self.arbiter is not None and t.is_finite():
                holder = self.arbiter.claim(CMD_VEL_SOURCE, self.base.clock.now(),
                                            lambda: self.base.set_velocity(t.vx, t.vy, t.wz))
                if holder is not None:  # someone else drives (a Foxglove client)
                    self.cmd_vel_refused += 1
                    self._log_refused(holder)
                return
            self.base.set_velocity(t.vx, t.vy, t.wz)
        except ValueError as exc:
            self.cmd_vel_rejected += 1
            now = time.monotonic()
            if now - self._last_reject_log > 5.0:
                self._last_reject_log = now
                logger.warning("cmd_vel ignored: %s", exc)
        except DriveError:
            pass  # closing

    def _log_refused(self, holder: str) -> None:
        now = time.monotonic()
        if now - self._last_refused_log > 5.0:
            self._last_refused_log = now
            logger.warning("cmd_vel ignored: %s is driving the base", holder)

    def _on_recover(self, msg: Any) -> None:
        with self._recover_lock:
            if self._recover_thread is not None and self._recover_thread.is_alive():
                logger.info("recover: already under way")
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
                   {"key": "last_recover", "value": self.recover_note or ""}]
        return {"level": 0, "name": f"{self._prefix}: ros2 bridge", "message": "running",
                "hardware_id": "", "values": values}

    # ------------------------------------------------------------ lifecycle

    def start(self) -> Bridge:
        if not self._started:
            self._started = True
            self.base.telemetry.add(self)
        return self

    def close(self) -> None:
        """Stop publishing; wait for a recover under way. Idempotent."""
        if self._started:
            self._started = False
            self.base.telemetry.remove(self)
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
