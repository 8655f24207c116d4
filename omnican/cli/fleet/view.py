"""What the fleet view draws: the table of bases, the selected base in full, the title
line and the dashboard's screen, as rich renderables. Pure rendering of what the fleet
says: no keys, no terminal modes (those are :mod:`omnican.cli.fleet.dashboard`'s)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from rich.console import Console, Group, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from omnican.cli.common import fixed

if TYPE_CHECKING:
    from omnican.zenoh.fleet import BaseView

REFRESH_S = 0.25  # how often the view is drawn (and --json prints a line)
MIN_EVENTS = 3  # event lines kept on screen however many bases there are
ONCE_WIDTH = 200  # the widest a --once table may be (it is as wide as its cells)
HELP = "up/down k/j: select   s: stop it   r: recover it   space: STOP ALL   q/Esc: quit"
STATE_STYLE = {"RUNNING": "green", "STARTING": "yellow", "STOPPED": "bold red",
               "LOST": "bold red reverse", "SILENT": "bold yellow",
               "BAD SUMMARY": "bold magenta", "?": "dim"}


def rendered(renderable: RenderableType, width: int) -> list[str]:
    """What ``renderable`` prints at most ``width`` columns wide, each line without the
    spaces that pad it."""
    console = Console(width=width, highlight=False, force_terminal=False, no_color=True)
    with console.capture() as got:
        console.print(renderable)
    return [line.rstrip() for line in got.get().splitlines()]


def heard(age_s: float | None) -> str:
    if age_s is None:
        return "never"
    return f"{age_s:.1f}s" if age_s < 10 else f"{age_s:.0f}s" if age_s < 600 else \
        f"{age_s / 60:.0f}m"


def notes(view: BaseView) -> str:
    """What is wrong with the base's summary or name, then the stop reason, the faults
    and who drives, in that order of urgency."""
    parts = []
    if view.bad_summary is not None:
        parts.append(f"BAD SUMMARY: {view.bad_summary}")
    if view.conflict:
        parts.append(f"name also claimed by session {', '.join(view.conflict)}")
    s = view.summary
    if s is not None:
        parts += [s.stopped_reason] if s.stopped_reason else []
        parts += list(s.faults)
        if s.driver:
            parts.append(f"driven by {s.driver}")
    return "; ".join(parts)


def base_id(view: BaseView) -> tuple[str, str]:
    """How the view tells one base (a row) from another: its name and session."""
    return view.name, view.zid


def base_table(views: Sequence[BaseView], selected: tuple[str, str] | None,
               width: int | None) -> Table:
    """One row per base: name, state, pose, speed, battery, last heard, then the notes
    (cut to ``width``; None: as wide as they are; the selected base's are in full below
    the table)."""
    table = Table(box=None, padding=(0, 1, 0, 0), pad_edge=False, width=width)
    for col, just in (("", "left"), ("base", "left"), ("state", "left"), ("x m", "right"),
                      ("y m", "right"), ("θ rad", "right"), ("m/s", "right"),
                      ("V", "right"), ("heard", "right"), ("stop / faults / driver", "left")):
        table.add_column(col, justify=just, no_wrap=True,  # type: ignore[arg-type]
                         overflow="ellipsis",
                         ratio=1 if col.startswith("stop") and width else None,
                         max_width=18 if col == "base" and width else None)
    for v in views:
        s = v.summary
        chosen = base_id(v) == selected
        state = Text(v.state, style=STATE_STYLE.get(v.state, ""))
        if s is None:
            cells = ["-"] * 5
        else:
            x, y, theta = s.pose
            cells = [fixed(x, 2, sign=True), fixed(y, 2, sign=True), fixed(theta, 2, sign=True),
                     f"{(s.speed[0] ** 2 + s.speed[1] ** 2) ** 0.5:.2f}",
                     "-" if s.battery_v is None else f"{s.battery_v:.1f}"]
        trouble = v.bad_summary is not None or v.conflict or (
            s is not None and (s.stopped_reason or s.faults))
        # every cell from the network a Text: never read as rich markup
        table.add_row(">" if chosen else "", Text(v.name), state, *cells, heard(v.age_s),
                      Text(notes(v), style="red" if trouble else "dim"),
                      style="reverse" if chosen else None)
    return table


def detail(view: BaseView) -> Text:
    """The selected base in full, a line each (cut at the screen's edge: a line that
    wrapped would push the screen past its height)."""
    text = Text(f"{view.name}  session {view.zid}  ", style="bold", no_wrap=True,
                overflow="ellipsis")
    text.append(view.state, style=STATE_STYLE.get(view.state, ""))
    if view.conflict:
        text.append(f"\nname also claimed by session {', '.join(view.conflict)}",
                    style="red")
    if view.bad_summary is not None:
        text.append(f"\nBAD SUMMARY: {view.bad_summary}", style="red")
    s = view.summary
    if s is None:
        text.append("\nno summary read yet", style="dim")
        return text
    vx, vy, wz = s.speed
    text.append(f"\nspeed vx {vx:+.3f} vy {vy:+.3f} m/s  wz {wz:+.3f} rad/s")
    if s.true_speed is not None:
        text.append(f"  (simulator: vx {s.true_speed[0]:+.3f} vy {s.true_speed[1]:+.3f} "
                    f"wz {s.true_speed[2]:+.3f})", style="dim")
    text.append(f"\ndriver: {s.driver or 'no one'}")
    if s.stopped_reason:
        text.append(f"\nstopped: {s.stopped_reason}", style="red")
    for fault in s.faults:
        text.append(f"\n{fault}", style="red")
    return text


def detail_lines(view: BaseView | None) -> int:
    if view is None:
        return 0
    s = view.summary
    extra = bool(view.conflict) + (view.bad_summary is not None)
    return extra + (2 if s is None else 3 + bool(s.stopped_reason) + len(s.faults))


def heading(views: Sequence[BaseView], where: str, ignored: dict[str, int],
            listing: bool = False) -> str:
    """The dashboard's title line, the counts first (an 80-column line cuts the end):
    the bases, lost and in conflict, the tokens ignored, while the view asks for the
    tokens already there that it does, then where the view looks."""
    lost = sum(v.lost for v in views)
    conflicts = len({v.name for v in views if v.conflict})
    n = sum(ignored.values())
    parts = [f"{len(views)} base{'s' * (len(views) != 1)}"]
    parts += [f"{lost} lost"] if lost else []
    parts += [f"{conflicts} in conflict"] if conflicts else []
    parts += [f"{n} token{'s' * (n != 1)} ignored"] if n else []
    parts += ["listing the tokens already there"] if listing else []
    return f"omnican fleet - {', '.join(parts)} - {where}"


def screen(views: Sequence[BaseView], selected: tuple[str, str] | None, title: str,
           events: Sequence[str], width: int, height: int,
           problem: str | None = None, ignored: dict[str, int] | None = None,
           listing: bool = False) -> Group:
    """The dashboard: title (what keeps the view from the bases under it, in red), the
    table (the rows around the selected base that fit), the selected base in full, the
    keys and the newest events, within width x height."""
    head = Text(heading(views, title, ignored or {}, listing), style="bold", no_wrap=True,
                overflow="ellipsis")
    top: list[RenderableType] = [head]
    if problem is not None:
        top.append(Text(f"{problem}: no base can be seen or stopped from here",
                        style="bold red reverse", no_wrap=True, overflow="ellipsis"))
    chosen = next((v for v in views if base_id(v) == selected), None)
    more: list[RenderableType] = []
    if chosen is not None:
        more.append(Panel(detail(chosen), title="selected", title_align="left"))
    more.append(Text(HELP, style="dim", no_wrap=True, overflow="ellipsis"))
    # the title lines, the table's header, the selected panel, the keys, the events' frame
    room = height - len(top) - 2 - (detail_lines(chosen) + 2 if chosen else 0) - 2
    rows = max(1, min(len(views), room - MIN_EVENTS))
    room_events = max(1, room - rows)
    shown = list(views)
    if len(shown) > rows:
        at = next((i for i, v in enumerate(shown) if base_id(v) == selected), 0)
        start = min(max(0, at - rows // 2), len(shown) - rows)
        shown = shown[start:start + rows]
    body: list[RenderableType] = [*top, base_table(shown, selected, width) if views else
                                  Text("no omnican base found yet", style="dim"), *more]
    lines = list(events)[-room_events:]
    body.append(Panel(Text("\n".join(lines), no_wrap=True, overflow="ellipsis"),
                      title="events", title_align="left"))
    return Group(*body)


