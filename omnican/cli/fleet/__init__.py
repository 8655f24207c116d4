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
import sys
from typing import TYPE_CHECKING, Any

from omnican.cli.common import UsageError, positive_float
from omnican.cli.fleet.dashboard import ARROWS, DOWN, QUIT, UP, dashboard, report, stop_all_keyed
from omnican.cli.fleet.link import (
    CLOSE_WAIT_S,
    CONFLICT,
    REACH_S,
    RECOVER_TIMEOUT_S,
    RETRY_S,
    ROUTER_LISTEN,
    VIEWER_RECOVERS,
    Link,
    may_recover,
    reach_problem,
)
from omnican.cli.fleet.scripts import (
    IGNORED,
    PEER_HINT,
    Asked,
    act,
    dumps,
    ignored_text,
    once,
    print_answer,
    recover_targets,
    report_unheard,
    say,
    snapshot,
    stop_as_found,
    stream,
)
from omnican.cli.fleet.view import (
    HELP,
    MIN_EVENTS,
    ONCE_WIDTH,
    REFRESH_S,
    STATE_STYLE,
    base_table,
    detail,
    detail_lines,
    heading,
    heard,
    notes,
    rendered,
    screen,
)

if TYPE_CHECKING:
    from omnican.zenoh.settings import ZenohSettings

# The subcommand's pieces, each importable from here as before: the link to the bases
# (link), what the view draws (view), the scripts' --once, --json, --stop and
# --recover (scripts) and the dashboard's keys (dashboard).
__all__ = [
    "ARROWS", "CLOSE_WAIT_S", "CONFLICT", "DOWN", "HELP", "IGNORED", "MIN_EVENTS",
    "ONCE_WIDTH", "PEER_HINT", "QUIT", "REACH_S", "RECOVER_TIMEOUT_S", "REFRESH_S", "RETRY_S",
    "ROUTER_LISTEN", "STATE_STYLE", "UP", "VIEWER_RECOVERS", "Asked", "Link", "act",
    "add_subparser", "base_table", "dashboard", "detail", "detail_lines", "dumps",
    "heading", "heard", "ignored_text", "may_recover", "notes", "once", "print_answer",
    "reach_problem", "recover_targets", "rendered", "report", "report_unheard", "run",
    "say", "screen", "settings_of", "snapshot", "stop_all_keyed", "stop_as_found", "stream"]


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

