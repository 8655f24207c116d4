"""One source of commands at a time: the arbiter's rules (pure, at given times), and the
handle a front end asks the base for (:meth:`Chassis.command_source`), which applies
them: two sources against a stand-in base on a simulated clock, and against a real base
in lock-step. A new front end (Zenoh, say) that sends only through its handle shares
control with the others by construction."""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import Chassis, Twist
from omnican.chassis.actions import RULES, Action, Rule, refuser
from omnican.chassis.arbiter import CommandArbiter, CommandSource
from omnican.clock import SimClock
from omnican.errors import DriveError
from omnican.sim import SimulatedBase
from tests.support.helpers import lockstep_rig, still

# ---------------------------------------------------------------- the arbiter


def test_the_first_source_holds_control_until_it_is_silent_or_leaves() -> None:
    arb = CommandArbiter(0.5)
    assert arb.claim("a", 0.0).ok
    assert arb.claim("b", 0.1).refused_by == "a"  # refused, told who drives
    assert arb.claim("a", 0.4).ok  # a fresh command keeps it
    assert arb.claim("b", 0.8).refused_by == "a"  # 0.4 s since a's last: still a's
    assert arb.claim("b", 0.95).ok  # a silent for 0.55 s: free, and b takes it
    assert arb.holder(0.95) == "b"
    assert not arb.release("a", 1.0)  # a does not hold it: nothing happens
    assert arb.holder(1.0) == "b"
    assert not arb.release("b", 1.6)  # b's hold had lapsed: it did not hold it then
    assert arb.claim("b", 1.6).ok
    assert arb.release("b", 1.7)
    assert arb.holder(1.7) is None
    assert arb.claim("a", 1.7).ok


def test_who_may_act_while_someone_drives() -> None:
    arb = CommandArbiter(0.5)
    assert arb.ask("b", Action.RECOVER, 0.0).refused_by is None  # no one drives
    arb.claim("a", 0.0)
    assert arb.ask("a", Action.RECOVER, 0.1).refused_by is None
    assert arb.ask("b", Action.RECOVER, 0.1).refused_by == "a"
    assert arb.holder(0.1) == "a"  # asking takes nothing
    assert arb.ask("b", Action.RECOVER, 0.6).refused_by is None


def test_a_stop_by_another_takes_control_until_the_driver_lets_go() -> None:
    arb = CommandArbiter(0.5)
    assert arb.stop_by("b", 0.0) is None  # no one drives: nothing to take
    arb.claim("a", 0.0)
    assert arb.stop_by("a", 0.1) is None  # its own stop: it keeps control
    assert arb.holder(0.1) == "a"
    assert arb.stop_by("b", 0.2) == "a"
    assert arb.holder(0.2) is None
    for t in (0.3, 0.6, 0.9):  # a keeps pressing: refused, told who stopped it
        assert arb.claim("a", t).refused_by == "b"
        assert arb.stopped_by("a", t) == "b"
    assert arb.claim("c", 1.0).ok  # anyone else may drive meanwhile
    arb.release("c", 1.0)
    assert arb.claim("a", 1.41).ok  # a let go for more than 0.5 s: it drives again
    assert arb.stopped_by("a", 1.41) is None


def test_a_release_runs_its_stop_only_for_the_holder() -> None:
    arb = CommandArbiter(0.5)
    stops: list[str] = []
    arb.claim("a", 0.0)
    assert not arb.release("b", 0.1, lambda: stops.append("b"))  # not b's to stop
    assert arb.release("a", 0.2, lambda: stops.append("a"))
    assert not arb.release("a", 0.3, lambda: stops.append("a again"))  # already let go
    assert stops == ["a"]


def test_no_one_starts_driving_while_another_recovers() -> None:
    """A recover takes seconds (it waits for the drives) and runs outside the arbiter's
    lock: while it runs, its source holds control, so a command that comes meanwhile is
    refused by it, however long it takes, and the base does not start under a recover
    whose source was told no one drove. Afterwards control is as it was."""
    arb = CommandArbiter(0.5)
    seen: list[tuple[str | None, str | None]] = []

    def recovering() -> None:  # another source tries meanwhile, 0.1 s and 5 s in
        for t in (0.1, 5.0):
            seen.append((arb.claim("b", t).refused_by, arb.ask("b", Action.RECOVER, t).refused_by))
        assert arb.holder(5.0) == "a"

    assert arb.perform("a", Action.RECOVER, 0.0, recovering, lambda: 5.1).ok
    assert seen == [("a", "a"), ("a", "a")]
    assert arb.holder(5.1) is None  # a did not drive before: no one holds control now
    assert arb.claim("b", 5.1).ok
    # b drives and recovers: it keeps control, counted from when the recover ended
    assert arb.perform("b", Action.RECOVER, 5.2, lambda: None, lambda: 9.0).ok
    assert arb.holder(9.4) == "b"
    assert arb.claim("a", 9.4).refused_by == "b"
    assert arb.perform("a", Action.RECOVER, 9.4, lambda: None, lambda: 9.4).refused_by == "b"


def test_a_stop_while_another_recovers_takes_control_as_from_a_driver() -> None:
    arb = CommandArbiter(0.5)
    took: list[str | None] = []

    def recovering() -> None:
        took.append(arb.stop_by("c", 1.0))  # anyone may stop, a recover too
        assert arb.claim("b", 1.1).ok  # then anyone may drive, as after any stop
        took.append(arb.stop_by("b", 1.2))  # (b's own stop: it keeps control)

    assert arb.perform("a", Action.RECOVER, 0.0, recovering, lambda: 3.0).ok
    assert took == ["a", None]
    assert arb.holder(1.5) == "b"  # the recover's end takes nothing from b
    assert arb.stopped_by("a", 1.5) == "c"
    assert arb.holder(1.7) is None  # b is silent: its hold lapses as any driver's


def test_a_recover_that_fails_gives_control_back() -> None:
    arb = CommandArbiter(0.5)

    def failing() -> None:
        assert arb.claim("b", 0.2).refused_by == "a"
        raise DriveError("recover refused: e-stop pressed")

    with pytest.raises(DriveError, match="e-stop"):
        arb.perform("a", Action.RECOVER, 0.0, failing, lambda: 0.3)
    assert arb.holder(0.3) is None
    assert arb.claim("b", 0.3).ok
    with pytest.raises(ValueError, match="own method"):
        arb.perform("a", Action.STOP, 0.4, lambda: None, lambda: 0.4)


@given(st.lists(st.tuples(st.sampled_from("abc"), st.floats(0.0, 1.0),
                          st.sampled_from(["claim", "release"])), max_size=60))
def test_control_changes_hands_only_when_the_holder_is_silent_or_gone(
        events: list[tuple[str, float, str]]) -> None:
    arb = CommandArbiter(0.5)
    now, holder, last = 0.0, None, -math.inf
    for source, dt, action in events:
        now += dt
        if holder is not None and now - last > 0.5:
            holder = None  # the model: silent for the timeout
        if action == "release":
            assert arb.release(source, now) == (holder == source)
            if holder == source:
                holder = None
            continue
        refused = arb.claim(source, now).refused_by
        if holder is None or holder == source:
            assert refused is None
            holder, last = source, now
        else:
            assert refused == holder
        assert arb.holder(now) == holder


def test_an_arbiter_needs_a_timeout() -> None:
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            CommandArbiter(bad)


# ---------------------------------------------------------------- the handle


@dataclass(eq=False)
class FakeBase:
    """What a source calls on a base, recorded, on a simulated clock; it hands out
    sources as :meth:`Chassis.command_source` does (one arbiter for all)."""

    clock: SimClock = field(default_factory=SimClock)
    calls: list[tuple[str, Any]] = field(default_factory=list)
    arbiter: CommandArbiter = field(default_factory=lambda: CommandArbiter(0.5))

    def command_source(self, name: str) -> CommandSource:
        return CommandSource(self, self.arbiter, name)

    def set_twist(self, twist: Twist) -> None:
        if not twist.is_finite():
            raise ValueError("velocity command refused: not finite")
        self.calls.append(("twist", twist))

    def stop(self) -> None:
        self.calls.append(("stop", None))

    refuse: str | None = None  # what recover raises, if anything

    def halt(self, reason: str) -> None:
        self.calls.append(("halt", reason))

    def recover(self) -> None:
        if self.refuse is not None:
            raise DriveError(self.refuse)
        self.calls.append(("recover", None))

    def reset_pose(self, pose: Any = None) -> None:
        self.calls.append(("reset_pose", pose))

    def set_limits(self, **changes: float) -> None:
        self.calls.append(("limits", changes))


def test_two_sources_share_the_base_one_at_a_time() -> None:
    """Claim, refusal, hand-over at the timeout, a stop by the one not driving, release:
    what a front end gets from its handle alone."""
    base = FakeBase()
    keys, zenoh = base.command_source("keys"), base.command_source("zenoh")
    clock = base.clock
    assert keys.timeout_s == 0.5

    # claim: the first to send drives; the other is refused and told who drives
    assert keys.drive(Twist(0.2, 0.0, 0.0)).ok
    assert (keys.holder(), zenoh.holder()) == ("keys", "keys")
    clock.sleep(0.1)
    assert zenoh.drive(Twist(0.0, 0.0, 1.0)).refused_by == "keys"
    assert zenoh.may(Action.RECOVER).refused_by == "keys" and keys.may(Action.RECOVER).ok
    assert base.calls == [("twist", Twist(0.2, 0.0, 0.0))]  # the refused twist went nowhere

    # timeout hand-over: keys silent for longer than the timeout, zenoh takes control
    clock.sleep(0.45)  # 0.55 s since keys' last command
    assert zenoh.drive(Twist(0.0, 0.0, 1.0)).ok
    assert keys.holder() == "zenoh"
    assert keys.drive(Twist(0.3, 0.0, 0.0)).refused_by == "zenoh"

    # a stop by the one not driving: the base stops, the driver is out until it lets go
    calls = len(base.calls)
    assert keys.stop() == "zenoh"
    assert base.calls[calls:] == [("stop", None)]
    assert keys.holder() is None
    for _ in range(3):  # zenoh keeps sending: refused, told who stopped it
        clock.sleep(0.2)
        assert zenoh.drive(Twist(0.0, 0.0, 1.0)).refused_by == "keys"
        assert zenoh.stopped_by() == "keys"
    assert base.calls[calls:] == [("stop", None)]
    assert keys.drive(Twist(0.1, 0.0, 0.0)).ok  # meanwhile anyone else may drive

    # release: keys leave; the base stops (they drove it) and control is free
    calls = len(base.calls)
    assert keys.release(stop=True)
    assert base.calls[calls:] == [("stop", None)]
    assert not keys.release(stop=True)  # not held any more: nothing more stops
    assert base.calls[calls:] == [("stop", None)]
    assert keys.holder() is None
    clock.sleep(0.6)  # zenoh let go of its refused commands: it drives again
    assert zenoh.stopped_by() is None
    assert zenoh.drive(Twist(0.0, 0.0, 0.5)).ok
    assert zenoh.release() and base.calls[-1] == ("twist", Twist(0.0, 0.0, 0.5))


def test_a_twist_the_base_refuses_takes_no_control() -> None:
    base = FakeBase()
    keys, zenoh = base.command_source("keys"), base.command_source("zenoh")
    with pytest.raises(ValueError, match="not finite"):
        zenoh.drive(Twist(math.nan, 0.0, 0.0))
    assert zenoh.holder() is None and base.calls == []
    assert keys.drive(Twist(0.1, 0.0, 0.0)).ok


_ACTIONS = st.lists(st.tuples(st.sampled_from(["a", "b"]),
                              st.sampled_from(["send", "stop", "release", "wait"]),
                              st.floats(0.0, 0.4)), max_size=40)


@given(_ACTIONS)
def test_the_base_moves_only_for_the_source_that_holds_control(
        actions: list[tuple[str, str, float]]) -> None:
    """Whatever two sources do, every twist the base receives comes from the one that
    then holds control, and a release stops the base only for the one that drove it."""
    base = FakeBase()
    sources = {name: base.command_source(name) for name in "ab"}
    for name, action, dt in actions:
        base.clock.sleep(dt)
        source, before = sources[name], base.arbiter.holder(base.clock.now())
        calls = len(base.calls)
        if action == "send":
            refused = source.drive(Twist(0.1, 0.0, 0.0)).refused_by
            sent = base.calls[calls:]
            assert (refused is None) == (sent == [("twist", Twist(0.1, 0.0, 0.0))])
            if refused is None:
                assert source.holder() == name
            else:
                assert sent == [] and refused != name
        elif action == "stop":
            taken = source.stop()
            assert base.calls[calls:] == [("stop", None)]  # anyone may stop
            assert taken == (before if before not in (None, name) else None)
        elif action == "release":
            released = source.release(stop=True)
            assert released == (before == name)
            assert base.calls[calls:] == ([("stop", None)] if released else [])


# ---------------------------------------------------------------- a real base


@pytest.fixture
def rig(channel: str) -> Iterator[tuple[SimClock, SimulatedBase, Chassis]]:
    with lockstep_rig(channel) as r:
        yield r


def test_every_source_of_a_base_shares_its_one_arbiter(
        rig: tuple[SimClock, SimulatedBase, Chassis]) -> None:
    """Sources of a real base, asked for one by one (as two front ends do), drive it one
    at a time."""
    clock, sim, base = rig
    keys, zenoh = base.command_source("keys"), base.command_source("zenoh")
    assert keys.timeout_s == base.cfg.chassis.cmd_timeout_s
    sent = Twist(0.2, 0.0, 0.0)
    assert keys.drive(sent).ok
    assert zenoh.drive(Twist(0.0, 0.0, 1.0)).refused_by == "keys"
    assert clock.run_until(lambda: sim.true_twist.vx == pytest.approx(0.2, abs=0.01),
                           2.0, 0.02)
    assert base.command == sent and abs(sim.true_twist.wz) < 1e-2  # zenoh's went nowhere
    assert zenoh.stop() == "keys"  # anyone may stop
    clock.sleep(0.1)
    assert keys.drive(sent).refused_by == "zenoh" and keys.stopped_by() == "zenoh"  # out till it lets go
    assert clock.run_until(lambda: still(sim), 2.0, 0.02)
    clock.sleep(base.cfg.chassis.cmd_timeout_s)
    assert zenoh.drive(Twist(0.0, 0.0, 0.5)).ok
    assert clock.run_until(lambda: base.command == Twist(0.0, 0.0, 0.5), 2.0, 0.02)
    assert zenoh.release(stop=True)
    assert clock.run_until(lambda: still(sim), 2.0, 0.02)


# ---------------------------------------------------------------- the table


@given(st.sampled_from(list(Action)), st.sampled_from("ab"), st.sampled_from([None, "a", "b"]))
def test_an_action_is_refused_only_by_another_that_drives_and_only_by_its_rule(
        action: Action, source: str, driver: str | None) -> None:
    refused = refuser(action, source, driver)
    if RULES[action] is Rule.ANYONE or driver in (None, source):
        assert refused is None
    else:
        assert refused == driver


def test_anyone_may_stop_and_the_rest_waits_for_the_driver() -> None:
    """The table's safety rows: a stop (held or not) is never refused."""
    assert RULES[Action.STOP] is RULES[Action.HALT] is Rule.ANYONE
    assert {a for a, r in RULES.items() if r is Rule.ANYONE} == {Action.STOP, Action.HALT}


_ASKED = st.lists(st.tuples(st.sampled_from("abc"), st.sampled_from(list(Action)),
                            st.floats(0.0, 0.4)), max_size=40)


@given(_ASKED)
def test_the_arbiter_answers_every_action_by_the_table(
        asked: list[tuple[str, Action, float]]) -> None:
    """Whatever three sources ask, each action is done (its ``run`` runs) exactly when
    the table lets it, the answer names the driver when it does not, and a stop by
    another than the driver takes control from it."""
    arb = CommandArbiter(0.5)
    now = 0.0
    for source, action, dt in asked:
        now += dt
        driver = arb.holder(now)
        ran: list[str] = []
        if action is Action.DRIVE:
            refused = arb.claim(source, now, functools.partial(ran.append, "drive")).refused_by
            assert (refused is None) == bool(ran)
            if refused is None:
                assert driver in (None, source) and arb.holder(now) == source
            continue
        assert arb.ask(source, action, now).refused_by == refuser(action, source, driver)
        answer = arb.decide(source, action, now, functools.partial(ran.append, "run"))
        assert answer.refused_by == refuser(action, source, driver)
        assert answer.ok == bool(ran) and answer.failed is None
        if action.stops and driver not in (None, source):
            assert answer.took_from == driver and arb.holder(now) is None
            assert arb.stopped_by(driver, now) == source
        else:
            assert answer.took_from is None and arb.holder(now) == driver


def test_a_source_that_recovers_holds_control_until_it_is_done() -> None:
    """Through the handles: a client's recover on a stand-in base whose recover takes
    two seconds, with the keys pressed meanwhile (refused: the client acts), and after
    it (done: the client did not drive)."""
    base = FakeBase()
    keys, client = base.command_source("keys"), base.command_source("client")
    meanwhile: list[str | None] = []
    slow = base.recover

    def recover_for_two_seconds() -> None:
        base.clock.sleep(1.0)
        meanwhile.append(keys.drive(Twist(0.3, 0.0, 0.0)).refused_by)
        meanwhile.append(keys.may(Action.RESET_POSE).refused_by)
        base.clock.sleep(1.0)
        slow()

    base.recover = recover_for_two_seconds  # type: ignore[method-assign]
    assert client.recover().ok
    assert meanwhile == ["client", "client"]
    assert [c for c, _ in base.calls] == ["recover"]  # the keys' command never reached it
    assert client.holder() is None
    assert keys.drive(Twist(0.3, 0.0, 0.0)).ok


def test_every_action_through_a_source_answers_who_refused_or_what_failed() -> None:
    """The handle's actions on a stand-in base: done, refused naming the driver (the base
    is not asked), or failed with the base's words (a refusal it raised)."""
    base = FakeBase()
    keys, client = base.command_source("keys"), base.command_source("client")
    acts = {"recover": client.recover, "reset_pose": client.reset_pose,
            "set_limits": lambda: client.set_limits(max_speed=0.2)}
    assert keys.drive(Twist(0.2, 0.0, 0.0)).ok
    for name, act in acts.items():
        answer = act()
        assert (answer.ok, answer.refused_by, answer.failed) == (False, "keys", None), name
        assert answer.why == (f"keys is driving; only it may {answer.action.value} now "
                              "(anyone may stop)")
    assert [c for c, _ in base.calls] == ["twist"]  # the base was asked nothing
    halted = client.halt("stopped by client")
    assert halted.ok and halted.took_from == "keys"
    assert base.calls[-1] == ("halt", "stopped by client")
    for name, act in acts.items():  # no one drives now: done
        assert act().ok, name
    assert [c for c, _ in base.calls[-3:]] == ["recover", "reset_pose", "limits"]
    base.refuse = "recover refused: e-stop pressed"
    failed = client.recover()
    assert (failed.ok, failed.refused_by, failed.failed) == (
        False, None, "recover refused: e-stop pressed")
    assert failed.why == "recover refused: e-stop pressed"
    assert keys.may(Action.RECOVER).ok and keys.may(Action.RECOVER).refused_by is None
    with pytest.raises(ValueError, match="own method"):
        client.act(Action.STOP, lambda: None)
