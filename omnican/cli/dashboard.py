"""The teleop dashboard: the screen ``omnican teleop`` draws each frame (header, pose and
twist, the wheels with what each drive reports, the stop line, the keys, the newest
events), as rich renderables. Pure rendering of a base's state: no keys, no terminal
modes (those are :mod:`omnican.cli.teleop`'s). The wheel columns of what a drive reports
come from the table (:data:`omnican.plan.health_fields.HEALTH_FIELDS`).
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any, Protocol

from rich.console import Console, Group, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from omnican.chassis import Chassis
from omnican.cli.common import fixed
from omnican.command.teleop import TeleopModel
from omnican.core.kinematics import Twist
from omnican.plan.health_fields import HEALTH_FIELDS
from omnican.protocol.cia402 import State


class Events(Protocol):
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


def dashboard(base: Chassis, keys: TeleopModel, command: Twist, title: str,
              events: Events, note: str, width: int = 120,
              height: int | None = None) -> Group:
    """The screen: header, pose and twist, wheels, status, keys, events (as many of the
    newest as fit ``height`` lines)."""
    st = base.status
    pose, twist, applied = base.pose, base.twist, base.command
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

    pose_t = Table.grid(padding=(0, 1))
    pose_t.add_row("x", f"{fixed(pose.x, 3, sign=True):>8} m")
    pose_t.add_row("y", f"{fixed(pose.y, 3, sign=True):>8} m")
    pose_t.add_row("θ", f"{fixed(pose.theta, 3, sign=True):>8} rad "
                        f"({fixed(math.degrees(pose.heading), 1, sign=True):>6}°)")

    tw = Table(box=None, padding=(0, 1))
    for col in ("", "keys", "applied", "measured"):
        tw.add_column(col, justify="right")
    unknown = any(w.stale for w in base.wheels)  # no fresh samples: no measured twist
    for name, unit, a, b, c in (("vx", "m/s", command.vx, applied.vx, twist.vx),
                                ("vy", "m/s", command.vy, applied.vy, twist.vy),
                                ("wz", "rad/s", command.wz, applied.wz, twist.wz)):
        tw.add_row(f"{name} {unit}", fixed(a, 3, sign=True), fixed(b, 3, sign=True),
                   "-" if unknown else fixed(c, 3, sign=True))

    wheels = Table(box=None, padding=(0, 1), pad_edge=False)
    fault_column = width >= FAULT_COLUMN_MIN_WIDTH
    for col in (*WHEEL_COLUMNS, "fault") if fault_column else WHEEL_COLUMNS:
        wheels.add_column(col, justify="left" if col in ("wheel", "state", "fault") else "right",
                          no_wrap=col != "fault")
    faults = []
    for w in base.wheels:
        node = f"{w.node_id}" + (f".{w.axis}" if w.axis else "")
        state = Text(str(w.state), style=STATE_STYLE.get(w.state, ""))
        if not w.online:
            state = Text("OFFLINE", style="bold red")
        trouble = w.fault or w.error or ""
        cells: list[Any] = [str(w.index), node, state, fixed(w.target_speed, 3, sign=True),
                            "-" if w.stale else fixed(w.actual_speed, 3, sign=True),
                            fixed(w.travel, 3, sign=True)]
        for reported in HEALTH_COLUMNS:  # what the drive reports
            value = getattr(w, reported.name)
            cells.append("-" if value is None else
                         fixed(value, reported.places, sign=reported.signed))
        if fault_column:
            cells.append(Text(trouble, style="red"))
        elif trouble:
            faults.append(f"wheel {w.index}: {trouble}")
        wheels.add_row(*cells)
    wheel_panel: RenderableType = wheels
    if faults:  # under the table, cut to a line each rather than wrapped
        wheel_panel = Group(wheels, *(Text(f, style="red", no_wrap=True, overflow="ellipsis")
                                      for f in faults))

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
    grid = Table.grid(padding=(0, 2))
    grid.add_row(Panel(pose_t, title="pose", title_align="left"),
                 Panel(tw, title="twist", title_align="left"))
    body: list[RenderableType] = [header, grid,
                                  Panel(wheel_panel, title=f"wheels ({WHEEL_UNITS})",
                                        title_align="left"),
                                  status]
    # A note and each warning on one line of its own, cut rather than wrapped: beside
    # the stop reason they wrapped it onto three lines and pushed the events off screen.
    if note:
        body.append(Text(note, style="yellow", no_wrap=True, overflow="ellipsis"))
    body += [settings, help_text]
    body += [Text(w, style="yellow", no_wrap=True, overflow="ellipsis") for w in st.warnings]
    if events.lines:
        lines = list(events.lines)
        if height is not None:  # the newest events that fit below the rest (2: the frame)
            # The key help (in --help too) and the speeds give way before the newest event.
            for spare in (help_text, settings):
                if height - _height(body, width) - 2 >= 1:
                    break
                body.remove(spare)
            room = max(1, height - _height(body, width) - 2)
            lines = lines[-room:]
        body.append(Panel(Text("\n".join(lines), no_wrap=True, overflow="ellipsis"),
                          title="events", title_align="left"))
    return Group(*body)
