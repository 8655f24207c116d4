"""Heartbeat timing: when the host sends its own, and how long a silence means "lost".

The host's heartbeat goes on a fixed schedule (``k`` periods after the first), each sent
in the control cycle nearest its time: it never drifts by a cycle per period, however
the loop rate divides the period. A consumer (a drive watching the host, the host
watching a drive) calls a heartbeat lost after ``factor`` periods plus half a period of
margin for the producer's jitter, so that ``factor - 1`` heartbeats lost in a row never
trip it, and ``factor`` always do. The host watches a drive (:class:`HeartbeatWatch`) from
the moment the drive's producer is switched on (1017h written), not from its boot-up: a
drive sends nothing between the two, for as long as its configuration takes.

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


class HeartbeatWatch:
    """The host's watch of one producer's heartbeat (a drive's).

    A drive's producer is switched on by its configuration (1017h written), which can
    take many periods after its boot-up; until then it sends nothing. So the silence is
    timed from the later of the last heartbeat and the moment the producer was switched
    on (:meth:`producer_on`), and not at all while the producer is not known to be on
    (:meth:`producer_off`: an NMT reset communication puts 1017h back to its power-on
    value). ``since`` is that start (None: not watched); the host's loop reads it and
    ``timeout_s`` directly (:meth:`lost`, written out).

    Each event is one write, from the thread it happens on (the receiving thread hears,
    the configuring thread switches on and off)."""

    __slots__ = ("_on", "since", "timeout_s")

    def __init__(self, timeout_s: float) -> None:
        if not timeout_s > 0:
            raise ValueError(f"a heartbeat timeout is positive, got {timeout_s}")
        self.timeout_s = timeout_s
        self._on = False
        self.since: float | None = None

    @property
    def watching(self) -> bool:
        """The producer is on: a silence longer than ``timeout_s`` is a lost heartbeat."""
        return self._on

    def producer_on(self, now: float) -> None:
        """The producer was switched on at ``now`` (1017h written): the silence counts
        from now, whatever was heard before (a boot-up)."""
        self.since = now
        self._on = True

    def producer_off(self) -> None:
        """The producer is no longer ours (a reset communication): not watched."""
        self._on = False
        self.since = None

    def heard(self, now: float) -> None:
        """A heartbeat (or boot-up) arrived at ``now``."""
        if self._on:
            self.since = now

    def lost(self, now: float) -> bool:
        """Watched, and silent for longer than ``timeout_s`` at ``now``."""
        since = self.since
        return since is not None and now - since > self.timeout_s
