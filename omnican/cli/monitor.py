"""``omnican monitor``: live decode of the bus through a DBC file (cantools).

One row per CAN id seen: frame count, rate (frames/s over the last second), and the
last frame's signals, decoded with the DBC (default: the bundled ``omnican.dbc``,
which describes the demo base, nodes 1-3) or shown as raw hex for ids it does not
describe. Below the table, the bus load: worst-case bits per second (bit stuffing
included) and, when the bitrate is known (``[bus] bitrate`` or ``-b``), its share of it.

The monitor only listens. Under ``--sim`` nothing else would be on the virtual bus,
so it also opens the simulated base and drives it slowly in a circle, to have
traffic to show. In a terminal the table updates in place; otherwise (pipe, file)
a plain-text table is printed every ``--interval`` seconds and a summary at the end.
Ctrl-C ends it (exit 0).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

import omnican
from omnican import cia402
from omnican.cia301 import canopen_name
from omnican.cli.common import EXIT_OK, add_bus_arguments, load, positive_float, session
from omnican.errors import BusError, ConfigError
from omnican.pdoplan import frame_bits

logger = logging.getLogger(__name__)

#: The bundled DBC: the PDO frames of the demo base (nodes 1-3, bundled EDS).
DEFAULT_DBC = Path(omnican.__file__).resolve().parent / "dbc" / "omnican.dbc"

RATE_WINDOW_S = 1.0  # rates and bus load are over this sliding window
LIVE_REFRESH_S = 0.25  # terminal refresh period
DEMO_PERIOD_S = 0.02  # command period of the --sim demo motion
DEMO_SPEED = 0.1  # m/s forward ...
DEMO_TURN = 0.4  # ... while turning at this rate: a circle of 0.25 m radius


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("monitor", help="live decode of the bus: per-id rates, signals, bus load",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=positive_float, metavar="S",
                   help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument("--dbc", metavar="FILE",
                   help="database to decode with (default: built from --config, else the "
                        "bundled omnican.dbc)")
    p.add_argument("--interval", type=positive_float, default=1.0, metavar="S",
                   help="when stdout is not a terminal: print the table every S seconds "
                        "(default 1.0)")
    add_bus_arguments(p, sim_help="monitor a simulated base in this process, driven slowly "
                                  "in a circle (a virtual bus; no hardware)")
    p.set_defaults(func=run)


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
class IdStats:
    """What was seen of one CAN id."""

    can_id: int
    extended: bool
    count: int = 0
    data: bytes = b""
    remote: bool = False  # the last frame was a remote request
    times: deque[float] = field(default_factory=deque)  # receive times within the window


@dataclass(frozen=True)
class Row:
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
class Snapshot:
    elapsed: float
    rows: list[Row]
    frames: int
    error_frames: int
    window_bits_per_s: float
    mean_bits_per_s: float
    bitrate: int | None
    no_bitrate: str  # what to say instead of the share of the bitrate

    def load_lines(self) -> list[str]:
        kbit = self.window_bits_per_s / 1000.0
        if self.bitrate:
            share = (f"{100.0 * self.window_bits_per_s / self.bitrate:.1f}% of "
                     f"{self.bitrate / 1000:g} kbit/s")
        else:
            share = self.no_bitrate
        total = (f"total: {self.frames} frames in {self.elapsed:.1f} s, mean "
                 f"{self.mean_bits_per_s / 1000.0:.1f} kbit/s")
        if self.error_frames:
            total += f", {self.error_frames} error frames"
        return [f"bus load: {kbit:.1f} kbit/s worst case over the last "
                f"{min(RATE_WINDOW_S, self.elapsed):.1f} s ({share})", total]


class Monitor(can.Listener):
    """Counts frames per CAN id (called from the Notifier's thread) and renders snapshots."""

    def __init__(self, db: Any, bitrate: int | None, window_s: float = RATE_WINDOW_S,
                 no_bitrate: str = "bitrate unknown: give -b for the load in %") -> None:
        self.db = db
        self.bitrate = bitrate
        self.no_bitrate = no_bitrate
        self.window_s = window_s
        self.start = time.monotonic()
        self._lock = threading.Lock()
        self._ids: dict[tuple[int, bool], IdStats] = {}
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
                stats = self._ids[key] = IdStats(*key)
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
        pass

    def _prune(self, now: float) -> None:
        cutoff = now - self.window_s
        while self._bits and self._bits[0][0] < cutoff:
            self._bits.popleft()

    def snapshot(self) -> Snapshot:
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
            name, signals = decode(self.db, can_id, extended, data)
            if remote:
                signals = "(remote request)"
            rows.append(Row(can_id, extended, name or canopen_name(can_id, extended), bool(name),
                            count, recent / span, signals))
        return Snapshot(elapsed, rows, frames, errors, window_bits / span, total_bits / elapsed,
                        self.bitrate, self.no_bitrate)


# ------------------------------------------------------------------ the display


HEADERS = ("ID", "Name", "Count", "Rate/s", "Signals (last frame)")


def plain_table(snap: Snapshot, title: str) -> str:
    """The table as plain text (for pipes, files and tests)."""
    cells = [(r.id_text, r.name or "?", str(r.count), f"{r.rate:.1f}", r.signals)
             for r in snap.rows]
    widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, h in enumerate(HEADERS[:-1])]
    right = (False, False, True, True)

    def line(values: Sequence[str]) -> str:
        parts = [v.rjust(w) if r else v.ljust(w)
                 for v, w, r in zip(values[:-1], widths, right, strict=True)]
        return "  ".join([*parts, values[-1]]).rstrip()

    out = [title, line(HEADERS)]
    out += [line(c) for c in cells]
    if not cells:
        out.append("(no frames seen)")
    out += snap.load_lines()
    return "\n".join(out)


def rich_table(snap: Snapshot, title: str) -> Any:
    from rich.table import Table
    from rich.text import Text

    table = Table(title=Text(title, style="bold"), caption=Text("\n".join(snap.load_lines())),
                  title_justify="left", caption_justify="left")
    table.add_column(HEADERS[0], style="bold", no_wrap=True)
    table.add_column(HEADERS[1], no_wrap=True)
    table.add_column(HEADERS[2], justify="right", no_wrap=True)
    table.add_column(HEADERS[3], justify="right", no_wrap=True)
    table.add_column(HEADERS[4], overflow="fold")
    for r in snap.rows:
        style = "" if r.known else "dim"
        table.add_row(r.id_text, Text(r.name or "?", style="cyan" if r.known else "dim"),
                      str(r.count), f"{r.rate:.1f}", Text(r.signals, style=style))
    if not snap.rows:
        table.add_row("", Text("(no frames seen)", style="dim"), "", "", "")
    return table


class _Display:
    """A rich Live table in a terminal; otherwise a plain table every ``interval``."""

    def __init__(self, source: str, interval: float, tty: bool) -> None:
        self.source = source
        self.tty = tty
        self.period = LIVE_REFRESH_S if tty else interval
        self._live: Any = None

    @contextlib.contextmanager
    def opened(self) -> Iterator[_Display]:
        if not self.tty:
            yield self
            return
        from rich.console import Console
        from rich.live import Live

        # A console of our own: the width and terminal of now, not of an earlier caller.
        with Live(console=Console(), auto_refresh=False, transient=False) as live:
            self._live = live
            try:
                yield self
            finally:
                self._live = None

    def title(self, snap: Snapshot, final: bool) -> str:
        what = "summary" if final else "live"
        return f"omnican monitor ({what}, {snap.elapsed:.1f} s) on {self.source}"

    def show(self, snap: Snapshot, final: bool = False) -> None:
        if self._live is not None:
            self._live.update(rich_table(snap, self.title(snap, final)), refresh=True)
        elif not self.tty:
            print(plain_table(snap, self.title(snap, final)) + "\n", flush=True)


# ------------------------------------------------------------------ running


class _Demo:
    """Under --sim: the simulated base, opened and driven slowly in a circle."""

    def __init__(self, base: Any) -> None:
        self.base = base
        self._warned = False

    def step(self) -> None:
        reason = self.base.status.stopped_reason
        if reason and not self._warned:
            logger.warning("the demo base stopped: %s", reason)
            self._warned = True
        self.base.set_velocity(DEMO_SPEED, 0.0, DEMO_TURN)


def _pause(seconds: float) -> None:
    time.sleep(seconds)


def _bus_name(bus_kwargs: dict[str, Any], sim: bool) -> str:
    if sim:
        return "the simulated base (virtual bus)"
    if not bus_kwargs:
        return "python-can's configured bus"
    where = [str(bus_kwargs[k]) for k in ("interface", "channel") if bus_kwargs.get(k)]
    return " ".join(where) or "the configured bus"


@contextlib.contextmanager
def listening(bus_kwargs: dict[str, Any], monitor: Monitor) -> Iterator[can.BusABC]:
    """A bus of our own on which ``monitor`` hears every frame; closed on exit."""
    try:
        bus = can.Bus(**bus_kwargs)
    except Exception as exc:  # python-can raises many kinds for a bad interface/channel
        where = ", ".join(f"{k}={v}" for k, v in bus_kwargs.items()) or \
            "python-can's configuration"
        raise BusError(f"cannot open CAN bus ({where}): {exc}") from None
    try:
        notifier = can.Notifier(bus, [monitor], timeout=0.1)
        try:
            yield bus
        finally:
            notifier.stop(1.0)
    finally:
        bus.shutdown()


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except KeyboardInterrupt:  # Ctrl-C while starting or closing: everything is unwound
        return EXIT_OK


def _run(args: argparse.Namespace) -> int:
    configured = load(args)  # the bitrate of --config, for the load under --sim too
    if args.dbc:
        db = load_dbc(args.dbc)
    elif args.config:  # this robot's own frames: vendor mappings decode under their names
        from omnican.dbcgen import build_database

        db = build_database(configured)
    else:
        db = load_dbc(DEFAULT_DBC)
    with session(args) as s:
        bus_kwargs = dict(s.cfg.bus or {})
        rate = bus_kwargs.get("bitrate") or (configured.bus or {}).get("bitrate")
        no_bitrate = ("a virtual bus has no bitrate; a --config with [bus] bitrate gives "
                      "the load in %" if s.sim is not None else
                      "bitrate unknown: give -b for the load in %")
        monitor = Monitor(db, int(rate) if rate else None, no_bitrate=no_bitrate)
        display = _Display(_bus_name(bus_kwargs, s.sim is not None), args.interval,
                           sys.stdout.isatty())
        deadline = None if args.duration is None else monitor.start + args.duration
        with listening(bus_kwargs, monitor), display.opened():
            try:
                _loop(s, monitor, display, deadline)
            except KeyboardInterrupt:
                pass
            display.show(monitor.snapshot(), final=True)
    return EXIT_OK


def _loop(s: Any, monitor: Monitor, display: _Display, deadline: float | None) -> None:
    with contextlib.ExitStack() as stack:
        demo = None
        if s.sim is not None:
            from omnican.chassis import Chassis

            demo = _Demo(stack.enter_context(Chassis.open(s.cfg)))
        step = DEMO_PERIOD_S if demo is not None else min(display.period, 0.1)
        next_show = monitor.start + display.period
        while True:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                return
            if demo is not None:
                demo.step()
            if now >= next_show:
                display.show(monitor.snapshot())
                next_show += display.period * max(1, math.ceil((now - next_show) /
                                                               display.period))
            wait = min(step, next_show - now)
            if deadline is not None:
                wait = min(wait, deadline - now)
            _pause(max(0.0, wait))
