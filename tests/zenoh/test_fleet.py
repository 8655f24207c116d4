"""The fleet view against two simulated bases in lock-step, each with its Zenoh bridge
on a loopback router under its own namespace: both found, both summarized, both stopped
by one fleet stop, a closed one shown lost, a quiet one silent. The test steps the
clocks while the Zenoh side delivers in its own threads (waits have a generous real-time
timeout for the event; nothing is timed)."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from omnican.chassis import Chassis
from omnican.clock import SimClock
from omnican.core.kinematics import Twist
from omnican.sim import SimulatedBase
from tests.support.helpers import lockstep_rig, with_truth
from tests.zenoh.conftest import client, wait_real

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed "
                    "(pip install 'omnican[zenoh]')")

TIMEOUT_S = 60.0  # real seconds: generous, for a loaded machine; a pass takes far less
Rig = tuple[SimClock, SimulatedBase, Chassis, Any, Any]  # clock, sim, base, bridge, session


@contextlib.contextmanager
def based(channel: str, router: str, namespace: str) -> Iterator[Rig]:
    """A lock-step base and its bridge (the simulator's truth attached) under
    ``namespace``, a client of ``router``."""
    from omnican.zenoh.bridge import ZenohBridge, open_session
    from omnican.zenoh.settings import ZenohSettings

    settings = ZenohSettings(mode="client", connect=(router,), namespace=namespace)
    with lockstep_rig(channel) as (clock, sim, base):
        session = open_session(settings)
        try:
            with with_truth(base, sim), \
                    ZenohBridge(base, settings, session, sim=sim, poll_thread=False) as bridge:
                yield clock, sim, base, bridge, session
        finally:
            session.close()


@pytest.fixture
def two(channel: str, router: str) -> Iterator[tuple[Rig, Rig]]:
    with based(channel, router, "/robot1") as a, based(channel + "-b", router, "/robot2") as b:
        yield a, b


@pytest.fixture
def fleet(router: str) -> Iterator[Any]:
    from omnican.zenoh.fleet import Fleet

    session = client(router)
    try:
        with Fleet(session) as f:
            yield f
    finally:
        session.close()


def run_until(rigs: tuple[Rig, ...], done: Callable[[], bool],
              each: Callable[[], None] | None = None) -> bool:
    """Step every base (and poll its bridge) until ``done()`` or TIMEOUT_S real seconds;
    ``each``: what a driver does every step."""
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        if each is not None:
            each()
        for clock, _, _, bridge, _ in rigs:
            clock.sleep(0.02)
            bridge.poll()
        if done():
            return True
        time.sleep(0.002)  # the Zenoh side's threads deliver meanwhile
    return done()


def summarized(fleet: Any, names: set[str]) -> Callable[[], bool]:
    def done() -> bool:
        return {v.name for v in fleet.bases() if v.summary is not None} >= names
    return done


NAMES = {"/robot1/omnican", "/robot2/omnican"}


def test_two_bases_are_found_and_summarized(two: tuple[Rig, Rig], fleet: Any) -> None:
    (_, sim1, base1, bridge1, ours1), _ = two
    assert run_until(two, lambda: summarized(fleet, NAMES)()
                     and fleet.find("robot1").summary.battery_v is not None)
    views = {v.name: v for v in fleet.bases()}
    assert set(views) == NAMES
    one = views["/robot1/omnican"]
    assert one.zid == str(ours1.info.zid())
    assert not one.lost and one.state in ("RUNNING", "STARTING")
    assert one.summary.node == "/robot1/omnican"
    assert one.summary.battery_v == pytest.approx(24.0, abs=0.5)
    assert one.summary.true_speed is not None  # the simulator's truth goes along
    assert json.loads(json.dumps(one.as_json()))["summary"]["node"] == "/robot1/omnican"
    assert fleet.find("robot2").name == "/robot2/omnican"
    assert fleet.find("/robot1").name == "/robot1/omnican"
    assert fleet.find("robot3") is None

    # Who drives and how fast, as the fleet hears it.
    driver = base1.command_source("the test's driver")
    assert run_until(two, lambda: fleet.find("robot1").summary.speed[0] > 0.15
                     and fleet.find("robot1").summary.driver == "the test's driver",
                     each=lambda: driver.drive(Twist(0.2, 0.0, 0.0)))
    assert sim1.true_twist.vx == pytest.approx(0.2, abs=0.02)
    assert bridge1.publishers["/base_summary"].count > 0
    assert bridge1.publishers["/status"].count > 0 and bridge1.publishers["/wheels"].count > 0


def test_the_fleet_stop_reaches_both_bases(two: tuple[Rig, Rig], fleet: Any) -> None:
    sims = [rig[1] for rig in two]
    drivers = [rig[2].command_source("a nav stack") for rig in two]

    def drive() -> None:  # both keep being driven: the stop must hold against them
        for d in drivers:
            d.drive(Twist(0.2, 0.0, 0.3))

    assert run_until(two, lambda: all(s.true_twist.vx > 0.15 for s in sims)
                     and summarized(fleet, NAMES)(), each=drive)
    call = fleet.stop_all_call(timeout_s=TIMEOUT_S)
    assert sorted(call.names) == sorted(NAMES)
    assert run_until(two, call.done, each=drive)
    answers = call.answers()
    assert [(a.answered, a.success, a.message) for a in answers] == [
        (True, True, "stopped: held until recover")] * 2
    assert run_until(two, lambda: all(abs(s.true_twist.vx) < 1e-3
                                      and abs(s.true_twist.wz) < 1e-3 for s in sims),
                     each=drive)

    # The bases say so: STOPPED with the stop's reason, speed zero, no one driving (the
    # stop took control from the nav stack, which stays refused while it keeps sending).
    def said_stopped() -> bool:
        views = fleet.bases()
        return len(views) == 2 and all(
            v.summary is not None and v.summary.driver is None
            and v.summary.state == "STOPPED"
            and v.summary.stopped_reason.startswith("stopped by Zenoh service client ")
            and max(map(abs, v.summary.speed)) < 1e-3 for v in views)

    assert run_until(two, said_stopped, each=drive)
    assert all(d.stopped_by() is not None for d in drivers)

    # The stop holds: another source (a second nav stack) moves nothing either, until
    # the base is recovered over the fleet.
    others = [rig[2].command_source("another nav stack") for rig in two]
    for _ in range(20):
        run_until(two, lambda: True, each=lambda: [o.drive(Twist(0.2, 0.0, 0.0))
                                                   for o in others])
    assert all(abs(s.true_twist.vx) < 1e-3 for s in sims)
    # A recover while a source still streams commands is refused (the base would move
    # on the next one): the nav stack is told who drives.
    call = fleet.request("recover", sorted(NAMES), timeout_s=TIMEOUT_S)
    assert run_until(two, call.done, each=lambda: [o.drive(Twist(0.2, 0.0, 0.0))
                                                   for o in others])
    assert all(not a.success and "another nav stack is driving" in a.message
               for a in call.answers()), call.answers()
    # Once it has let go, the recover goes through and it drives again.
    clock = two[0][0]
    let_go = clock.now() + 2 * two[0][2].cfg.chassis.cmd_timeout_s
    assert run_until(two, lambda: clock.now() > let_go)
    call = fleet.request("recover", sorted(NAMES), timeout_s=TIMEOUT_S)
    assert run_until(two, call.done)
    assert all(a.success for a in call.answers()), call.answers()
    assert run_until(two, lambda: all(s.true_twist.vx > 0.1 for s in sims),
                     each=lambda: [o.drive(Twist(0.2, 0.0, 0.0)) for o in others])


def test_recover_and_a_base_that_does_not_answer(two: tuple[Rig, Rig], fleet: Any) -> None:
    (_, sim1, _, _, _), _ = two
    assert run_until(two, summarized(fleet, NAMES))
    sim1.drives[1].inject_fault(0x2310)
    assert run_until(two, lambda: fleet.find("robot1").summary.state == "STOPPED"
                     and fleet.find("robot1").summary.faults != ())
    view = fleet.find("robot1")
    assert view.summary.faults[0].startswith("wheel ")
    assert "fault" in view.summary.stopped_reason
    call = fleet.request("recover", ["/robot1/omnican"], timeout_s=TIMEOUT_S)
    assert run_until(two, call.done)
    assert call.answers()[0].success, call.answers()[0]
    assert run_until(two, lambda: fleet.find("robot1").summary.state == "RUNNING")
    # Nobody steps the bases: no answer, within the bound.
    unanswered = fleet.request("stop", sorted(NAMES), timeout_s=0.5).wait(TIMEOUT_S)
    assert [a.answered for a in unanswered] == [False, False], unanswered
    assert "no answer" in str(unanswered[0])
    assert fleet.request("stop", ["/nobody/omnican"]).wait()[0].message == "no such base"


class _RouterFirst:
    """A session whose queries' timeouts reach it as the router's first: the router's
    "Timeout" reply, in the name of the base it asked (zenoh's QueryCleanup), comes
    before the session's own (the race CI lost)."""

    def __init__(self, session: Any) -> None:
        self._session = session
        self.zids: list[str] = []  # the bases the router times out for

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)

    def get(self, key: str, handler: Any, **kwargs: Any) -> None:
        import zenoh

        def on_reply(reply: Any) -> None:
            if reply.replier_id is None and reply.ok is None:  # the session's timeout
                for zid in self.zids:
                    handler.callback(_Reply(zid))
            handler.callback(reply)

        self._session.get(key, zenoh.handlers.Callback(on_reply, handler.drop), **kwargs)


class _Reply:
    """A router's timeout reply as zenoh-python gives it."""

    def __init__(self, zid: str) -> None:
        self.replier_id = type("Id", (), {"zid": zid})()
        self.ok = None
        self.err = type("Err", (), {"payload": type("P", (), {
            "to_bytes": staticmethod(lambda: b"Timeout")})()})()


def test_a_routers_timeout_is_no_answer_from_the_base(two: tuple[Rig, Rig],
                                                       router: str) -> None:
    from omnican.zenoh.fleet import Fleet

    session = client(router)
    try:
        wrapped = _RouterFirst(session)
        with Fleet(wrapped) as f:
            assert run_until(two, summarized(f, NAMES))
            wrapped.zids = [b.zid for b in f.bases()]
            # Nobody steps the bases: the router's timeout comes first, in their names.
            answers = f.request("stop", sorted(NAMES), timeout_s=0.5).wait(TIMEOUT_S)
            assert [a.answered for a in answers] == [False, False], answers
            assert all("none within 0.5 s" in str(a) for a in answers), answers
    finally:
        session.close()


def test_a_closed_base_is_lost(channel: str, router: str, fleet: Any) -> None:
    with based(channel, router, "/robot1") as one:
        with based(channel + "-b", router, "/robot2") as other:
            assert run_until((one, other), summarized(fleet, NAMES))
        # robot2's bridge and session closed: its tokens went
        assert wait_real(lambda: fleet.find("robot2").lost, TIMEOUT_S)
        assert fleet.find("robot2").state == "LOST"
        assert not fleet.find("robot1").lost
        assert [a.name for a in fleet.stop_all_call(TIMEOUT_S).answers()] == \
            ["/robot1/omnican"]  # the fleet stop asks those still there


def test_a_base_heard_no_more_is_silent(channel: str, router: str) -> None:
    from omnican.zenoh.fleet import Fleet

    now = [0.0]
    session = client(router)
    try:
        with based(channel, router, "/robot1") as rig, Fleet(session, clock=lambda: now[0]) as f:
            assert run_until((rig,), summarized(f, {"/robot1/omnican"}))
            view = f.bases()[0]
            assert not view.silent and view.age_s == 0.0
            now[0] += 3 * view.summary.period_s + 0.01  # its clock no longer steps
            assert f.bases()[0].silent and f.bases()[0].state == "SILENT"
    finally:
        session.close()


def test_status_and_wheels_go_out_as_strings_of_the_models_json(
        two: tuple[Rig, Rig], router: str) -> None:
    from omnican.telemetry import cdr
    from omnican.zenoh import rmw

    session = client(router)
    got: dict[str, list[dict[str, Any]]] = {"status": [], "wheels": []}
    try:
        subs = []
        for topic in got:
            key = rmw.data_key(0, f"/robot2/{topic}", "std_msgs/msg/String",
                               rmw.type_hash("std_msgs/msg/String"))
            assert key == two[1][3].publishers[f"/{topic}"].key
            subs.append(session.declare_subscriber(key, lambda sample, t=topic: got[t].append(
                json.loads(cdr.decode("std_msgs/msg/String", sample.payload.to_bytes())["data"]))))
        assert run_until(two, lambda: bool(got["status"] and got["wheels"]))
        assert got["status"][-1]["state"] in ("RUNNING", "STARTING")
        assert [w["index"] for w in got["wheels"][-1]["wheels"]] == [0, 1, 2]
        for sub in subs:
            sub.undeclare()
    finally:
        session.close()
