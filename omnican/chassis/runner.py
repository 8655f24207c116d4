"""What runs the control cycle: a real-time thread of its own, or the simulated clock.

:class:`ThreadRunner` calls the cycle every period on a thread, sleeping between cycles
and counting the cycles that start late (at real-time priority where the process may:
:mod:`omnican.chassis.realtime`); :class:`SyncRunner` is that thread woken by each SYNC
the kernel sends instead of by its own clock (SocketCAN: :mod:`omnican.io.kernel_sync`);
:class:`LockstepRunner` registers it with a
:class:`~omnican.clock.SimClock`, whose ``sleep`` calls it on the caller's thread. Both
keep the base stopping whatever a cycle raised: ``on_error`` is told, the next cycle
runs.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from omnican.chassis.realtime import make_realtime
from omnican.clock import Clock
from omnican.io.bus import CanBus
from omnican.io.stepped import Stepped

logger = logging.getLogger("omnican.chassis")

LATE_FRACTION_OF_PERIOD = 0.2  # a cycle starting later than this is late
#: A kernel-timed loop that sees no SYNC for this many periods runs the cycle anyway (the
#: checks, heartbeats and the bus, never wait for SYNC), and starts the kernel's timer
#: anew once no SYNC came for longer than it was armed for (it ran out while the loop
#: was stalled, or the interface went away): not before, which would move its phase.
NO_SYNC_PERIODS = 2.0

Cycle = Callable[[float], None]


class ThreadRunner:
    """The control cycle on a thread of its own, every ``period_s`` (real time); the
    thread runs SCHED_FIFO at ``rt_priority`` where the process may (0: never).

    ``companion``: simulated drives in this process that the thread runs with the cycle
    (:mod:`omnican.io.stepped`): their timers before each cycle, the frames that reached
    them after it; set before :meth:`start`."""

    def __init__(self, period_s: float, cycle: Cycle, on_error: Callable[[], None],
                 rt_priority: int = 0) -> None:
        self.period_s = period_s
        self.rt_priority = rt_priority
        self.realtime = False  # whether the thread got its real-time priority
        self.cycle = cycle  # what it calls each period (a benchmark may wrap it)
        self._on_error = on_error
        self.late = 0  # cycles that started more than a fifth of a period late
        self.companion: Stepped | None = None
        self._stop = threading.Event()
        self._cpu_at_end = 0.0
        self.thread = threading.Thread(target=self._run, name="omnican-loop", daemon=True)

    @property
    def running(self) -> bool:
        return self.thread.is_alive()

    def start(self) -> None:
        self.thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self.thread.is_alive():
            self.thread.join(timeout=timeout_s)

    def _run(self) -> None:
        if self.rt_priority:  # the thread's own: the threads it starts run normally
            self.realtime = make_realtime(self.rt_priority)
        companion = self._begin_companion()
        period = self.period_s
        on_error = self._on_error
        next_t = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now - next_t > period * LATE_FRACTION_OF_PERIOD:
                self.late += 1
            if companion is not None:
                companion = self._companion_step(companion, now)
            try:
                self.cycle(now)
            except Exception:  # keep stopping the base whatever went wrong
                logger.exception("control cycle failed")
                on_error()
            if companion is not None:
                companion = self._companion_step(companion, None)
            next_t += period
            delay = next_t - time.monotonic()
            if delay < -period:
                next_t = time.monotonic()  # fell far behind: do not burst to catch up
                delay = 0.0
            if delay > 0:
                time.sleep(delay)  # finer than Event.wait's timed lock: fewer late cycles
        if companion is not None:
            self._end_companion(companion)
        self._cpu_at_end = time.thread_time()

    def _begin_companion(self) -> Stepped | None:
        companion = self.companion
        if companion is None:
            return None
        try:
            companion.begin()
        except Exception:  # they keep their own threads: the base runs as before
            logger.exception("simulated drives: running them on the control loop failed")
            return None
        return companion

    def _companion_step(self, companion: Stepped, now: float | None) -> Stepped | None:
        """Their timers at ``now`` (before the cycle), or (None) their frames (after it).
        A failure is theirs, not the base's: said, and they go back to their threads."""
        try:
            if now is not None:
                companion.tick(now)
            else:
                companion.drain()
        except Exception:
            logger.exception("simulated drives failed on the control loop: back on their "
                             "own threads")
            self._end_companion(companion)
            return None
        return companion

    @staticmethod
    def _end_companion(companion: Stepped) -> None:
        try:
            companion.end()
        except Exception:
            logger.exception("simulated drives: giving them their threads back failed")

    @property
    def cpu_s(self) -> float:
        """CPU seconds the loop thread has used, its wake-ups included. Read from the
        thread's own clock, so the loop pays nothing for it."""
        thread = self.thread
        ident = thread.ident
        if ident is not None and thread.is_alive() and hasattr(time, "pthread_getcpuclockid"):
            try:
                return time.clock_gettime(time.pthread_getcpuclockid(ident))
            except OSError:  # it ended meanwhile
                pass
        return self._cpu_at_end


class SyncRunner(ThreadRunner):
    """:class:`ThreadRunner` woken by SYNC: the kernel's broadcast manager sends SYNC on
    its own timer (:meth:`omnican.io.bus.CanBus.start_kernel_sync`), the thread waits for
    each one to come back on the bus and runs the cycle at once, so that the cycle's
    RPDOs reach the bus before the next SYNC; the cycle's ``bus.sync()`` re-arms the
    kernel for a bounded count of SYNCs (a hung loop stops SYNC). Where the kernel cannot
    send SYNC (no broadcast manager), it is a :class:`ThreadRunner` as before. Stopping
    it stops SYNC.

    A cycle is late when it starts more than a fifth of a period after its SYNC came, or
    when no SYNC came for :data:`NO_SYNC_PERIODS`."""

    def __init__(self, period_s: float, cycle: Cycle, on_error: Callable[[], None],
                 bus: CanBus, rt_priority: int = 0) -> None:
        super().__init__(period_s, cycle, on_error, rt_priority)
        self.bus = bus
        self.kernel = False  # whether the kernel sends SYNC (known once the thread runs)

    def _run(self) -> None:
        bus = self.bus
        if self.companion is not None or not bus.start_kernel_sync(self.period_s):
            super()._run()  # simulated drives on the loop, or no broadcast manager
            return
        self.kernel = True
        try:
            self._run_on_sync(bus)
        finally:
            bus.stop_kernel_sync()
            self._cpu_at_end = time.thread_time()

    def _run_on_sync(self, bus: CanBus) -> None:
        if self.rt_priority:
            self.realtime = make_realtime(self.rt_priority)
        period = self.period_s
        late_after = period * LATE_FRACTION_OF_PERIOD
        wait_s = period * NO_SYNC_PERIODS
        on_error = self._on_error
        stop = self._stop
        while not stop.is_set():
            came = bus.wait_sync(wait_s)
            if stop.is_set():
                break
            now = time.monotonic()
            if not came:
                self.late += 1
                if bus.kernel_sync_ran_out(now):
                    bus.restart_kernel_sync()
            elif now - bus.seen_sync_time > late_after:
                self.late += 1
            try:
                self.cycle(now)
            except Exception:  # keep stopping the base whatever went wrong
                logger.exception("control cycle failed")
                on_error()


class LockstepRunner:
    """The control cycle as a task of a lock-step clock: no thread; the clock's
    ``sleep`` runs it every ``period_s`` of simulated time."""

    late = 0  # simulated time is never late
    cpu_s = 0.0  # no thread of its own
    realtime = False  # nor a priority
    companion: Stepped | None = None  # simulated drives run on the clock, not here

    def __init__(self, clock: Clock, period_s: float, cycle: Cycle,
                 on_error: Callable[[], None]) -> None:
        self.clock = clock
        self.period_s = period_s
        self.cycle = cycle  # what it calls each period (a benchmark may wrap it)
        self._on_error = on_error
        self._task: object | None = None

    @property
    def running(self) -> bool:
        return self._task is not None

    def start(self) -> None:
        self._task = self.clock.every(self.period_s, self.step, first_s=self.clock.now())

    def stop(self, timeout_s: float = 2.0) -> None:
        if self._task is not None:
            self.clock.cancel(self._task)
            self._task = None

    def step(self, now: float) -> None:
        try:
            self.cycle(now)
        except Exception:  # keep stopping the base whatever went wrong
            logger.exception("control cycle failed")
            self._on_error()
