"""Bus traffic, counted: per-id frame counts and rates, the bus load, DBC decoding.

:class:`TrafficCounter` is a ``can.Listener``: attach it to any Notifier (or open a
bus of its own with :func:`listening`) and take :meth:`TrafficCounter.snapshot`\\ s
from another thread. Rates and the bus load are over a sliding window; bits are the
worst case on the wire, bit stuffing included. :func:`decode` turns a frame into
its message name and signal text with a cantools database (:func:`load_dbc`), and
names frames a database lacks after CANopen's predefined connection set.

Nothing here prints; ``omnican monitor`` renders the snapshots.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

import omnican
from omnican.errors import BusError, ConfigError
from omnican.io.bus_watch import describe_open_error
from omnican.plan.pdo import frame_bits
from omnican.protocol import cia402
from omnican.protocol.cia301 import canopen_name

#: The bundled DBC: the PDO frames of the demo base (nodes 1-3, bundled EDS).
DEFAULT_DBC = Path(omnican.__file__).resolve().parent / "dbc" / "omnican.dbc"

RATE_WINDOW_S = 1.0  # rates and bus load are over this sliding window


# ------------------------------------------------------------------ the database


def load_dbc(path: str | Path) -> Any:
    """The cantools CAN database in ``path``; a ConfigError naming the file if unusable."""
    import cantools

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--dbc {path}: no such file")
    try:
        db = cantools.database.load_file(str(path))
    except OSError as exc:
        raise ConfigError(f"--dbc {path}: cannot read it: {exc.strerror or exc}") from None
    except Exception as exc:  # cantools raises parse errors of many kinds, often multi-line
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"--dbc {path}: not a database cantools can read: {first[:160]}") \
            from None
    if not isinstance(db, cantools.database.can.Database):
        raise ConfigError(f"--dbc {path}: not a CAN database")
    return db


def _format_value(name: str, value: Any, unit: str | None) -> str:
    lname = name.lower()
    if isinstance(value, int) and lname == "statusword":
        return f"0x{value:04X} {cia402.decode_state(value)}"
    if isinstance(value, int) and lname == "controlword":
        command = cia402.decode_command(value)
        named = f" {command.name.lower().replace('_', ' ')}" if command else ""
        return f"0x{value:04X}{named}"
    # ints as they are; a NamedSignalValue (a choice) as its name
    text = f"{value:.6g}" if isinstance(value, float) else str(value)
    return f"{text} {unit}" if unit and not hasattr(value, "name") else text


def decode(db: Any, can_id: int, extended: bool, data: bytes) -> tuple[str, str]:
    """(message name, signals text) of one frame; raw hex when the DBC lacks the id or
    its length does not match."""
    raw = data.hex(" ").upper() if data else "(no data)"
    try:
        message = db.get_message_by_frame_id(can_id)
    except KeyError:
        message = None
    if message is None or bool(message.is_extended_frame) != extended:
        return "", raw
    if len(data) != message.length:
        return message.name, f"{raw}  (length {len(data)}, DBC says {message.length})"
    try:
        values = message.decode(data, decode_choices=True, scaling=True)
    except Exception as exc:  # cantools' decode errors; show the frame rather than fail
        return message.name, f"{raw}  (cannot decode: {exc})"
    units = {s.name: s.unit for s in message.signals}
    return message.name, "  ".join(
        f"{name}={_format_value(name, value, units.get(name))}" for name, value in values.items())


# ------------------------------------------------------------------ the counting


@dataclass
class _IdStats:
    """What was seen of one CAN id (the listener's own bookkeeping)."""

    can_id: int
    extended: bool
    count: int = 0
    data: bytes = b""
    remote: bool = False  # the last frame was a remote request
    times: deque[float] = field(default_factory=deque)  # receive times within the window


@dataclass(frozen=True)
class IdRow:
    """One CAN id in a snapshot: ``name`` from the DBC (``known``) or from CANopen's
    predefined connection set; ``rate`` frames/s over the window; ``signals`` the last
    frame decoded (raw hex where the DBC does not describe it)."""

    can_id: int
    extended: bool
    name: str
    known: bool
    count: int
    rate: float
    signals: str

    @property
    def id_text(self) -> str:
        return f"0x{self.can_id:08X}" if self.extended else f"0x{self.can_id:03X}"


@dataclass(frozen=True)
class TrafficSnapshot:
    """The traffic since the counter started (``elapsed`` s). ``window_bits_per_s``:
    worst-case bits per second over the last ``window_s``; ``load``: its share of
    ``bitrate`` (None when the bitrate is unknown)."""

    elapsed: float
    window_s: float
    rows: tuple[IdRow, ...]
    frames: int
    error_frames: int
    window_bits_per_s: float
    mean_bits_per_s: float
    bitrate: int | None

    @property
    def load(self) -> float | None:
        return self.window_bits_per_s / self.bitrate if self.bitrate else None


class TrafficCounter(can.Listener):
    """Counts frames per CAN id (called from a Notifier's thread); thread-safe snapshots.

    ``db``: a cantools database to decode with (None: raw hex and CANopen names);
    ``bitrate``: bit/s, for the load (None: unknown)."""

    def __init__(self, db: Any = None, bitrate: int | None = None,
                 window_s: float = RATE_WINDOW_S) -> None:
        self.db = db
        self.bitrate = bitrate
        self.window_s = window_s
        self.start = time.monotonic()
        self._lock = threading.Lock()
        self._ids: dict[tuple[int, bool], _IdStats] = {}
        self._bits: deque[tuple[float, int]] = deque()
        self._total_bits = 0
        self._frames = 0
        self._error_frames = 0

    def on_message_received(self, msg: can.Message) -> None:
        now = time.monotonic()
        with self._lock:
            if msg.is_error_frame:
                self._error_frames += 1
                return
            key = (msg.arbitration_id, bool(msg.is_extended_id))
            stats = self._ids.get(key)
            if stats is None:
                stats = self._ids[key] = _IdStats(*key)
            stats.count += 1
            stats.data = bytes(msg.data)
            stats.remote = bool(msg.is_remote_frame)
            stats.times.append(now)
            cutoff = now - self.window_s
            while stats.times[0] < cutoff:
                stats.times.popleft()
            bits = frame_bits(len(msg.data))
            self._bits.append((now, bits))
            self._total_bits += bits
            self._frames += 1
            self._prune(now)

    def stop(self) -> None:
        """Called by the Notifier when it stops; the counts stay readable."""

    def _prune(self, now: float) -> None:
        cutoff = now - self.window_s
        while self._bits and self._bits[0][0] < cutoff:
            self._bits.popleft()

    def snapshot(self) -> TrafficSnapshot:
        now = time.monotonic()
        elapsed = max(now - self.start, 1e-6)
        span = min(self.window_s, elapsed)
        cutoff = now - self.window_s
        with self._lock:
            self._prune(now)
            window_bits = sum(b for _, b in self._bits)
            seen = []
            for stats in self._ids.values():
                while stats.times and stats.times[0] < cutoff:
                    stats.times.popleft()
                seen.append((stats.can_id, stats.extended, stats.count, len(stats.times),
                             stats.data, stats.remote))
            frames, errors, total_bits = self._frames, self._error_frames, self._total_bits
        rows = []
        for can_id, extended, count, recent, data, remote in sorted(seen,
                                                                    key=lambda s: (s[1], s[0])):
            if self.db is not None:
                name, signals = decode(self.db, can_id, extended, data)
            else:
                name, signals = "", data.hex(" ").upper() if data else "(no data)"
            if remote:
                signals = "(remote request)"
            rows.append(IdRow(can_id, extended, name or canopen_name(can_id, extended),
                              bool(name), count, recent / span, signals))
        return TrafficSnapshot(elapsed, span, tuple(rows), frames, errors, window_bits / span,
                               total_bits / elapsed, self.bitrate)


@contextlib.contextmanager
def listening(bus_kwargs: Mapping[str, Any], listener: can.Listener,
              *more: can.Listener) -> Iterator[can.BusABC]:
    """A bus of our own (``can.Bus(**bus_kwargs)``) on which ``listener`` (and ``more``)
    hear every frame; closed on exit. A bus that does not open is a BusError."""
    try:
        bus = can.Bus(**bus_kwargs)
    except Exception as exc:  # python-can raises many kinds for a bad interface/channel
        raise BusError(describe_open_error(bus_kwargs, exc)) from None
    try:
        notifier = can.Notifier(bus, [listener, *more], timeout=0.1)
        try:
            yield bus
        finally:
            notifier.stop(1.0)
    finally:
        bus.shutdown()
