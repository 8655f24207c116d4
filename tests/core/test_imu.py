"""The IMU inbox: what a source puts, the loop drains once, oldest first; a full inbox
drops the oldest and counts it."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.core.imu import ImuInbox, ImuSample


@given(st.lists(st.floats(-10, 10), max_size=50), st.integers(1, 20))
def test_drain_gives_the_newest_in_order_and_counts_the_dropped(rates: list[float],
                                                                 capacity: int) -> None:
    inbox = ImuInbox(capacity)
    for i, rate in enumerate(rates):
        inbox.put(ImuSample(float(i), rate))
    got = inbox.drain()
    assert [s.yaw_rate for s in got] == rates[-capacity:] if rates else got == []
    assert [s.t for s in got] == sorted(s.t for s in got)
    assert inbox.received == len(rates)
    assert inbox.dropped == max(0, len(rates) - capacity)
    assert inbox.drain() == []


def test_an_inbox_without_room_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one sample"):
        ImuInbox(0)
