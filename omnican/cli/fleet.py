"""omnican fleet: every omnican base on the Zenoh network, seen and stopped from one place.

A terminal dashboard, a few refreshes a second: one row per base (found by liveliness:
each 'omnican zenoh', or a front end with --zenoh, is one), its state, pose, speed,
battery, stop reason, drive faults, who drives it and when it was last heard. A base
whose Zenoh session went is LOST (at once for a killed process; after the Zenoh lease,
10 s by default, for a network cut); one whose summaries stopped coming is SILENT.

keys: up/down or k/j select a base;  s  stop it;  r  recover it;
      space  STOP EVERY BASE (each base's own ~/stop, all at once);  q, Esc or Ctrl-C quit.
A stop holds until the base is recovered (r, or --recover): no cmd_vel ends it.

For scripts: --json prints one JSON object per refresh (every base); --once waits for
discovery (--wait) and prints one snapshot; --stop NAME (repeatable; 'all': every base)
and --recover NAME act, print each base's answer and exit 0 when every one succeeded.
A NAME is a base's node name (/robot1/omnican) or its namespace (robot1). Point it at
the router the bases use (--zenoh-connect tcp/HOST:7447), or on one machine let it be
the router (--router). Needs eclipse-zenoh.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from typing import Any

from rich.console import Console, Group, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from omnican.cli.common import EXIT_FAILURE, EXIT_OK, UsageError, fixed, positive_float

REFRESH_S = 0.25
ROUTER_LISTEN = "tcp/127.0.0.1:7447"  # rmw_zenoh's port, loopback unless told
MIN_EVENTS = 3  # event lines kept on screen however many bases there are
RECOVER_TIMEOUT_S = 15.0  # a recover waits for the drives to enable
HELP = "up/down k/j: select   s: stop it   r: recover it   space: STOP ALL   q/Esc: quit"
STATE_STYLE = {"RUNNING": "green", "STARTING": "yellow", "STOPPED": "bold red",
               "LOST": "bold red reverse", "SILENT": "bold yellow", "?": "dim"}
UP, DOWN = frozenset({"k"}), frozenset({"j"})
ARROWS = {"A": "k", "B": "j"}  # up and down select; left and right do nothing
QUIT = frozenset({"q", "Q", "\x1b", "\x03"})


def add_subparser(sub: Any) -> None:
    from omnican.cli.zenoh import add_network_arguments

    p = sub.add_parser("fleet", help="every base on the Zenoh network: view, stop, recover",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true",
                   help="JSON lines (one object per refresh with every base), not the dashboard")
    p.add_argument("--once", action="store_true",
                   help="wait for discovery (--wait), print one snapshot and exit")
    p.add_argument("--wait", type=positive_float, default=2.0, metavar="S",
                   help="how long to wait for the bases (default 2)")
    p.add_argument("--stop", action="append", default=[], metavar="NAME",
                   help="stop base NAME ('all': every base), print the answers, exit")
    p.add_argument("--recover", action="append", default=[], metavar="NAME",
                   help="recover base NAME ('all': every base), print the answers, exit")
    p.add_argument("--timeout", type=positive_float, default=2.0, metavar="S",
                   help="how long a stop waits for each base's answer (default 2)")
    p.add_argument("--domain-id", type=int, metavar="N", default=0,
                   help="ROS domain 0-232 of the bases (default 0)")
    add_network_arguments(p)
    p.add_argument("--router", action="store_true",
                   help="be the Zenoh router the bases connect to (listening on "
                        f"--zenoh-listen, default {ROUTER_LISTEN}): one machine, no zenohd; "
                        "a fleet on a network runs zenohd or rmw_zenohd instead")
    p.set_defaults(func=run)


def settings_of(args: argparse.Namespace) -> Any:
    """The fleet view's session settings: the flags, else the defaults (multicast off)."""
    from dataclasses import replace

    from omnican.cli.zenoh import settings_from

    settings = settings_from(args)
    if not getattr(args, "router", False):
        return settings
    if args.zenoh_mode is not None:
        raise UsageError("--router makes this view the Zenoh router: drop --zenoh-mode")
    from omnican.zenoh.settings import default_listen

    router = replace(settings, mode="router")  # loopback (tls/ with credentials) unless told
    return replace(router, listen=settings.listen or default_listen(router)).validate()


def run(args: argparse.Namespace) -> int:
    from omnican.extras import needs

    why = needs("zenoh", "'fleet'")
    if why is not None:
        raise UsageError(why)
    acting = bool(args.stop or args.recover)
    if not (acting or args.once or args.json) and not sys.stdin.isatty():
        raise UsageError("the fleet dashboard reads keys from a terminal, and stdin is not "
                         "one (for scripts: --once, --json, --stop, --recover)")
    from omnican.zenoh.bridge import open_session
    from omnican.zenoh.fleet import Fleet

    settings = settings_of(args)
    session = open_session(settings)
    try:
        with Fleet(session, settings.domain_id) as fleet:
            if acting:
                return act(fleet, args)
            if args.once:
                snapshot(fleet, args.wait)
                print_views(fleet.bases(), args.json)
                return EXIT_OK
            if args.json:
                try:
                    while True:
                        print_views(fleet.bases(), True)
                        time.sleep(REFRESH_S)
                except KeyboardInterrupt:
                    return EXIT_OK
            return dashboard(fleet, args)
    finally:
        session.close()


def snapshot(fleet: Any, wait_s: float) -> None:
    """Discovery, then until every base found was heard from (or ``wait_s``)."""
    deadline = time.monotonic() + wait_s
    fleet.discover(wait_s)
    while time.monotonic() < deadline:
        views = fleet.bases()
        if views and all(v.summary is not None or v.lost for v in views):
            return
        time.sleep(0.05)


def print_views(views: Sequence[Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps({"time": time.time(), "bases": [v.as_json() for v in views]}),
              flush=True)
        return
    if not views:
        print("no omnican base found", flush=True)
        return
    console = Console(width=160, highlight=False)
    console.print(base_table(views, None, 160))


def targets(fleet: Any, names: Sequence[str], wait_s: float) -> list[str]:
    """The bases ``names`` say ('all': every base not lost), waiting up to ``wait_s`` for
    them to be found; UsageError naming one that is not."""
    deadline = time.monotonic() + wait_s
    fleet.discover(wait_s)
    wanted = [n for n in names if n != "all"]
    while any(fleet.find(n) is None for n in wanted) and time.monotonic() < deadline:
        time.sleep(0.05)
    out: list[str] = []
    for name in names:
        if name == "all":
            out += [v.name for v in fleet.bases() if not v.lost]
            continue
        view = fleet.find(name)
        if view is None:
            found = ", ".join(v.name for v in fleet.bases()) or "none"
            raise UsageError(f"fleet: no base named {name!r} (found: {found})")
        out.append(view.name)
    return list(dict.fromkeys(out))


def act(fleet: Any, args: argparse.Namespace) -> int:
    """--stop and --recover: every request of a kind at once, then the answers."""
    stops = targets(fleet, args.stop, args.wait) if args.stop else []
    recovers = targets(fleet, args.recover, args.wait) if args.recover else []
    if not (stops or recovers):
        raise UsageError("fleet: no base found to act on")
    answers = []
    for service, names, timeout in (("stop", stops, args.timeout),
                                    ("recover", recovers, max(args.timeout, RECOVER_TIMEOUT_S))):
        if names:
            for answer in fleet.request(service, names, timeout).wait():
                answers.append(answer)
                if args.json:
                    print(json.dumps({"service": service, "base": answer.name,
                                      "answered": answer.answered, "success": answer.success,
                                      "message": answer.message}), flush=True)
                else:
                    print(f"{service} {answer}", flush=True)
    return EXIT_OK if all(a.success for a in answers) else EXIT_FAILURE


# ------------------------------------------------------------------ the dashboard


def heard(age_s: float | None) -> str:
    if age_s is None:
        return "never"
    return f"{age_s:.1f}s" if age_s < 10 else f"{age_s:.0f}s" if age_s < 600 else \
        f"{age_s / 60:.0f}m"


def notes(view: Any) -> str:
    """The stop reason, the faults and who drives, in that order of urgency."""
    s = view.summary
    if s is None:
        return ""
    parts = [s.stopped_reason] if s.stopped_reason else []
    parts += list(s.faults)
    if s.driver:
        parts.append(f"driven by {s.driver}")
    return "; ".join(parts)


def base_table(views: Sequence[Any], selected: str | None, width: int) -> Table:
    """One row per base: name, state, pose, speed, battery, last heard, then the notes
    (cut to the width; the selected base's are in full below the table)."""
    table = Table(box=None, padding=(0, 1, 0, 0), pad_edge=False, width=width)
    for col, just in (("", "left"), ("base", "left"), ("state", "left"), ("x m", "right"),
                      ("y m", "right"), ("θ rad", "right"), ("m/s", "right"),
                      ("V", "right"), ("heard", "right"), ("stop / faults / driver", "left")):
        table.add_column(col, justify=just, no_wrap=True,  # type: ignore[arg-type]
                         overflow="ellipsis", ratio=1 if col.startswith("stop") else None,
                         max_width=18 if col == "base" else None)
    for v in views:
        s = v.summary
        mark = ">" if v.name == selected else ""
        state = Text(v.state, style=STATE_STYLE.get(v.state, ""))
        if s is None:
            cells = ["-"] * 5
        else:
            x, y, theta = s.pose
            cells = [fixed(x, 2, sign=True), fixed(y, 2, sign=True), fixed(theta, 2, sign=True),
                     f"{(s.speed[0] ** 2 + s.speed[1] ** 2) ** 0.5:.2f}",
                     "-" if s.battery_v is None else f"{s.battery_v:.1f}"]
        table.add_row(mark, v.name, state, *cells, heard(v.age_s),
                      Text(notes(v), style="red" if s and (s.stopped_reason or s.faults)
                           else "dim"),
                      style="reverse" if v.name == selected else None)
    return table


def detail(view: Any) -> Text:
    """The selected base in full."""
    text = Text(f"{view.name}  session {view.zid}  ", style="bold")
    text.append(view.state, style=STATE_STYLE.get(view.state, ""))
    s = view.summary
    if s is None:
        text.append("\nno summary heard yet", style="dim")
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


def screen(views: Sequence[Any], selected: str | None, title: str, events: Sequence[str],
           width: int, height: int) -> Group:
    """The dashboard: title, the table (the rows around the selected base that fit),
    the selected base in full, the keys and the newest events, within width x height."""
    lost = sum(v.lost for v in views)
    head = Text(f"{title} - {len(views)} base{'s' * (len(views) != 1)}"
                + (f", {lost} lost" if lost else ""), style="bold", no_wrap=True,
                overflow="ellipsis")
    chosen = next((v for v in views if v.name == selected), None)
    more: list[RenderableType] = []
    if chosen is not None:
        more.append(Panel(detail(chosen), title="selected", title_align="left"))
    more.append(Text(HELP, style="dim", no_wrap=True, overflow="ellipsis"))
    # title, the table's header, the selected panel, the keys, the events' frame
    room = height - 3 - (detail_lines(chosen) + 2 if chosen else 0) - 2
    rows = max(1, min(len(views), room - MIN_EVENTS))
    room_events = max(1, room - rows)
    shown = list(views)
    if len(shown) > rows:
        at = next((i for i, v in enumerate(shown) if v.name == selected), 0)
        start = min(max(0, at - rows // 2), len(shown) - rows)
        shown = shown[start:start + rows]
    body: list[RenderableType] = [head, base_table(shown, selected, width) if views else
                                  Text("no omnican base found yet", style="dim"), *more]
    lines = list(events)[-room_events:]
    body.append(Panel(Text("\n".join(lines), no_wrap=True, overflow="ellipsis"),
                      title="events", title_align="left"))
    return Group(*body)


def detail_lines(view: Any) -> int:
    s = view.summary if view is not None else None
    return 2 if s is None else 3 + bool(s.stopped_reason) + len(s.faults)


def dashboard(fleet: Any, args: argparse.Namespace) -> int:
    from rich.live import Live

    from omnican.cli.terminal import Events, cbreak, logs_into, read_keys

    fd = sys.stdin.fileno()
    console = Console()
    events = Events()
    where = ("the router on " + (", ".join(args.zenoh_listen) or ROUTER_LISTEN)
             if getattr(args, "router", False) else ", ".join(args.zenoh_connect) or "peers")
    title = f"omnican fleet - domain {args.domain_id} via {where}"
    selected: str | None = None
    calls: list[Any] = []
    with cbreak(fd, lambda: events.say("Ctrl-Z: the fleet view does not suspend; q quits")), \
            logs_into(events), \
            Live(console=console, screen=True, auto_refresh=False, transient=True) as live:
        try:
            while True:
                views = fleet.bases()
                names = [v.name for v in views]
                if selected not in names:
                    selected = names[0] if names else None
                for key in read_keys(fd, REFRESH_S, ARROWS):
                    if key in QUIT:
                        return EXIT_OK
                    if key in UP | DOWN and names:
                        at = names.index(selected) if selected in names else 0
                        at += -1 if key in UP else 1
                        selected = names[max(0, min(len(names) - 1, at))]
                    elif key == " ":
                        call = fleet.stop_all_call(args.timeout)
                        events.say(f"STOP ALL: asked {len(call.names)} base"
                                   f"{'s' * (len(call.names) != 1)}")
                        calls.append(call)
                    elif key in ("s", "r") and selected is not None:
                        service = "stop" if key == "s" else "recover"
                        timeout = args.timeout if key == "s" else max(args.timeout,
                                                                      RECOVER_TIMEOUT_S)
                        calls.append(fleet.request(service, [selected], timeout))
                        events.say(f"{service} {selected}: asked")
                for call in [c for c in calls if c.done()]:
                    calls.remove(call)
                    for answer in call.answers():
                        events.say(f"{call.service} {answer}")
                views = fleet.bases()  # as they are now, the selection among them
                if selected not in [v.name for v in views]:
                    selected = views[0].name if views else None
                live.update(screen(views, selected, title, events.lines,
                                   live.console.width, live.console.height), refresh=True)
        except KeyboardInterrupt:  # Ctrl-C quits like q
            return EXIT_OK
