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
:mod:`omnican.record.replay` (``omnican plot``, ``omnican calibrate --fit``); from a recording
cut short or damaged it reads what comes before the damage and says how much it could
not (:func:`read_recording` gives both).
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import IO

from omnican import telemetry
from omnican.config import ChassisConfig
from omnican.errors import ConfigError
from omnican.telemetry import cdr
from omnican.telemetry.model import Message

logger = logging.getLogger(__name__)

FLUSH_EVERY_S = 1.0  # the longest a message waits in the open chunk: what a crash loses


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
        cdr.typestore()  # import errors surface here, not on the telemetry's thread
        self.path = Path(path)
        try:
            self._file: IO[bytes] = self.path.open("wb")
        except OSError as exc:
            raise ConfigError(f"cannot record to {path}: {exc.strerror or exc}") from None
        from omnican import __version__

        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile=telemetry.ROS2, library=f"omnican {__version__}")
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
                from omnican.plan.dbc import dbc_text

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
            sid = self._writer.register_schema(msg.schema, cdr.SCHEMA_ENCODING,
                                               cdr.msgdef(msg.schema).encode())
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
