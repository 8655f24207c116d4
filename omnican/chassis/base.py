"""The base: drives + kinematics + odometry + limits + watchdog + safety, behind one
small API (:class:`Chassis`).

Who does what: :class:`~omnican.chassis.cycle.ControlCycle` is the control cycle;
:class:`~omnican.chassis.supervisor.NodeSupervisor` owns every node's lifecycle (startup,
health, reconfiguration, recover, shutdown); a runner (a real-time thread or the
simulated clock, :mod:`omnican.chassis.runner`) calls the cycle every period; the
base's own start and stop, on every way out, are :mod:`omnican.chassis.lifecycle`'s
(the signal guard, :mod:`omnican.chassis.signals`, keeps a second Ctrl-C from cutting
the stop short); opening is :mod:`omnican.chassis.opening`'s. This module wires them
and is what users call.

Safety: no command for ``cmd_timeout_s`` -> controlled stop; a drive fault, a lost
heartbeat, a drive reboot, a drive leaving OPERATIONAL or a bus that stays down -> every
wheel stops and the base stays stopped until :meth:`Chassis.recover`; drives watch the
host's heartbeat, so they stop by themselves if this process dies; leaving the ``with``
block, a failed open, Ctrl-C or SIGTERM stops the wheels and disables every drive.
"""

from __future__ import annotations

import atexit
import threading
import weakref
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from omnican.chassis.arbiter import CommandArbiter, CommandSource
from omnican.chassis.checks import ChassisChecks
from omnican.chassis.cycle import ControlCycle, reset_pose
from omnican.chassis.lifecycle import Lifecycle
from omnican.chassis.opening import make_base
from omnican.chassis.runner import LockstepRunner, SyncRunner, ThreadRunner
from omnican.chassis.signals import guard
from omnican.chassis.sink import Attachments, Recording, SnapshotSink
from omnican.chassis.state import ChassisStatus, WheelState
from omnican.chassis.supervisor import NodeSupervisor
from omnican.clock import REAL_TIME, Clock
from omnican.config import ChassisConfig, ChassisSettings, with_live_limits
from omnican.core.imu import ImuInbox
from omnican.core.kinematics import Twist
from omnican.core.limits import command_problem, pose_problem
from omnican.core.odometry import Pose2D
from omnican.drive import DriveNode
from omnican.errors import DriveError
from omnican.io.bus import CanBus
from omnican.io.imu import CanImu

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
                                                ChassisChecks(cfg, nodes, bus))
        self._loop = loop = ControlCycle(cfg, bus, nodes, sup, clock)
        sup.checks.speeds = loop.wheel_speeds
        self._runner: ThreadRunner | LockstepRunner
        if self._lockstep:
            self._runner = LockstepRunner(clock, self._period, loop.run, self._cycle_failed)
        elif bus.sync_mode == "kernel":  # SocketCAN: woken by the kernel's SYNC
            self._runner = SyncRunner(self._period, loop.run, self._cycle_failed, bus,
                                      cfg.chassis.rt_priority)
        else:
            self._runner = ThreadRunner(self._period, loop.run, self._cycle_failed,
                                        cfg.chassis.rt_priority)
        loop.runner = self._runner
        #: what layers above attached (the telemetry feed, a recording): closed with the base
        self.attachments = Attachments()
        #: the start and the stop, on every way out
        self._life = Lifecycle(cfg, bus, sup, loop, self._runner, self.attachments, clock)
        self._limits_lock = threading.Lock()
        self._configured = cfg.chassis  # what a live limit may only make safer
        self._arbiter = CommandArbiter(cfg.chassis.cmd_timeout_s)  # one source at a time
        #: where the configured IMU's samples wait for the loop (None: no [imu]). A CAN
        #: IMU feeds it from the bus (:mod:`omnican.io.imu`); a ROS 2 or Zenoh one, the
        #: front end that subscribes to its topic.
        self.imu: ImuInbox | None = None
        if cfg.imu is not None:
            loop.imu = self.imu = ImuInbox()
            if cfg.imu.source == "can":
                self.attachments.add("imu", CanImu(cfg.imu, self.imu, clock).attach(bus))

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
        self._life.start(handle_signals, configured=lambda: _open_chassis.add(self))

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
        if self._life.closed:
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
        if self._life.closed:
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
        self._life.recover(timeout_s)

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
            if self._life.closed:
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
        loop.call_soon(lambda: reset_pose(loop, target))
        deadline = self.clock.now() + 1.0
        while loop.snapshot.pose != target and self.clock.now() < deadline:
            if not self._runner.running:
                reset_pose(loop, target)
                break
            self.clock.sleep(self._period if self._lockstep else self._period / 2)

    @property
    def pose(self) -> Pose2D:
        return self._loop.snapshot.pose

    @property
    def fused_pose(self) -> Pose2D | None:
        """The pose fused with an attached IMU's gyro (:mod:`omnican.core.fusion`); None
        without an IMU. :attr:`pose` stays the wheels' own."""
        return self._loop.snapshot.fused_pose

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
    def stopped_reason(self) -> str | None:
        """Why the base is held stopped until :meth:`recover` (None: it is not), as of the
        last cycle: :attr:`status`'s ``stopped_reason`` without making the rest of it (a
        script that watches for a stop each step)."""
        return self._loop.snapshot.stopped_reason

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
        _open_chassis.discard(self)
        self._life.close(controlled)

    @property
    def not_disabled(self) -> tuple[str, ...]:
        """After :meth:`close`: the drives it could not confirm disabled, each as the
        closing error says it (``node 1 (OFFLINE: heartbeat lost; last seen OPERATION
        ENABLED)``); empty when every drive was, and while the base is open. A front end
        ends with a run-time failure (exit 1) when it is not empty."""
        return self._life.not_disabled

    def __enter__(self) -> Chassis:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"<Chassis {len(self._loop.axes)} wheels on nodes "
                f"{[n.node_id for n in self.nodes]}>")
