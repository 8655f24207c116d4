"""The fleet view's pure parts: which tokens can be a base's, what a view shows of a base
and of an answer, what keeps a view from its bases, the mode a view takes, and its
tables (printable, unpadded, within the screen)."""

from __future__ import annotations

import argparse
import json
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.zenoh import rmw
from omnican.zenoh.fleet import STRING, Answer, BaseView, check, same_session
from omnican.zenoh.settings import ZenohSettings
from omnican.zenoh.summary import Summary

CHUNK = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True)
NAMESPACES = st.lists(CHUNK, max_size=3).map(lambda cs: "/" + "/".join(cs))
ZIDS = st.binary(min_size=1, max_size=16).map(bytes.hex)
HASH = rmw.type_hash(STRING)


def token(node: rmw.RosNode, topic: str | None = None, type_name: str = STRING,
          kind: rmw.Kind = rmw.Kind.PUBLISHER) -> rmw.Token:
    fq = topic or rmw.fully_qualified(node.namespace, "base_summary")
    return rmw.parse_token(node.endpoint_token(1, kind, fq, type_name, HASH, rmw.Qos()))


@given(ZIDS, NAMESPACES, CHUNK, st.integers(0, 232))
def test_a_bases_summary_token_can_be_a_base(zid: str, ns: str, name: str,
                                             domain: int) -> None:
    node = rmw.RosNode(domain, zid, 3, name, namespace=ns)
    assert check(token(node), domain) is None
    assert check(token(node), (domain + 1) % 233) == f"domain {domain}, not {(domain + 1) % 233}"


@pytest.mark.parametrize(("node", "topic", "type_name", "kind", "why"), [
    (rmw.RosNode(0, "ab12", 0, "omnican", namespace="/r1"), "/r2/base_summary", STRING,
     rmw.Kind.PUBLISHER, "not its node's base_summary"),
    (rmw.RosNode(0, "ab12", 0, "omnican", namespace="/r1"), None, "nav_msgs/msg/Odometry",
     rmw.Kind.PUBLISHER, "not a String publisher"),
    (rmw.RosNode(0, "ab12", 0, "omnican", namespace="/r1"), None, STRING,
     rmw.Kind.SUBSCRIPTION, "not a String publisher"),
    (rmw.RosNode(0, "not-hex", 0, "omnican", namespace="/r1"), None, STRING,
     rmw.Kind.PUBLISHER, "its session id is not a Zenoh id"),
    (rmw.RosNode(0, "ab12", 0, "omnican", namespace="/evil\x1b[2J"), None, STRING,
     rmw.Kind.PUBLISHER, "its node's name is not a ROS 2 name"),
    (rmw.RosNode(0, "ab12", 0, "omni can", namespace="/r1"), None, STRING,
     rmw.Kind.PUBLISHER, "its node's name is not a ROS 2 name"),
])
def test_what_cannot_be_a_bases_token_says_why(node: rmw.RosNode, topic: str | None,
                                               type_name: str, kind: rmw.Kind,
                                               why: str) -> None:
    assert check(token(node, topic, type_name, kind), 0) == why


@given(st.binary(min_size=1, max_size=16))
def test_a_zenoh_id_names_one_session_however_it_is_written(raw: bytes) -> None:
    text = raw.hex()
    assert same_session(text, text.upper())
    assert same_session(text, "00" + text)
    assert not same_session(text, text + "1")


def summary(**changes: Any) -> Summary:
    fields: dict[str, Any] = {
        "node": "/r1/omnican", "state": "RUNNING", "stopped_reason": "", "enabled": True,
        "estop": False, "pose": (1.0, 2.0, 0.5), "speed": (0.2, 0.0, 0.1), "faults": (),
        "stamp": 1.0, "period_s": 0.5}
    fields.update(changes)
    return Summary(**fields)


def view(**changes: Any) -> BaseView:
    fields: dict[str, Any] = {"name": "/r1/omnican", "zid": "ab12", "summary": summary(),
                              "age_s": 0.1, "lost": False, "silent": False}
    fields.update(changes)
    return BaseView(**fields)


def test_a_views_state_says_the_worst_first() -> None:
    assert view().state == "RUNNING"
    assert view(heard=False, summary=None).state == "NOT HEARD"
    assert view(silent=True).state == "SILENT"
    assert view(silent=True, bad_summary="not JSON").state == "BAD SUMMARY"
    assert view(lost=True, bad_summary="not JSON").state == "LOST"
    got = json.loads(json.dumps(view(bad_summary="x", conflict=("cd34",)).as_json(),
                                allow_nan=False))
    assert (got["state"], got["bad_summary"], got["conflict"]) == (
        "BAD SUMMARY", "x", ["cd34"])


def test_an_answer_says_who_else_replied() -> None:
    assert str(Answer("/r1/omnican", True, True, "stopped")) == "/r1/omnican: ok: stopped"
    assert str(Answer("/r1/omnican", False, False, "none within 2 s")) == \
        "/r1/omnican: no answer (none within 2 s)"
    assert str(Answer("/r1/omnican", True, True, "stopped", "ab12", ("cd34",))) == (
        "/r1/omnican: ok: stopped [ignored: a reply from another session (cd34): an "
        "intruder on its service]")
    assert "[ignored: a reply from 4 other sessions (a, b, c, ...)" in str(
        Answer("/r1/omnican", True, True, "stopped", "ab12", ("a", "b", "c", "d")))


# ------------------------------------------------------------------ the command line


def args(*argv: str) -> argparse.Namespace:
    from omnican.cli import build_parser

    return build_parser("fleet").parse_args(["fleet", *argv])


@pytest.mark.parametrize(("argv", "mode"), [
    ((), "peer"),  # nothing to go through: a peer (multicast, if asked)
    (("--zenoh-connect", "tcp/10.0.0.1:7447"), "client"),  # a router: its client
    (("--zenoh-connect", "tcp/10.0.0.1:7447", "--zenoh-mode", "peer"), "peer"),
    (("--router",), "router"),
])
def test_a_view_given_a_router_is_its_client(argv: tuple[str, ...], mode: str) -> None:
    from omnican.cli.fleet import settings_of

    assert settings_of(args(*argv)).mode == mode


def test_what_keeps_a_view_from_its_bases() -> None:
    from omnican.cli.fleet import reach_problem

    to = ZenohSettings(mode="client", connect=("tcp/127.0.0.1:1", "tcp/10.0.0.1:7447"))
    assert reach_problem(to, 0) == "cannot reach tcp/127.0.0.1:1, tcp/10.0.0.1:7447"
    assert reach_problem(to, 1) is None
    assert reach_problem(ZenohSettings(mode="router"), 0) is None  # bases come to it
    assert reach_problem(ZenohSettings(), 0) == (
        "reaches no Zenoh router or peer (no --zenoh-connect, and multicast is off)")
    assert reach_problem(ZenohSettings(multicast=True), 0) == "reaches no Zenoh router or peer"


def test_the_title_says_the_counts_first() -> None:
    from omnican.cli.fleet import heading

    views = [view(conflict=("cd34",)), view(name="/r2/omnican", lost=True)]
    assert heading(views, "domain 0 via tcp/h:7447", {"no summary": 5000}, True) == (
        "omnican fleet - 2 bases, 1 lost, 1 in conflict, 5000 tokens ignored, listing "
        "the tokens already there - domain 0 via tcp/h:7447")
    assert heading([view()], "domain 0 via peers", {"no summary": 0}) == \
        "omnican fleet - 1 base - domain 0 via peers"


def test_the_ignored_tokens_are_counted_by_why() -> None:
    from omnican.cli.fleet import ignored_text

    assert ignored_text({"no summary": 0, "not a base": 0, "over the limit": 0}) == ""
    assert ignored_text({"no summary": 5000, "not a base": 0, "over the limit": 0}) == \
        "5000 tokens ignored (no summary)"
    assert ignored_text({"no summary": 2, "not a base": 1, "over the limit": 0}) == \
        "3 tokens ignored (2 no summary, 1 not a base)"


def test_a_snapshot_is_as_wide_as_its_cells_and_unpadded() -> None:
    from omnican.cli.fleet import ONCE_WIDTH, base_table, rendered

    lines = rendered(base_table([view(), view(name="/r2/omnican", zid="cd34")], None, None),
                     ONCE_WIDTH)
    assert len(lines) == 3 and lines[1].startswith(" /r1/omnican RUNNING")
    assert all(line == line.rstrip() for line in lines)
    assert max(map(len, lines)) < 80


@given(st.text(min_size=1, max_size=60) | st.sampled_from(["[bold]x[/]", "[/]", "[link=x]"]))
def test_the_dashboard_shows_a_peers_text_and_no_escape(raw: str) -> None:
    """Text from the network is made printable as it is read (the fleet's views hold
    it so); the dashboard shows it as it is: never as rich markup, never wider or
    taller than the screen."""
    from omnican.cli.fleet import rendered, screen
    from omnican.errors import printable

    text = printable(raw)
    bad = view(name=text, zid=text, bad_summary=text, conflict=(text,),
               summary=summary(stopped_reason=text, driver=text, faults=(text,), state=text))
    lines = rendered(screen([bad], (text, text), "fleet", [text], 80, 24,
                            f"cannot reach {text}", {"no summary": 3}), 80)
    from rich.cells import cell_len

    assert all(line.isprintable() for line in lines)
    assert len(lines) <= 24 and all(cell_len(line) <= 80 for line in lines)  # columns
    if raw.startswith("[") and len(text) < 20:
        assert any(text in line for line in lines), lines  # shown, not taken as markup


def test_the_dashboard_says_what_keeps_it_from_the_bases() -> None:
    from omnican.cli.fleet import rendered, screen

    lines = rendered(screen([], None, "domain 0 via tcp/127.0.0.1:1", [], 80,
                            24, "cannot reach tcp/127.0.0.1:1", {}), 80)
    assert lines[0] == "omnican fleet - 0 bases - domain 0 via tcp/127.0.0.1:1"
    assert lines[1] == "cannot reach tcp/127.0.0.1:1: no base can be seen or stopped from here"
