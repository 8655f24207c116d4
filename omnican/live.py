"""Live view in Foxglove: a Foxglove WebSocket server (the official ``foxglove-sdk``,
``pip install 'omnican[foxglove]'``) that publishes what the base is doing.

Topics are those of an MCAP recording (:mod:`omnican.mcap_record`), so one Foxglove layout
(``foxglove/omnican-layout.json``) serves both: ``/odom``, ``/tf``, ``/joint_states``,
``/diagnostics`` (ROS 2 types, CDR), ``/pose2d``, ``/twist``, ``/wheels``, ``/status``
(JSON), ``/sim/true_pose`` and ``/sim/pose2d`` under simulation, the raw frames on
``/from_can_bus`` / ``/to_can_bus`` (``can_msgs/msg/Frame``), and every frame the base's DBC
describes decoded on ``/can/<message name>`` (JSON, one number per signal).

A publisher thread polls the base's snapshot at ``rate_hz``; frames arrive through a
listener on the bus that only appends to a bounded queue. Nothing is encoded for a topic
no client subscribed to. The server binds to loopback unless a host is given.
"""

from __future__ import annotations

import collections
import contextlib
import json
import logging
import threading
import time
from collections.abc import Iterator
from typing import Any

import can

from omnican import rosmsg, telemetry
from omnican.errors import ConfigError

logger = logging.getLogger(__name__)

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8765
RATE_HZ = 30.0
QUEUE_FRAMES = 20_000
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def parse_address(text: str | None) -> tuple[str, int]:
    """``[HOST:]PORT`` (or empty: 127.0.0.1:8765) -> (host, port); ValueError if bad."""
    if not text:
        return DEFAULT_HOST, DEFAULT_PORT
    host, sep, port = text.rpartition(":")
    if not sep and not text.isdigit():
        host, port = text, str(DEFAULT_PORT)  # a bare host
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"want [HOST:]PORT, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"port must be 0-65535, got {number}")
    host = host.strip("[]") or DEFAULT_HOST
    return host, number


_prepared: list[tuple[Any, Any]] = []  # (config, its DBC database) from prepare()


def prepare(cfg: Any) -> None:
    """Do the live view's slow set-up (the SDK, the ROS 2 type store, the base's DBC:
    about a second of CPU) now, before the base's control loop runs and has to share the
    CPU with it. Optional: :class:`LiveView` does what was not done here."""
    try:
        import foxglove  # noqa: F401
    except ImportError:
        return  # LiveView says what to install
    rosmsg.typestore()
    _prepared[:] = [(cfg, _database(cfg))]


def _database(cfg: Any) -> Any:
    for known, db in _prepared:
        if known is cfg:
            return db
    from omnican.dbcgen import build_database

    return build_database(cfg)


class _Tap(can.Listener):
    """Frames into a bounded queue; called on the Notifier (and control loop) thread."""

    def __init__(self, size: int) -> None:
        self.queue: collections.deque[can.Message] = collections.deque()
        self.size = size
        self.dropped = 0

    def on_message_received(self, msg: can.Message) -> None:
        if len(self.queue) >= self.size:
            self.dropped += 1
            return
        self.queue.append(msg)

    def stop(self) -> None:
        pass


# How the SDK's server words a viewer that went away without a closing handshake (a
# closed browser tab, a laptop that slept): a viewer leaving, not an error.
_LEFT_WORDS = ("Connection reset", "closing handshake", "Broken pipe", "os error 104",
               "os error 32")


class _ViewerLeft(logging.Filter):
    """Turns the SDK's ERROR "Error receiving from client ...: Connection reset ..." into
    an INFO line that a viewer left; other records pass as they are."""

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
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


def _signal_schema(message: Any) -> dict[str, Any]:
    props: dict[str, Any] = {"timestamp": {"type": "object", "properties": {
        "sec": {"type": "integer"}, "nsec": {"type": "integer"}}}}
    for sig in message.signals:
        props[sig.name] = {"type": "number", "description": sig.comment or ""}
    return {"title": f"omnican.can.{message.name}", "type": "object", "properties": props}


class LiveView:
    """A running Foxglove server publishing ``base`` (an :class:`omnican.Chassis`, or None
    for the simulator alone) and ``sim``'s ground truth. A context manager."""

    def __init__(self, base: Any = None, sim: Any = None, *, host: str = DEFAULT_HOST,
                 port: int = DEFAULT_PORT, rate_hz: float = RATE_HZ,
                 frames: telemetry.Frames | None = None) -> None:
        try:
            import foxglove
        except ImportError:
            from omnican.extras import install_hint

            raise ConfigError("--foxglove needs the Foxglove SDK: "
                              f"{install_hint('foxglove')}") from None
        if base is None and sim is None:
            raise ValueError("nothing to publish: give a base, a simulated base or both")
        self.base, self.sim = base, sim
        self._frames_cfg = frames or telemetry.Frames()
        self._period = 1.0 / rate_hz
        cfg = base.cfg if base is not None else sim.cfg
        self._radius = tuple(w.wheel_radius for w in cfg.wheels)
        self._channel_name = str((cfg.bus or {}).get("channel", ""))
        self._ctx = foxglove.Context()
        _quiet_viewers_leaving()
        if host not in LOOPBACK:
            logger.warning("Foxglove server on %s: anyone who reaches this host on port %d "
                           "sees the robot's data", host, port)
        try:
            self._server = foxglove.start_server(name="omnican", host=host, port=port,
                                                 context=self._ctx)
        except Exception as exc:  # the SDK raises its own error kinds (address in use, ...)
            raise ConfigError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        self.host, self.port = host, int(self._server.port)
        try:
            self._setup(foxglove, cfg, base, sim)
        except BaseException:
            self._server.stop()
            raise

    def _setup(self, foxglove: Any, cfg: Any, base: Any, sim: Any) -> None:
        self._channels: dict[str, Any] = {}
        topics = telemetry.TOPICS if base is not None else {
            k: v for k, v in telemetry.TOPICS.items() if k.startswith("/sim/")}
        for topic, (schema, _) in topics.items():
            if topic.startswith("/sim/") and sim is None:
                continue
            self._channels[topic] = self._make_channel(topic, schema)
        for topic in (telemetry.CAN_RX, telemetry.CAN_TX):
            self._channels[topic] = self._make_channel(topic, telemetry.CAN_FRAME)
        self._decoded: dict[tuple[int, bool], tuple[Any, Any]] = {}
        try:
            db = _database(cfg)
            for message in db.messages:
                channel = foxglove.Channel(f"/can/{message.name}", schema=_signal_schema(message),
                                           context=self._ctx)
                self._decoded[(message.frame_id, bool(message.is_extended_frame))] = \
                    (channel, message)
        except Exception as exc:  # decoded frames are a convenience; the raw ones still go
            logger.warning("live view without decoded CAN frames: %s", exc)
        self._tap = _Tap(QUEUE_FRAMES)
        if base is not None:
            base.bus.add_listener(self._tap, sent=True)
        elif sim.network.notifier is not None:
            sim.network.notifier.add_listener(self._tap)
        self._stop = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="omnican-foxglove", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def _make_channel(self, topic: str, schema: str) -> Any:
        import foxglove

        if schema in telemetry.JSON_SCHEMAS:
            return foxglove.Channel(topic, schema=telemetry.JSON_SCHEMAS[schema],
                                    context=self._ctx)
        return foxglove.Channel(
            topic, schema=foxglove.Schema(name=schema, encoding="ros2msg",
                                          data=rosmsg.msgdef(schema).encode()),
            message_encoding="cdr", context=self._ctx)

    # ------------------------------------------------------------ publishing

    def _publish_state(self) -> None:
        if self.base is not None:
            sample = telemetry.sample(self.base, self.sim)
            ns = sample.stamp_ns
            items = telemetry.messages(sample, self._frames_cfg, self._radius)
        else:
            ns = time.time_ns()
            p = self.sim.true_pose
            items = [("/sim/true_pose", telemetry.pose_stamped(ns, p, self._frames_cfg.odom)),
                     ("/sim/pose2d", telemetry.pose2d(ns, p))]
        for topic, message in items:
            channel = self._channels.get(topic)
            if channel is None or not channel.has_sinks():
                continue
            schema, kind = telemetry.TOPICS[topic]
            if kind == telemetry.JSON:
                channel.log(message, log_time=ns)
            else:
                channel.log(rosmsg.encode(schema, message), log_time=ns)

    def _publish_frames(self) -> None:
        queue = self._tap.queue
        rx, tx = self._channels[telemetry.CAN_RX], self._channels[telemetry.CAN_TX]
        raw = {True: rx.has_sinks(), False: tx.has_sinks()}
        while queue:
            msg = queue.popleft()
            ns = int(msg.timestamp * 1e9)
            if raw[bool(msg.is_rx)]:
                data = rosmsg.encode_can_frame(
                    ns, msg.arbitration_id, bytes(msg.data),
                    str(msg.channel) if msg.channel is not None else self._channel_name,
                    extended=msg.is_extended_id, remote=msg.is_remote_frame,
                    error=msg.is_error_frame)
                (rx if msg.is_rx else tx).log(data, log_time=ns)
            found = self._decoded.get((msg.arbitration_id, bool(msg.is_extended_id)))
            if found is None or msg.is_remote_frame or msg.is_error_frame:
                continue
            channel, message = found
            if not channel.has_sinks() or len(msg.data) != message.length:
                continue
            try:
                values = message.decode(bytes(msg.data), decode_choices=False)
            except Exception:  # a frame the DBC cannot decode: the raw topic has it
                continue
            out = {"timestamp": telemetry.json_time(ns)}
            out.update({k: float(v) for k, v in values.items()})
            channel.log(json.dumps(out).encode(), log_time=ns)

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                self._publish_frames()
                if time.monotonic() >= next_t:
                    next_t = max(next_t + self._period, time.monotonic())
                    self._publish_state()
            except Exception:  # the view must never take the robot down
                logger.exception("live view: publishing failed")
            self._stop.wait(min(0.01, self._period))

    # ------------------------------------------------------------ closing

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.base is not None:
            self.base.bus.remove_listener(self._tap)
        elif self.sim.network.notifier is not None:
            with contextlib.suppress(ValueError):
                self.sim.network.notifier.remove_listener(self._tap)
        self._stop.set()
        self._thread.join()
        self._server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextlib.contextmanager
def watch(base: Any, sim: Any = None, foxglove: str | None = None, announce: Any = None,
          frames: telemetry.Frames | None = None) -> Iterator[LiveView | None]:
    """What a front end adds around a running base: the simulator's ground truth into an
    MCAP recording, and a Foxglove server when ``foxglove`` (``[HOST:]PORT``) is given.
    ``frames``: the odometry and body frame names (default odom, base_link).
    ``announce(text)`` is told where the server listens."""
    recorder = getattr(base.bus, "recorder", None) if base is not None else None
    if sim is not None and hasattr(recorder, "attach"):
        recorder.attach(base, sim, frames)  # type: ignore[union-attr]
    if foxglove is None:
        yield None
        return
    try:
        host, port = parse_address(foxglove)
    except ValueError as exc:
        raise ConfigError(f"--foxglove: {exc}") from None
    with LiveView(base, sim, host=host, port=port, frames=frames) as view:
        if announce is not None:
            announce(f"Foxglove: open a connection to {view.url} "
                     "(layout: foxglove/omnican-layout.json)")
        yield view


def foxglove_address(text: str) -> str:
    """argparse type for ``--foxglove [HOST:]PORT``: checked here, so a bad address or a
    missing SDK is a usage error before any drive is touched."""
    import argparse
    import importlib.util

    try:
        parse_address(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if importlib.util.find_spec("foxglove") is None:
        from omnican.extras import install_hint

        raise argparse.ArgumentTypeError(f"needs the Foxglove SDK: {install_hint('foxglove')}")
    return text


FOXGLOVE_HELP = ("serve a live view to Foxglove on [HOST:]PORT (default 127.0.0.1:8765; "
                 "loopback unless a host is given, e.g. 0.0.0.0:8765 to watch from another "
                 "machine)")
