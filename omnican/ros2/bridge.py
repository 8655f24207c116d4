"""The ROS 2 bridge: a running :class:`~omnican.chassis.Chassis` on DDS.

``cmd_vel`` goes into the base's commands (:mod:`omnican.ros2.cmd_vel`: each publisher
a source of the base's own, one driving at a time), so the chassis watchdog stops the
base when commands stop. Commands are polled, not called back: a thread of the bridge
takes what arrived at most :data:`MAX_POLL_HZ` times a second (the control rate, if
lower), up to the reader's depth each time, and applies only the newest sample of each
publisher. A flood costs DDS's receive thread (C, without the GIL) and at most
``depth x rate`` samples a second here, whoever sends it.

A recover (the ``~/recover`` topic, the console's ``recover``) is asked of the base as
any other source's action (:mod:`omnican.chassis.actions`): refused while another source
drives. The topic's writer is told apart by its ROS 2 process (its DDS participant): the
process whose cmd_vel publisher drives is the driver.

``odom``, ``tf``, ``joint_states``, ``diagnostics`` and the simulator's true pose are
the base's telemetry (:mod:`omnican.telemetry`), the same messages the live view and an
MCAP recording carry, published at the configured rates; the bridge builds none of its
own and adds no work to the control loop.

The DDS side is a :class:`~omnican.ros2.transport.Transport`
(:mod:`omnican.ros2.transport`): Cyclone DDS in use, an in-memory one in the unit tests.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import threading
import time
import typing
from typing import TYPE_CHECKING, Any

from omnican.clock import PollThread
from omnican.log_throttle import Throttle
from omnican.ros2.cmd_vel import CmdVel
from omnican.ros2.imu import ImuReader
from omnican.ros2.settings import Ros2Settings, resolve_name
from omnican.ros2.transport import M, TopicQos, Transport
from omnican.telemetry import Message
from omnican.telemetry.attach import feed_of

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.chassis.arbiter import CommandSource
    from omnican.sim import SimulatedBase

logger = logging.getLogger(__name__)

#: tf2's history depth for /tf (its TransformListener subscribes with keep-last 100).
TF_DEPTH = 100
#: At most this many polls of cmd_vel and recover a second (fewer if the loop is slower).
MAX_POLL_HZ = 100.0
#: What the other sources are told of a recover: from the topic's writer (by its GUID),
#: from ``omnican ros2``'s console
RECOVER_SOURCE, CONSOLE_SOURCE = "ROS 2 recover publisher", "omnican ros2's console"


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
                 sim: SimulatedBase | None = None, poll_thread: bool = True) -> None:
        from omnican.ros2 import msgs

        self.base = base
        self.settings = settings
        self.sim = sim
        self._feed = feed = feed_of(base)  # the truth in it: telemetry.attach.add_truth
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
        # Beside /odom (fused with an IMU where one is attached): the same by
        # robot_localization's name, and the wheels' own odometry; at /odom's rate.
        self._pub_odom_more = {
            topic: transport.publisher(resolve_name(topic[1:], settings.node_namespace,
                                                    settings.node_name), msgs.Odometry, default)
            for topic in ("/odometry/filtered", "/odom/wheels")}
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
        self.cmd_vel = CmdVel(base, settings, transport)
        imu = base.cfg.imu
        #: the configured IMU's topic into the base's inbox ([imu] source = "ros2")
        self.imu = (ImuReader(base.imu, imu, transport)
                    if imu is not None and imu.source == "ros2" and base.imu is not None
                    else None)
        self._recover_topic = settings.topic("recover")
        self._take_recover = transport.reader(self._recover_topic, msgs.Empty,
                                              TopicQos(depth=1))
        self.poll_period_s = 1.0 / min(MAX_POLL_HZ, base.cfg.chassis.rate_hz)
        self._poller = (PollThread(self.poll, self.poll_period_s, "omnican-ros2-poll", logger,
                                   "handling ROS 2 commands failed") if poll_thread else None)
        self._poll_lock = threading.Lock()
        self._polls = 0
        self._throttle = Throttle(logger)
        self._wanted = {"/odom", "/diagnostics", "/battery_state", *self._pub_odom_more}
        if self._pub_tf is not None:
            self._wanted.add("/tf")
        if self._pub_joints is not None:
            self._wanted.add("/joint_states")
        if self._pub_truth is not None:
            self._wanted.add("/sim/true_pose")

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
            self.cmd_vel.take(check_publications=self._polls % 10 == 1)
            if self.imu is not None:
                self.imu.poll()
            asked = self._take_recover()
            if asked:
                self._on_recover(self._recover_source(asked[-1].writer))

    def _recover_source(self, writer: int) -> CommandSource:
        """Who asks for a recover on the topic: the ROS 2 process of a cmd_vel publisher
        (one DDS participant) is that publisher (a node that drives may recover), another
        is a source of its own."""
        guid = self.transport.writer_guid(self._recover_topic, writer)
        publisher = self.cmd_vel.of_participant(guid)
        if publisher is not None:
            return publisher
        return self.base.command_source(f"{RECOVER_SOURCE} {guid or hex(writer)}")

    def _on_recover(self, source: CommandSource) -> None:
        with self._recover_lock:
            if self._recover_thread is not None and self._recover_thread.is_alive():
                self._throttle.log(logging.INFO, "recover", "recover: already under way")
                return
            self._recover_thread = threading.Thread(target=self.recover, args=(False, source),
                                                    name="omnican-ros2-recover", daemon=True)
            self._recover_thread.start()

    def recover(self, answered: bool = False, source: CommandSource | None = None) -> bool:
        """Clear a latched stop (what the recover topic does) as ``source`` (default:
        the console's), if it may: refused while another source drives
        (:mod:`omnican.chassis.actions`). True when it worked. A refusal or failure is
        logged as a warning, unless ``answered`` (the console prints it)."""
        source = source or self.base.command_source(CONSOLE_SOURCE)
        logger.info("recover requested by %s", source.name)
        answer = source.recover()
        if answer.refused_by is not None:
            note = f"refused: {answer.refused_by} is driving the base"
        elif answer.failed is not None:
            note = f"failed: {answer.failed}"
        else:
            note = "ok"
        self.recover_note = f"{note} ({time.strftime('%H:%M:%S')})"
        (logger.info if answer.ok or answered else logger.warning)("recover %s", note)
        return answer.ok

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
            elif topic in self._pub_odom_more:
                if self._odom_sent:
                    self._pub_odom_more[topic](to_idl(msgs.Odometry, data))
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
        c = self.cmd_vel
        values += [{"key": "cmd_vel_received", "value": str(c.received)},
                   {"key": "cmd_vel_rejected", "value": str(c.rejected)},
                   {"key": "cmd_vel_parsed", "value": str(c.parsed)},
                   {"key": "cmd_vel_polls", "value": str(self._polls)},
                   {"key": "cmd_vel_ignored", "value": str(c.refused)},
                   {"key": "cmd_vel_last_driver", "value": c.driver or ""},
                   {"key": "last_recover", "value": self.recover_note or ""}]
        if self.imu is not None:
            last = self.imu.last
            values += [{"key": "imu_received", "value": str(self.imu.received)},
                       {"key": "imu_rejected", "value": str(self.imu.rejected)},
                       {"key": "imu_yaw_rate", "value": "" if last is None
                        else f"{last.yaw_rate:.6f}"},
                       {"key": "imu_silent_s", "value": "" if last is None
                        else f"{max(0.0, mono - last.t):.3f}"}]
        return {"level": 0, "name": f"{self._prefix}: ros2 bridge", "message": "running",
                "hardware_id": "", "values": values}

    # ------------------------------------------------------------ lifecycle

    def start(self) -> Bridge:
        """Publish the telemetry and (unless made with ``poll_thread=False``: then call
        :meth:`poll`) take commands on a thread of its own."""
        if not self._started:
            self._started = True
            self._feed.add(self)
            if self._poller is not None:
                self._poller.start()
        return self

    def close(self) -> None:
        """Stop publishing; wait for a recover under way. Idempotent."""
        if self._started:
            self._started = False
            self._feed.remove(self)
        if self._poller is not None:
            self._poller.stop()
        self._throttle.flush()
        self.cmd_vel.flush()
        if self.imu is not None:
            self.imu.flush()
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

    # what cmd_vel did, as the bridge's own (its summary, its diagnostics, the tests)
    @property
    def cmd_vel_count(self) -> int:
        return self.cmd_vel.received

    @property
    def cmd_vel_parsed(self) -> int:
        return self.cmd_vel.parsed

    @property
    def cmd_vel_rejected(self) -> int:
        return self.cmd_vel.rejected

    @property
    def cmd_vel_refused(self) -> int:
        return self.cmd_vel.refused

    @property
    def wrong_types(self) -> dict[str, str]:
        return self.cmd_vel.wrong_types
