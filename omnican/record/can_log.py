"""Recordings of a bus: the frames, to a python-can log file (:class:`LogRecorder`:
``.log`` candump text, ``.asc``, ``.blf``, ``.csv``, ...), and reading them back. (Frames
and the robot's state go to an MCAP file, :mod:`omnican.record.mcap`, a telemetry sink;
:mod:`omnican.record.recording` picks by the file's extension.)

A recorder never holds up the bus or the control loop: frames go into a bounded queue
and a writer thread of its own turns them into lines; a full queue drops and counts.
"""

from __future__ import annotations

import bisect
import collections
import logging
import math
import struct
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from omnican.errors import ConfigError
from omnican.protocol.cia301 import COB_ID_MASK
from omnican.telemetry.messages import CAN_FRAME, CAN_RX, CAN_TX

logger = logging.getLogger("omnican.io.bus")

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
    # Frames come from two threads (the loop's sent frames, the Notifier's received ones)
    # and reach the queue a little out of time order: the newest this long are held for
    # the next batch, so that each batch is written in time order (a candump .log went
    # back by up to 0.34 ms on 16 of 3,115 lines).
    REORDER_S = 0.05

    def __init__(self, path: Path) -> None:
        try:
            self._writer: can.Listener | None = can.Logger(str(path))
        except (ValueError, OSError) as exc:  # unknown suffix, unwritable place
            raise ConfigError(f"cannot record to {path}: {exc}") from None
        self.path = path
        self.dropped = 0
        self._queue: collections.deque[can.Message | SentFrame] = collections.deque()
        self._held: list[can.Message | SentFrame] = []  # the newest, for the next batch
        self._last_t = -math.inf  # the timestamp written last
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
                self._drain(final=True)
                return

    def _in_time_order(self, final: bool) -> list[can.Message | SentFrame]:
        """What is queued and held, sorted by time; the newest REORDER_S are held back
        (unless ``final``); a frame older than one already written gets that one's time."""
        queue, batch = self._queue, self._held
        while queue:
            batch.append(queue.popleft())
        batch.sort(key=_stamp)
        self._held = []
        if not final and batch:
            cut = bisect.bisect_right(batch, _stamp(batch[-1]) - self.REORDER_S, key=_stamp)
            batch, self._held = batch[:cut], batch[cut:]
        out: list[can.Message | SentFrame] = []
        for item in batch:
            t = _stamp(item)
            if t < self._last_t:  # later than REORDER_S: written at the last time, not back
                out.append(_restamped(item, self._last_t))
            else:
                self._last_t = t
                out.append(item)
        return out

    def _drain(self, final: bool = False) -> None:
        writer = self._writer
        # candump's .log, the default: lines made here and written a batch at a time
        # (python-can's writer makes the same line, one write per frame).
        log = writer if type(writer) is can.CanutilsLogWriter else None
        lines: list[str] = []
        for item in self._in_time_order(final):
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


def _stamp(item: can.Message | SentFrame) -> float:
    return (item.timestamp or 0.0) if isinstance(item, can.Message) else item[0]


def _restamped(item: can.Message | SentFrame, t: float) -> can.Message | SentFrame:
    if not isinstance(item, can.Message):
        return (t, *item[1:])
    return can.Message(timestamp=t, arbitration_id=item.arbitration_id,
                       is_extended_id=item.is_extended_id, is_remote_frame=item.is_remote_frame,
                       is_error_frame=item.is_error_frame, dlc=item.dlc, data=item.data,
                       is_rx=item.is_rx, channel=item.channel, is_fd=item.is_fd)


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


# ------------------------------------------------------------------ reading back

MCAP_MAGIC = b"\x89MCAP0\r\n"


def size_text(n: int) -> str:
    """A byte count as people read it: 1 byte, 812 bytes, 12 KB, 3.4 MB."""
    if n < 1024:
        return f"{n} byte{'s' if n != 1 else ''}"
    return f"{n / 1024:.0f} KB" if n < 1024 * 1024 else f"{n / 1024 / 1024:.1f} MB"


def cut_note(frames: Sequence[Any], unreadable: int | None, lines: int | None = None,
             timeless: int = 0) -> str:
    """What to say of a recording that could not be read whole (after its name):
    ``read 5.1 s of frames; the rest (12 KB) is damaged or cut off`` (``unreadable``
    bytes; None: unknown). ``lines``: the damaged lines a text log left out
    (``unreadable`` bytes of them). ``timeless``: frames left out because their time is
    no number (NaN, inf)."""
    stamps = [f.timestamp for f in frames]
    read = f"read {max(stamps) - min(stamps) if stamps else 0.0:.1f} s of frames"
    if timeless:
        read += (f"; {timeless} frame{'s' if timeless != 1 else ''} with no valid time "
                 "left out")
        if lines is None:
            return read
    if lines is not None:
        return (f"{read}; {lines} damaged or cut-off line{'s' if lines != 1 else ''} "
                f"({size_text(unreadable or 0)}) left out")
    if unreadable is None:
        return f"{read}; the rest is damaged or cut off"
    if unreadable == 0:
        return f"{read}; the file ends there, cut off (never closed)"
    return f"{read}; the rest ({size_text(unreadable)}) is damaged or cut off"


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


def read_mcap(path: str | Path) -> RecordingRead:
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
                elif isinstance(record, Schema) and record.name == CAN_FRAME:
                    frame_schemas.add(record.id)
                elif isinstance(record, Channel) and record.schema_id in frame_schemas and \
                        record.topic in (CAN_RX, CAN_TX):
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
    from omnican.telemetry import cdr

    ns, can_id, payload, name, extended, remote, error = cdr.decode_can_frame(data)
    return can.Message(timestamp=ns / 1e9, arbitration_id=can_id, data=payload,
                       is_extended_id=extended, is_remote_frame=remote, is_error_frame=error,
                       channel=name or None, is_rx=topic == CAN_RX, check=False)


def mcap_frames(path: str | Path) -> list[can.Message]:
    """The CAN frames of an MCAP recording, in file order; of a damaged or cut-off one,
    those before the damage, with one warning saying how much could not be read. Raises
    ImportError without the mcap package; ValueError if no frame can be read."""
    read = read_mcap(path)
    if not read.frames and read.problem:
        raise ValueError(read.problem)
    if not read.whole and read.frames:
        logger.warning("%s: %s", path, cut_note(read.frames, read.unreadable))
    return read.frames
