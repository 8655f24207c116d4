"""CAN frames as messages: raw (``can_msgs/msg/Frame`` on ``/from_can_bus`` and
``/to_can_bus``, the names of ROS 2's socketcan bridge) and, for each frame the base's DBC
describes, decoded (``/can/<message name>``, JSON, one number per signal).

:class:`FrameTap` is what the bus hands frames to: received ones on the receiving
thread, sent ones on the sending thread (the control loop's), as plain values; it only
appends them to a bounded queue. :class:`FrameMessages` turns a batch of them into
messages, on the telemetry's thread.
"""

from __future__ import annotations

import collections
import json
import logging
from collections.abc import Callable
from typing import Any

import can

from omnican.telemetry import messages as m
from omnican.telemetry.model import Message

logger = logging.getLogger("omnican.telemetry")

QUEUE_FRAMES = 100_000  # about 10 s of a busy 1 Mbit/s bus
# timestamp (s, the base's clock), COB-ID, data, channel, extended, remote, error, received
Frame = tuple[float, int, bytes, Any, bool, bool, bool, bool]


class FrameTap(can.Listener):
    """Frames into a bounded queue; a full queue drops (and counts) rather than waits."""

    def __init__(self, size: int = QUEUE_FRAMES) -> None:
        self.queue: collections.deque[Frame] = collections.deque()
        self.size = size
        self.dropped = 0

    def on_message_received(self, msg: can.Message) -> None:
        queue = self.queue
        if len(queue) >= self.size:
            self.dropped += 1
            return
        queue.append((msg.timestamp, msg.arbitration_id, bytes(msg.data), msg.channel,
                      msg.is_extended_id, msg.is_remote_frame, msg.is_error_frame, msg.is_rx))

    def record_sent(self, timestamp: float, can_id: int, data: bytes, channel: Any) -> None:
        """A frame this host sent, as plain values (no message made on the control loop)."""
        queue = self.queue
        if len(queue) >= self.size:
            self.dropped += 1
            return
        queue.append((timestamp, can_id, data, channel, can_id > 0x7FF, False, False, False))

    def take(self) -> list[Frame]:
        """Everything queued so far, oldest first."""
        queue, out = self.queue, []
        while queue:
            out.append(queue.popleft())
        return out

    def stop(self) -> None:
        """Called by a Notifier when it stops: the tap stays for the next one."""


def _signal_schema(message: Any) -> dict[str, Any]:
    props: dict[str, Any] = {"timestamp": {"type": "object", "properties": {
        "sec": {"type": "integer"}, "nsec": {"type": "integer"}}}}
    for sig in message.signals:
        props[sig.name] = {"type": "number", "description": sig.comment or ""}
    return {"title": f"omnican.can.{message.name}", "type": "object", "properties": props}


class FrameMessages:
    """Frames -> raw and decoded messages. ``database``: the base's DBC (a cantools
    database), made on first need by ``make_database`` (about a second of CPU)."""

    def __init__(self, channel: str, make_database: Callable[[], Any] | None = None) -> None:
        self.channel = channel
        self._make_database = make_database
        self._database: Any = None
        self._by_id: dict[tuple[int, bool], Any] = {}

    @property
    def database(self) -> Any:
        if self._database is None and self._make_database is not None:
            make, self._make_database = self._make_database, None
            try:
                self._database = make()
            except Exception as exc:  # decoded frames are a convenience; raw ones still go
                logger.warning("no decoded CAN frames: %s", exc)
                return None
            self._by_id = {(msg.frame_id, bool(msg.is_extended_frame)): msg
                           for msg in self._database.messages}
        return self._database

    def decoded_topics(self) -> dict[str, dict[str, Any]]:
        """``/can/<name>`` -> its JSON schema, for every message of the DBC."""
        db = self.database
        if db is None:
            return {}
        return {m.CAN_DECODED_PREFIX + msg.name: _signal_schema(msg) for msg in db.messages}

    def messages(self, frames: list[Frame], wants: Callable[[str], bool]) -> list[Message]:
        from omnican.telemetry import cdr

        raw = {True: wants(m.CAN_RX), False: wants(m.CAN_TX)}
        decode = self.database is not None
        out: list[Message] = []
        for stamp, can_id, data, channel, extended, remote, error, rx in frames:
            ns = int(stamp * 1e9)
            if raw[rx]:
                out.append(Message(m.CAN_RX if rx else m.CAN_TX, m.CAN_FRAME, m.ROS2, ns, None,
                                   cdr.encode_can_frame(
                                       ns, can_id, data,
                                       str(channel) if channel is not None else self.channel,
                                       extended=extended, remote=remote, error=error)))
            if not decode or remote or error:
                continue
            message = self._by_id.get((can_id, extended))
            if message is None or len(data) != message.length:
                continue
            topic = m.CAN_DECODED_PREFIX + message.name
            if not wants(topic):
                continue
            try:
                values = message.decode(data, decode_choices=False)
            except Exception:  # a frame the DBC cannot decode: the raw topic has it
                continue
            body: dict[str, Any] = {"timestamp": m.json_time(ns)}
            body.update({k: float(v) for k, v in values.items()})
            out.append(Message(topic, f"omnican.can.{message.name}", m.JSON, ns, body,
                               json.dumps(body).encode()))
        return out
