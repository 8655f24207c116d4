"""Reading a recording of the bus: every python-can log format by extension, and
``.mcap``. A recording cut short (the recording process killed) or damaged is read up to
the damage (a text log line by line: only the damaged lines are lost), with one warning
saying how much could not be read (:func:`~omnican.record.can_log.cut_note`). How each
format shows it was cut: a text log's last line has no end (and an ``.asc`` no ``end
triggerblock``), a ``.blf``'s header gives its size when it was closed (and none when it
never was), an MCAP file has its footer. A frame whose time is no number (NaN, inf) is
damaged too: it is left out and counted.
The only I/O of replaying; :mod:`omnican.record.replay` decodes what this reads.
"""

from __future__ import annotations

import io
import logging
import math
import struct
from pathlib import Path
from typing import IO, Any, TextIO, cast

from omnican.errors import RecordingError
from omnican.record.can_log import cut_note, size_text

logger = logging.getLogger("omnican.record.replay")  # the name its warnings always had


# What each python-can log format looks like, for the error of an unreadable file.
_FORMATS = {
    ".log": "candump -L lines such as '(1700000000.000000) can0 181#0637'",
    ".asc": "a Vector ASC text log",
    ".blf": "a Vector BLF binary log",
    ".csv": "python-can CSV rows: timestamp,arbitration_id,extended,remote,error,dlc,data",
    ".trc": "a PEAK PCAN-View trace",
}


def read_frames(path: str | Path) -> list[Any]:
    """Every frame of a recording (format by extension: .log, .asc, .blf, ..., .mcap);
    of one cut short or damaged, what could be read, with one warning (:func:`cut_note`).

    Raises RecordingError (one line) for a missing, unreadable or empty file or an
    unknown format."""
    frames, note = read_recording(path)
    if note:
        logger.warning("%s: %s", path, note)
    return frames


def read_recording(path: str | Path) -> tuple[list[Any], str | None]:
    """The frames of a recording, and what could not be read of it (:func:`cut_note`;
    None: nothing)."""
    import can

    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"recording not found: {p}")
    if p.suffix.lower() == ".mcap":
        return _read_mcap(p)
    note = None
    suffix = p.suffix.lower()
    try:
        if suffix == ".blf":  # python-can's BLFReader leaks its file on a bad header
            with p.open("rb") as f:
                if f.read(4) != b"LOGG":
                    raise RecordingError(f"{p}: not a readable .blf recording: no BLF header")
        if suffix == ".log":
            frames, lines, bad, timeless = _read_candump(p)
            if lines and frames:
                note = cut_note(frames, bad, lines)
            elif timeless:
                raise RecordingError(f"{p}: no CAN frame with a valid time ({timeless} "
                                     "lines whose time is no number, such as '(nan)')")
            elif lines:
                raise ValueError("no line is a frame")
        elif suffix in _TEXT_READERS:
            frames, note = _read_text_log(p, suffix)
        else:
            frames = []
            reader = can.LogReader(str(p))
            with reader:
                try:
                    for frame in reader:
                        frames.append(frame)
                except Exception:
                    if not frames:
                        raise
                    note = cut_note(frames, None)
            timeless = _drop_timeless(frames)
            if suffix == ".blf" and frames and note is None:
                note = _blf_cut(p, frames)
            if timeless and frames:
                note = cut_note(frames, None, timeless=timeless)
    except OSError as exc:
        raise RecordingError(f"cannot read recording {p}: {exc.strerror or exc}") from None
    except RecordingError:
        raise
    except Exception as exc:  # unknown suffix (ValueError); the readers raise many kinds
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "unknown log format" in text:
            raise RecordingError(f"{p}: {text}") from None
        # The reader's own words ("not enough values to unpack") say nothing to a user.
        logger.debug("reading %s: %s: %s", p, type(exc).__name__, text)
        expected = _FORMATS.get(p.suffix.lower())
        hint = f" (expected {expected})" if expected else ""
        raise RecordingError(f"{p}: not a readable {p.suffix or 'CAN'} recording{hint}") \
            from None
    if not frames:
        raise RecordingError(f"{p}: no CAN frames in the recording")
    return frames, note


class _CandumpLines:
    """The lines of a candump log for python-can's reader, as text; a line that is no
    text, or the last one when the file does not end with a newline (cut off mid-line),
    is counted and left out here."""

    def __init__(self, raw: IO[bytes]) -> None:
        self._raw = raw
        self.bad_lines = 0
        self.bad_bytes = 0
        self.taken = 0  # lines handed to the reader
        self.last = b""

    def __iter__(self) -> _CandumpLines:
        return self

    def __next__(self) -> str:
        for line in self._raw:
            if line.endswith(b"\n"):
                try:
                    text = line.decode("ascii")
                except UnicodeDecodeError:
                    pass
                else:
                    self.last = line
                    self.taken += 1
                    return text
            self.count_bad(line)
        raise StopIteration

    def count_bad(self, line: bytes) -> None:
        self.bad_lines += 1
        self.bad_bytes += len(line)

    def close(self) -> None:
        """The reader closes its file when done; the file is the caller's."""


def _read_candump(p: Path) -> tuple[list[Any], int, int, int]:
    """A candump ``.log`` line by line: its frames, the number of lines (and bytes) that
    were no frame: damaged (a time that is no number included), or cut off at the end,
    and how many of those were frames whose time is no number."""
    from can.io.canutils import CanutilsLogReader

    frames: list[Any] = []
    timeless = 0
    with p.open("rb") as raw:
        lines = _CandumpLines(raw)
        while True:
            taken = lines.taken
            try:
                for frame in CanutilsLogReader(cast(TextIO, lines)):
                    if math.isfinite(frame.timestamp):
                        frames.append(frame)
                    else:  # "(nan)": the line it came from (the reader reads one a frame)
                        lines.count_bad(lines.last)
                        timeless += 1
                break
            except Exception:  # that line is no frame: go on with the next one
                if lines.taken == taken:  # not a line's fault
                    raise
                lines.count_bad(lines.last)
    return frames, lines.bad_lines, lines.bad_bytes, timeless


def _text_readers() -> dict[str, Any]:
    import can

    return {".asc": can.ASCReader, ".csv": can.CSVReader, ".trc": can.TRCReader}


_TEXT_READERS = (".asc", ".csv", ".trc")


class _FailedLines(logging.Filter):
    """Counts (and keeps out of the log) the lines python-can's TRC reader could not
    parse: it logs each one and goes on, in words that are its own."""

    def __init__(self) -> None:
        super().__init__()
        self.lines = 0
        self.bytes = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if str(record.msg).startswith("TRCReader: Failed to parse message"):
            self.lines += 1
            args = record.args if isinstance(record.args, tuple) else ()
            self.bytes += len(str(args[0])) + 1 if args else 0
            return False
        return True


def _read_text_log(p: Path, suffix: str) -> tuple[list[Any], str | None]:
    """An ``.asc``, ``.csv`` or ``.trc`` log: its frames, and what to say of what could not
    be read: a last line with no end (cut off mid-line, left out), lines the reader could
    not parse, no ``end triggerblock`` at the end of an ``.asc`` (never closed)."""
    raw = p.read_bytes()
    cut_lines = cut_bytes = 0
    if raw and not raw.endswith(b"\n"):
        keep = raw.rfind(b"\n") + 1
        cut_lines, cut_bytes, raw = 1, len(raw) - keep, raw[:keep]
    text = raw.decode("utf-8", errors="replace")
    failed = _FailedLines()
    trc_log = logging.getLogger("can.io.trc")
    trc_log.addFilter(failed)
    frames: list[Any] = []
    stopped = False
    try:
        with _text_readers()[suffix](io.StringIO(text)) as reader:
            try:
                for frame in reader:
                    frames.append(frame)
            except Exception:
                if not frames:
                    raise
                stopped = True  # the rest is unreadable from here on
    finally:
        trc_log.removeFilter(failed)
    bad_lines = cut_lines + failed.lines
    timeless = _drop_timeless(frames)
    if not frames:
        return frames, None
    if stopped:
        return frames, cut_note(frames, None)
    if bad_lines or timeless:
        return frames, cut_note(frames, cut_bytes + failed.bytes, bad_lines or None,
                                timeless=timeless)
    if suffix == ".asc" and "end triggerblock" not in text[-200:].lower():
        return frames, cut_note(frames, 0)
    return frames, None


def _drop_timeless(frames: list[Any]) -> int:
    """Leave out, in place, the frames whose time is no number; how many there were."""
    kept = [f for f in frames if math.isfinite(f.timestamp)]
    dropped = len(frames) - len(kept)
    if dropped:
        frames[:] = kept
    return dropped


#: A BLF file's header: its signature, then (little-endian) the file's size when the
#: writer closed it, at byte 16 (python-can writes the header size there until then).
_BLF_SIZE = struct.Struct("<Q")
_BLF_SIZE_AT, _BLF_HEADER = 16, 144


def _blf_cut(p: Path, frames: list[Any]) -> str | None:
    """What to say of a ``.blf`` that is not as long as its header says, or was never
    closed (its header still gives the header's size); None when it is whole."""
    with p.open("rb") as f:
        head = f.read(_BLF_SIZE_AT + _BLF_SIZE.size)
    if len(head) < _BLF_SIZE_AT + _BLF_SIZE.size:
        return None
    (closed_size,) = _BLF_SIZE.unpack_from(head, _BLF_SIZE_AT)
    size = p.stat().st_size
    if closed_size <= _BLF_HEADER < size:
        return cut_note(frames, 0)  # never closed: it ends where the writer stopped
    if closed_size > size:
        return cut_note(frames, closed_size - size)
    return None


def _read_mcap(p: Path) -> tuple[list[Any], str | None]:
    """The CAN frames of an MCAP recording (``--record run.mcap``)."""
    try:
        from omnican.record.can_log import read_mcap
        read = read_mcap(p)
    except ImportError:
        from omnican.extras import install_hint

        raise RecordingError(f"{p}: reading MCAP needs {install_hint('mcap')}") from None
    except OSError as exc:
        raise RecordingError(f"cannot read recording {p}: {exc.strerror or exc}") from None
    if not read.frames:
        if read.problem.startswith("not an MCAP file"):
            raise RecordingError(f"{p}: not a readable .mcap recording: {read.problem}")
        if not read.whole:
            raise RecordingError(
                f"{p}: no CAN frames in the recording: it is cut off or damaged before the "
                f"first ones ({size_text(read.size - read.unreadable)} of {size_text(read.size)} "
                "readable)")
        raise RecordingError(f"{p}: no CAN frames in the recording (no /from_can_bus or "
                             "/to_can_bus messages)")
    return read.frames, None if read.whole else cut_note(read.frames, read.unreadable)
