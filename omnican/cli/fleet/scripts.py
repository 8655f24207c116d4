"""omnican fleet for scripts: --once (one snapshot), --json (a line per refresh), --stop
and --recover (each base's answer printed; exit 1 when one failed)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from omnican.cli.common import EXIT_FAILURE, EXIT_OK, UsageError
from omnican.cli.fleet.link import CONFLICT, REACH_S, RECOVER_TIMEOUT_S, Link
from omnican.cli.fleet.view import ONCE_WIDTH, REFRESH_S, base_table, rendered
from omnican.errors import OmnicanError, printable

if TYPE_CHECKING:
    from omnican.zenoh.fleet import Answer, BaseView, Call, Fleet

IGNORED = ("tokens that announce a base but whose summary never came (a stranger's, or a "
           "base this view cannot hear) or that do not read as a base's")
PEER_HINT = ("a peer sees only the bases it can open a link of its own to: "
             "--zenoh-mode client goes through the router")


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


