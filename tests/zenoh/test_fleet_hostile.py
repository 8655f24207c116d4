"""The fleet view with a stranger on the network: raw eclipse-zenoh sessions in this
process (tests/zenoh/hostile.py), clients of the loopback router beside lock-step bases
and their bridges. The stranger declares tokens that announce bases, claims a real
base's name, answers its stop in its place, sends escape sequences and NaN; the view
must show the real bases and only them, take only the real base's answer, and never
pass a peer's text to the terminal or NaN to JSON. Waits have a generous real-time
timeout for the event; nothing is timed."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest

from tests.support.helpers import still
from tests.zenoh import hostile
from tests.zenoh.conftest import client, wait_real
from tests.zenoh.test_fleet import TIMEOUT_S, based, run_until, summarized

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                    "(pip install 'omnican[zenoh]')")

ROBOT1 = "/robot1/omnican"


@pytest.fixture
def fleet(router: str) -> Iterator[Any]:
    from omnican.zenoh.fleet import Fleet

    session = client(router)
    try:
        with Fleet(session) as f:
            yield f
    finally:
        session.close()


@pytest.fixture
def stranger(router: str) -> Iterator[Any]:
    session = hostile.session_of(router)
    try:
        yield session
    finally:
        session.close()


def test_a_second_session_claiming_a_name_is_a_conflict_not_a_lost_base(
        channel: str, router: str, fleet: Any, stranger: Any) -> None:
    with based(channel, router, "/robot1") as rig:
        assert run_until((rig,), summarized(fleet, {ROBOT1}))
        real = fleet.find("robot1")
        fake = hostile.FakeBase(stranger, "/robot1")  # the same name, its own session
        stranger_zid = str(stranger.info.zid())
        assert run_until((rig,), lambda: fleet.bases()[0].conflict == (stranger_zid,))
        views = fleet.bases()
        assert [(v.name, v.zid, v.state) for v in views] == [(ROBOT1, real.zid, "RUNNING")]
        assert fleet.find("robot1") is not None and fleet.find("robot1").zid == real.zid
        # a recover would reach both sessions' services (one key): not asked
        from omnican.cli.common import UsageError
        from omnican.cli.fleet import recover_targets

        with pytest.raises(UsageError, match="more than one session claims the name"):
            recover_targets(fleet, ["robot1"])
        assert recover_targets(fleet, ["all"]) == ([], [
            f"recover {ROBOT1}: not asked: more than one session claims the name, and a "
            f"recover would reach each ({real.zid}, {stranger_zid})"])
        fake.close()  # the stranger's token goes: nothing of the real base changes
        assert run_until((rig,), lambda: fleet.bases()[0].conflict == ())
        for _ in range(20):
            run_until((rig,), lambda: True)
        assert [(v.name, v.zid, v.state, v.lost) for v in fleet.bases()] == [
            (ROBOT1, real.zid, "RUNNING", False)]


def test_only_the_session_that_owns_a_service_answers_for_it(
        channel: str, router: str, fleet: Any, stranger: Any) -> None:
    from omnican.zenoh.services import trigger_response

    with based(channel, router, "/robot1") as rig:
        assert run_until((rig,), summarized(fleet, {ROBOT1}))
        node = rig[3].node

        def answer(query: Any) -> None:  # at once, before the base's poll: garbage, then
            query.reply(query.key_expr, b"garbage", attachment=query.attachment)  # an error
            query.reply_err(f"{hostile.ESCAPES}rogue error".encode())
            query.reply(query.key_expr, trigger_response(False, "refused by a stranger"))

        rogue = hostile.rogue(stranger, node, "stop", answer)
        driver = rig[2].command_source("a nav stack")
        from omnican.core.kinematics import Twist

        assert run_until((rig,), lambda: rig[1].true_twist.vx > 0.1,
                         each=lambda: driver.drive(Twist(0.2, 0.0, 0.0)))
        call = fleet.request("stop", [ROBOT1], TIMEOUT_S)
        assert run_until((rig,), call.done, each=lambda: driver.drive(Twist(0.2, 0.0, 0.0)))
        (got,) = call.answers()
        assert (got.name, got.answered, got.success, got.message) == (
            ROBOT1, True, True, "stopped: held until recover"), got
        assert got.intruders == (str(stranger.info.zid()),)
        assert "an intruder on its service" in str(got)
        assert fleet.intruders >= 1
        assert run_until((rig,), lambda: still(rig[1]),
                         each=lambda: driver.drive(Twist(0.2, 0.0, 0.0)))
        rogue.undeclare()


def test_a_summary_with_nan_is_a_bad_summary_and_json_stays_json(
        router: str, fleet: Any, stranger: Any) -> None:
    base = hostile.FakeBase(stranger, "/nan")
    try:
        def state() -> str | None:
            views = fleet.bases()
            return views[0].state if views else None

        base.publish(json.dumps(hostile.summary_of(base.name, speed={
            "vx": float("nan"), "vy": 0.0, "wz": float("inf")})))
        assert wait_real(lambda: state() == "BAD SUMMARY", TIMEOUT_S)
        (view,) = fleet.bases()
        assert view.bad_summary == "not JSON: NaN is not a JSON number"
        text = json.dumps(view.as_json(), allow_nan=False)  # no NaN reaches JSON
        assert json.loads(text)["bad_summary"] == view.bad_summary
        assert json.loads(text)["state"] == "BAD SUMMARY"

        base.publish(json.dumps(hostile.summary_of(base.name, battery_v="B")).replace(
            '"B"', "1e999"))  # JSON's number, a float's infinity
        assert wait_real(lambda: "battery_v is not a finite" in (
            fleet.bases()[0].bad_summary or ""), TIMEOUT_S)
        base.publish("{not json")
        assert wait_real(lambda: (fleet.bases()[0].bad_summary or "").startswith(
            "not JSON"), TIMEOUT_S)
        base.publish(json.dumps(hostile.summary_of("/robot1/omnican")))
        assert wait_real(lambda: "names node '/robot1/omnican'" in (
            fleet.bases()[0].bad_summary or ""), TIMEOUT_S)
        base.publish(hostile.summary_of(base.name))  # a good one: the base is well again
        assert wait_real(lambda: state() == "RUNNING", TIMEOUT_S)
        assert fleet.bases()[0].bad_summary is None and fleet.rejected == 4
    finally:
        base.close()


def test_summaries_no_base_claims_are_counted_not_shown(router: str, fleet: Any) -> None:
    from omnican.zenoh import rmw
    from omnican.zenoh.bridge import string_cdr

    session = client(router)
    try:
        key = rmw.data_key(0, "/robot9/base_summary", "std_msgs/msg/String",
                           rmw.type_hash("std_msgs/msg/String"))
        pub = session.declare_publisher(key)
        assert wait_real(lambda: pub.matching_status.matching)
        good = string_cdr(json.dumps(hostile.summary_of("/robot9/omnican")).encode())
        for payload in (b"\x00\x01", string_cdr(b"{not json"), good):
            pub.put(payload)  # no attachment: no GID, no token
        pub.put(good, attachment=rmw.Attachment(1, 0, bytes(16)).encode())  # a GID, no token
        assert wait_real(lambda: fleet.unclaimed == 4)
        assert fleet.bases() == [] and fleet.rejected == 0
        pub.undeclare()
    finally:
        session.close()


def test_what_a_peer_sends_is_shown_printable(router: str, fleet: Any, stranger: Any) -> None:
    from omnican.cli.fleet import rendered, screen

    bases = hostile.evil(stranger)
    try:
        names = {"/loud/omnican", "/nan/omnican"}
        assert wait_real(lambda: (hostile.publish_evil(bases) or True)
                         and {v.name for v in fleet.bases()} == names, TIMEOUT_S)
        assert wait_real(lambda: fleet.ignored()["not a base"] == 1, TIMEOUT_S)  # its name
        loud = fleet.find("loud")
        assert loud.summary.stopped_reason == "stopped\\x1b[2J\\x1b]0;PWNED\\x07"
        assert loud.summary.driver == "a driver\\x1b[2J\\x1b]0;PWNED\\x07"
        assert loud.summary.faults == ("wheel 1: \\x1b[2J\\x1b]0;PWNED\\x07",)
        lines = rendered(screen(fleet.bases(), (loud.name, loud.zid), "fleet", [], 200, 40,
                                None, fleet.ignored()), 200)
        assert not any("\x1b" in line or "\x07" in line for line in lines), lines
        assert any("stopped\\x1b[2J" in line for line in lines), lines

        call = fleet.request("stop", fleet.bases(), TIMEOUT_S)
        answers = {a.name: a for a in call.wait(TIMEOUT_S)}
        assert str(answers["/loud/omnican"]) == (
            "/loud/omnican: refused: error: \\x1b[2J\\x1b]0;PWNED\\x07rogue error")
        assert answers["/nan/omnican"].message == "stopped\\x1b[2J\\x1b]0;PWNED\\x07"
    finally:
        for base in bases:
            base.close()


def test_a_stop_to_a_lost_base_says_at_once_that_nothing_serves_it(
        channel: str, router: str, fleet: Any) -> None:
    with based(channel, router, "/robot2") as rig:
        assert run_until((rig,), summarized(fleet, {"/robot2/omnican"}))
    assert wait_real(lambda: fleet.bases()[0].lost, TIMEOUT_S)
    (answer,) = fleet.request("stop", ["/robot2/omnican"], TIMEOUT_S).wait(TIMEOUT_S)
    assert not answer.answered
    assert answer.message.startswith("lost "), answer
    assert "nothing serves its stop service: the query ended after" in answer.message
    assert f"none within {TIMEOUT_S:g} s" not in answer.message


def test_fake_tokens_neither_hide_the_bases_nor_are_listed(
        channel: str, router: str, stranger: Any) -> None:
    """2,000 tokens that announce a base, declared before the view starts: the base that
    publishes is listed alone, and stopped first; the tokens are counted, and asked to
    stop after it."""
    from omnican.zenoh.fleet import Fleet

    tokens = hostile.fake_tokens(stranger, 2000)
    session = client(router)
    try:
        with based(channel, router, "/robot1") as rig, Fleet(session) as fleet:
            assert run_until((rig,), summarized(fleet, {ROBOT1}))
            assert run_until((rig,), fleet.settled)
            assert [v.name for v in fleet.bases()] == [ROBOT1]
            assert fleet.ignored() == {"no summary": 2000, "not a base": 0,
                                       "over the limit": 0}
            assert len(fleet.unheard()) == 2000
            first = fleet.stop_all_call(TIMEOUT_S)
            rest = fleet.stop_unheard_call(TIMEOUT_S)
            assert first.names == [ROBOT1] and len(rest.names) == 2000
            assert run_until((rig,), lambda: first.done() and rest.done())
            assert [(a.answered, a.success) for a in first.answers()] == [(True, True)]
            assert not any(a.answered for a in rest.answers())
    finally:
        session.close()
        for token in tokens:
            token.undeclare()


def test_a_link_that_comes_after_wait_is_no_unreachable_router(router: str) -> None:
    """--wait bounds discovery, not the verdict that the router cannot be reached: a
    peer's link to its router comes later than a very short --wait (and later than 0.5 s
    on a busy machine, where CI found a reachable router said unreachable)."""
    from omnican.cli import main

    assert main(["fleet", "--once", "--wait", "0.001", "--zenoh-mode", "peer",
                 "--zenoh-connect", router]) == 0


def test_a_peer_view_that_sees_no_base_says_why(router: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    from omnican.cli import main

    assert main(["fleet", "--once", "--wait", "0.5", "--zenoh-mode", "peer",
                 "--zenoh-connect", router]) == 0
    out, err = capsys.readouterr()
    assert out == "no omnican base found\n"
    assert err == ("omnican: a peer sees only the bases it can open a link of its own to: "
                   "--zenoh-mode client goes through the router\n")
