"""Reading a recording of the bus: every python-can log format by extension, and
``.mcap``. A recording cut short (the recording process killed) or damaged is read up to
the damage (a candump ``.log`` line by line: only the damaged lines are lost), with one
warning saying how much could not be read (:func:`~omnican.record.can_log.cut_note`).
The only I/O of replaying; :mod:`omnican.record.replay` decodes what this reads.
"""

from __future__ import annotations

import logging
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
    try:
        if p.suffix.lower() == ".blf":  # python-can's BLFReader leaks its file on a bad header
            with p.open("rb") as f:
                if f.read(4) != b"LOGG":
                    raise RecordingError(f"{p}: not a readable .blf recording: no BLF header")
        if p.suffix.lower() == ".log":
            frames, lines, bad = _read_candump(p)
            if lines and frames:
                note = cut_note(frames, bad, lines)
            elif lines:
                raise ValueError("no line is a frame")
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


def _read_candump(p: Path) -> tuple[list[Any], int, int]:
    """A candump ``.log`` line by line: its frames, and the number of lines (and bytes)
    that were no frame: damaged, or cut off at the end."""
    from can.io.canutils import CanutilsLogReader

    frames: list[Any] = []
    with p.open("rb") as raw:
        lines = _CandumpLines(raw)
        while True:
            taken = lines.taken
            try:
                frames.extend(CanutilsLogReader(cast(TextIO, lines)))
                break
            except Exception:  # that line is no frame: go on with the next one
                if lines.taken == taken:  # not a line's fault
                    raise
                lines.count_bad(lines.last)
    return frames, lines.bad_lines, lines.bad_bytes


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
