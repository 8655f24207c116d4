"""omnican fleet's dashboard: its keys, the requests they make and the events their
answers give.

A few times a second it reads the keys (select a base, stop it, recover it, stop every
base), collects the answers that came into the events, and draws the screen
(:mod:`omnican.cli.fleet.view`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from rich.console import Console

from omnican.cli.common import EXIT_OK
from omnican.cli.fleet.link import (
    CONFLICT,
    RECOVER_TIMEOUT_S,
    ROUTER_LISTEN,
    VIEWER_RECOVERS,
    Link,
    may_recover,
)
from omnican.cli.fleet.view import REFRESH_S, base_id, screen

if TYPE_CHECKING:
    from omnican.zenoh.fleet import Call, Fleet
    from omnican.zenoh.settings import ZenohSettings

UP, DOWN = frozenset({"k"}), frozenset({"j"})
ARROWS = {"A": "k", "B": "j"}  # up and down select; left and right do nothing
QUIT = frozenset({"q", "Q", "\x1b", "\x03"})


@contextmanager
def _quiet_errors() -> Iterator[None]:
    try:
        yield
    except KeyboardInterrupt:  # Ctrl-C quits like q
        pass


def dashboard(settings: ZenohSettings, args: argparse.Namespace) -> int:
    from rich.live import Live

    from omnican.cli.terminal import RecentEvents, Screen, cbreak, logs_into, read_keys

    fd = sys.stdin.fileno()
    console = Console()
    events = RecentEvents()
    where = ("the router on " + (", ".join(args.zenoh_listen) or ROUTER_LISTEN)
             if getattr(args, "router", False) else ", ".join(args.zenoh_connect) or "peers")
    title = f"domain {args.domain_id} via {where}"
    picked: tuple[str, str] | None = None  # the base the keys chose (None: the first)
    calls: list[Call] = []
    term = Screen(fd)  # draws nothing while a shell holds the terminal (kill -STOP, bg)
    with cbreak(fd, lambda: events.say("Ctrl-Z: the fleet view does not suspend; q quits"),
                term.resumed), \
            logs_into(events), Link(settings) as link, _quiet_errors(), \
            Live(console=console, screen=True, auto_refresh=False, transient=True) as live:
        term.live = live
        while True:
            fleet = link.fleet()
            problem = link.problem()
            views = fleet.bases() if fleet is not None else []
            ids = [base_id(v) for v in views]
            selected = picked if picked in ids else ids[0] if ids else None
            for key in read_keys(fd, REFRESH_S, ARROWS):
                if key in QUIT:
                    return EXIT_OK
                if key in UP | DOWN and ids:
                    at = ids.index(selected) if selected in ids else 0
                    at += -1 if key in UP else 1
                    picked = selected = ids[max(0, min(len(ids) - 1, at))]
                elif key == " ":
                    calls += stop_all_keyed(fleet, problem, events, args.timeout)
                elif key in ("s", "r") and selected is not None and fleet is not None:
                    service = "stop" if key == "s" else "recover"
                    timeout = args.timeout if key == "s" else max(args.timeout,
                                                                  RECOVER_TIMEOUT_S)
                    view = next(v for v in views if base_id(v) == selected)
                    if service == "recover" and not may_recover(settings):
                        events.say(f"recover {view.name}: not asked: {VIEWER_RECOVERS}")
                        continue
                    if service == "recover" and view.conflict:
                        events.say(f"recover {view.name}: not asked: "
                                   f"{CONFLICT} ({', '.join((view.zid, *view.conflict))})")
                        continue
                    calls.append(fleet.request(service, [view], timeout))
                    events.say(f"{service} {view.name}: asked"
                               + (f" (but {problem})" if problem else ""))
            calls = report(calls, events)
            views = fleet.bases() if fleet is not None else []  # as they are now
            ids = [base_id(v) for v in views]
            selected = picked if picked in ids else ids[0] if ids else None
            term.draw(screen(views, selected, title, events.lines, live.console.width,
                              live.console.height, problem,
                              fleet.ignored() if fleet is not None else None,
                              fleet is not None and fleet.inventory is None))
    return EXIT_OK


def report(calls: list[Call], events: Any) -> list[Call]:
    """The answers of the calls that are done, into the events; the calls still on
    their way. Tokens not heard from that did not answer are one line."""
    done = [c for c in calls if c.done()]
    for call in done:
        for answer in call.answers():
            if answer.answered or not call.unheard:
                events.say(f"{call.service} {answer}")
        if call.unheard:
            got = sum(a.answered for a in call.answers())
            events.say(f"stop: {len(call.names)} tokens not heard from also asked: "
                       f"{got} answered")
    return [c for c in calls if c not in done]


def stop_all_keyed(fleet: Fleet | None, problem: str | None, events: Any,
                   timeout: float) -> list[Call]:
    """Space: the fleet stop, the bases heard from first, then the tokens not heard
    from; the events say how many were asked, and what keeps the view from them."""
    if fleet is None or problem is not None:
        events.say(f"STOP ALL: {problem or 'no Zenoh session yet'}: nothing was stopped")
        return []
    call = fleet.stop_all_call(timeout)
    rest = fleet.stop_unheard_call(timeout)
    n = len(call.names)
    events.say(f"STOP ALL: asked {n} base{'s' * (n != 1)}"
               + (f" (and {len(rest.names)} tokens not heard from)" if rest.names else ""))
    return [call, rest] if rest.names else [call]
