"""One housekeeping thread for the simulated drives of a process.

Drives advance their motion lazily (on SYNC and on reads); this slow timer covers
what needs time to pass without traffic: heartbeats, heartbeat-consumer timeouts,
event timers and event-driven TPDOs, and automatic state transitions.

Its thread can be paused (:meth:`SimScheduler.pause`) while a base's control loop in
the same process steps the drives itself (:class:`~omnican.sim.base.SimulatedBase`,
``stepped``), and resumed after.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from omnican.clock import REAL_TIME, Clock

logger = logging.getLogger(__name__)

Tick = Callable[[float], None]


class SimScheduler:
    """Calls each registered ``tick(now)`` every ``period_s`` on one thread, or, on a
    lock-step :class:`~omnican.clock.SimClock`, from that clock's ``sleep``.

    A context manager; :meth:`close` stops and joins the thread (idempotent)."""

    def __init__(self, period_s: float = 0.002, name: str = "omnican-sim",
                 clock: Clock = REAL_TIME) -> None:
        if period_s <= 0:
            raise ValueError("period_s must be positive")
        self.period_s = period_s
        self.clock = clock
        self.name = name
        self._task: object | None = None
        self._ticks: list[Tick] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = False
        self._closed = False

    def add(self, tick: Tick) -> None:
        with self._lock:
            self._ticks.append(tick)

    def remove(self, tick: Tick) -> None:
        with self._lock:
            if tick in self._ticks:
                self._ticks.remove(tick)

    def start(self) -> SimScheduler:
        if not self._started:
            self._started = True
            if self.clock.lockstep:
                self._task = self.clock.every(self.period_s, self.step)
            else:
                self._start_thread()
        return self

    def _start_thread(self) -> None:
        self._stop = stop = threading.Event()  # each thread its own: a late one still ends
        self._thread = threading.Thread(target=self._run, args=(stop,), name=self.name,
                                        daemon=True)
        self._thread.start()

    def pause(self) -> None:
        """Stop the thread (joined): someone else calls :meth:`step` from now on.
        Nothing in lock-step, where the clock calls it."""
        thread = self._thread
        if thread is None:
            return
        self._stop.set()
        if thread is not threading.current_thread():
            thread.join(timeout=2.0)
        self._thread = None

    def resume(self) -> None:
        """The thread again, after :meth:`pause` (not once closed)."""
        if self._started and not self._closed and not self.clock.lockstep \
                and self._thread is None:
            self._start_thread()

    def step(self, now: float) -> None:
        """Run every tick once at ``now``."""
        # A copy (add/remove may run meanwhile, on another thread): one C call, atomic
        # under the interpreter's lock, so the lock is not taken each period.
        for tick in tuple(self._ticks):
            try:
                tick(now)
            except Exception:  # one broken drive must not stop the others
                logger.exception("simulated drive tick failed")

    @property
    def native_id(self) -> int | None:
        """The thread's id in the kernel while it runs (None: no thread)."""
        thread = self._thread
        return thread.native_id if thread is not None else None

    def _run(self, stop: threading.Event) -> None:
        next_t = time.monotonic()
        while not stop.is_set():
            self.step(time.monotonic())
            next_t += self.period_s
            delay = next_t - time.monotonic()
            if delay < 0:  # fell behind (a loaded machine): skip, do not burst
                next_t = time.monotonic()
                delay = 0
            stop.wait(delay)

    def close(self) -> None:
        self._closed = True
        self._stop.set()
        if self._task is not None:
            self.clock.cancel(self._task)
            self._task = None
        thread, self._thread = self._thread, None
        if thread is not None and thread.is_alive() and thread is not threading.current_thread():
            thread.join(timeout=2.0)

    def __enter__(self) -> SimScheduler:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
