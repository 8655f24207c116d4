"""The base: drives + kinematics + odometry + limits + watchdog + safety, behind one
small API (:class:`Chassis`).

Who does what: :class:`~omnican.chassis.cycle.ControlCycle` is the control cycle;
:class:`~omnican.chassis.supervisor.NodeSupervisor` owns every node's lifecycle (startup,
health, reconfiguration, recover, shutdown); a runner (a real-time thread or the
simulated clock, :mod:`omnican.chassis.runner`) calls the cycle every period; the
signal guard (:mod:`omnican.chassis.signals`) keeps a second Ctrl-C from cutting the
stop short. This module wires them and is what users call.

Safety: no command for ``cmd_timeout_s`` -> controlled stop; a drive fault, a lost
heartbeat, a drive reboot, a drive leaving OPERATIONAL or a bus that stays down -> every
wheel stops and the base stays stopped until :meth:`Chassis.recover`; drives watch the
host's heartbeat, so they stop by themselves if this process dies; leaving the ``with``
block, a failed open, Ctrl-C or SIGTERM stops the wheels and disables every drive.

Size: :class:`Chassis` is about 360 lines, above the 300 the package keeps to, on
purpose: it is the public API, and most of it is the docstrings of the calls users make.
The two sequences left in it, :meth:`Chassis.recover` and :meth:`Chassis.close`, run
across the caller's thread and the loop's and hold this object's locks; the machinery
behind them is the supervisor's, the configurator's and the cycle's. Opening is
:mod:`omnican.chassis.opening`'s.
"""

from __future__ import annotations

import atexit
import logging
import threading
import weakref
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

from omnican.chassis import realtime
from omnican.chassis.arbiter import CommandArbiter, CommandSource
from omnican.chassis.cycle import ControlCycle
from omnican.chassis.health import HealthMonitor
from omnican.chassis.opening import make_base
from omnican.chassis.runner import LockstepRunner, ThreadRunner
from omnican.chassis.signals import guard
from omnican.chassis.sink import Attachments, Recording, SnapshotSink
from omnican.chassis.state import ChassisStatus, WheelState
from omnican.chassis.supervisor import NodeSupervisor
from omnican.clock import REAL_TIME, Clock
from omnican.config import ChassisConfig, ChassisSettings, with_live_limits
from omnican.core.kinematics import Twist
from omnican.core.limits import MAX_STOP_S, command_problem, pose_problem
from omnican.core.odometry import Pose2D
from omnican.drive import DriveNode
from omnican.errors import DriveError
from omnican.io import stepped
from omnican.io.bus import CanBus

logger = logging.getLogger("omnican.chassis")

_open_chassis: weakref.WeakSet[Chassis] = weakref.WeakSet()


@atexit.register
def _close_all() -> None:
    for base in list(_open_chassis):
        base.close()
    guard.at_exit()


class Chassis:
    """A running base. Use :meth:`open` (a context manager)."""

    def __init__(self, cfg: ChassisConfig, bus: CanBus, nodes: list[DriveNode],
                 clock: Clock = REAL_TIME) -> None:
        self.cfg = cfg
        self.clock = clock
        self._lockstep = clock.lockstep
        self._bus = bus
        self.nodes = nodes
        self._period = 1.0 / cfg.chassis.rate_hz
        self._supervisor = sup = NodeSupervisor(nodes, bus, clock, self._call_soon,
                                                HealthMonitor(cfg, nodes, bus))
        self._loop = loop = ControlCycle(cfg, bus, nodes, sup, clock)
        sup.monitor.speeds = loop.wheel_speeds
        self._runner: ThreadRunner | LockstepRunner = (
            LockstepRunner(clock, self._period, loop.run, self._cycle_failed)
            if self._lockstep else ThreadRunner(self._period, loop.run, self._cycle_failed,
                                                cfg.chassis.rt_priority))
        loop.runner = self._runner
        #: what layers above attached (the telemetry feed, a recording): closed with the base
        self.attachments = Attachments()
        self._limits_lock = threading.Lock()
        self._configured = cfg.chassis  # what a live limit may only make safer
        self._closed = False
        self._close_lock = threading.Lock()
        self._not_disabled: tuple[str, ...] = ()
        self._guards_signals = False
        self._froze_heap = False
        self._arbiter = CommandArbiter(cfg.chassis.cmd_timeout_s)  # one source at a time

    def _call_soon(self, fn: Any) -> None:
        self._loop.call_soon(fn)

    def _cycle_failed(self) -> None:
        self._supervisor.latch("internal error in the control loop (see log)")

    # ------------------------------------------------------------ opening

    @classmethod
    def open(
        cls,
        cfg: ChassisConfig,
        *,
        bus: Mapping[str, Any] | None = None,
        record: Recording[Chassis] | None = None,
        handle_signals: bool = True,
        clock: Clock | None = None,
    ) -> Chassis:
        """Open the bus, configure and enable every drive, start the loop.

        Args:
            cfg: the robot config.
            bus: ``can.Bus`` arguments overriding ``cfg.bus``.
            record: a recording of the bus from its first frame on, closed with the
                base: ``FileRecording(path)`` (:mod:`omnican.record.recording`) records to
                a python-can log (.log/.asc/.blf: the frames) or .mcap (the frames and the
                robot's state).
            handle_signals: in the main thread, turn SIGTERM into SystemExit so the
                ``with`` block unwinds and the drives are disabled, and keep a second
                SIGINT/SIGTERM from cutting that stop short.
            clock: :data:`omnican.clock.REAL_TIME` (default: a loop thread) or a
                :class:`omnican.clock.SimClock` (lock-step against a
                :class:`~omnican.sim.SimulatedBase` on the same clock: no threads; the
                clock's ``sleep`` runs the control cycles).

        Raises:
            BusError: the bus cannot be opened.
            DriveError: a drive did not come up (the message says which and why).
        """
        clock = clock if clock is not None else REAL_TIME
        base = make_base(lambda can_bus, nodes: cls(cfg, can_bus, nodes, clock),
                         cfg, bus, record, clock)
        try:
            if record is not None:  # from the first frame on: the configuration too
                base.attachments.add("record", record)  # closed after what it attaches
                record.attach(base)
            base._start(handle_signals)
        except BaseException:
            base.close(controlled=False)
            raise
        return base

    def _start(self, handle_signals: bool) -> None:
        started = self.clock.now()
        self._supervisor.configure_all()
        _open_chassis.add(self)
        if handle_signals:
            self._guards_signals = guard.acquire()
        if not self._lockstep:
            self._bus.start_polling()  # the loop reads the bus itself: one wake-up a cycle
            # Simulated drives of this process that asked to, run on the loop's thread.
            self._runner.companion = stepped.claim(self._bus.bus_kwargs)
        self._runner.start()
        self._wait_enabled(self.cfg.chassis.enable_timeout_s + 4 * self._period, "startup")
        self._supervisor.started()
        if not self._lockstep:  # what start-up made is out of the collector's way
            realtime.freeze_startup()
            self._froze_heap = True
        logger.info("every drive enabled, %.2f s after the bus opened", self.clock.now() - started)

    def _wait_enabled(self, timeout: float, what: str,
                      refuse: Callable[[], str | None] | None = None) -> None:
        """Until every drive is enabled; ``refuse`` says why it may not be (an interlock
        reached meanwhile): then at once."""
        clock = self.clock
        deadline = clock.now() + timeout
        while clock.now() < deadline:
            status = self._loop.snapshot.status
            if status.enabled and status.cycles > 0:
                return
            if self._closed:
                raise DriveError(f"{what}: the base was closed")
            refused = refuse() if refuse is not None else None
            if refused is not None:
                raise DriveError(f"{what} refused: {refused}")
            clock.sleep(self._period if self._lockstep else 0.002)
        raise DriveError(f"{what}: {self._supervisor.not_enabled_why(timeout)}")

    # ------------------------------------------------------------ public API

    def set_velocity(self, vx: float, vy: float, wz: float) -> None:
        """Command a body velocity (m/s, m/s, rad/s); it lapses after ``cmd_timeout_s``.

        Raises ValueError for NaN/inf or a value beyond any wheeled base (beyond
        :data:`omnican.core.limits.MAX_SPEED_SENSE`; nothing changes then); DriveError if the
        base is closed. Within that, a command beyond the limits drives at them."""
        self.set_twist(Twist(float(vx), float(vy), float(wz)))

    def set_twist(self, twist: Twist) -> None:
        """:meth:`set_velocity` with the command as one :class:`Twist`, kept as it is."""
        if not (type(twist.vx) is float and type(twist.vy) is float
                and type(twist.wz) is float):
            twist = Twist(float(twist.vx), float(twist.vy), float(twist.wz))
        problem = command_problem(twist.vx, twist.vy, twist.wz)
        if problem is not None:
            raise ValueError(f"velocity command refused: {problem}")
        if self._closed:
            raise DriveError("the base is closed")
        self._loop.command = (twist, self.clock.now())

    def stop(self) -> None:
        """Controlled stop now (at the stop deceleration); a new command moves again."""
        self._loop.command = (Twist(), self.clock.now())

    def halt(self, reason: str) -> None:
        """A stop held until :meth:`recover`: the base ramps to rest at the stop
        deceleration and stays there whatever is commanded, with ``reason`` as the stop's
        reason (one already held stays first). A remote operator's stop (the Zenoh
        ``~/stop`` service, the fleet stop) is one; ``stop()`` lets the next command go."""
        if self._closed:
            raise DriveError("the base is closed")
        self._loop.command = (Twist(), self.clock.now())
        self._loop.call_soon(lambda: self._supervisor.latch(reason))

    def command_source(self, name: str) -> CommandSource:
        """The handle by which a front end commands this base as ``name`` (the name the
        others are told): one source drives at a time, by the base's one arbiter, shared
        by every source it hands out (:mod:`omnican.chassis.arbiter`)."""
        return CommandSource(self, self._arbiter, name)

    def recover(self, timeout_s: float | None = None) -> None:
        """Clear a latched stop: reset faulted drives, re-enable every drive, and wait
        (bounded) until all are enabled. The base stays still until the next command.

        Raises DriveError naming what could not be recovered."""
        if self._closed:
            raise DriveError("the base is closed")
        sup, loop = self._supervisor, self._loop
        if loop.watch.down:
            raise DriveError(f"{sup.latched or 'the CAN bus is down'}: recover once it is "
                             "back (status.bus_up)")
        refused = sup.monitor.recover_refused()
        if refused is not None:
            raise DriveError(f"recover refused: {refused}")
        timeout = timeout_s if timeout_s is not None else (
            self.cfg.chassis.enable_timeout_s + self.cfg.chassis.boot_timeout_s)
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
                       if loop.watch.down else sup.monitor.recover_refused())
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
            self._wait_enabled(timeout, "recover", refuse=sup.monitor.recover_refused)
            logger.info("recovered: every drive enabled")
        finally:
            loop.call_soon(sup.end_recover)
        loop.command = (Twist(), self.clock.now())

    def set_limits(self, **changes: float) -> ChassisSettings:
        """Change velocity limits while the base runs: the [chassis] keys of
        :data:`omnican.config.LIVE_LIMITS` (``max_speed=0.3``, ``max_accel=0.5``, ...),
        each checked as the config checks it. They take effect at the next control cycle.
        A live value may only make the base safer than the config it was opened with: no
        speed or acceleration above the config's, no stop deceleration below it (every
        stop keeps the config's bounded stop time). Returns the settings now in force
        (also ``base.cfg.chassis``).

        Raises ConfigError (a ValueError) naming the key and why; nothing changes then."""
        with self._limits_lock:
            if self._closed:
                raise DriveError("the base is closed")
            settings = with_live_limits(self.cfg.chassis, changes,
                                        configured=self._configured)
            cfg = replace(self.cfg, chassis=settings)
            limits, limiter = cfg.limits(), self._loop.limiter

            def apply() -> None:
                limiter.limits = limits

            self._loop.call_soon(apply)
            self.cfg = cfg
        return settings

    def reset_pose(self, pose: Pose2D | None = None) -> None:
        """Set the odometry pose (default: origin).

        Raises ValueError for a pose no base can have (NaN, inf, beyond
        :data:`omnican.core.limits.MAX_POSE_SENSE`); the pose stays then."""
        target = pose if pose is not None else Pose2D()
        problem = pose_problem(target.x, target.y, target.theta)
        if problem is not None:
            raise ValueError(f"odometry reset refused: {problem}")
        loop = self._loop
        loop.call_soon(lambda: loop.odometry.reset(target))
        deadline = self.clock.now() + 1.0
        while loop.snapshot.pose != target and self.clock.now() < deadline:
            if not self._runner.running:
                loop.odometry.reset(target)
                break
            self.clock.sleep(self._period if self._lockstep else self._period / 2)

    @property
    def pose(self) -> Pose2D:
        return self._loop.snapshot.pose

    @property
    def twist(self) -> Twist:
        """Measured body velocity from the encoders, averaged over the last 0.1 s."""
        return self._loop.snapshot.twist

    @property
    def command(self) -> Twist:
        """The limited twist being applied this cycle."""
        return self._loop.snapshot.command

    @property
    def wheels(self) -> tuple[WheelState, ...]:
        return self._loop.snapshot.wheels

    @property
    def status(self) -> ChassisStatus:
        return self._loop.snapshot.status

    @property
    def bus(self) -> CanBus:
        return self._bus

    def offer_snapshots(self, sink: SnapshotSink | None, every: int = 1) -> None:
        """Hand every ``every``-th cycle's snapshot to ``sink.offer`` on the loop thread
        (it must queue and return), from the next cycle on; None: stop. One sink at a
        time: the telemetry feed (:func:`omnican.telemetry.attach.feed_of`) is the one
        that fans them out to every front end."""
        self._loop.offer_to(sink, every)

    @property
    def warnings(self) -> list[str]:
        """What the configuration warned of (an EDS that understates the drive, ...)."""
        return self._supervisor.warnings

    def cycle_bits(self) -> int:
        """Worst-case bits per control cycle: every node's cyclic PDOs plus the SYNC."""
        return self._loop.cycle_bits()

    def step(self, now: float) -> None:
        """One control cycle at ``now`` (lock-step: the clock calls this every period)."""
        if not isinstance(self._runner, LockstepRunner):
            raise RuntimeError("step() is for lock-step simulation: a real-time base runs "
                               "its own loop thread")
        self._runner.step(now)

    @property
    def loop_cpu_s(self) -> float:
        """CPU seconds the loop thread has used, its wake-ups included (for benchmarks;
        0.0 in lock-step, where there is no such thread)."""
        return self._runner.cpu_s

    # ------------------------------------------------------------ closing

    def close(self, controlled: bool = True) -> None:
        """Stop the wheels (controlled), disable every drive, release the bus. Idempotent.

        ``controlled=False`` skips the deceleration only: every drive is disabled on
        every way out, a failed open included."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        _open_chassis.discard(self)
        sup = self._supervisor
        sup.closed = True  # nothing is started again from here on
        bus_works = True  # what the close found, for its last line
        with guard.closing():
            try:
                if self._runner.running:
                    self._controlled_shutdown(decelerate=controlled)
                    self._runner.stop()
                if self._runner.companion is not None:  # their own threads again by now
                    stepped.release(self._runner.companion)
                self._bus.stop_polling()  # a Notifier again, for the SDOs of the stop
                sup.join_workers(self.cfg.chassis.boot_timeout_s + 1.0)
                bus_works = not self._loop.watch.down and self._bus.failing is None
                sup.stop_nodes(bus_works=bus_works)
            finally:
                sup.detach()
                # The telemetry's last sample (and the frames of the stop), then a recording.
                self.attachments.close(self._loop.snapshot)
                self._bus.close()
                if self._guards_signals:
                    self._guards_signals = False
                    guard.release()
                if self._froze_heap:
                    self._froze_heap = False
                    realtime.thaw()
        powered = sup.still_powered(bus_works)
        self._not_disabled = tuple(powered)
        if powered:
            logger.error("base closed; not confirmed disabled: %s", ", ".join(powered))
        else:
            logger.info("base closed; drives disabled")

    @property
    def not_disabled(self) -> tuple[str, ...]:
        """After :meth:`close`: the drives it could not confirm disabled, each as the
        closing error says it (``node 1 (OFFLINE: heartbeat lost; last seen OPERATION
        ENABLED)``); empty when every drive was, and while the base is open. A front end
        ends with a run-time failure (exit 1) when it is not empty."""
        return self._not_disabled

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

    def __enter__(self) -> Chassis:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"<Chassis {len(self._loop.axes)} wheels on nodes "
                f"{[n.node_id for n in self.nodes]}>")
