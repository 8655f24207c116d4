"""Time for the control loop and the simulator.

:data:`REAL_TIME` is the machine's monotonic clock: the control loop runs on a thread
of its own and sleeps between cycles. :class:`SimClock` is simulated time for
lock-step simulation: nothing runs by itself; :meth:`SimClock.sleep` advances the
time and, on the way, calls every registered task (the chassis's control cycle, the
simulated drives' housekeeping) at its own period, in time order, on the calling
thread. Runs are deterministic and as fast as the CPU allows, or paced at ``speed``
times real time. :class:`PollThread` calls a function at a period on a thread of its own
in real time (the front ends' pollers).

No I/O: the clock only orders calls.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

Step = Callable[[float], None]

_SLACK_S = 1e-9  # float rounding in due times, far below any task period


class Clock:
    """Real time (the default everywhere): ``time.monotonic`` and ``time.sleep``."""

    lockstep = False

    def now(self) -> float:
        """Seconds on a monotonic clock."""
        return time.monotonic()

    def wall(self) -> float:
        """Seconds since the epoch, for frame timestamps and recordings."""
        return time.time()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    @property
    def can_wait(self) -> bool:
        """Waiting on this clock lets time pass (not so inside a task of a lock-step
        clock: it must return for time to go on)."""
        return True

    def every(self, period_s: float, step: Step, first_s: float | None = None) -> object:
        """Lock-step clocks run tasks; in real time each loop has a thread of its own."""
        raise RuntimeError("tasks run on a lock-step clock only (omnican.clock.SimClock)")

    def cancel(self, handle: object) -> None:
        raise RuntimeError("tasks run on a lock-step clock only (omnican.clock.SimClock)")

    def __repr__(self) -> str:
        return "<real-time clock>"


REAL_TIME = Clock()


class PollThread:
    """``poll()`` every ``period_s`` seconds of real time on a thread of its own (named
    ``name``), from :meth:`start` to :meth:`stop`, as often as asked. A poll that fell
    behind is followed by the next a period later, never by a burst; one that raises is
    logged on ``logger`` as ``failed`` and the polling goes on."""

    def __init__(self, poll: Callable[[], None], period_s: float, name: str,
                 logger: logging.Logger, failed: str) -> None:
        self.poll, self.period_s, self.name = poll, period_s, name
        self._logger, self._failed = logger, failed
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop polling and wait (at most ``timeout_s``) for a poll under way. Idempotent."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=timeout_s)

    def _run(self) -> None:
        period = self.period_s
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                self.poll()
            except Exception:  # keep polling whatever one poll did
                self._logger.exception(self._failed)
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:  # fell behind: the next poll a period from now, no burst
                next_t, delay = time.monotonic() + period, period
            self._stop.wait(delay)


@dataclass
class _Task:
    """A task of a :class:`SimClock`, on its heap as (due, order, task)."""

    due: float
    order: int  # ties run in the order the tasks were added
    period: float = field(compare=False)
    step: Step = field(compare=False)
    start: float = field(compare=False)
    count: int = field(default=0, compare=False)
    cancelled: bool = field(default=False, compare=False)


class SimClock(Clock):
    """Simulated time, advanced in lock-step by :meth:`sleep`.

    Args:
        start: the time it starts at (s).
        speed: pace the run at this many times real time (None: as fast as possible).
        epoch: wall-clock time of ``start``, for frame timestamps (default: a fixed date,
            so recordings of two runs are identical).
    """

    lockstep = True

    def __init__(self, start: float = 0.0, speed: float | None = None,
                 epoch: float = 1_767_225_600.0) -> None:
        if speed is not None and not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a positive number, got {speed}")
        self._t = float(start)
        self.speed = speed
        self.epoch = epoch
        # A heap of (due, order, task): tuples compare in C, where the task's own order
        # (a dataclass's __lt__, a Python call) cost each push and pop several calls.
        self._tasks: list[tuple[float, int, _Task]] = []
        self._order = itertools.count()
        self._running = False
        self._pace: tuple[float, float] | None = None  # (sim time, real time) at the mark

    def now(self) -> float:
        return self._t

    @property
    def can_wait(self) -> bool:
        return not self._running

    def wall(self) -> float:
        return self.epoch + self._t

    def every(self, period_s: float, step: Step, first_s: float | None = None) -> object:
        """Call ``step(now)`` every ``period_s`` from ``first_s`` (default: one period
        from now). Returns a handle for :meth:`cancel`."""
        if not period_s > 0:
            raise ValueError(f"period must be positive, got {period_s}")
        start = self._t + period_s if first_s is None else first_s
        task = _Task(start, next(self._order), period_s, step, start)
        heapq.heappush(self._tasks, (task.due, task.order, task))
        return task

    def cancel(self, handle: object) -> None:
        if isinstance(handle, _Task):
            handle.cancelled = True

    def sleep(self, seconds: float) -> None:
        """Advance the time by ``seconds``, running every task that falls due."""
        if self._running:
            raise RuntimeError("SimClock.sleep() called from a task it runs: a task must "
                               "return, and let the clock call it again")
        end = self._t + max(0.0, seconds)
        # A task due within a nanosecond of the end is due now: 0.001 + 29 * 0.001
        # is 0.030000000000000002, and sleep(0.03) must still run its 30th call.
        horizon = end + _SLACK_S
        self._running = True
        try:
            tasks = self._tasks
            while tasks and tasks[0][0] <= horizon:
                task = heapq.heappop(tasks)[2]
                if task.cancelled:
                    continue
                self._t = max(self._t, min(task.due, end))
                started = False
                try:
                    if self.speed is not None:
                        self._wait_real(self._t)
                    started = True
                    task.step(self._t)
                finally:
                    # A KeyboardInterrupt (Ctrl-C, SIGTERM) raised in the task or in the
                    # wait must not drop it from the clock: a control cycle dropped so
                    # stopped the host's heartbeat while the drives' time went on.
                    if not task.cancelled:
                        if started:  # its next time: no drift from summing periods
                            count = task.count = task.count + 1
                            task.due = task.start + count * task.period
                        heapq.heappush(tasks, (task.due, task.order, task))
            self._t = end
            if self.speed is not None:
                self._wait_real(end)
        finally:
            self._running = False

    def run_until(self, done: Callable[[], bool], timeout_s: float,
                  step_s: float = 0.001) -> bool:
        """Advance in steps of ``step_s`` until ``done()`` or ``timeout_s`` of
        simulated time; returns ``done()``."""
        end = self._t + timeout_s
        while not done():
            if self._t >= end:
                return done()
            self.sleep(min(step_s, end - self._t))
        return True

    def _wait_real(self, sim_t: float) -> None:
        speed = self.speed
        assert speed is not None
        real = time.monotonic()
        if self._pace is None:
            self._pace = (sim_t, real)
            return
        mark_sim, mark_real = self._pace
        ahead = mark_real + (sim_t - mark_sim) / speed - real
        if ahead > 0:
            time.sleep(ahead)
        elif ahead < -0.25:  # fell behind (a slow step): do not race to catch up
            self._pace = (sim_t, real)

    def __repr__(self) -> str:
        pace = "as fast as possible" if self.speed is None else f"{self.speed:g}x real time"
        return f"<SimClock t={self._t:.6f} s, {pace}>"
