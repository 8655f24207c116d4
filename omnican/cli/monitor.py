"""omnican monitor: live decode of the bus through a DBC file (cantools).

One row per CAN id seen: frame count, rate (frames/s over the last second), and the
last frame's signals, decoded with the DBC (--dbc; default: one built from --config
for that robot's drives, else the bundled omnican.dbc, which describes the demo base,
nodes 1-3) or shown as raw hex for ids it does not describe. With the table (above
it in a terminal, below it in plain text), the bus load: worst-case bits per second
(bit stuffing included) and, when the bitrate is known ([bus] bitrate or -b), its
share of it.

The monitor only listens. Under --sim nothing else would be on the virtual bus,
so it also opens the simulated base and drives it slowly in a circle, to have
traffic to show. In a terminal the table updates in place; otherwise (pipe, file)
a plain-text table is printed every --interval seconds and a summary at the end.
--record FILE keeps every frame it hears (plot and calibrate --fit read it).
Ctrl-C or SIGTERM ends it (exit 0).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import sys
import time
from collections.abc import Iterator, Sequence
from typing import Any

from omnican.analysis.traffic import (
    DEFAULT_DBC,
    TrafficCounter,
    TrafficSnapshot,
    listening,
    load_dbc,
)
from omnican.cli.common import EXIT_OK, positive_float
from omnican.cli.session import add_bus_arguments, add_record_argument, load, session

logger = logging.getLogger(__name__)

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
    add_record_argument(p, "record every frame heard to FILE")
    add_bus_arguments(p, sim_help="monitor a simulated base in this process, driven slowly "
                                  "in a circle (a virtual bus; no hardware)")
    p.set_defaults(func=run)


def load_lines(snap: TrafficSnapshot, no_bitrate: str) -> list[str]:
    """The bus load and the totals, in words (``no_bitrate``: what to say instead of
    the share of the bitrate when it is unknown)."""
    kbit = snap.window_bits_per_s / 1000.0
    if snap.load is not None and snap.bitrate:
        share = f"{100.0 * snap.load:.1f}% of {snap.bitrate / 1000:g} kbit/s"
    else:
        share = no_bitrate
    total = (f"total: {snap.frames} frames in {snap.elapsed:.1f} s, mean "
             f"{snap.mean_bits_per_s / 1000.0:.1f} kbit/s")
    if snap.error_frames:
        total += f", {snap.error_frames} error frames"
    return [f"bus load: {kbit:.1f} kbit/s worst case over the last {snap.window_s:.1f} s "
            f"({share})", total]


# ------------------------------------------------------------------ the display


HEADERS = ("ID", "Name", "Count", "Rate/s", "Signals (last frame)")


def plain_table(snap: TrafficSnapshot, title: str, no_bitrate: str) -> str:
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
    out += load_lines(snap, no_bitrate)
    return "\n".join(out)


# Lines of the screen besides the rows: the title, two of bus load, the table's top
# border, header and rule, its bottom border, and the line that counts rows left out.
_FRAME_LINES = 8


def rich_table(snap: TrafficSnapshot, title: str, no_bitrate: str,
               height: int | None = None, width: int | None = None) -> Any:
    """The title, the bus load (the headline, above the table: a table taller than the
    screen hid it until exit) and one line per id, as many as fit ``height`` lines."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    table = Table()
    rows = snap.rows
    # The short columns keep their widths; the signals give way (one line a row).
    widths = [max([len(HEADERS[0])] + [len(r.id_text) for r in rows]),
              min(22, max([len(HEADERS[1])] + [len(r.name or "?") for r in rows])),
              max([len(HEADERS[2])] + [len(str(r.count)) for r in rows]),
              max([len(HEADERS[3])] + [len(f"{r.rate:.1f}") for r in rows])]
    table.add_column(HEADERS[0], style="bold", no_wrap=True, width=widths[0])
    table.add_column(HEADERS[1], no_wrap=True, overflow="ellipsis", width=widths[1])
    table.add_column(HEADERS[2], justify="right", no_wrap=True, width=widths[2])
    table.add_column(HEADERS[3], justify="right", no_wrap=True, width=widths[3])
    # 6 borders and a space either side of each of the 5 columns
    signals_width = None if width is None else max(10, width - sum(widths) - 16)
    table.add_column(HEADERS[4], no_wrap=True, overflow="ellipsis", width=signals_width)
    room = len(rows) if height is None else max(1, height - _FRAME_LINES)
    shown = rows if len(rows) <= room else rows[:room]
    for r in shown:
        style = "" if r.known else "dim"
        table.add_row(r.id_text, Text(r.name or "?", style="cyan" if r.known else "dim"),
                      str(r.count), f"{r.rate:.1f}", Text(r.signals, style=style))
    if not rows:
        table.add_row("", Text("(no frames seen)", style="dim"), "", "", "")
    parts: list[Any] = [Text(title, style="bold", no_wrap=True, overflow="ellipsis")]
    parts += [Text(line, no_wrap=True, overflow="ellipsis") for line in load_lines(snap,
                                                                                   no_bitrate)]
    parts.append(table)
    if len(shown) < len(rows):
        parts.append(Text(f"... {len(rows) - len(shown)} more ids (a taller terminal shows "
                          "them)", style="dim"))
    return Group(*parts)


class _Display:
    """A rich Live table in a terminal; otherwise a plain table every ``interval``."""

    def __init__(self, source: str, interval: float, tty: bool, no_bitrate: str) -> None:
        self.source = source
        self.no_bitrate = no_bitrate
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

    def title(self, snap: TrafficSnapshot, final: bool) -> str:
        what = "summary" if final else "live"
        return f"omnican monitor ({what}, {snap.elapsed:.1f} s) on {self.source}"

    def show(self, snap: TrafficSnapshot, final: bool = False) -> None:
        if self._live is not None:
            self._live.update(rich_table(snap, self.title(snap, final), self.no_bitrate,
                                         self._live.console.height,
                                         self._live.console.width), refresh=True)
        elif not self.tty:
            print(plain_table(snap, self.title(snap, final), self.no_bitrate) + "\n", flush=True)


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
        from omnican.plan.dbc import build_database

        db = build_database(configured)
    else:
        db = load_dbc(DEFAULT_DBC)
    with session(args) as s:
        bus_kwargs = dict(s.cfg.bus or {})
        rate = bus_kwargs.get("bitrate") or (configured.bus or {}).get("bitrate")
        no_bitrate = "bitrate unknown: give -b for the load in %"  # --sim has one
        monitor = TrafficCounter(db, int(rate) if rate else None)
        display = _Display(_bus_name(bus_kwargs, s.sim is not None), args.interval,
                           sys.stdout.isatty(), no_bitrate)
        deadline = None if args.duration is None else monitor.start + args.duration
        with contextlib.ExitStack() as stack:
            more = []
            if args.record:  # what the monitor hears, recorded
                from omnican.record.recording import recording_frames

                more.append(stack.enter_context(recording_frames(args.record, s.cfg)))
            stack.enter_context(listening(bus_kwargs, monitor, *more))
            stack.enter_context(display.opened())
            try:
                _loop(s, monitor, display, deadline)
            except KeyboardInterrupt:
                pass
            display.show(monitor.snapshot(), final=True)
    return EXIT_OK


def _loop(s: Any, monitor: TrafficCounter, display: _Display, deadline: float | None) -> None:
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
