"""Recordings of a bus: the frames, to a python-can log file (:class:`LogRecorder`:
``.log`` candump text, ``.asc``, ``.blf``, ``.csv``, ...), or frames and the robot's
state to an MCAP file (the MCAP front end, :mod:`omnican.mcap_record`, a telemetry sink).
:func:`open_recording` picks by the file's extension.

A recorder never holds up the bus or the control loop: frames go into a bounded queue
and a writer thread of its own turns them into lines; a full queue drops and counts.
"""

from __future__ import annotations

import collections
import contextlib
import importlib
import logging
import struct
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can

from omnican.cia301 import COB_ID_MASK
from omnican.config import ChassisConfig
from omnican.errors import ConfigError

logger = logging.getLogger("omnican.bus")

#: Recording formats that are front ends of their own (extension -> "module:Class"):
#: made by name, so the bus layer needs nothing of theirs.
FRONT_END_RECORDERS = {".mcap": "omnican.mcap_record:McapRecorder"}


def open_recording(path: str | Path, cfg: ChassisConfig | None = None) -> Any:
    """The recorder for ``path``'s format: an MCAP recording (frames and the robot's
    state: a telemetry sink; ``cfg``'s DBC goes along) or a :class:`LogRecorder`
    (frames, any python-can format). Raises ConfigError for a path it cannot write."""
    path = Path(path)
    target = FRONT_END_RECORDERS.get(path.suffix.lower())
    if target is not None:
        module, _, name = target.partition(":")
        return getattr(importlib.import_module(module), name)(path, cfg)
    return LogRecorder(path)


@contextlib.contextmanager
def recording_frames(path: str | Path, cfg: ChassisConfig) -> Iterator[can.Listener]:
    """A listener that records the frames it is handed to ``path`` (any format
    :func:`open_recording` takes), for a front end that listens to a bus of its own
    (``omnican monitor``); closed, with the file, when the block ends."""
    recorder = open_recording(path, cfg)
    if not records_state(recorder):
        try:
            yield recorder
        finally:
            recorder.close()
        return
    from omnican.clock import REAL_TIME
    from omnican.dbcgen import database_for
    from omnican.telemetry import Feed, TelemetrySettings

    feed = Feed(TelemetrySettings.from_config(cfg), cfg.kinematics(), REAL_TIME,
                make_database=lambda: database_for(cfg), has_base=False)
    try:
        feed.add(recorder)
        yield feed.frames
    finally:
        feed.close()
        recorder.close()


def records_state(recorder: Any) -> bool:
    """Whether ``recorder`` records the robot's state too (a telemetry sink), not only
    the frames."""
    return hasattr(recorder, "publish")


class LogRecorder(can.Listener):
    """Writes frames to a python-can log file on a thread of its own; survives Notifier
    restarts (reconnects).

    The threads that see frames (the control loop, the Notifier) only append them to a
    bounded queue: a slow disk (an SD card) must never stall the loop. When the queue
    is full, frames are dropped and counted (:attr:`dropped`)."""

    QUEUE_FRAMES = 100_000  # about 20 s of a busy 1 Mbit/s bus
    # The writer wakes for a batch this big, or this often: each wake-up of a thread is
    # a few tens of microseconds on a small computer (or a VM), per cycle if it wakes
    # for every few frames.
    BATCH_FRAMES = 1024
    WRITE_EVERY_S = 0.2

    def __init__(self, path: Path) -> None:
        try:
            self._writer: can.Listener | None = can.Logger(str(path))
        except (ValueError, OSError) as exc:  # unknown suffix, unwritable place
            raise ConfigError(f"cannot record to {path}: {exc}") from None
        self.path = path
        self.dropped = 0
        self._queue: collections.deque[can.Message | SentFrame] = collections.deque()
        self._wake = threading.Event()
        self._closing = False
        self._thread = threading.Thread(target=self._write_loop, name="omnican-recorder",
                                        daemon=True)
        self._thread.start()

    def on_message_received(self, msg: can.Message) -> None:
        self._put(msg)

    def record_sent(self, timestamp: float, can_id: int, data: bytes, channel: Any) -> None:
        """A frame this host sent: queued as plain values, made into a message (or a log
        line) on the writer thread, not on the control loop."""
        self._put((timestamp, can_id, data, channel))

    def _put(self, item: can.Message | SentFrame) -> None:
        queue = self._queue
        if len(queue) >= self.QUEUE_FRAMES:
            self.dropped += 1
            return
        queue.append(item)  # deque.append is atomic: no lock on the sending threads
        if len(queue) >= self.BATCH_FRAMES and not self._wake.is_set():
            self._wake.set()

    def _write_loop(self) -> None:
        while True:
            self._wake.wait(self.WRITE_EVERY_S)
            self._wake.clear()
            self._drain()
            if self._closing:
                self._drain()
                return

    def _drain(self) -> None:
        queue = self._queue
        writer = self._writer
        # candump's .log, the default: lines made here and written a batch at a time
        # (python-can's writer makes the same line, one write per frame).
        log = writer if type(writer) is can.CanutilsLogWriter else None
        lines: list[str] = []
        while queue:
            item = queue.popleft()
            if self._writer is None:
                continue
            if log is not None:
                line = log_line(log, item)
                if line is not None:
                    lines.append(line)
                    continue
                self._write_lines(log, lines)  # keep the order around a frame it writes
                lines = []
            self._write(item if isinstance(item, can.Message) else sent_message(item))
        if lines and log is not None:
            self._write_lines(log, lines)

    def _write_lines(self, log: can.CanutilsLogWriter, lines: list[str]) -> None:
        if not lines or self._writer is None:
            return
        try:
            log.file.write("".join(lines))
            log.file.flush()  # whole lines to the OS each batch: a crash loses only the queue
        except Exception as exc:  # a full disk must not take the bus down with it
            logger.error("recording to %s stopped: %s", self.path, exc)
            self._writer = None

    def _write(self, msg: can.Message) -> None:
        writer = self._writer
        if writer is None:
            return
        try:
            writer.on_message_received(msg)
        except (struct.error, ValueError, OverflowError):
            # BLF stores the channel as a 16-bit number taken from the trailing digits
            # of its name ("omnican-sim-95857398" overflows): write it without one.
            try:
                writer.on_message_received(can.Message(
                    timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                    is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                    is_error_frame=msg.is_error_frame, dlc=msg.dlc, data=msg.data,
                    is_rx=msg.is_rx, channel=None))
            except Exception as exc:  # a broken log must not take the bus down with it
                logger.error("recording to %s stopped: %s", self.path, exc)
                self._writer = None
        except Exception as exc:
            logger.error("recording to %s stopped: %s", self.path, exc)
            self._writer = None

    def stop(self) -> None:
        """Called by the Notifier when it stops: keep writing after a reconnect."""

    def close(self) -> None:
        """Write what is queued, then close the file (idempotent)."""
        if self._closing:
            return
        self._closing = True
        self._wake.set()
        self._thread.join(timeout=10.0)
        if self._writer is not None:
            self._writer.stop()
            self._writer = None
        if self.dropped:
            logger.warning("recording to %s dropped %d frames (the disk did not keep up)",
                           self.path, self.dropped)


SentFrame = tuple[float, int, bytes, Any]  # timestamp, COB-ID, data, channel


def sent_message(frame: SentFrame) -> can.Message:
    """The message of a frame this host sent."""
    timestamp, can_id, data, channel = frame
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=can_id > COB_ID_MASK,
                       timestamp=timestamp, is_rx=False, channel=channel)


FrameFields = tuple[float, int, "bytes | bytearray", Any, bool, bool, bool, bool]


def frame_fields(item: can.Message | SentFrame) -> FrameFields:
    """(timestamp, COB-ID, data, channel, extended, remote, error, received) of a frame
    a recorder queued: a received message, or a frame this host sent (plain values)."""
    if isinstance(item, tuple):
        timestamp, can_id, data, channel = item
        return timestamp, can_id, data, channel, can_id > COB_ID_MASK, False, False, False
    return (item.timestamp, item.arbitration_id, item.data, item.channel, item.is_extended_id,
            item.is_remote_frame, item.is_error_frame, item.is_rx)


def log_line(log: can.CanutilsLogWriter, item: can.Message | SentFrame) -> str | None:
    """The line python-can's candump writer ``log`` writes for ``item`` (and the same
    time-keeping), or None for a frame it formats otherwise (error, remote, CAN FD)."""
    if not isinstance(item, tuple) and item.is_fd:
        return None
    timestamp, can_id, data, channel, extended, remote, error, rx = frame_fields(item)
    if remote or error:
        return None
    if log.last_timestamp is None:  # python-can keeps the first frame's time as its floor
        log.last_timestamp = timestamp or 0.0
    if timestamp is None or timestamp < log.last_timestamp:
        timestamp = log.last_timestamp
    if channel is None:
        channel = log.channel
    if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
        channel = f"can{channel}"
    ident = f"{can_id:08X}" if extended else f"{can_id:03X}"
    return f"({timestamp:f}) {channel} {ident}#{data.hex().upper()}{' R' if rx else ' T'}\n"
