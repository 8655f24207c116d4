"""Live view in Foxglove: a Foxglove WebSocket server (the official ``foxglove-sdk``,
``pip install 'omnican[foxglove]'``) that publishes what the base is doing.

It is a front end of the base's telemetry (:mod:`omnican.telemetry.feed`), as an MCAP
recording is, so one Foxglove layout (:data:`LAYOUT`, installed with the package) serves
both, with the same messages and stamps: ``/odom``, ``/odom/pose`` and ``/odom/path``
(what the 3D panel draws), ``/tf``, ``/joint_states``, ``/diagnostics`` (ROS 2 types,
CDR), ``/pose2d``, ``/twist``, ``/wheels``, ``/status`` (JSON), ``/sim/true_pose`` and
``/sim/pose2d`` under simulation, the raw frames on ``/from_can_bus`` / ``/to_can_bus``
(``can_msgs/msg/Frame``), and every frame the base's DBC describes decoded on
``/can/<message name>`` (JSON, one number per signal).

It has no thread of its own: the telemetry hands it each sample's messages. Nothing is
encoded for a topic no client subscribed to. The server binds to loopback unless a
host is given; clients reach it through :mod:`omnican.live.relay` (either name of the
protocol, TLS). With control on (:mod:`omnican.live.control`) clients may drive.
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from omnican import telemetry
from omnican.errors import ConfigError, quote
from omnican.live.control import PARAMETERS, Control
from omnican.live.relay import Relay, tls_context
from omnican.live.settings import DEFAULT_HOST, DEFAULT_PORT, FoxgloveSettings, parse_address
from omnican.log_throttle import Throttle
from omnican.telemetry import Feed, Message, cdr
from omnican.telemetry.attach import feed_of, simulator_feed

logger = logging.getLogger(__name__)

#: The Foxglove layout for the live view and recordings (Import from file... in the app),
#: installed with the package (``foxglove/omnican-layout.json`` in a clone).
LAYOUT = Path(__file__).resolve().parents[1] / "foxglove" / "omnican-layout.json"


def prepare(cfg: Any) -> None:
    """Do the live view's slow set-up (the SDK, the ROS 2 type store and its serializers,
    the base's DBC: about a second of CPU) now, before the base's control loop runs and
    has to share the CPU with it. Optional: what is not done here is done when first
    needed."""
    try:
        import foxglove  # noqa: F401
    except ImportError:
        return  # LiveView says what to install
    from omnican.plan.dbc import database_for

    store = cdr.typestore()
    # Each ROS 2 type's serializer is generated and compiled on its first message (about
    # 170 ms for the view's types, most of it holding the interpreter's lock): when the
    # first client subscribed to everything, that stalled the control loop by ~100 ms.
    for schema in sorted({schema for schema, kind in telemetry.TOPICS.values()
                          if kind == telemetry.ROS2} | {telemetry.CAN_FRAME}):
        store.get_msgdef(schema)
    database_for(cfg)


# How the SDK's server words a viewer that went away without a closing handshake (a
# closed browser tab, a laptop that slept): a viewer leaving, not an error.
_LEFT_WORDS = ("Connection reset", "closing handshake", "Broken pipe", "os error 104",
               "os error 32")


# The SDK's logger of what one client does (its protocol mistakes among it, an ERROR line
# each: "Invalid message from ...", "... attempted to subscribe to unknown channel").
_CLIENT_LOGGER = "foxglove.websocket.connected_client"
_MISTAKE_LINE = 200  # characters of such a line kept (a client's words may be in it)


def mistake_kind(text: str) -> str:
    """What a line of the SDK's says with the client's address and the numbers left out:
    lines of one kind are logged once every few seconds."""
    return re.sub(r"\d+", "N", text.split(": ", 2)[0] if "Invalid message" in text else text)[:80]


class _ViewerLeft(logging.Filter):
    """Turns the SDK's ERROR "Error receiving from client ...: Connection reset ..." into
    an INFO line that a viewer left, and its lines about a client's protocol mistakes into
    WARNING lines, each kind at most once every few seconds (a count of the others with
    the next); other records pass as they are."""

    def __init__(self) -> None:
        super().__init__()
        self.mistakes = Throttle(logger)

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        left = "from client" in text and any(w in text for w in _LEFT_WORDS)
        if record.name == _CLIENT_LOGGER and record.levelno >= logging.WARNING and not left:
            self.mistakes.warning(mistake_kind(text), "Foxglove: %s",
                                  quote(text, _MISTAKE_LINE).strip("'\""))
            return False
        if record.levelno >= logging.ERROR and "from client" in text and any(
                w in text for w in _LEFT_WORDS):
            client = text.split("from client", 1)[1].split(":", 2)
            who = ":".join(client[:2]).strip() if len(client) > 1 else "a client"
            record.msg, record.args = "Foxglove viewer %s left", (who,)
            record.levelno, record.levelname = logging.INFO, "INFO"
            return logging.getLogger(record.name).isEnabledFor(logging.INFO)
        return True


_VIEWER_LEFT = _ViewerLeft()


def _quiet_viewers_leaving() -> None:
    for name in ("foxglove.websocket.connected_client.poller",
                 "foxglove.websocket.connected_client", "foxglove.websocket.server"):
        logger_ = logging.getLogger(name)
        if _VIEWER_LEFT not in logger_.filters:
            logger_.addFilter(_VIEWER_LEFT)


class LiveView:
    """A running Foxglove server publishing ``feed`` (a base's, ``feed_of(base)``,
    or a simulator's alone): a :class:`~omnican.telemetry.Sink`. With ``control``, its
    clients may drive the base (:class:`~omnican.live.control.Control`). A context
    manager."""

    def __init__(self, feed: Feed, *, host: str = DEFAULT_HOST,
                 port: int = DEFAULT_PORT, control: Control | None = None,
                 settings: FoxgloveSettings | None = None) -> None:
        try:
            import foxglove
        except ImportError:
            from omnican.extras import install_hint

            raise ConfigError("--foxglove needs the Foxglove SDK: "
                              f"{install_hint('foxglove')}") from None
        s = settings if settings is not None else FoxgloveSettings(host=host, port=port)
        host, port = s.host, s.port
        self.feed = feed
        self.settings = s
        self.control = control
        self._ctx = foxglove.Context()
        _quiet_viewers_leaving()
        tls = None
        if s.tls_cert is not None and s.tls_key is not None:
            try:
                tls = tls_context(s.tls_cert, s.tls_key)
            except ValueError as exc:
                raise ConfigError(f"--foxglove: {exc}") from None
        if s.remote:
            logger.warning("Foxglove server on %s: anyone who reaches this host on port %d "
                           "sees the robot's data", host, port)
        options = control.server_options(foxglove) if control is not None else {}
        try:
            # The SDK's own server stays on loopback; clients come in through the relay.
            self._server = foxglove.start_server(name="omnican", host="127.0.0.1", port=0,
                                                 context=self._ctx, **options)
        except Exception as exc:  # the SDK raises its own error kinds
            raise ConfigError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        try:
            self._relay = Relay(host, port, int(self._server.port), tls,
                                origin_allowed=s.origin_allowed, token=s.token,
                                grant=control.grant if control is not None else None)
        except OSError as exc:
            self._server.stop()
            why = exc.strerror or str(exc)
            raise ConfigError(f"cannot serve Foxglove on {host}:{port}: {why}") from None
        if control is not None:
            control.attach(self._server)
        self.host, self.port = host, self._relay.port
        self._closed = False
        try:
            self._channels = self._make_channels(foxglove)
            feed.add(self)
        except BaseException:
            self._relay.close()
            self._server.stop()
            raise

    def _make_channels(self, foxglove: Any) -> dict[str, Any]:
        feed, ctx = self.feed, self._ctx
        channels: dict[str, Any] = {}
        for topic, (schema, kind) in telemetry.TOPICS.items():
            if topic.startswith("/sim/") if feed.truth is None else (
                    not feed.has_base and not topic.startswith("/sim/")):
                continue
            channels[topic] = self._channel(foxglove, topic, schema, kind)
        for topic in (telemetry.CAN_RX, telemetry.CAN_TX):
            channels[topic] = self._channel(foxglove, topic, telemetry.CAN_FRAME, telemetry.ROS2)
        for topic, json_schema in feed.frame_messages.decoded_topics().items():
            channels[topic] = foxglove.Channel(topic, schema=json_schema, context=ctx)
        return channels

    def _channel(self, foxglove: Any, topic: str, schema: str, kind: str) -> Any:
        if kind == telemetry.JSON:
            return foxglove.Channel(topic, schema=telemetry.JSON_SCHEMAS[schema],
                                    context=self._ctx)
        return foxglove.Channel(
            topic, schema=foxglove.Schema(name=schema, encoding=cdr.SCHEMA_ENCODING,
                                          data=cdr.msgdef(schema).encode()),
            message_encoding="cdr", context=self._ctx)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.settings.scheme}://{host}:{self.port}"

    # ------------------------------------------------------------ the sink

    def wants(self, topic: str) -> bool:
        channel = self._channels.get(topic)
        return channel is not None and channel.has_sinks()

    def publish(self, messages: list[Message]) -> None:
        channels = self._channels
        for msg in messages:
            channels[msg.topic].log(msg.payload(), log_time=msg.stamp_ns)

    # ------------------------------------------------------------ closing

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.feed.remove(self)
        if self.control is not None:
            self.control.close()  # clients leaving now (the relay closing) change nothing
        self._relay.close()
        self._server.stop()
        _VIEWER_LEFT.mistakes.flush()  # how many a client's mistakes went unlogged

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def describe_control(view: LiveView) -> list[str]:
    """What the startup lines say of control: what a client may send, and the warning
    when other hosts can drive."""
    c, s = view.control, view.settings
    if c is None:
        return []
    params = ", ".join(PARAMETERS[:3]) + ", ..."
    lines = [f"Foxglove control on: Twists on {s.cmd_vel_topic} (Teleop panel; JSON or CDR), "
             f"services {', '.join(c.service_names())}, parameters {params}; one client "
             f"drives at a time, and the base stops when it leaves or sends nothing for "
             f"{c.timeout_s:g} s"]
    pages = "any web page" if "*" in s.origins else ", ".join(s.origins)
    lines.append(f"Foxglove clients: browsers from {pages}, and programs; "
                 + ("only a client with the token drives (its URL ending /?token=...), "
                    "the others watch" if s.token is not None else
                    "any of them may drive (--foxglove-token keeps it to those with it)"))
    if s.remote:
        lines.append(f"warning: anyone who reaches this host on port {view.port} can drive "
                     "the robot (--foxglove-allow-remote)")
    return lines


@contextlib.contextmanager
def watch(base: Any, sim: Any = None, foxglove: str | FoxgloveSettings | None = None,
          announce: Any = None) -> Iterator[LiveView | None]:
    """A Foxglove server beside a running base (or a simulator alone, ``base`` None: its
    own telemetry, its ground truth and the frames its drives hear) while the block runs,
    when ``foxglove`` (``[HOST:]PORT``, or :class:`FoxgloveSettings`) is given. It shows
    the base's telemetry as it is: the simulator's ground truth is in it when whoever
    runs the base beside a simulator put it there
    (:func:`omnican.telemetry.attach.add_truth`). With control on in the settings, its
    clients may drive the base, each a source of commands of the base's own
    (:meth:`~omnican.chassis.Chassis.command_source`: one at a time, shared with the front
    end's other sources); ``sim``: the simulator whose fault console they may use.
    ``announce(text)`` is told where the server listens and what control allows."""
    settings: FoxgloveSettings | None = None
    if isinstance(foxglove, FoxgloveSettings):
        settings = foxglove
    elif foxglove is not None:
        try:
            host, port = parse_address(foxglove)
        except ValueError as exc:
            raise ConfigError(f"--foxglove: {exc}") from None
        settings = FoxgloveSettings(host=host, port=port)
    if settings is None:
        yield None
        return
    with contextlib.ExitStack() as stack:
        feed = feed_of(base) if base is not None else stack.enter_context(simulator_feed(sim))
        control = None
        if settings.control and base is not None:
            control = Control(base, settings, sim)
        view = stack.enter_context(LiveView(feed, control=control, settings=settings))
        if announce is not None:
            announce(f"Foxglove: open a connection to {view.url} (layout: {LAYOUT})")
            for line in describe_control(view):
                announce(line)
        if settings.control and settings.remote:
            logger.warning("Foxglove control on %s:%d: anyone who reaches this host can "
                           "drive the robot", settings.host, view.port)
        yield view
