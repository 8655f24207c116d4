"""The base on Zenoh, in rmw_zenoh's format: a ROS 2 node on ``rmw_zenoh_cpp`` (or any
peer speaking it) sees its telemetry and drives it with cmd_vel.

The telemetry is the one model's (:mod:`omnican.telemetry`): the bridge is a sink of the
base's telemetry feed (:func:`~omnican.telemetry.attach.feed_of`) and puts each
message's CDR bytes, built once for every front end, on its rmw_zenoh key with the
attachment (sequence number one higher each message, the sample's time, a fixed GID per
publisher). The model's JSON topics ``status`` and ``wheels`` go out as
``std_msgs/msg/String`` (the JSON as the string's text), and ``base_summary``, the
fleet's view of the base (:mod:`omnican.zenoh.summary`: made from the same sample's
messages, once a period and at once on a stop or a fault). It declares the liveliness
tokens a ROS 2 graph reads: the node (``NN``), each publisher (``MP``) and the cmd_vel
subscription (``MS``). Publishing is on the feed's thread, never the control loop's.

cmd_vel (``geometry_msgs/msg/Twist``, or TwistStamped if the settings say) arrives in a
ring of :data:`CMD_VEL_DEPTH` samples (a flood costs the oldest, in Zenoh's threads) and
is polled, by the ROS 2 bridge's rules (:mod:`omnican.command.intake`): the newest
sample of each publisher (told apart by its attachment's GID) is parsed, up to
:data:`~omnican.command.intake.MAX_PARSED_PER_POLL` a poll. One
publisher drives at a time, each through its own command source
(:meth:`~omnican.chassis.Chassis.command_source`, the base's one arbiter);
the chassis watchdog stops the base when its commands stop (a dropped network stops
it). What cannot be a command (oversized, malformed CDR, NaN) is refused with one log
line and moves nothing.
"""

from __future__ import annotations

import json
import logging
import re
import struct
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnican.chassis.arbiter import CommandSource
from omnican.clock import PollThread
from omnican.command.intake import CmdVelIntake
from omnican.core.kinematics import Twist
from omnican.errors import ConfigError
from omnican.telemetry import JSON, TOPICS, Message
from omnican.telemetry.attach import feed_of
from omnican.zenoh import rmw
from omnican.zenoh.imu import ZenohImu
from omnican.zenoh.security import ENFORCING, tls_entries
from omnican.zenoh.services import SERVICES, Services
from omnican.zenoh.services import SOURCE as SERVICE_CLIENT
from omnican.zenoh.settings import (
    ZenohSettings,
    config_entries,
    default_listen,
    exposed,
    exposed_refusal,
    role_problem,
)
from omnican.zenoh.summary import SOURCES, Summarizer

if TYPE_CHECKING:
    from omnican.chassis import Chassis

logger = logging.getLogger(__name__)

TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
#: The telemetry this front end publishes (tf with odom, joint states with wheel radii).
PUBLISHED = ("/odom", "/tf", "/joint_states", "/diagnostics", "/battery_state",
             "/status", "/wheels", "/odometry/filtered", "/odom/wheels")
#: What goes out with its sample's /odom (besides the simulator's truth).
WITH_ODOM = ("/tf", "/odometry/filtered", "/odom/wheels")
STRING = "std_msgs/msg/String"  # what the JSON topics travel as (the JSON its text)
#: The fleet's view of the base (:mod:`omnican.zenoh.summary`).
SUMMARY = "/base_summary"
#: The simulator's true pose, published beside the odometry when the base runs against
#: simulated drives in its own process (``sim=``).
TRUE_POSE = "/sim/true_pose"
TF_DEPTH = 100  # tf2's listener keeps 100
CMD_VEL_DEPTH = 256  # samples kept between polls (the newest)
MAX_POLL_HZ = 100.0
SOURCE = "Zenoh cmd_vel publisher"


def string_cdr(text: bytes) -> bytes:
    """``text`` (UTF-8: a JSON topic's payload) as a std_msgs/msg/String's CDR: the
    little-endian header, the length with the terminating NUL, the bytes and the NUL
    (made directly: no type store on the way of a base's first summary)."""
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(text) + 1) + text + b"\x00"


def _type_of(topic: str) -> str:
    """The ROS 2 type ``topic`` travels as: its own, or a String carrying its JSON."""
    schema, kind = TOPICS.get(topic, (STRING, JSON))
    return STRING if kind == JSON else schema


def open_session(settings: ZenohSettings) -> Any:
    """A Zenoh session as ``settings`` say (:func:`session_config`). ConfigError, one
    line, when it cannot open (Zenoh's words, without the place in its source)."""
    import zenoh

    conf = session_config(settings)
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ConfigError(f"cannot open a Zenoh session: {zenoh_words(exc)}") from None


def session_config(settings: ZenohSettings) -> Any:
    """The ``zenoh.Config`` of a session as ``settings`` say: the config file first, then
    the credentials' certificates and (a base's, a router's) access control, then the
    settings; where nothing says where to listen, loopback
    (:func:`~omnican.zenoh.settings.default_listen`). ConfigError, one line, for a file
    that is not there or not a Zenoh config (named), credentials that do not fit, or a
    session that would listen beyond loopback without credentials
    (:func:`~omnican.zenoh.settings.exposed`) unless ``allow_insecure``. Opens nothing:
    a command calls it before its drives come up."""
    import zenoh

    settings.validate()
    problem = role_problem(settings)
    if problem is not None:
        raise ConfigError(problem)
    conf = _read_config(settings.config_file, "Zenoh config") if settings.config_file \
        else zenoh.Config()
    zenoh_default_listen = conf.get_json("listen/endpoints") == \
        zenoh.Config().get_json("listen/endpoints")
    try:
        if settings.mtls:
            _put_credentials(conf, settings)
        for path, value in config_entries(settings):
            conf.insert_json5(path, value)
        if not settings.listen and zenoh_default_listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(default_listen(settings))))
    except zenoh.ZError as exc:
        raise ConfigError(f"Zenoh config: {zenoh_words(exc)}") from None
    if not settings.allow_insecure:
        open_to = exposed(_listening(conf, settings.mode), mtls=_mutual_tls(conf),
                          password=_passwords(conf))
        if open_to:
            raise ConfigError(exposed_refusal(settings, open_to))
    return conf


def zenoh_words(exc: BaseException) -> str:
    """Zenoh's message without the place in its Rust source (`` at /root/.cargo/...rs:1507.``)."""
    return re.sub(r"\s+at\s+\S+\.rs:\d+\.?\s*$", "", str(exc)).strip()


def _read_config(path: str | Path, what: str) -> Any:
    """A Zenoh JSON5 file as a ``zenoh.Config``; ConfigError naming it (``what PATH: ...``)
    when it is not there or not a Zenoh config."""
    import zenoh

    if not Path(path).is_file():
        raise ConfigError(f"{what} {path}: no such file")
    try:
        return zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise ConfigError(f"{what} {path}: {zenoh_words(exc)}") from None


def _put_credentials(conf: Any, settings: ZenohSettings) -> None:
    """The identity's certificates (found in the credentials' folder, wherever it is now)
    and, for a base or router, the access control of its ``zenoh.json5``, into ``conf``."""
    from omnican.zenoh.credentials import files_for

    assert settings.credentials is not None and settings.identity is not None
    who, files = files_for(settings.credentials, settings.identity)
    for path, value in tls_entries(str(files.ca), str(files.cert), str(files.key)):
        conf.insert_json5(path, value)
    if who.role in ENFORCING:
        acl = json.loads(_read_config(files.config, "Zenoh credentials").get_json(
            "access_control"))
        if not (isinstance(acl, dict) and acl.get("enabled") is True):
            raise ConfigError(f"Zenoh credentials {files.config}: its access control is "
                              f"off, and a {who.role} must say who may drive")
        conf.insert_json5("access_control", json.dumps(acl))


def _listening(conf: Any, mode: str) -> list[str]:
    """The endpoints ``conf`` listens on in ``mode`` (Zenoh's per-mode defaults read)."""
    value = json.loads(conf.get_json("listen/endpoints"))
    if isinstance(value, dict):
        value = value.get(mode, [])
    return [str(v) for v in value or []]


def _mutual_tls(conf: Any) -> bool:
    tls = json.loads(conf.get_json("transport/link/tls"))
    return bool(isinstance(tls, dict) and tls.get("enable_mtls")
                and tls.get("root_ca_certificate"))


def _passwords(conf: Any) -> bool:
    """Every session that links must give a user and password (a dictionary is set)."""
    import zenoh

    try:
        return bool(json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")))
    except zenoh.ZError:  # a Zenoh without the key: no passwords
        return False


class _Publisher:
    """One topic's Zenoh publisher, its liveliness token and its attachment's state."""

    def __init__(self, session: Any, node: rmw.RosNode, entity_id: int, fq_name: str,
                 type_name: str, qos: rmw.Qos) -> None:
        hash_ = rmw.type_hash(type_name)
        self.name = fq_name
        self.key = rmw.data_key(node.domain_id, fq_name, type_name, hash_)
        self.token_key = node.endpoint_token(entity_id, rmw.Kind.PUBLISHER, fq_name,
                                             type_name, hash_, qos)
        self.gid = rmw.gid_of(self.token_key)
        self.sequence = 0
        self.count = 0
        self._pub = session.declare_publisher(self.key)
        self._token = session.liveliness().declare_token(self.token_key)

    def put(self, payload: bytes, stamp_ns: int) -> None:
        self.sequence += 1  # rmw_zenoh's first is 1
        self._pub.put(payload, attachment=rmw.Attachment(self.sequence, stamp_ns,
                                                         self.gid).encode())
        self.count += 1

    def close(self) -> None:
        self._token.undeclare()
        self._pub.undeclare()


class ZenohBridge:
    """Publishes the base's telemetry on a Zenoh session and takes cmd_vel from it (see
    the module docstring). It owns neither the base nor the session; use as a context
    manager (or :meth:`start` and :meth:`close`). ``poll_thread=False``: no thread of
    its own; call :meth:`poll` (the lock-step tests do)."""

    def __init__(self, base: Chassis, settings: ZenohSettings, session: Any, *,
                 sim: Any = None, poll_thread: bool = True) -> None:
        import zenoh

        self.base = base
        self.settings = settings.validate()
        self.session = session
        feed = feed_of(base)  # the simulator's truth in it: omnican.telemetry.attach.add_truth
        ns = settings.ros_namespace
        self.node = rmw.RosNode(settings.domain_id, str(session.info.zid()), 0,
                             settings.node_name, namespace=ns)
        self._node_token = session.liveliness().declare_token(self.node.token())
        topics = [t for t in PUBLISHED
                  if t != "/joint_states" or feed.settings.wheel_radii is not None]
        if sim is not None:
            topics.append(TRUE_POSE)
        topics.append(SUMMARY)
        self.publishers: dict[str, _Publisher] = {}
        for entity_id, topic in enumerate(topics, start=1):
            qos = rmw.Qos(depth=TF_DEPTH if topic == "/tf" else 10)
            self.publishers[topic] = _Publisher(session, self.node, entity_id,
                                                rmw.fully_qualified(ns, topic[1:]),
                                                _type_of(topic), qos)
        state_rate = feed.settings.state_rate_hz
        self._every = {t: max(1, round(state_rate / r)) for t, r in settings.rates_hz.items()}
        self._seen = dict.fromkeys(self._every, 0)
        self._odom_sent = False
        self._summary = Summarizer(rmw.fully_qualified(ns, settings.node_name),
                                   1.0 / settings.rates_hz.get(SUMMARY, 2.0))

        self.cmd_topic = rmw.fully_qualified(ns, "cmd_vel")
        self.cmd_type = TWIST_STAMPED if settings.cmd_vel_stamped else TWIST
        hash_ = rmw.type_hash(self.cmd_type)
        self.cmd_key = rmw.data_key(settings.domain_id, self.cmd_topic, self.cmd_type, hash_)
        self._cmd_token = session.liveliness().declare_token(self.node.endpoint_token(
            len(topics) + 1, rmw.Kind.SUBSCRIPTION, self.cmd_topic, self.cmd_type, hash_,
            rmw.Qos()))
        self._cmd_sub = session.declare_subscriber(
            self.cmd_key, zenoh.handlers.RingChannel(CMD_VEL_DEPTH))

        # One command source per publisher (its GID names it), handed out by the base,
        # whose one arbiter the other front ends share: one drives at a time.
        self._sources: dict[str, CommandSource] = {}
        self._anyone = base.command_source(SOURCE)
        self.services = Services(session, self.node, self.caller, len(topics) + 2)
        imu = base.cfg.imu
        #: the configured IMU's topic into the base's inbox ([imu] source = "zenoh")
        self.imu = (ZenohImu(session, self.node, len(topics) + 2 + len(SERVICES),
                             settings.domain_id, base.imu, imu)
                    if imu is not None and imu.source == "zenoh" and base.imu is not None
                    else None)
        self.poll_period_s = 1.0 / min(MAX_POLL_HZ, base.cfg.chassis.rate_hz)
        self._poller = (PollThread(self.poll, self.poll_period_s, "omnican-zenoh-poll", logger,
                                   "handling Zenoh cmd_vel failed") if poll_thread else None)
        self._poll_lock = threading.Lock()
        self._publish_lock = threading.Lock()
        #: what became of cmd_vel's samples (the ROS 2 bridge's rules: omnican.command.intake)
        self.intake = CmdVelIntake(logger, self.cmd_type, self._read)
        self._started = False
        self._closed = False
        self.polls = 0
        self.cmd_vel_count = 0  # samples taken

    # ------------------------------------------------------------ outputs (the sink)

    def wants(self, topic: str) -> bool:
        return topic in self.publishers or topic in SOURCES

    def publish(self, messages: list[Message]) -> None:
        with self._publish_lock:  # close() may run meanwhile (the feed's thread is ours)
            if not self._closed:
                self._publish(messages)

    def _publish(self, messages: list[Message]) -> None:
        data = {m.topic: m.data for m in messages if m.topic in SOURCES and m.data}
        if data:  # the fleet's view first: a stop or a new base is heard before the rest
            stamp_ns = next(m.stamp_ns for m in messages if m.topic in data)
            summary = self._summary.offer(data, stamp_ns, self.holder())
            if summary is not None:
                self.publishers[SUMMARY].put(string_cdr(json.dumps(summary).encode()),
                                             stamp_ns)
        for message in messages:
            pub = self.publishers.get(message.topic)
            if pub is None:
                continue
            topic = message.topic
            if topic in WITH_ODOM or topic == TRUE_POSE:  # with the odometry of their sample
                due = self._odom_sent
            elif topic in self._every:
                self._seen[topic] += 1
                due = (self._seen[topic] - 1) % self._every[topic] == 0
                if topic == "/odom":
                    self._odom_sent = due
            else:
                due = True
            if due:
                payload = message.payload()
                pub.put(string_cdr(payload) if message.kind == JSON else payload,
                        message.stamp_ns)

    # ------------------------------------------------------------ inputs

    def poll(self) -> None:
        """Take what arrived on cmd_vel and act on the newest sample of each publisher;
        answer the service requests (:mod:`omnican.zenoh.services`)."""
        with self._poll_lock:
            if self._closed:
                return
            self.polls += 1
            newest: dict[str, bytes] = {}
            for _ in range(CMD_VEL_DEPTH):
                sample = self._cmd_sub.try_recv()
                if sample is None:
                    break
                self.cmd_vel_count += 1
                source = _source(sample.attachment)
                newest.pop(source, None)  # oldest first: the last of each stays
                newest[source] = sample.payload.to_bytes()
            self.intake.take({self.command_source(name): data
                              for name, data in newest.items()})
            self.services.poll()

    def _read(self, data: bytes) -> Twist:
        from omnican.telemetry import cdr

        msg = cdr.decode(self.cmd_type, data)
        if self.cmd_type == TWIST_STAMPED:
            msg = msg["twist"]
        return Twist(float(msg["linear"]["x"]), float(msg["linear"]["y"]),
                     float(msg["angular"]["z"]))

    def command_source(self, name: str) -> CommandSource:
        """The base's command source for the cmd_vel publisher or service client ``name``."""
        source = self._sources.get(name)
        if source is None:
            source = self._sources[name] = self.base.command_source(name)
        return source

    def caller(self, gid: bytes) -> CommandSource:
        """The base's command source for a service request by its GID: one GID is one
        client, so the cmd_vel publisher of that GID if it has sent (a client that drives
        and calls), else the service client ``Zenoh service client <gid>``. (rmw_zenoh
        gives each publisher and client of a node a GID of its own.)"""
        publisher = self._sources.get(f"{SOURCE} {gid.hex()}")
        if publisher is not None:
            return publisher
        return self.command_source(f"{SERVICE_CLIENT} {gid.hex()}")

    def holder(self) -> str | None:
        """Who drives the base now, of every front end (None: no one)."""
        return self._anyone.holder()

    @property
    def cmd_vel_parsed(self) -> int:
        return self.intake.parsed

    @property
    def cmd_vel_rejected(self) -> int:
        """Samples refused: not a Twist one may drive with."""
        return self.intake.rejected

    @property
    def cmd_vel_refused(self) -> int:
        """Samples ignored: another source held control."""
        return self.intake.refused

    # ------------------------------------------------------------ lifecycle

    def start(self) -> ZenohBridge:
        if not self._started:
            self._started = True
            feed_of(self.base).add(self)
            if self._poller is not None:
                self._poller.start()
        return self

    def close(self) -> None:
        """Stop publishing and taking commands; withdraw the liveliness tokens (the graph
        sees the node leave). Idempotent; the session stays open."""
        if self._started:
            self._started = False
            feed_of(self.base).remove(self)
        if self._poller is not None:
            self._poller.stop()
        with self._poll_lock, self._publish_lock:
            if self._closed:
                return
            self._closed = True
        self.intake.flush()
        self._cmd_sub.undeclare()
        self._cmd_token.undeclare()
        self.services.close()
        if self.imu is not None:
            self.imu.close()
        for pub in self.publishers.values():
            pub.close()
        self._node_token.undeclare()

    def __enter__(self) -> ZenohBridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


def _source(attachment: Any) -> str:
    """A cmd_vel sample's publisher, by its attachment's GID."""
    if attachment is None:
        return f"{SOURCE} without an attachment"
    try:
        gid = rmw.Attachment.decode(attachment.to_bytes()).gid
    except ValueError:
        return f"{SOURCE} with a malformed attachment"
    return f"{SOURCE} {gid.hex()}"
