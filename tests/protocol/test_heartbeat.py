"""The host's watch of a drive's heartbeat (omnican.protocol.heartbeat.HeartbeatWatch), pure:
no bus, no clock. A drive's producer is switched on by its configuration (1017h), many
periods after its boot-up: the silence is timed from then, not from the boot-up."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.protocol.heartbeat import HeartbeatWatch, timeout_s

PERIOD_S, FACTOR = 0.2, 3.0
TIMEOUT_S = timeout_s(PERIOD_S, FACTOR)  # 0.7 s

# One event of a run: (kind, time step to it in s). Kinds: "on" (1017h written), "off" (a
# reset communication), "heard" (a heartbeat or a boot-up), "check" (the loop looks).
events = st.lists(st.tuples(st.sampled_from(["on", "off", "heard", "check"]),
                            st.floats(0.0, 2.0)), max_size=60)


def _reference(run: list[tuple[str, float]]) -> list[bool]:
    """What each check must say, worked out from the whole history: the producer is on
    (switched on, not off since), and nothing since the later of the switching on and the
    last heartbeat after it for longer than the timeout."""
    out, t, on_at, last = [], 0.0, None, -math.inf
    for kind, step in run:
        t += step
        if kind == "on":
            on_at, last = t, -math.inf
        elif kind == "off":
            on_at = None
        elif kind == "heard" and on_at is not None:
            last = t
        elif kind == "check":
            out.append(on_at is not None and t - max(on_at, last) > TIMEOUT_S)
    return out


@given(run=events)
def test_lost_is_the_silence_since_the_producer_was_switched_on(
        run: list[tuple[str, float]]) -> None:
    watch = HeartbeatWatch(TIMEOUT_S)
    said, t = [], 0.0
    for kind, step in run:
        t += step
        if kind == "on":
            watch.producer_on(t)
        elif kind == "off":
            watch.producer_off()
        elif kind == "heard":
            watch.heard(t)
        else:
            said.append(watch.lost(t))
            # The loop's form (since and timeout_s read directly) says the same.
            since = watch.since
            assert (since is not None and t - since > watch.timeout_s) == said[-1]
    assert said == _reference(run)


@given(configuring_s=st.floats(0.0, 60.0), first_after=st.floats(0.0, PERIOD_S),
       gaps=st.lists(st.floats(0.0, FACTOR * PERIOD_S), max_size=30))
def test_a_drive_that_configures_for_long_is_never_lost(
        configuring_s: float, first_after: float, gaps: list[float]) -> None:
    """The issue's drive: a boot-up, a configuration of any length, 1017h written, the
    first heartbeat up to a period later (lely starts its producer's timer then) and the
    next ones at most ``factor`` periods apart: never lost, at any check time."""
    watch = HeartbeatWatch(TIMEOUT_S)
    watch.heard(0.0)  # the boot-up, before the producer is ours
    assert not watch.lost(configuring_s)
    on_at = configuring_s
    watch.producer_on(on_at)
    beats = [on_at + first_after]
    for gap in gaps:
        beats.append(beats[-1] + gap)
    previous = on_at
    for beat in beats:
        for frac in (0.0, 0.5, 1.0):  # checks on the way to the next heartbeat
            assert not watch.lost(previous + frac * (beat - previous))
        watch.heard(beat)
        previous = beat


@given(silence=st.floats(TIMEOUT_S, 10.0, exclude_min=True), start=st.floats(0.0, 100.0))
def test_factor_heartbeats_lost_in_a_row_are_lost(silence: float, start: float) -> None:
    watch = HeartbeatWatch(TIMEOUT_S)
    watch.producer_on(start)
    watch.heard(start + 0.1)
    assert not watch.lost(start + 0.1 + TIMEOUT_S - 1e-6)
    assert watch.lost(start + 0.1 + silence + 1e-6)


def test_a_reset_communication_stops_the_watch_until_the_producer_is_on_again() -> None:
    watch = HeartbeatWatch(TIMEOUT_S)
    watch.producer_on(0.0)
    assert watch.watching and watch.lost(1.0)
    watch.producer_off()
    watch.heard(1.1)  # its boot-up
    assert not watch.watching and not watch.lost(50.0) and watch.since is None
    watch.producer_on(50.0)
    assert not watch.lost(50.0 + TIMEOUT_S - 0.01) and watch.lost(50.0 + TIMEOUT_S + 0.01)


@pytest.mark.parametrize("timeout", [0.0, -1.0, math.nan])
def test_a_timeout_is_positive(timeout: float) -> None:
    with pytest.raises(ValueError, match="positive"):
        HeartbeatWatch(timeout)
