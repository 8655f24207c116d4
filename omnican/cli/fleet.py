"""omnican fleet: every omnican base on the Zenoh network, seen and stopped from one place.

A terminal dashboard, a few refreshes a second: one row per base (each 'omnican zenoh',
or a front end with --zenoh, is one, once its summary is heard), its state, pose, speed,
battery, stop reason, drive faults, who drives it and when it was last heard. A base
whose Zenoh session went is LOST (at once for a killed process; after the Zenoh lease,
10 s by default, for a network cut); one whose summaries stopped coming is SILENT; one
whose summary cannot be read is BAD SUMMARY. Tokens that announce a base but send no
summary of their own (a stranger's, or a base this view cannot reach) are not listed:
the header counts them. The header says when the router cannot be reached.

keys: up/down or k/j select a base;  s  stop it;  r  recover it;
      space  STOP EVERY BASE (each base's own ~/stop, all at once);  q, Esc or Ctrl-C quit.
A stop holds until the base is recovered (r, or --recover): no cmd_vel ends it.

For scripts: --json prints one JSON object per refresh (every base), from the end of
discovery on; --once waits for discovery (at most --wait) and prints one snapshot;
--stop NAME (repeatable; 'all': every base) and --recover NAME act, print each base's
answer and exit 0 when every one succeeded (1 when one did not, or the router cannot be
reached). A NAME is a base's node name (/robot1/omnican) or its namespace (robot1).
Point it at the router the bases use (--zenoh-connect tcp/HOST:7447: the view is then a
client of that router, unless --zenoh-mode says otherwise), or on one machine let it be
the router (--router). Needs eclipse-zenoh.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from rich.console import Console, Group, RenderableType
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from omnican.cli.common import EXIT_FAILURE, EXIT_OK, UsageError, fixed, positive_float
from omnican.errors import ConfigError, OmnicanError, printable

if TYPE_CHECKING:
    from omnican.zenoh.fleet import Answer, BaseView, Call, Fleet
    from omnican.zenoh.settings import ZenohSettings

REFRESH_S = 0.25
RETRY_S = 1.0  # how often a view tries again to reach its router
#: how long a view waits for its first link before it says it cannot reach its router,
#: however short --wait (a peer's links, a client's session, come later on a busy machine)
REACH_S = 3.0
CLOSE_WAIT_S = 5.0  # the longest a view waits, when it quits, for a session being opened
ROUTER_LISTEN = "tcp/127.0.0.1:7447"  # rmw_zenoh's port, loopback unless told
MIN_EVENTS = 3  # event lines kept on screen however many bases there are
RECOVER_TIMEOUT_S = 15.0  # a recover waits for the drives to enable
ONCE_WIDTH = 200  # the widest a --once table may be (it is as wide as its cells)
HELP = "up/down k/j: select   s: stop it   r: recover it   space: STOP ALL   q/Esc: quit"
STATE_STYLE = {"RUNNING": "green", "STARTING": "yellow", "STOPPED": "bold red",
               "LOST": "bold red reverse", "SILENT": "bold yellow",
               "BAD SUMMARY": "bold magenta", "?": "dim"}
UP, DOWN = frozenset({"k"}), frozenset({"j"})
ARROWS = {"A": "k", "B": "j"}  # up and down select; left and right do nothing
QUIT = frozenset({"q", "Q", "\x1b", "\x03"})
#: Why a recover of a name two sessions claim is not asked: it would reach both (a
#: service's key is the name's, whoever serves it), and a recover moves a base.
CONFLICT = "more than one session claims the name, and a recover would reach each"
IGNORED = ("tokens that announce a base but whose summary never came (a stranger's, or a "
           "base this view cannot hear) or that do not read as a base's")
PEER_HINT = ("a peer sees only the bases it can open a link of its own to: "
             "--zenoh-mode client goes through the router")


def add_subparser(sub: Any) -> None:
    from omnican.zenoh.arguments import add_network_arguments

    p = sub.add_parser("fleet", help="every base on the Zenoh network: view, stop, recover",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true",
                   help="JSON lines (one object per refresh with every base), not the dashboard")
    p.add_argument("--once", action="store_true",
                   help="wait for discovery (--wait), print one snapshot and exit")
    p.add_argument("--wait", type=positive_float, default=2.0, metavar="S",
                   help="how long discovery may take (default 2)")
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


def settings_of(args: argparse.Namespace) -> ZenohSettings:
    """The fleet view's session settings: the flags, else the defaults (multicast off).
    Given a router (--zenoh-connect) and no --zenoh-mode, the view is a client of it: a
    peer would see only the bases it can open a link of its own to (none, where their
    addresses are loopback or firewalled), a client sees every base its router sees."""
    from dataclasses import replace

    from omnican.zenoh.arguments import settings_from

    settings = settings_from(args)
    if not getattr(args, "router", False):
        if args.zenoh_mode is None and settings.connect:
            return replace(settings, mode="client").validate()
        return settings
    if args.zenoh_mode is not None:
        raise UsageError("--router makes this view the Zenoh router: drop --zenoh-mode")
    from omnican.zenoh.settings import default_listen

    router = replace(settings, mode="router")  # loopback (tls/ with credentials) unless told
    return replace(router, listen=settings.listen or default_listen(router)).validate()


def reach_problem(settings: ZenohSettings, links: int) -> str | None:
    """What keeps a view with ``links`` routers and peers from every base (None: nothing):
    a mistyped router must not look like a fleet with nothing to stop."""
    if links or settings.mode == "router":
        return None
    if settings.connect:
        return f"cannot reach {', '.join(settings.connect)}"
    return "reaches no Zenoh router or peer" + (
        "" if settings.multicast else " (no --zenoh-connect, and multicast is off)")


def _unreachable(exc: ConfigError) -> bool:
    """Zenoh refused to open a client's session because no router answered."""
    return "Unable to connect" in str(exc)


class Link:
    """The view's session and its :class:`~omnican.zenoh.fleet.Fleet`, opened in a thread
    of its own and again every :data:`RETRY_S` while its router cannot be reached (a
    client's session opens only once it reaches one), so that the view says so, and
    hears Ctrl-C, meanwhile. A context manager."""

    def __init__(self, settings: ZenohSettings) -> None:
        self.settings = settings
        self._lock = threading.Lock()
        self._fleet: Fleet | None = None
        self._session: Any = None
        self._fatal: BaseException | None = None
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._open, name="omnican-fleet-open",
                                        daemon=True)  # zenoh.open cannot be interrupted
        self._thread.start()

    def _open(self) -> None:
        from omnican.zenoh.bridge import open_session
        from omnican.zenoh.fleet import Fleet

        while not self._closed.is_set():
            try:
                session = open_session(self.settings)
            except ConfigError as exc:
                if not _unreachable(exc):
                    self._fatal = exc
                    return
                logging.getLogger(__name__).debug("%s; trying again in %g s", exc, RETRY_S)
                self._closed.wait(RETRY_S)
                continue
            except Exception as exc:  # said in the main thread
                self._fatal = exc
                return
            with self._lock:
                if self._closed.is_set():
                    session.close()
                    return
                try:
                    self._fleet = Fleet(session, self.settings.domain_id)
                    self._session = session
                except Exception as exc:
                    session.close()
                    self._fatal = exc
                return

    def fleet(self) -> Fleet | None:
        """The fleet once the session is open (None before); what kept it from opening,
        raised, if that was not the router being out of reach."""
        if self._fatal is not None:
            raise self._fatal
        return self._fleet

    def wait_open(self, deadline: float) -> Fleet | None:
        """The fleet, waiting for the session until ``deadline`` (monotonic s)."""
        while (fleet := self.fleet()) is None and time.monotonic() < deadline:
            time.sleep(0.02)
        return fleet

    def wait_linked(self, deadline: float) -> Fleet | None:
        """The fleet, waiting until it is open and linked to a router or peer or until
        ``deadline`` (monotonic s)."""
        while time.monotonic() < deadline:
            fleet = self.fleet()
            if fleet is not None and reach_problem(self.settings, fleet.links()) is None:
                return fleet
            time.sleep(0.02)
        return self.fleet()

    def problem(self) -> str | None:
        """What keeps this view from the bases now (None: nothing)."""
        fleet = self.fleet()
        if fleet is None:
            return reach_problem(self.settings, 0) or "the Zenoh session is not open yet"
        return reach_problem(self.settings, fleet.links())

    def close(self) -> None:
        """Close the fleet and the session, and wait (a bounded time) for a session
        being opened: Python must not exit under a thread inside Zenoh."""
        self._closed.set()
        self._thread.join(CLOSE_WAIT_S)
        with self._lock:
            fleet, session = self._fleet, self._session
            self._fleet = self._session = None
        if fleet is not None:
            fleet.close()
        if session is not None:
            session.close()

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run(args: argparse.Namespace) -> int:
    from omnican.extras import needs

    why = needs("zenoh", "'fleet'")
    if why is not None:
        raise UsageError(why)
    acting = bool(args.stop or args.recover)
    if not (acting or args.once or args.json) and not sys.stdin.isatty():
        raise UsageError("the fleet dashboard reads keys from a terminal, and stdin is not "
                         "one (for scripts: --once, --json, --stop, --recover)")
    settings = settings_of(args)
    if args.recover and not may_recover(settings):
        raise UsageError(f"fleet --recover: {VIEWER_RECOVERS}")
    if not (acting or args.once or args.json):
        return dashboard(settings, args)  # its link opens inside it: its events from the start
    with Link(settings) as link:
        if acting:
            return act(link, args)
        if args.once:
            return once(link, args)
        return stream(link, args)


#: Why a viewer's recover is not sent: the fleet's access control lets none through, and
#: unanswered it would read as a base that is gone.
VIEWER_RECOVERS = ("a viewer may only stop: its certificate lets no recover through "
                   "(an operator's identity may recover)")


def may_recover(settings: ZenohSettings) -> bool:
    """The session's certificate lets a recover through (a viewer's does not)."""
    who = settings.who
    return who is None or who.role != "viewer"


# ------------------------------------------------------------------ for scripts


def ignored_text(ignored: dict[str, int]) -> str:
    """``5000 tokens ignored (no summary)``; empty when none was."""
    reasons = [(why, n) for why, n in ignored.items() if n]
    total = sum(n for _, n in reasons)
    if not total:
        return ""
    why = reasons[0][0] if len(reasons) == 1 else ", ".join(f"{n} {w}" for w, n in reasons)
    return f"{total} token{'s' * (total != 1)} ignored ({why})"


def snapshot(link: Link, fleet: Fleet | None) -> dict[str, Any]:
    """One --json object: the bases, what keeps the view from them, what it ignored."""
    problem = link.problem()
    out: dict[str, Any] = {"time": time.time(), "reachable": problem is None,
                           "problem": problem}
    if fleet is None:
        out.update(ignored_tokens={}, intruder_replies=0, bases=[])
        return out
    out.update(ignored_tokens=fleet.ignored(), intruder_replies=fleet.intruders,
               bases=[v.as_json() for v in fleet.bases()])
    return out


def dumps(obj: Any) -> str:
    """JSON that jq and JSON.parse read: never NaN or Infinity (a ValueError instead)."""
    return json.dumps(obj, allow_nan=False)


def rendered(renderable: RenderableType, width: int) -> list[str]:
    """What ``renderable`` prints at most ``width`` columns wide, each line without the
    spaces that pad it."""
    console = Console(width=width, highlight=False, force_terminal=False, no_color=True)
    with console.capture() as got:
        console.print(renderable)
    return [line.rstrip() for line in got.get().splitlines()]


def once(link: Link, args: argparse.Namespace) -> int:
    """--once: discovery (at most --wait), one snapshot; exit 1 if the view reaches no
    router or peer."""
    start = time.monotonic()
    deadline = start + args.wait
    fleet = link.wait_open(deadline)
    if link.problem() is not None:  # not linked yet: the verdict waits REACH_S at least
        fleet = link.wait_linked(max(deadline, start + REACH_S))
    if fleet is not None:
        fleet.discover(max(0.0, deadline - time.monotonic()))
    problem = link.problem()
    views = fleet.bases() if fleet is not None else []
    if args.json:
        print(dumps(snapshot(link, fleet)), flush=True)
    else:
        lines = rendered(base_table(views, None, None), ONCE_WIDTH) if views else \
            ["no omnican base found" + (f": {problem}" if problem else "")]
        if fleet is not None and (text := ignored_text(fleet.ignored())):
            lines.append(f"{text}: {IGNORED}")
        print("\n".join(lines), flush=True)
    if problem is not None:
        raise OmnicanError(f"fleet: {problem}")
    if not views and args.zenoh_mode == "peer" and link.settings.connect:
        print(f"omnican: {PEER_HINT}", file=sys.stderr)
    return EXIT_OK


def stream(link: Link, args: argparse.Namespace) -> int:
    """--json: one line per refresh, from the end of discovery (or, while the router
    cannot be reached, saying so) until Ctrl-C."""
    deadline = time.monotonic() + args.wait
    fleet = link.wait_open(deadline)
    try:
        if fleet is not None:
            fleet.discover(max(0.0, deadline - time.monotonic()))
        while True:
            if fleet is None and (fleet := link.fleet()) is not None:
                fleet.discover(args.wait)  # a session that opened late: its discovery first
            print(dumps(snapshot(link, fleet)), flush=True)
            time.sleep(REFRESH_S)
    except KeyboardInterrupt:
        return EXIT_OK


# ------------------------------------------------------------------ --stop, --recover


class Asked:
    """The requests of one kind made so far, with the tokens they went to."""

    def __init__(self) -> None:
        self.calls: list[Call] = []
        self.unheard: list[Call] = []  # to tokens not heard from
        self.keys: set[str] = set()

    def ask(self, fleet: Fleet, service: str, views: Sequence[BaseView], timeout: float,
            unheard: bool = False) -> None:
        new = [v for v in views if v.key not in self.keys]
        if new:
            self.keys |= {v.key for v in new}
            call = fleet.request(service, new, timeout, unheard=unheard)
            (self.unheard if unheard else self.calls).append(call)


def stop_as_found(fleet: Fleet, names: Sequence[str], timeout: float,
                  deadline: float) -> tuple[Asked, list[str]]:
    """--stop: each base asked the moment it is heard from (the bases whose summary
    comes first are stopped first, whatever else is on the network), until discovery
    settles or ``deadline``; then, for 'all', the tokens not heard from, and for a name,
    the tokens of that name. Returns the requests and the names nothing has."""
    asked = Asked()
    everything = "all" in names
    named = [n for n in dict.fromkeys(names) if n != "all"]
    while True:
        if everything:
            asked.ask(fleet, "stop", [v for v in fleet.bases() if not v.lost], timeout)
        for name in named:
            asked.ask(fleet, "stop", fleet.find_all(name), timeout)
        found = all(fleet.find_all(n) for n in named)
        if (fleet.settled() and found) or time.monotonic() >= deadline:
            break
        time.sleep(0.02)
    if everything:
        asked.ask(fleet, "stop", fleet.unheard(), timeout, unheard=True)
        if asked.keys and not fleet.settled():
            logging.getLogger(__name__).warning(
                "stop all: discovery did not end within --wait: a token that announces a "
                "base and was not listed by then was not asked (a longer --wait asks it)")
    unknown = []
    for name in named:
        tokens = fleet.find_all(name, heard=False)
        if not tokens:
            unknown.append(name)
        elif not any(v.heard for v in tokens):  # a base heard was asked: its query went
            asked.ask(fleet, "stop", tokens, timeout, unheard=True)  # to them all
    return asked, unknown


def recover_targets(fleet: Fleet, names: Sequence[str]) -> tuple[list[BaseView], list[str]]:
    """--recover: the bases ``names`` say ('all': every base not lost), and the lines of
    those not asked: a name two sessions claim (a recover moves a base, and would reach
    each). UsageError for a name no base has, or a name in conflict asked by name."""
    out: list[BaseView] = []
    skipped: list[str] = []
    for name in dict.fromkeys(names):
        if name == "all":
            for v in fleet.bases():
                if v.conflict and not v.lost:
                    skipped.append(f"recover {v.name}: not asked: {CONFLICT} "
                                   f"({', '.join((v.zid, *v.conflict))})")
                elif not v.lost:
                    out.append(v)
            continue
        found = fleet.find_all(name)
        if not found:
            known = ", ".join(v.name for v in fleet.bases()) or "none"
            raise UsageError(f"fleet: no base named {printable(name, 80)!r} (found: {known})")
        if len(found) > 1 or found[0].conflict:
            sessions = ", ".join(sorted({v.zid for v in found} | set(found[0].conflict)))
            raise UsageError(f"fleet: {found[0].name}: {CONFLICT} ({sessions}): "
                             "not recovered")
        out += found
    return list({v.key: v for v in out}.values()), list(dict.fromkeys(skipped))


def act(link: Link, args: argparse.Namespace) -> int:
    """--stop and --recover: the stops as the bases are found, then the recovers; each
    answer printed; exit 1 when one failed or the router cannot be reached."""
    deadline = time.monotonic() + args.wait
    fleet = link.wait_open(deadline)
    while fleet is not None and link.problem() is not None and time.monotonic() < deadline:
        time.sleep(0.05)  # a peer's session links up after it opened
    problem = link.problem()
    if fleet is None or problem is not None:
        problem = problem or "the Zenoh session did not open"
        for service, names in (("stop", args.stop), ("recover", args.recover)):
            for name in names:
                say(args.json, {"service": service, "base": name, "answered": False,
                                "success": False, "message": problem},
                    f"{service} {name}: {problem}: nothing was asked")
        raise OmnicanError(f"fleet: {problem}")
    failed = False
    unknown: list[str] = []
    asked = Asked()
    if args.stop:
        asked, unknown = stop_as_found(fleet, args.stop, args.timeout, deadline)
    stopped = [a for call in asked.calls for a in call.wait()]  # by name: as found, they
    for answer in sorted(stopped, key=lambda a: (a.name, a.zid)):  # came in any order
        failed |= not answer.success
        print_answer(args.json, "stop", answer)
    failed |= report_unheard(args.json, asked.unheard)
    recovering: Call | None = None
    skipped: list[str] = []
    if args.recover:  # after the stops are answered (a name no base has is then said)
        if not args.stop:
            fleet.discover(max(0.0, deadline - time.monotonic()))
        targets, skipped = recover_targets(fleet, args.recover)
        recovering = fleet.request("recover", targets, max(args.timeout, RECOVER_TIMEOUT_S))
    for line in skipped:
        failed = True
        say(args.json, {"service": "recover", "base": line.split()[1], "answered": False,
                        "success": False, "message": CONFLICT}, line)
    if recovering is not None:
        for answer in recovering.wait():
            failed |= not answer.success
            print_answer(args.json, "recover", answer)
    if unknown:
        known = ", ".join(v.name for v in fleet.bases()) or "none"
        raise UsageError(f"fleet: no base named {printable(unknown[0], 80)!r} "
                         f"(found: {known})")
    answered = any(a.answered for c in asked.unheard for a in c.answers())
    if not asked.calls and not answered and (recovering is None or not recovering.names):
        text = ignored_text(fleet.ignored())
        raise UsageError("fleet: no base found to act on" + (f" ({text})" if text else ""))
    if (problem := link.problem()) is not None:
        raise OmnicanError(f"fleet: {problem}")
    return EXIT_FAILURE if failed else EXIT_OK


def say(as_json: bool, obj: dict[str, Any], text: str) -> None:
    print(dumps(obj) if as_json else text, flush=True)


def print_answer(as_json: bool, service: str, answer: Answer) -> None:
    say(as_json, {"service": service, "base": answer.name, "zid": answer.zid,
                  "answered": answer.answered, "success": answer.success,
                  "message": answer.message, "intruders": list(answer.intruders)},
        f"{service} {answer}")


def report_unheard(as_json: bool, calls: Sequence[Call]) -> bool:
    """The tokens not heard from that a stop also went to: the ones that answered (from
    their own session), each; the rest in one line. True when one refused."""
    answers = [a for call in calls for a in call.wait()]
    if not answers:
        return False
    got = [a for a in answers if a.answered]
    for answer in got:
        print_answer(as_json, "stop", answer)
    silent = len(answers) - len(got)
    if silent:
        say(as_json, {"service": "stop", "unheard_asked": len(answers),
                      "unheard_answered": len(got)},
            f"stop: also asked {len(answers)} token{'s' * (len(answers) != 1)} that "
            f"announce a base but sent no summary: {silent} did not answer (not bases, "
            "or out of reach)")
    return any(not a.success for a in got)


# ------------------------------------------------------------------ the dashboard


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


def _id(view: BaseView) -> tuple[str, str]:
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
        chosen = _id(v) == selected
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
    chosen = next((v for v in views if _id(v) == selected), None)
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
        at = next((i for i, v in enumerate(shown) if _id(v) == selected), 0)
        start = min(max(0, at - rows // 2), len(shown) - rows)
        shown = shown[start:start + rows]
    body: list[RenderableType] = [*top, base_table(shown, selected, width) if views else
                                  Text("no omnican base found yet", style="dim"), *more]
    lines = list(events)[-room_events:]
    body.append(Panel(Text("\n".join(lines), no_wrap=True, overflow="ellipsis"),
                      title="events", title_align="left"))
    return Group(*body)


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
            ids = [_id(v) for v in views]
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
                    view = next(v for v in views if _id(v) == selected)
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
            ids = [_id(v) for v in views]
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
