"""The teleop dashboard: the screen ``omnican teleop`` draws each frame (header, pose and
twist, the wheels with what each drive reports, the stop line, the keys, the newest
events), as rich renderables. Pure rendering of a base's state: no keys, no terminal
modes (those are :mod:`omnican.cli.teleop`'s). The wheel columns of what a drive reports
come from the table (:data:`omnican.plan.health_fields.HEALTH_FIELDS`).
"""

from __future__ import annotations

import io
import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from rich.console import Console, Group, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from omnican.chassis import Chassis
from omnican.cli.common import fixed
from omnican.cli.terminal import event_lines, events_panel
from omnican.command.teleop import TeleopModel
from omnican.core.kinematics import Twist
from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.protocol.cia402 import State


class EventLines(Protocol):
    """What the dashboard shows of the events: the newest lines, oldest first."""

    @property
    def lines(self) -> Sequence[str]: ...


# The key help under the dashboard, in phrases that are never broken across lines.
HELP_PHRASES = ("u i o / j k l / m , .  move", "Shift: strafe", "q/z w/x e/c: speeds",
                "space/k: stop", "r: recover", "Esc/Ctrl-C: quit")

STATE_STYLE = {
    State.OPERATION_ENABLED: "green",
    State.FAULT: "bold red",
    State.FAULT_REACTION_ACTIVE: "bold red",
    State.QUICK_STOP_ACTIVE: "yellow",
    State.UNKNOWN: "dim",
}


def wrap_phrases(phrases: Sequence[str], width: int, gap: int = 4) -> str:
    """The phrases on lines of at most ``width`` columns, broken only between phrases."""
    lines: list[str] = []
    for phrase in phrases:
        if lines and len(lines[-1]) + gap + len(phrase) <= width:
            lines[-1] += " " * gap + phrase
        else:
            lines.append(phrase)
    return "\n".join(lines)


# Below this width the fault text leaves the wheel table for lines of its own under it,
# so that no row wraps (a wrapped row pushes the newest events off an 80x24 screen).
FAULT_COLUMN_MIN_WIDTH = 110
# The wheel table's columns; their units are in the panel's title (an 80-column screen
# has room for the values, not for units beside each header). What the drives report:
# the values of omnican.plan.health_fields that have a column.
HEALTH_COLUMNS = tuple(f for f in HEALTH_FIELDS if f.column is not None)
WHEEL_COLUMNS = ("wheel", "node", "state", "target", "actual", "travel",
                 *(f.column or "" for f in HEALTH_COLUMNS))
WHEEL_UNITS = "; ".join(("target, actual m/s", "travel m",
                         *(f.legend for f in HEALTH_COLUMNS)))


def bus_back_after_down(status: Any) -> bool:
    """The base is held stopped because the bus went down, and the bus is up again:
    the user's move (r), not a wait."""
    return bool(status.bus_up and (status.stopped_reason or "").startswith("CAN bus down"))


def stop_line(status: Any) -> Text:
    """What the status line says of a latched stop."""
    reason = status.stopped_reason
    if bus_back_after_down(status):
        why = reason[len("CAN bus down"):].strip(" ()")
        return Text(f"STOPPED: the CAN bus is back up - press r to recover (it was down"
                    f"{': ' + why if why else ''})", style="bold yellow", no_wrap=True,
                    overflow="ellipsis")
    if reason.startswith("CAN bus-off") and getattr(status, "can_state", None) != "bus-off":
        return Text("STOPPED: the CAN controller restarted - press r to recover (it was "
                    "bus-off)", style="bold yellow")
    if getattr(status, "estop", False):
        return Text(f"STOPPED: {reason} - release it, then press r", style="bold red")
    if getattr(status, "battery", None) == "cutoff":
        return Text(f"STOPPED: {reason} - charge it, then press r", style="bold red")
    return Text(f"STOPPED: {reason} - press r to recover", style="bold red")


def _height(body: Sequence[RenderableType], width: int) -> int:
    """Lines ``body`` takes at ``width`` columns."""
    console = Console(width=width, file=io.StringIO(), color_system=None)
    return len(console.render_lines(Group(*body), console.options, pad=False))


def _width(renderable: RenderableType) -> int:
    """Columns ``renderable`` takes when it has all it wants (a table's natural width)."""
    console = Console(width=1000, file=io.StringIO(), color_system=None)
    return console.measure(renderable).maximum


@dataclass(eq=False)
class _Block:
    """One part of the screen: kept by ``rank`` (0 first) while the window has room."""

    name: str  # how the too-small note names it when it is left out
    rank: int
    parts: list[RenderableType]
    lines: int = 0


# What gives way first when the window is short, last first: the key help and the speeds
# (in --help too), then the events, the header, the pose, the twist, the wheels, the
# warnings and a note; the state line (RUNNING, STOPPED and why) never.
_RANKS = {"state": 0, "too small": 1, "note": 2, "warnings": 3, "wheels": 4, "twist": 5,
          "pose": 6, "header": 7, "events": 8, "speeds": 9, "keys": 10}
#: The size the whole dashboard is drawn for (the demo base: 3 wheels, a few events).
FULL_SIZE = (80, 24)


def _pose_twist(base: Chassis, command: Twist, width: int) -> tuple[list[_Block], bool]:
    """The pose and the twist: panels side by side, or (narrower than both) lines of
    phrases; True when narrowed to phrases."""
    pose, twist, applied = base.pose, base.twist, base.command
    pose_t = Table.grid(padding=(0, 1))
    pose_t.add_row("x", f"{fixed(pose.x, 3, sign=True):>8} m")
    pose_t.add_row("y", f"{fixed(pose.y, 3, sign=True):>8} m")
    pose_t.add_row("θ", f"{fixed(pose.theta, 3, sign=True):>8} rad "
                        f"({fixed(math.degrees(pose.heading), 1, sign=True):>6}°)")
    fused = base.fused_pose  # an IMU's gyro fused in: its heading beside the wheels'
    if fused is not None:
        pose_t.add_row("θ gyro", f"{fixed(fused.theta, 3, sign=True):>8} rad "
                                 f"({fixed(math.degrees(fused.heading), 1, sign=True):>6}°)")
    tw = Table(box=None, padding=(0, 1))
    for col in ("", "keys", "applied", "measured"):
        tw.add_column(col, justify="right", no_wrap=True)
    unknown = any(w.stale for w in base.wheels)  # no fresh samples: no measured twist
    rows = (("vx", "m/s", command.vx, applied.vx, twist.vx),
            ("vy", "m/s", command.vy, applied.vy, twist.vy),
            ("wz", "rad/s", command.wz, applied.wz, twist.wz))
    for name, unit, a, b, c in rows:
        tw.add_row(f"{name} {unit}", fixed(a, 3, sign=True), fixed(b, 3, sign=True),
                   "-" if unknown else fixed(c, 3, sign=True))
    pose_p = Panel(pose_t, title="pose", title_align="left", expand=False)
    twist_p = Panel(tw, title="twist", title_align="left", expand=False)
    if _width(pose_p) + 2 + _width(twist_p) <= width:
        grid = Table.grid(padding=(0, 2))
        grid.add_row(pose_p, twist_p)
        return [_Block("pose and twist", _RANKS["twist"], [grid])], False
    # Narrower: lines of phrases (three lines, where the panels one above the other
    # would take ten of a window that is likely short too).
    pose_text = Text(wrap_phrases([
        "pose", f"x {fixed(pose.x, 3, sign=True)} m", f"y {fixed(pose.y, 3, sign=True)} m",
        f"θ {fixed(pose.theta, 3, sign=True)} rad "
        f"({fixed(math.degrees(pose.heading), 1, sign=True)}°)",
        *([] if fused is None else [f"θ gyro {fixed(fused.theta, 3, sign=True)} rad"])],
        width, 2))
    lines = [wrap_phrases(["applied", *(f"{name} {fixed(b, 3, sign=True)}"
                                        for name, _, _, b, _ in rows)], width, 1),
             wrap_phrases(["measured", *(f"{name} {'-' if unknown else fixed(c, 3, sign=True)}"
                                         for name, _, _, _, c in rows)], width, 1)]
    return [_Block("pose", _RANKS["pose"], [pose_text]),
            _Block("twist", _RANKS["twist"], [Text("\n".join(lines))])], True


def _wheels(base: Chassis, width: int) -> tuple[RenderableType, bool]:
    """The wheel table, with as many columns as fit ``width`` (what a drive reports gives
    way first, then travel and target), or under a minimum, a line of phrases a wheel;
    True when anything gave way."""
    fault_column = width >= FAULT_COLUMN_MIN_WIDTH
    rows: list[dict[str, Any]] = []
    faults = []
    for w in base.wheels:
        state = Text(str(w.state), style=STATE_STYLE.get(w.state, ""))
        if not w.online:
            state = Text("OFFLINE", style="bold red")
        trouble = w.fault or w.error or ""
        row: dict[str, Any] = {
            "wheel": str(w.index), "node": f"{w.node_id}" + (f".{w.axis}" if w.axis else ""),
            "state": state, "target": fixed(w.target_speed, 3, sign=True),
            "actual": "-" if w.stale else fixed(w.actual_speed, 3, sign=True),
            "travel": fixed(w.travel, 3, sign=True), "fault": Text(trouble, style="red")}
        for reported in HEALTH_COLUMNS:  # what the drive reports
            value = getattr(w, reported.name)
            row[reported.column or ""] = ("-" if value is None else
                                          fixed(value, reported.places, sign=reported.signed))
        rows.append(row)
        if trouble and not fault_column:
            faults.append(f"wheel {w.index}: {trouble}")
    columns = [*WHEEL_COLUMNS, "fault"] if fault_column else list(WHEEL_COLUMNS)
    units = {"target": "target, actual m/s", "travel": "travel m",
             **{f.column or "": f.legend for f in HEALTH_COLUMNS}}
    # What gives way, first to last: the drives' values, travel, the target.
    order = [*reversed([f.column or "" for f in HEALTH_COLUMNS]), "travel", "target"]
    narrowed = False
    while True:
        table = Table(box=None, padding=(0, 1), pad_edge=False)
        for col in columns:
            table.add_column(col, no_wrap=col != "fault",
                             justify="left" if col in ("wheel", "state", "fault") else "right")
        for row in rows:
            table.add_row(*(row[col] for col in columns))
        # (the fault column wraps: only wide windows have it, and it takes what is left)
        fits = "fault" in columns or _width(table) + 4 <= width
        if fits or not order:
            break
        columns.remove(order.pop(0))
        narrowed = True
    if not fits:  # not even wheel, node, state, actual: a wheel a line of phrases
        lines = [wrap_phrases([f"node {r['node']}", r["state"].plain, f"{r['actual']} m/s"],
                              width, 1) for r in rows]
        return Text("\n".join([*lines, *faults])), True
    shown = [units[c] for c in columns if c in units]
    if "target" not in columns:
        shown.insert(0, "actual m/s")
    title = f"wheels ({'; '.join(shown)})"
    if len(title) + 6 > width:
        title = "wheels"
    panel: RenderableType = table
    if faults:  # under the table, wrapped
        panel = Group(table, *(Text(f, style="red") for f in faults))
    return Panel(panel, title=title, title_align="left"), narrowed


def dashboard(base: Chassis, keys: TeleopModel, command: Twist, title: str,
              events: EventLines, note: str, width: int = 120,
              height: int | None = None) -> Group:
    """The screen: header, pose and twist, wheels, status, keys, events (as many of the
    newest as fit ``height`` lines). In a window too small for all of it, the parts give
    way from the key help up (:data:`_RANKS`) and a line says what is hidden; the state
    line (RUNNING, STOPPED and why) is the last to go. Numbers are never cut: a narrow
    window drops whole columns, stacks the panels, or writes them as lines of phrases."""
    st = base.status
    bitrate = base.bus.bitrate
    load = (f"{st.bus_load:.0%} of {bitrate // 1000} kbit/s"
            if st.bus_load is not None and bitrate else
            f"{st.bus_bits_per_s / 1000:.1f} kbit/s (bitrate unknown)")
    # Phrases never broken across lines; the CAN controller's and the battery's in colour
    # when they need attention.
    phrases = [title, f"loop {st.loop_hz:.0f} Hz", f"bus {load}"]
    marked: list[tuple[str, str]] = []
    if st.can_state is not None and st.can_state != "error-active":
        counters = (f" (tx {st.can_tx_errors}, rx {st.can_rx_errors})"
                    if st.can_tx_errors is not None and st.can_rx_errors is not None else "")
        marked.append((f"CAN {st.can_state}{counters}",
                       "bold red" if st.can_state == "bus-off" else "bold yellow"))
    if st.battery_v is not None:
        marked.append((f"battery {st.battery_v:.1f} V",
                       "bold red" if st.battery in ("low", "cutoff") else "dim"))
    header = Text(wrap_phrases(phrases + [text for text, _ in marked], width, 3), style="dim")
    header.stylize("bold not dim", 0, len(title))
    for text, style in marked:
        at = header.plain.rfind(text)
        header.stylize(f"not dim {style}", at, at + len(text))
    if not st.bus_up:
        header.append("   BUS DOWN", style="bold red")

    if st.stopped_reason:
        status = stop_line(st)
    elif st.enabled:
        status = Text("RUNNING", style="bold green")
    else:
        status = Text("starting...", style="yellow")
    settings = Text(wrap_phrases([f"speed {keys.speed:.2f} m/s", f"turn {keys.turn:.2f} rad/s",
                                  f"key timeout {keys.timeout_s:g} s",
                                  f"last key {keys.last_input!r}"], width, 3))
    help_text = Text(wrap_phrases(HELP_PHRASES, width), style="dim")
    motion, squeezed = _pose_twist(base, command, width)
    wheels, narrowed = _wheels(base, width)
    # A note and the warnings wrap: read whole, they cost lines, which the parts of
    # lower rank give up when the window is short.
    blocks = [_Block("header", _RANKS["header"], [header]), *motion,
              _Block("wheels", _RANKS["wheels"], [wheels]),
              _Block("state", _RANKS["state"], [status])]
    if note:
        blocks.append(_Block("note", _RANKS["note"], [Text(note, style="yellow")]))
    blocks += [_Block("speeds", _RANKS["speeds"], [settings]),
               _Block("keys", _RANKS["keys"], [help_text])]
    if st.warnings:
        blocks.append(_Block("warnings", _RANKS["warnings"],
                             [Text(w, style="yellow") for w in st.warnings]))
    lines = list(events.lines)
    if height is None:
        body = [part for b in blocks for part in b.parts]
        if lines:
            body.append(events_panel(lines, width, len(lines) * 8))
        return Group(*body)
    for b in blocks:
        b.lines = _height(b.parts, width)
    state = next(b for b in blocks if b.name == "state")
    if state.lines > height:  # not even the state line whole: as much of it as fits
        cut = textwrap.wrap(status.plain, width)[:max(1, height)]
        cut[-1] = cut[-1][: width - 1] + "…"
        state.parts, state.lines = [Text("\n".join(cut), style=status.style)], len(cut)
    kept, events_lines, hidden = _fit(blocks, lines, width, height)
    if hidden or narrowed or squeezed:  # say so, in the room of what ranks below it
        at = next(i for i, b in enumerate(blocks) if b.name == "state") + 1
        said: list[str] | None = None
        for _ in range(3):  # what it says takes room, which may hide more: say that too
            if said == hidden:
                break
            said = hidden
            _say(blocks, at, _too_small(width, height, hidden, narrowed), width)
            kept, events_lines, hidden = _fit(blocks, lines, width, height)
        if blocks[at] not in kept:  # no room to say what: only that it is too small
            _say(blocks, at, _too_small(width, height, [], False), width)
            kept, events_lines, hidden = _fit(blocks, lines, width, height)
        elif said != hidden:  # it says what it hides, in no more lines than it has
            final = _too_small(width, height, hidden, narrowed)
            if _height([final], width) > blocks[at].lines:
                final = _too_small(width, height, [], False)
            blocks[at].parts = [final]
    body = [part for b in blocks if b in kept for part in b.parts]
    if events_lines:
        body.append(events_panel(lines, width, events_lines))
    return Group(*body)


def _say(blocks: list[_Block], at: int, small: Text, width: int) -> None:
    """The too-small line at ``at`` in ``blocks`` (in place of the one there)."""
    blocks[at:at + (blocks[at].name == "too small")] = [
        _Block("too small", _RANKS["too small"], [small], _height([small], width))]


def _too_small(width: int, height: int, hidden: Sequence[str], narrowed: bool) -> Text:
    parts = [*hidden, *(["some columns"] if narrowed else [])]
    what = f": {', '.join(parts)} hidden" if parts else ""
    return Text(wrap_phrases([f"window {width}x{height} is too small{what}",
                              f"({FULL_SIZE[0]}x{FULL_SIZE[1]} shows it all)"], width, 1),
                style="bold yellow")


def _fit(blocks: list[_Block], events: Sequence[str], width: int,
         height: int) -> tuple[list[_Block], int, list[str]]:
    """The blocks that fit ``height`` lines, kept by rank; the lines of events shown (their
    frame takes two more; after the blocks of rank below theirs); what is hidden."""
    room = height
    kept: list[_Block] = []
    events_lines = 0
    placed = not events
    for b in sorted(blocks, key=lambda b: b.rank):
        if not placed and b.rank > _RANKS["events"]:
            events_lines, placed = _events_room(events, width, room), True
            room -= events_lines + 2 if events_lines else 0
        if b.lines <= room:
            kept.append(b)
            room -= b.lines
    if not placed:
        events_lines = _events_room(events, width, room)
    hidden = [b.name for b in blocks if b not in kept and b.rank < _RANKS["events"]]
    if events and not events_lines:
        hidden.append("events")
    return kept, events_lines, hidden


def _events_room(lines: Sequence[str], width: int, room: int) -> int:
    """Lines of events to show in ``room`` lines of screen (2 of them the frame): all
    the newest that fit, wrapped; 0 when not even one line fits."""
    if room < 3:
        return 0
    return len(event_lines(lines, width - 4, room - 2))
