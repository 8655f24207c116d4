"""The simulated node's heartbeat bookkeeping (1017h producer, 1016h consumer), pure."""

from __future__ import annotations

from collections.abc import Callable

import canopen
from hypothesis import example, given, settings
from hypothesis import strategies as st

from omnican import WHEEL_EDS
from omnican.sim.heartbeat import Heartbeat


def getter(values: dict[tuple[int, int], int]) -> Callable[[int, int], bytes]:
    def get(index: int, sub: int) -> bytes:
        return values[(index, sub)].to_bytes(4, "little")  # KeyError: no value

    return get


def test_load_reads_the_producer_time_and_every_consumer_entry() -> None:
    od = canopen.import_od(str(WHEEL_EDS), 1)
    hb = Heartbeat()
    values = {(0x1017, 0): 250, (0x1016, 1): (0x7F << 16) | 300, (0x1016, 2): (5 << 16) | 0}
    assert hb.load(od, getter(values)) == [0x7F]  # an entry with 0 ms watches nothing
    assert hb.period_s == 0.25 and hb.timeouts == {0x7F: 0.3}
    assert hb.load(od, getter({})) == [] and hb.period_s == 0.0  # nothing configured


def test_a_consumer_starts_at_the_first_heartbeat_and_reports_a_loss_once() -> None:
    hb = Heartbeat()
    hb.timeouts = {0x7F: 0.1}
    assert hb.expired(10.0) == []  # never heard: not watched yet
    assert hb.heard(0x7F, 10.0) is False
    assert hb.expired(10.1) == []  # exactly the timeout: still alive
    assert hb.expired(10.15) == [0x7F]
    assert hb.expired(11.0) == []  # reported once
    assert hb.heard(0x7F, 11.0) is True  # back
    assert hb.expired(11.05) == []
    hb.restart()  # a boot: the next heartbeat starts the watch again
    assert hb.expired(20.0) == []


def test_reloading_keeps_what_was_heard_of_producers_still_watched() -> None:
    od = canopen.import_od(str(WHEEL_EDS), 1)
    hb = Heartbeat()
    hb.load(od, getter({(0x1016, 1): (0x7F << 16) | 100, (0x1016, 2): (3 << 16) | 100}))
    hb.heard(0x7F, 1.0)
    hb.heard(3, 1.0)
    assert sorted(hb.expired(1.2)) == [3, 0x7F]
    hb.load(od, getter({(0x1016, 1): (0x7F << 16) | 500}))
    assert hb.expired(5.0) == []  # 0x7F is still lost (reported), node 3 is gone
    assert hb.heard(0x7F, 5.0) is True


def test_the_producer_is_due_once_a_period_has_passed() -> None:
    hb = Heartbeat()
    assert not hb.due(100.0)  # 1017h = 0: no heartbeat
    hb.period_s, hb.last_sent = 0.05, 1.0
    assert not hb.due(1.04)
    assert hb.due(1.05)



@given(period_ms=st.integers(10, 1000),
       ticks=st.lists(st.floats(0.0005, 1.0), min_size=50, max_size=400))
def test_the_producer_keeps_its_cadence_however_late_each_tick_finds_it(
        period_ms: int, ticks: list[float]) -> None:
    """A drive's heartbeat timer keeps its period: ticks that come late (a control cycle
    apart, as when the base's loop runs the simulated drives) delay a heartbeat, never
    the ones after it. Over any run, as many heartbeats as whole periods (one more at
    most) whenever no tick gap exceeds a period; main's producer restarted its period at
    each late tick, 5 % fewer heartbeats at 100 ms with 10 ms cycles."""
    hb = Heartbeat()
    hb.period_s = period_ms / 1000.0
    hb.last_sent = 0.0
    now, sent = 0.0, 0
    gaps = [t * hb.period_s for t in ticks]  # every tick within a period of the last
    for gap in gaps:
        now += gap
        if hb.due(now):
            hb.last_sent = hb.next_from(now)
            sent += 1
            assert hb.last_sent <= now + 1e-9  # never counted as sent in the future
    assert int(now / hb.period_s) - 1 <= sent <= int(now / hb.period_s)


def test_a_producer_far_behind_starts_its_period_again() -> None:
    """A tick more than a period late (a frozen host, a stopped process) does not send a
    burst of heartbeats to catch up: the next is a period after this one."""
    hb = Heartbeat()
    hb.period_s, hb.last_sent = 0.1, 0.0
    assert hb.due(0.35)
    hb.last_sent = hb.next_from(0.35)
    assert hb.last_sent == 0.35 and not hb.due(0.44) and hb.due(0.45)


class _Reference:
    """The consumer's bookkeeping as it was: every producer looked at on every call."""

    def __init__(self) -> None:
        self.timeouts: dict[int, float] = {}
        self.seen: dict[int, float] = {}
        self.lost: set[int] = set()

    def heard(self, producer: int, now: float) -> bool:
        self.seen[producer] = now
        if producer in self.lost:
            self.lost.discard(producer)
            return True
        return False

    def expired(self, now: float) -> list[int]:
        lost = []
        for producer, timeout in self.timeouts.items():
            seen = self.seen.get(producer)
            if seen is None or producer in self.lost:
                continue
            if now - seen > timeout:
                self.lost.add(producer)
                lost.append(producer)
        return lost


_OPS = st.lists(st.one_of(
    st.tuples(st.just("heard"), st.sampled_from([1, 2, 0x7F])),
    st.tuples(st.just("step"), st.sampled_from([0.0, 0.01, 0.05, 0.1, 0.2, 0.3, 1.0])),
    st.tuples(st.just("jump"), st.floats(0, 1e5, allow_nan=False)),
    st.tuples(st.just("timeouts"), st.dictionaries(st.sampled_from([1, 2, 0x7F]),
                                                   st.sampled_from([0.05, 0.1, 0.3, 2.0]))),
    st.tuples(st.just("restart"),),
    st.tuples(st.just("period"), st.sampled_from([0.0, 0.1, 0.25])),
    st.tuples(st.just("sent"),),
), max_size=60)


@example([("timeouts", {1: 2.0}), ("heard", 1), ("step", 0.1), ("timeouts", {1: 0.05}),
          ("step", 0.1)])
@settings(max_examples=300)
@given(_OPS)
def test_expired_reports_what_looking_at_every_producer_every_time_reports(
        ops: list[tuple]) -> None:  # type: ignore[type-arg]
    """The consumer skips its producers until the first of them could time out: the
    losses it reports, and when, are those of looking at each at every call (checked
    after every step; time going backwards, new timeouts and boots included); a tick
    told nothing is pending has no heartbeat due and no loss to report."""
    hb, ref = Heartbeat(), _Reference()
    now = 0.0
    for op in ops:
        kind = op[0]
        if kind == "heard":
            assert hb.heard(op[1], now) == ref.heard(op[1], now)
        elif kind in ("step", "jump"):
            now = now + op[1] if kind == "step" else op[1]
        elif kind == "timeouts":
            hb.timeouts, ref.timeouts = dict(op[1]), dict(op[1])
        elif kind == "restart":
            hb.restart()
            ref.seen, ref.lost = {}, set()
        elif kind == "period":
            hb.period_s = op[1]
        else:
            hb.last_sent = now
        quiet = not hb.pending(now)  # then neither a heartbeat due nor a loss
        lost = hb.expired(now)
        assert lost == ref.expired(now)
        assert not (quiet and (lost or hb.due(now)))
