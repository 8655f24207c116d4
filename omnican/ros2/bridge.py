"""The ROS 2 bridge: a running :class:`~omnican.chassis.Chassis` on DDS.

``cmd_vel`` goes straight into :meth:`Chassis.set_velocity`, so the chassis watchdog
stops the base when commands stop. One publisher thread polls the chassis snapshot
(pose, twist, wheels, status) at its own rates and publishes ``odom``, ``tf``,
``joint_states`` and ``diagnostics``; it never adds work to the control loop.

The DDS side is a :class:`Transport`: :class:`DdsTransport` (Cyclone DDS) in use, an
in-memory one in the unit tests.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from omnican.encoder import SPEED_WINDOW_S
from omnican.errors import ConfigError, DriveError
from omnican.ros2 import model
from omnican.ros2.settings import Ros2Settings, cyclone_config, dds_topic, resolve_name

if TYPE_CHECKING:
    from cyclonedds.idl import IdlStruct

    from omnican.chassis import Chassis, WheelState
    from omnican.sim import SimulatedBase

logger = logging.getLogger(__name__)

M = TypeVar("M", bound="IdlStruct")

#: tf2's history depth for /tf (its TransformListener subscribes with keep-last 100).
TF_DEPTH = 100


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


class Bridge:
    """Publishes the base's state and takes its commands over a :class:`Transport`.

    Use as a context manager (or :meth:`start` and :meth:`close`); it does not own the
    chassis or the transport."""

    def __init__(self, base: Chassis, settings: Ros2Settings, transport: Transport, *,
                 sim: SimulatedBase | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        from omnican.ros2 import msgs

        self.base = base
        self.settings = settings
        self.sim = sim
        self._clock = clock
        cfg = base.cfg
        n = len(cfg.wheels)
        self.joint_names = settings.wheel_joint_names(n)
        if len(self.joint_names) != n:
            raise ConfigError(f"ros2.joint_names: {len(self.joint_names)} names for {n} wheels")
        radii = [settings.wheel_radius or w.wheel_radius for w in cfg.wheels]
        self.wheel_radii: list[float] | None = (
            [float(r) for r in radii if r is not None] if all(r is not None for r in radii)
            else None)
        self._prefix = settings.node_name
        self._covariance = model.OdomCovariance(
            cfg.kinematics(), settings.odom_slip, [w.position_scale for w in cfg.wheels],
            SPEED_WINDOW_S)
        self._channel = str((cfg.bus or {}).get("channel", ""))

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
        self.true_pose_topic = resolve_name("~/sim/true_pose", settings.node_namespace,
                                            settings.node_name)
        self._pub_truth = (transport.publisher(self.true_pose_topic, msgs.PoseStamped, default)
                           if sim is not None else None)
        cmd_type: type[Any] = msgs.TwistStamped if settings.cmd_vel_stamped else msgs.Twist
        transport.subscribe(settings.topic("cmd_vel"), cmd_type, default, self._on_cmd_vel)
        transport.subscribe(settings.topic("recover"), msgs.Empty, default, self._on_recover)

        self.cmd_vel_count = 0
        self.cmd_vel_rejected = 0
        self._last_reject_log = -math.inf
        self.recover_note: str | None = None
        self._recover_thread: threading.Thread | None = None
        self._recover_lock = threading.Lock()
        self._diag_now = threading.Event()
        self._stop = threading.Event()
        now = time.monotonic()
        self.rates = {name: _Rate(now) for name in ("odom", "joint_states", "diagnostics")}
        self._thread = threading.Thread(target=self._run, name="omnican-ros2-publish",
                                        daemon=True)
        self._started = False

    # ------------------------------------------------------------ inputs

    def _on_cmd_vel(self, msg: Any) -> None:
        twist = msg.twist if self.settings.cmd_vel_stamped else msg
        self.cmd_vel_count += 1
        t = model.twist_from_msg((twist.linear.x, twist.linear.y, twist.linear.z),
                                 (twist.angular.x, twist.angular.y, twist.angular.z))
        try:
            self.base.set_velocity(t.vx, t.vy, t.wz)
        except ValueError as exc:
            self.cmd_vel_rejected += 1
            now = time.monotonic()
            if now - self._last_reject_log > 5.0:
                self._last_reject_log = now
                logger.warning("cmd_vel ignored: %s", exc)
        except DriveError:
            pass  # closing

    def _on_recover(self, msg: Any) -> None:
        with self._recover_lock:
            if self._recover_thread is not None and self._recover_thread.is_alive():
                logger.info("recover: already under way")
                return
            self._recover_thread = threading.Thread(target=self.recover,
                                                    name="omnican-ros2-recover", daemon=True)
            self._recover_thread.start()

    def recover(self) -> bool:
        """Clear a latched stop (what the recover topic does); True when it worked."""
        logger.info("recover requested")
        ok = True
        try:
            self.base.recover()
            note = "ok"
        except DriveError as exc:
            ok, note = False, f"failed: {exc}"
        stamp = time.strftime("%H:%M:%S")
        self.recover_note = f"{note} ({stamp})"
        (logger.info if ok else logger.warning)("recover %s", note)
        self._diag_now.set()
        return ok

    # ------------------------------------------------------------ outputs

    def _header(self, stamp: tuple[int, int], frame: str) -> Any:
        from omnican.ros2 import msgs

        return msgs.Header(msgs.Time(*stamp), frame)

    def publish_odom(self, now: float) -> None:
        from omnican.ros2 import msgs

        s = self.settings
        pose, twist, wheels = self.base.pose, self.base.twist, self.base.wheels
        self._covariance.update(pose)
        stamp = model.ros_time(now)
        qx, qy, qz, qw = model.yaw_quaternion(pose.theta)
        speeds = [w.actual_speed for w in wheels]
        odom = msgs.Odometry(
            header=self._header(stamp, s.odom_frame),
            child_frame_id=s.base_frame,
            pose=msgs.PoseWithCovariance(
                msgs.Pose(msgs.Point(pose.x, pose.y, 0.0), msgs.Quaternion(qx, qy, qz, qw)),
                self._covariance.pose_covariance()),
            twist=msgs.TwistWithCovariance(
                msgs.Twist(msgs.Vector3(twist.vx, twist.vy, 0.0),
                           msgs.Vector3(0.0, 0.0, twist.wz)),
                self._covariance.twist_covariance(speeds)),
        )
        self._pub_odom(odom)
        if self._pub_tf is not None:
            tf = msgs.TransformStamped(
                self._header(stamp, s.odom_frame), s.base_frame,
                msgs.Transform(msgs.Vector3(pose.x, pose.y, 0.0),
                               msgs.Quaternion(qx, qy, qz, qw)))
            self._pub_tf(msgs.TFMessage([tf]))
        if self._pub_truth is not None and self.sim is not None:
            true = self.sim.true_pose
            tx, ty, tz, tw = model.yaw_quaternion(true.theta)
            self._pub_truth(msgs.PoseStamped(
                self._header(stamp, s.odom_frame),
                msgs.Pose(msgs.Point(true.x, true.y, 0.0), msgs.Quaternion(tx, ty, tz, tw))))
        self.rates["odom"].tick()

    def publish_joint_states(self, now: float) -> None:
        from omnican.ros2 import msgs

        if self._pub_joints is None or self.wheel_radii is None:
            return
        wheels = self.base.wheels
        pos, vel = model.joint_values([w.travel for w in wheels],
                                      [w.actual_speed for w in wheels], self.wheel_radii)
        self._pub_joints(msgs.JointState(self._header(model.ros_time(now), ""),
                                         list(self.joint_names), pos, vel, []))
        self.rates["joint_states"].tick()

    def statuses(self, wheels: tuple[WheelState, ...] | None = None) -> list[model.Status]:
        """The diagnostic statuses as of now."""
        status = self.base.status
        wheels = wheels if wheels is not None else self.base.wheels
        mono = time.monotonic()
        rates = {name: r.sample(mono) for name, r in self.rates.items()}
        out = [model.chassis_status(self._prefix, status, self.recover_note),
               model.bus_status(self._prefix, status, self._channel)]
        out += [model.wheel_status(self._prefix, w, self.joint_names[i])
                for i, w in enumerate(wheels)]
        out.append(model.bridge_status(self._prefix, rates, self.cmd_vel_count,
                                       self.cmd_vel_rejected))
        return out

    def publish_diagnostics(self, now: float, wheels: tuple[WheelState, ...] | None = None
                            ) -> None:
        from omnican.ros2 import msgs

        array = msgs.DiagnosticArray(self._header(model.ros_time(now), ""), [
            msgs.DiagnosticStatus(st.level, st.name, st.message, st.hardware_id,
                                  [msgs.KeyValue(k, v) for k, v in st.values])
            for st in self.statuses(wheels)])
        self._pub_diag(array)
        self.rates["diagnostics"].tick()

    def _signature(self, wheels: tuple[WheelState, ...]) -> tuple[Any, ...]:
        """What changes the diagnostic levels: published at once when it changes."""
        st = self.base.status
        return (st.enabled, st.stopped_reason,
                tuple((w.state, w.fault, w.online, w.error) for w in wheels))

    # ------------------------------------------------------------ the thread

    def _run(self) -> None:
        s = self.settings
        periods = {"odom": 1.0 / s.odom_rate_hz, "joint_states": 1.0 / s.joint_states_rate_hz,
                   "diagnostics": 1.0 / s.diagnostics_rate_hz}
        due = dict.fromkeys(periods, time.monotonic())
        signature: tuple[Any, ...] | None = None
        while not self._stop.is_set():
            mono = time.monotonic()
            try:
                now = self._clock()
                if mono >= due["odom"]:
                    self.publish_odom(now)
                if mono >= due["joint_states"]:
                    self.publish_joint_states(now)
                wheels = self.base.wheels
                sig = self._signature(wheels)
                if mono >= due["diagnostics"] or sig != signature or self._diag_now.is_set():
                    self._diag_now.clear()
                    signature = sig
                    self.publish_diagnostics(now, wheels)
                    due["diagnostics"] = mono  # a change restarts the period
            except Exception:  # keep publishing whatever one message did
                logger.exception("publishing failed")
            for name, period in periods.items():
                if mono >= due[name]:
                    due[name] += period
                    if due[name] < mono:  # fell behind: do not burst to catch up
                        due[name] = mono + period
            self._stop.wait(max(0.0, min(due.values()) - time.monotonic()))

    # ------------------------------------------------------------ lifecycle

    def start(self) -> Bridge:
        self._started = True
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop publishing; wait for a recover under way. Idempotent."""
        self._stop.set()
        if self._started:
            self._thread.join(timeout=2.0)
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
