"""The simulated node's heartbeat bookkeeping (1017h producer, 1016h consumer), pure."""

from __future__ import annotations

from collections.abc import Callable

import canopen

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

