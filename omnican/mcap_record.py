"""MCAP recordings: every CAN frame plus the robot's state, in one file that Foxglove
opens and ROS 2's bag tools read (``pip install 'omnican[mcap]'``).

What a recording holds (profile ``ros2``; ROS 2 types are CDR with ``ros2msg`` schemas):

* ``/from_can_bus`` and ``/to_can_bus``: every frame received and sent, as
  ``can_msgs/msg/Frame`` (the message and topic names of ROS 2's socketcan bridge);
* the state topics of :data:`omnican.telemetry.TOPICS` (``/odom``, ``/tf``,
  ``/joint_states``, ``/diagnostics`` as ROS 2 types; ``/pose2d``, ``/twist``, ``/wheels``,
  ``/status`` as schemaless JSON), sampled from the running base at ``state_rate_hz``;
* attachment ``omnican.dbc`` (the base's frames, for any DBC tool) and metadata
  ``omnican`` (version, bus channel, dropped frames).

Recording never holds up the bus or the control loop: frames arrive on the Notifier
thread (and the loop thread, for the frames it sends) and only go into a bounded queue;
one writer thread serializes, compresses and writes. When the writer falls behind, frames
are dropped and counted (``dropped``, also in the file's metadata), never waited for.

A crash must not take the recording with it: the writer closes its chunk and hands the
file to the operating system at least every :data:`FLUSH_EVERY_S` (a chunk that fills
sooner goes at once), so a killed process loses about the last second. Only a clean
close writes the summary and footer.

:func:`read_frames` reads the frames back as :class:`can.Message` objects for
:mod:`omnican.replay` (``omnican plot``, ``omnican calibrate --fit``); from a recording
cut short or damaged it reads what comes before the damage and says how much it could
not (:func:`read_recording` gives both).
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import can

from omnican import rosmsg, telemetry
from omnican.bus import SentFrame, frame_fields
from omnican.errors import ConfigError

logger = logging.getLogger(__name__)

QUEUE_FRAMES = 100_000  # ~10 s of a busy 1 Mbit/s bus
STATE_RATE_HZ = 50.0
DIAGNOSTICS_PERIOD_NS = 1_000_000_000
WRITER_IDLE_S = 0.2  # the longest the writer sleeps: frames wait at most this in memory
FLUSH_EVERY_S = 1.0  # the longest a frame waits in the open chunk: what a crash loses
MCAP_MAGIC = b"\x89MCAP0\r\n"


class McapRecorder(can.Listener):
    """Writes frames (and, once :meth:`attach` is called, the base's state) to ``path``."""

    def __init__(self, path: str | Path, *, queue_frames: int = QUEUE_FRAMES,
                 state_rate_hz: float = STATE_RATE_HZ) -> None:
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError:
            from omnican.extras import install_hint

            raise ConfigError(f"recording to {path} needs the MCAP packages: "
                              f"{install_hint('mcap')}") from None
        rosmsg.typestore()  # import errors surface here, not on the writer thread
        self.path = Path(path)
        try:
            self._file: IO[bytes] = self.path.open("wb")
        except OSError as exc:
            raise ConfigError(f"cannot record to {path}: {exc.strerror or exc}") from None
        from omnican import __version__

        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library=f"omnican {__version__}")
        self._queue: collections.deque[can.Message | SentFrame] = collections.deque()
        self._max = queue_frames
        self.dropped = 0
        self.frames = 0
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._source: Callable[[], telemetry.Sample] | None = None
        self._frames_cfg = telemetry.Frames()
        self._radius: tuple[float | None, ...] = ()
        self._period = 1.0 / state_rate_hz
        self._diag_signature: tuple[tuple[Any, Any], ...] | None = None
        self._diag_ns = 0
        self._channel_name = ""
        self._attachments: list[tuple[str, str, bytes]] = []
        self._wake = threading.Event()
        self._stopping = False
        self._closed = False
        self._lock = threading.Lock()
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name="omnican-mcap", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------ producers (never block)

    def on_message_received(self, msg: can.Message) -> None:
        if len(self._queue) >= self._max:
            self.dropped += 1
            return
        self._queue.append(msg)

    def record_sent(self, timestamp: float, can_id: int, data: bytes, channel: Any) -> None:
        """A frame this host sent, as plain values (no message made on the control loop)."""
        if len(self._queue) >= self._max:
            self.dropped += 1
            return
        self._queue.append((timestamp, can_id, data, channel))

    def stop(self) -> None:
        """Called by the Notifier when it stops: keep recording after a reconnect."""

    def attach(self, base: Any, truth: Any = None, frames: telemetry.Frames | None = None) -> None:
        """Record ``base``'s state too (a :class:`omnican.Chassis`; ``truth``: a simulated
        base whose ground truth goes along), and its DBC as an attachment. Calling it again
        (e.g. to add the truth) replaces the source."""
        cfg = base.cfg
        first = self._source is None
        self._radius = tuple(w.wheel_radius for w in cfg.wheels)
        self._channel_name = str((cfg.bus or {}).get("channel", ""))
        if frames is not None:
            self._frames_cfg = frames
        try:
            from omnican.dbcgen import dbc_text

            if first:
                    self._attachments.append(("omnican.dbc", "text/x-dbc",
                                          dbc_text(cfg).encode()))
        except Exception as exc:  # a DBC is a convenience; the frames are what counts
            logger.warning("recording without a DBC: %s", exc)
        self._source = lambda: telemetry.sample(base, truth)

    # ------------------------------------------------------------ the writer thread

    def _schema(self, name: str) -> int:
        if name in telemetry.JSON_SCHEMAS:
            # Schemaless JSON (schema id 0): Foxglove reads it all the same, and ROS 2 bag
            # readers pass it through, where a "jsonschema" schema makes some (rosbags) fail.
            return 0
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._writer.register_schema(name, "ros2msg", rosmsg.msgdef(name).encode())
            self._schemas[name] = sid
        return sid

    def _channel(self, topic: str, schema: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            encoding = "json" if schema in telemetry.JSON_SCHEMAS else "cdr"
            cid = self._writer.register_channel(topic, encoding, self._schema(schema))
            self._channels[topic] = cid
        return cid

    def _write_frames(self) -> None:
        queue = self._queue
        rx = self._channel(telemetry.CAN_RX, telemetry.CAN_FRAME)
        tx = self._channel(telemetry.CAN_TX, telemetry.CAN_FRAME)
        add = self._writer.add_message
        while queue:
            stamp, can_id, payload, channel, extended, remote, error, received = \
                frame_fields(queue.popleft())
            ns = int(stamp * 1e9)
            data = rosmsg.encode_can_frame(
                ns, can_id, bytes(payload),
                str(channel) if channel is not None else self._channel_name,
                extended=extended, remote=remote, error=error)
            add(rx if received else tx, log_time=ns, data=data, publish_time=ns)
            self.frames += 1

    def _write_state(self, sample: telemetry.Sample, last: bool = False) -> None:
        ns = sample.stamp_ns
        for topic, message in telemetry.messages(sample, self._frames_cfg, self._radius):
            if topic == "/diagnostics" and not last and not self._diagnostics_due(ns, message):
                continue
            schema, kind = telemetry.TOPICS[topic]
            data = (json.dumps(message).encode() if kind == telemetry.JSON
                    else rosmsg.encode(schema, message))
            self._writer.add_message(self._channel(topic, schema), log_time=ns, data=data,
                                     publish_time=ns)

    def _diagnostics_due(self, ns: int, message: dict[str, Any]) -> bool:
        """Diagnostics go once a second, as ROS's diagnostic aggregator expects, and at
        once when a level or a message changes (a fault, the bus down). Serializing them
        with every state sample was most of what a recording cost; /wheels and /status
        carry the changing values at the state rate."""
        signature = tuple((st["level"], st["message"]) for st in message["status"])
        if signature == self._diag_signature and ns - self._diag_ns < DIAGNOSTICS_PERIOD_NS:
            return False
        self._diag_signature, self._diag_ns = signature, ns
        return True

    def _run(self) -> None:
        next_state = time.monotonic()
        next_flush = next_state + FLUSH_EVERY_S
        try:
            while True:
                stopping = self._stopping
                while self._attachments:
                    name, media, data = self._attachments.pop(0)
                    now = time.time_ns()
                    self._writer.add_attachment(now, now, name, media, data)
                self._write_frames()
                source = self._source
                if source is not None and (stopping or time.monotonic() >= next_state):
                    next_state = max(next_state + self._period, time.monotonic())
                    self._write_state(source(), last=stopping)
                if stopping:
                    break
                if time.monotonic() >= next_flush:  # the chunk so far, to the disk
                    next_flush = time.monotonic() + FLUSH_EVERY_S
                    self._writer.flush()
                # Sleep until the next state sample is due: a wake-up per sample, not per
                # 10 ms (each one costs tens of microseconds on a small computer).
                due = WRITER_IDLE_S if source is None else next_state - time.monotonic()
                self._wake.wait(min(max(due, 0.0), WRITER_IDLE_S))
        except Exception as exc:  # a full disk must not stop the robot: report, stop writing
            self.error = str(exc)
            logger.error("recording to %s stopped: %s", self.path, exc)
            self._queue.clear()
            self._max = 0

    # ------------------------------------------------------------ closing

    def close(self) -> None:
        """Write what is queued, then the file's index. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stopping = True
        self._wake.set()
        self._thread.join()
        self._max = 0  # late frames (none should come: the bus closes first) are dropped
        try:
            if self.dropped:
                logger.warning("recording to %s dropped %d frames (the writer fell behind)",
                               self.path, self.dropped)
            from omnican import __version__

            self._writer.add_metadata("omnican", {
                "version": __version__, "channel": self._channel_name,
                "frames": str(self.frames), "dropped_frames": str(self.dropped)})
            self._writer.finish()
        except Exception as exc:
            logger.error("finishing %s failed: %s", self.path, exc)
        finally:
            self._file.close()


@dataclass(frozen=True)
class RecordingRead:
    """What :func:`read_recording` could read of a file: ``frames`` in file order, and
    ``unreadable`` bytes at its end (damaged, or cut off mid-record). ``closed``: the
    file ends with its footer (a recording that was closed, not cut short)."""

    frames: list[can.Message]
    size: int
    unreadable: int
    closed: bool
    problem: str  # what the reader met where it stopped; "" when the file is whole

    @property
    def whole(self) -> bool:
        return self.closed and not self.problem


def read_recording(path: str | Path) -> RecordingRead:
    """The CAN frames of an MCAP recording (``/from_can_bus`` and ``/to_can_bus``), read
    record by record up to the first damage (a chunk whose CRC or compression fails, a
    record cut short, bytes that are no record). Raises ImportError without the mcap
    package, OSError if the file cannot be read."""
    from mcap.exceptions import UnsupportedCompressionError
    from mcap.records import Channel, Footer, Message, Schema
    from mcap.stream_reader import StreamReader

    p = Path(path)
    size = p.stat().st_size
    out: list[can.Message] = []
    topics: dict[int, str] = {}  # channel id -> topic, for the CAN frame channels
    frame_schemas: set[int] = set()
    good_end, closed, problem = 0, False, ""
    with p.open("rb") as f:
        # A length beyond the file is damage, not a reason to allocate it.
        reader = StreamReader(f, validate_crcs=True, record_size_limit=size)
        try:
            for record in reader.records:
                if isinstance(record, Message):
                    topic = topics.get(record.channel_id)
                    if topic is not None:
                        out.append(_frame(record.data, topic))
                elif isinstance(record, Schema) and record.name == telemetry.CAN_FRAME:
                    frame_schemas.add(record.id)
                elif isinstance(record, Channel) and record.schema_id in frame_schemas and \
                        record.topic in (telemetry.CAN_RX, telemetry.CAN_TX):
                    topics[record.id] = record.topic
                elif isinstance(record, Footer):
                    closed = True
                good_end = f.tell()  # the records of a chunk come after the whole chunk
        except UnsupportedCompressionError as exc:
            raise ImportError(str(exc)) from None
        except Exception as exc:  # the reader and the decoders raise many kinds
            problem = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        else:
            good_end = f.tell()
    if good_end == 0:
        with p.open("rb") as f:
            if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                problem = "not an MCAP file (it does not start with MCAP's magic bytes)"
    return RecordingRead(out, size, size - good_end, closed, problem)


def _frame(data: bytes, topic: str) -> can.Message:
    ns, can_id, payload, name, extended, remote, error = rosmsg.decode_can_frame(data)
    return can.Message(timestamp=ns / 1e9, arbitration_id=can_id, data=payload,
                       is_extended_id=extended, is_remote_frame=remote, is_error_frame=error,
                       channel=name or None, is_rx=topic == telemetry.CAN_RX, check=False)


def read_frames(path: str | Path) -> list[can.Message]:
    """The CAN frames of an MCAP recording, in file order; of a damaged or cut-off one,
    those before the damage, with one warning saying how much could not be read. Raises
    ImportError without the mcap package; ValueError if no frame can be read."""
    read = read_recording(path)
    if not read.frames and read.problem:
        raise ValueError(read.problem)
    if not read.whole and read.frames:
        from omnican.replay import cut_note

        logger.warning("%s: %s", path, cut_note(read.frames, read.unreadable))
    return read.frames
