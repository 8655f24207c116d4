"""Heartbeat timing: when the host sends its own, and how long a silence means "lost".

The host's heartbeat goes on a fixed schedule (``k`` periods after the first), each sent
in the control cycle nearest its time: it never drifts by a cycle per period, however
the loop rate divides the period. A consumer (a drive watching the host, the host
watching a drive) calls a heartbeat lost after ``factor`` periods plus half a period of
margin for the producer's jitter, so that ``factor - 1`` heartbeats lost in a row never
trip it, and ``factor`` always do.

Pure: no I/O; times in seconds.
"""

from __future__ import annotations

import math

#: The consumer's margin over ``factor`` periods, as a fraction of the period.
MARGIN_PERIODS = 0.5


def timeout_s(period_s: float, factor: float) -> float:
    """How long a consumer waits for a heartbeat before it counts it lost."""
    return period_s * (factor + MARGIN_PERIODS)


def consumer_time_ms(period_ms: int, factor: float) -> int:
    """The consumer heartbeat time (1016h) for a producer of ``period_ms``: 16 bits."""
    return min(round(timeout_s(period_ms, factor)), 0xFFFF)


def max_cycle_s(period_s: float) -> float:
    """The longest control cycle that still keeps each heartbeat within the consumer's
    margin of its time (the schedule sends each in the cycle nearest it)."""
    return period_s * 2 * MARGIN_PERIODS


class HeartbeatSchedule:
    """When the host sends its heartbeat, for a loop of ``cycle_s`` cycles.

    ``send_at`` is the earliest cycle time at which the next heartbeat goes out (half a
    cycle before it is due): the loop compares it with ``now`` and calls :meth:`sent`."""

    __slots__ = ("_due", "_half_cycle", "period_s", "send_at")

    def __init__(self, period_s: float, cycle_s: float) -> None:
        if not period_s > 0 or not cycle_s > 0:
            raise ValueError(f"periods must be positive, got {period_s} and {cycle_s}")
        self.period_s = period_s
        self._half_cycle = cycle_s / 2
        self._due = -math.inf
        self.send_at = -math.inf  # the first cycle sends one

    def sent(self, now: float) -> None:
        """The heartbeat due now went out: schedule the next one."""
        due = self._due + self.period_s if math.isfinite(self._due) else now
        if due + self.period_s <= now:  # the loop stalled for a period or more: restart
            due = now
        self._due = due
        self.send_at = due + self.period_s - self._half_cycle
