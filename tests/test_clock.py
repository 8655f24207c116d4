"""The simulated clock: tasks run at their own periods, in time order, deterministically."""

from __future__ import annotations

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from omnican.clock import REAL_TIME, SimClock


@given(periods=st.lists(st.sampled_from([0.001, 0.002, 0.005, 0.01, 0.02, 0.1]), min_size=1,
                        max_size=4),
       sleeps=st.lists(st.floats(min_value=0.0, max_value=0.05), min_size=1, max_size=20))
@settings(max_examples=60, deadline=None)
@example(periods=[0.001], sleeps=[0.03])  # 0.001 + 29 * 0.001 > 0.03 in floats
def test_tasks_run_at_their_periods_in_time_order(periods: list[float],
                                                  sleeps: list[float]) -> None:
    clock = SimClock()
    calls: list[tuple[float, int]] = []
    for k, period in enumerate(periods):
        clock.every(period, lambda now, k=k: calls.append((now, k)))
    for s in sleeps:
        clock.sleep(s)
    total = sum(sleeps)
    assert clock.now() == pytest.approx(total)
    assert [t for t, _ in calls] == sorted(t for t, _ in calls)  # never back in time
    for k, period in enumerate(periods):
        times = [t for t, j in calls if j == k]
        assert len(times) == int(total / period + 1e-9)  # every due call, no more
        assert times == pytest.approx([period * (i + 1) for i in range(len(times))])


def test_ties_run_in_the_order_tasks_were_added() -> None:
    clock = SimClock()
    calls: list[str] = []
    clock.every(0.01, lambda now: calls.append("a"))
    clock.every(0.01, lambda now: calls.append("b"))
    clock.sleep(0.03)
    assert calls == ["a", "b"] * 3


def test_cancelled_tasks_stop_and_sleep_inside_a_task_is_refused() -> None:
    clock = SimClock()
    calls: list[float] = []
    handle = clock.every(0.01, calls.append)
    clock.sleep(0.025)
    clock.cancel(handle)
    clock.sleep(0.1)
    assert calls == pytest.approx([0.01, 0.02])
    clock.every(0.01, lambda now: clock.sleep(0.01))
    with pytest.raises(RuntimeError, match="task must return"):
        clock.sleep(0.02)


@given(interrupt_at=st.integers(min_value=1, max_value=30),
       others=st.integers(min_value=0, max_value=2))
@settings(max_examples=40, deadline=None)
def test_a_ctrl_c_inside_a_task_leaves_every_task_on_the_clock(interrupt_at: int,
                                                              others: int) -> None:
    """Issue 31 item 9: Ctrl-C or SIGTERM under --fast lands inside a task (the control
    cycle, a simulated drive's); the task it interrupted was dropped from the clock, so the
    host's heartbeat stopped while the drives' time went on (false EMCY 0x8130)."""
    clock = SimClock()
    calls: list[float] = []

    def cycle(now: float) -> None:
        calls.append(now)
        if len(calls) == interrupt_at:
            raise KeyboardInterrupt

    clock.every(0.01, cycle)
    for _ in range(others):
        clock.every(0.003, lambda now: None)
    with pytest.raises(KeyboardInterrupt):
        clock.sleep(1.0)
    at = clock.now()
    clock.sleep(0.1)  # what the stop does after the interrupt: the cycle still runs
    assert len(calls) == interrupt_at + 10
    assert calls[interrupt_at:] == pytest.approx([at + 0.01 * (i + 1) for i in range(10)])


def test_run_until_stops_when_done_or_at_the_timeout() -> None:
    clock = SimClock()
    assert clock.run_until(lambda: clock.now() >= 0.05, 1.0)
    assert clock.now() == pytest.approx(0.05, abs=0.0011)
    assert not clock.run_until(lambda: False, 0.2)
    assert clock.now() == pytest.approx(0.25, abs=0.0011)


def test_speed_paces_simulated_time_against_real_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    class FakeTime:  # real time that passes only when slept
        t = 100.0

        def monotonic(self) -> float:
            return self.t

        def sleep(self, seconds: float) -> None:
            self.t += seconds

    fake = FakeTime()
    monkeypatch.setattr("omnican.clock.time", fake)
    clock = SimClock(speed=10.0)
    clock.every(0.01, lambda now: None)
    clock.sleep(1.0)
    assert fake.t - 100.0 == pytest.approx(0.1, abs=0.002)  # 1 s at 10x: 0.1 s of real time
    with pytest.raises(ValueError, match="speed"):
        SimClock(speed=0)


def test_real_time_clock_runs_no_tasks() -> None:
    assert not REAL_TIME.lockstep
    with pytest.raises(RuntimeError, match="lock-step"):
        REAL_TIME.every(0.01, lambda now: None)


@given(st.integers(0, 0x1FFFFFFF), st.binary(max_size=8), st.booleans(), st.booleans(),
       st.floats(0, 1e4, allow_nan=False))
def test_a_lockstep_peer_receives_the_frame_as_sent(can_id: int, data: bytes, extended: bool,
                                                    remote: bool, later: float) -> None:
    """The lock-step bus's field-by-field copy is the message python-can would make,
    stamped with the clock's wall time when it was sent."""
    import can

    from omnican.io.lockstep import LockstepBus

    clock = SimClock()
    clock.sleep(later)
    sender, peer = LockstepBus("ch-copy", clock), LockstepBus("ch-copy", clock)
    try:
        sent = can.Message(arbitration_id=can_id, data=data, is_extended_id=extended,
                           is_remote_frame=remote, dlc=len(data))
        sender.send(sent)
        got = peer.recv(0)
        assert got is not None and sender.recv(0) is None  # the sender hears nothing back
        stamp = clock.wall()
        want = can.Message(timestamp=stamp, arbitration_id=can_id, is_extended_id=extended,
                           is_remote_frame=remote, is_error_frame=False, dlc=len(data),
                           data=data, channel="ch-copy", is_rx=True)
        assert got.equals(want, timestamp_delta=None)
        assert got.timestamp == stamp and got.is_rx and got.channel == "ch-copy"
        assert isinstance(got.data, bytearray) and got.data is not sent.data
    finally:
        sender.shutdown()
        peer.shutdown()


def test_a_poll_thread_polls_survives_a_failing_poll_and_restarts() -> None:
    """The front ends' poller (ROS 2, Zenoh): it keeps polling after a poll raised, stops
    when asked (twice is fine) and starts again; no thread is left behind."""
    import logging
    import threading

    from omnican.clock import PollThread

    calls: list[int] = []
    enough = threading.Event()

    def poll() -> None:
        calls.append(len(calls))
        if len(calls) == 1:
            raise RuntimeError("the first poll fails")
        if len(calls) >= 3:
            enough.set()

    poller = PollThread(poll, 0.001, "omnican-test-poll", logging.getLogger("test"), "failed")
    poller.start()
    poller.start()  # already running: one thread
    assert enough.wait(30.0)
    poller.stop()
    poller.stop()
    assert not any(t.name == "omnican-test-poll" for t in threading.enumerate())
    seen = len(calls)
    enough.clear()
    calls.clear()
    poller.start()
    assert enough.wait(30.0)
    poller.stop()
    assert seen >= 3
