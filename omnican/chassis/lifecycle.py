"""How a base starts, and how it stops on every way out.

:meth:`Lifecycle.start` (``Chassis.open``): every node configured, the signal guard
taken, the bus's reception handed to the loop, the loop started, every drive enabled
(bounded), what start-up made frozen out of the collector's way. :meth:`Lifecycle.recover`
(``Chassis.recover``): the same wait for every drive, after a latched stop is cleared on
the loop thread.
:meth:`Lifecycle.close` (idempotent, whatever failed before): the wheels ramped to rest
(bounded, :data:`omnican.core.limits.MAX_STOP_S`), every drive disabled (by the loop,
then by SDO), the attachments closed with the last snapshot, the bus released, the
signal guard given back; the drives it could not confirm disabled are said.

:class:`omnican.chassis.base.Chassis` owns one.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from omnican.chassis import realtime
from omnican.chassis.cycle import ControlCycle
from omnican.chassis.runner import LockstepRunner, ThreadRunner
from omnican.chassis.signals import guard
from omnican.chassis.sink import Attachments
from omnican.chassis.supervisor import NodeSupervisor
from omnican.clock import Clock
from omnican.config import ChassisConfig
from omnican.core.kinematics import Twist
from omnican.core.limits import MAX_STOP_S
from omnican.errors import DriveError
from omnican.io import stepped
from omnican.io.bus import CanBus

logger = logging.getLogger("omnican.chassis")


class Lifecycle:
    """The start and the stop of one base (see the module docstring)."""

    def __init__(self, cfg: ChassisConfig, bus: CanBus, supervisor: NodeSupervisor,
                 loop: ControlCycle, runner: ThreadRunner | LockstepRunner,
                 attachments: Attachments, clock: Clock) -> None:
        self._cfg = cfg.chassis  # its boot and enable timeouts (no live limit changes them)
        self._bus = bus
        self._supervisor = supervisor
        self._loop = loop
        self._runner = runner
        self._attachments = attachments
        self.clock = clock
        self._lockstep = clock.lockstep
        self._period = 1.0 / cfg.chassis.rate_hz
        self.closed = False
        self._close_lock = threading.Lock()
        #: after :meth:`close`: the drives it could not confirm disabled
        self.not_disabled: tuple[str, ...] = ()
        self._guards_signals = False
        self._froze_heap = False

    def start(self, handle_signals: bool, configured: Callable[[], None]) -> None:
        """Configure every node (``configured()`` once that worked), start the loop, wait
        until every drive is enabled. Raises DriveError naming what failed."""
        started = self.clock.now()
        self._supervisor.configure_all()
        configured()
        if handle_signals:
            self._guards_signals = guard.acquire()
        runner, bus = self._runner, self._bus
        if not self._lockstep:
            bus.start_polling()  # the loop reads the bus itself: one wake-up a cycle
            # Simulated drives of this process that asked to, run on the loop's thread.
            runner.companion = stepped.claim(bus.bus_kwargs)
        runner.start()
        self.wait_enabled(self._cfg.enable_timeout_s + 4 * self._period, "startup")
        self._supervisor.started()
        if not self._lockstep:  # what start-up made is out of the collector's way
            realtime.freeze_startup()
            self._froze_heap = True
        logger.info("every drive enabled, %.2f s after the bus opened", self.clock.now() - started)

    def wait_enabled(self, timeout: float, what: str,
                     refuse: Callable[[], str | None] | None = None) -> None:
        """Until every drive is enabled; ``refuse`` says why it may not be (an interlock
        reached meanwhile): then at once."""
        clock = self.clock
        deadline = clock.now() + timeout
        while clock.now() < deadline:
            status = self._loop.snapshot.status
            if status.enabled and status.cycles > 0:
                return
            if self.closed:
                raise DriveError(f"{what}: the base was closed")
            refused = refuse() if refuse is not None else None
            if refused is not None:
                raise DriveError(f"{what} refused: {refused}")
            clock.sleep(self._period if self._lockstep else 0.002)
        raise DriveError(f"{what}: {self._supervisor.not_enabled_why(timeout)}")

    def recover(self, timeout_s: float | None = None) -> None:
        """Clear a latched stop, re-enable every drive and wait (bounded) until all are
        (``Chassis.recover``). Raises DriveError naming what could not be recovered."""
        if self.closed:
            raise DriveError("the base is closed")
        sup, loop = self._supervisor, self._loop
        if loop.watch.down:
            raise DriveError(f"{sup.latched or 'the CAN bus is down'}: recover once it is "
                             "back (status.bus_up)")
        refused = sup.checks.recover_refused()
        if refused is not None:
            raise DriveError(f"recover refused: {refused}")
        timeout = timeout_s if timeout_s is not None else (
            self._cfg.enable_timeout_s + self._cfg.boot_timeout_s)
        # Asked again where the latch is cleared, on the loop thread: an interlock reached
        # between the check above and then (the battery's cutoff, an e-stop) must hold.
        outcome: list[str | None] = []
        taken = threading.Lock()  # begin() runs whole, or (given up on) not at all

        def begin() -> None:
            with taken:
                if outcome:
                    return
                now = self.clock.now()
                loop.command = (Twist(), now)
                why = ("the CAN bus is down: recover once it is back (status.bus_up)"
                       if loop.watch.down else sup.checks.recover_refused())
                if why is None:
                    sup.begin_recover(now)
                outcome.append(why)

        loop.call_soon(begin)
        self.clock.sleep(2 * self._period)
        deadline = self.clock.now() + max(1.0, 10 * self._period)
        while not outcome and self.clock.now() < deadline and self._runner.running:
            self.clock.sleep(self._period if self._lockstep else 0.002)
        with taken:
            if not outcome:
                outcome.append("the control loop did not take the request")
                raise DriveError("recover: the control loop did not take the request")
        if outcome[0] is not None:
            raise DriveError(f"recover refused: {outcome[0]}")
        try:
            self.wait_enabled(timeout, "recover", refuse=sup.checks.recover_refused)
            logger.info("recovered: every drive enabled")
        finally:
            loop.call_soon(sup.end_recover)
        loop.command = (Twist(), self.clock.now())

    def close(self, controlled: bool = True) -> None:
        """Stop the wheels (``controlled``: at the stop deceleration), disable every
        drive, release the bus. Idempotent."""
        with self._close_lock:
            if self.closed:
                return
            self.closed = True
        sup, runner, bus = self._supervisor, self._runner, self._bus
        sup.closed = True  # nothing is started again from here on
        bus_works = True  # what the close found, for its last line
        with guard.closing():
            try:
                if runner.running:
                    self._controlled_shutdown(decelerate=controlled)
                    runner.stop()
                if runner.companion is not None:  # their own threads again by now
                    stepped.release(runner.companion)
                bus.stop_polling()  # a Notifier again, for the SDOs of the stop
                sup.join_workers(self._cfg.boot_timeout_s + 1.0)
                bus_works = not self._loop.watch.down and bus.failing is None
                sup.stop_nodes(bus_works=bus_works)
            finally:
                sup.detach()
                # The telemetry's last sample (and the frames of the stop), then a recording.
                self._attachments.close(self._loop.snapshot)
                bus.close()
                if self._guards_signals:
                    self._guards_signals = False
                    guard.release()
                if self._froze_heap:
                    self._froze_heap = False
                    realtime.thaw()
        powered = sup.still_powered(bus_works)
        self.not_disabled = tuple(powered)
        if powered:
            logger.error("base closed; not confirmed disabled: %s", ", ".join(powered))
        else:
            logger.info("base closed; drives disabled")

    def _controlled_shutdown(self, decelerate: bool = True) -> None:
        loop, clock = self._loop, self.clock
        loop.command = (Twist(), -float("inf"))
        # The limiter's stop ramp is bounded (limits.MAX_STOP_S) whatever the limits say:
        # so is this wait; the drives are disabled after it, stopped or not.
        deadline = clock.now() + min(loop.limiter.stop_time_s(), MAX_STOP_S) + 0.5
        while decelerate and clock.now() < deadline:
            if loop.speeds_settled:
                break
            clock.sleep(self._period)
        loop.call_soon(self._supervisor.disable_all)
        deadline = clock.now() + 0.5
        while clock.now() < deadline:
            if self._supervisor.all_disabled():
                break
            clock.sleep(self._period)
