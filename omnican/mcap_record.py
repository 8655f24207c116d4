"""MCAP recordings: every CAN frame plus the robot's state, in one file that Foxglove
opens and ROS 2's bag tools read (``pip install 'omnican[mcap]'``).

A recording is a front end like the live view: a sink of the base's telemetry
(:mod:`omnican.telemetry.feed`), so it holds exactly what the live view shows, with the
same stamps (profile ``ros2``; ROS 2 types are CDR with ``ros2msg`` schemas):

* ``/from_can_bus`` and ``/to_can_bus``: every frame received and sent, as
  ``can_msgs/msg/Frame`` (the message and topic names of ROS 2's socketcan bridge), and
  ``/can/<message>``, each frame the base's DBC describes, decoded (JSON);
* the state topics of :data:`omnican.telemetry.TOPICS` (``/odom``, ``/tf``,
  ``/joint_states``, ``/diagnostics`` as ROS 2 types; ``/pose2d``, ``/twist``, ``/wheels``,
  ``/status`` as schemaless JSON) at the telemetry's state rate, in the base's clock;
* attachment ``omnican.dbc`` (the base's frames, for any DBC tool) and metadata
  ``omnican`` (version, bus channel, frames).

Writing happens on the telemetry's thread (in lock-step, on the clock's), never on the
control loop. A crash must not take the recording with it: the writer closes its chunk
and hands the file to the operating system at least every :data:`FLUSH_EVERY_S` of the
clock the messages carry (a chunk that fills sooner goes at once), so a killed process
loses about the last second. Only a clean close writes the summary and footer.

:func:`read_frames` reads the frames back as :class:`can.Message` objects for
:mod:`omnican.replay` (``omnican plot``, ``omnican calibrate --fit``); from a recording
cut short or damaged it reads what comes before the damage and says how much it could
not (:func:`read_recording` gives both).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import can

from omnican import rosmsg, telemetry
from omnican.config import ChassisConfig
from omnican.errors import ConfigError
from omnican.telemetry.model import Message

logger = logging.getLogger(__name__)

FLUSH_EVERY_S = 1.0  # the longest a message waits in the open chunk: what a crash loses
MCAP_MAGIC = b"\x89MCAP0\r\n"


class McapRecorder:
    """Writes what the telemetry publishes to ``path`` (a :class:`~omnican.telemetry.Sink`;
    ``cfg``: the base, whose DBC goes into the file)."""

    def __init__(self, path: str | Path, cfg: ChassisConfig | None = None) -> None:
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError:
            from omnican.extras import install_hint

            raise ConfigError(f"recording to {path} needs the MCAP packages: "
                              f"{install_hint('mcap')}") from None
        rosmsg.typestore()  # import errors surface here, not on the telemetry's thread
        self.path = Path(path)
        try:
            self._file: IO[bytes] = self.path.open("wb")
        except OSError as exc:
            raise ConfigError(f"cannot record to {path}: {exc.strerror or exc}") from None
        from omnican import __version__

        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library=f"omnican {__version__}")
        self.frames = 0
        self.error: str | None = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._channel_name = str(((cfg.bus if cfg else None) or {}).get("channel", ""))
        self._flushed_ns: int | None = None
        self._lock = threading.Lock()
        self._closed = False
        if cfg is not None:
            try:
                from omnican.dbcgen import dbc_text

                now = time.time_ns()
                self._writer.add_attachment(now, now, "omnican.dbc", "text/x-dbc",
                                            dbc_text(cfg).encode())
            except Exception as exc:  # a DBC is a convenience; the frames are what counts
                logger.warning("recording without a DBC: %s", exc)

    # ------------------------------------------------------------ the sink

    def wants(self, topic: str) -> bool:
        return not self._closed and self.error is None

    def publish(self, messages: list[Message]) -> None:
        with self._lock:
            if self._closed or self.error is not None:
                return
            try:
                add = self._writer.add_message
                for msg in messages:
                    add(self._channel(msg), log_time=msg.stamp_ns, data=msg.payload(),
                        publish_time=msg.stamp_ns)
                    if msg.data is None:
                        self.frames += 1
                if messages:
                    ns = messages[-1].stamp_ns
                    if self._flushed_ns is None:
                        self._flushed_ns = ns
                    elif ns - self._flushed_ns >= FLUSH_EVERY_S * 1e9:  # the chunk, to disk
                        self._flushed_ns = ns
                        self._writer.flush()
            except Exception as exc:  # a full disk must not stop the robot: report, stop
                self.error = str(exc)
                logger.error("recording to %s stopped: %s", self.path, exc)

    def _schema(self, msg: Message) -> int:
        if msg.kind == telemetry.JSON:
            # Schemaless JSON (schema id 0): Foxglove reads it all the same, and ROS 2 bag
            # readers pass it through, where a "jsonschema" schema makes some (rosbags) fail.
            return 0
        sid = self._schemas.get(msg.schema)
        if sid is None:
            sid = self._writer.register_schema(msg.schema, "ros2msg",
                                               rosmsg.msgdef(msg.schema).encode())
            self._schemas[msg.schema] = sid
        return sid

    def _channel(self, msg: Message) -> int:
        cid = self._channels.get(msg.topic)
        if cid is None:
            encoding = "json" if msg.kind == telemetry.JSON else "cdr"
            cid = self._writer.register_channel(msg.topic, encoding, self._schema(msg))
            self._channels[msg.topic] = cid
        return cid

    # ------------------------------------------------------------ closing

    def close(self, dropped_frames: int = 0) -> None:
        """Write the file's index (and, in its metadata, the frames that never reached
        it: ``dropped_frames``). Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                from omnican import __version__

                self._writer.add_metadata("omnican", {
                    "version": __version__, "channel": self._channel_name,
                    "frames": str(self.frames), "dropped_frames": str(dropped_frames)})
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
