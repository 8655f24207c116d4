"""The base: drives + kinematics + odometry + limits + watchdog + safety.

One thread runs the control loop at ``rate_hz``. Each cycle it integrates the
encoder samples of the previous SYNC (all wheels, same SYNC, or none), checks the
drives' health, limits the newest command, writes the targets on the SYNC RPDOs,
walks the CiA 402 state machines, sends SYNC and the host heartbeat, and publishes
an immutable snapshot that any thread may read.

Safety: no command for ``cmd_timeout_s`` -> controlled stop; a drive
fault, a lost heartbeat, a drive reboot or a bus that stays down -> every wheel
stops and the base stays stopped until :meth:`Chassis.recover`; drives watch the
host's heartbeat, so they stop by themselves if this process dies; leaving the
``with`` block, Ctrl-C or SIGTERM stops the wheels and disables every drive.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import logging
import math
import queue
import signal
import threading
import time
import weakref
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from omnican import bus as bus_module
from omnican import cia402
from omnican.bus import CanBus
from omnican.cia301 import (
    HEARTBEAT_BASE,
    NMT_COB_ID,
    NMT_COMMAND_NAMES,
    NmtCommand,
    NmtState,
    nmt_state_name,
)
from omnican.cia402 import Command, State, describe_emcy
from omnican.clock import REAL_TIME, Clock
from omnican.config import ChassisConfig
from omnican.drive import AxisIO, DriveNode
from omnican.encoder import SPEED_WINDOW_S
from omnican.errors import DriveError, OmnicanError
from omnican.heartbeat import HeartbeatSchedule
from omnican.kinematics import Twist
from omnican.layout import cycle_bits, node_layouts
from omnican.limits import VelocityLimiter
from omnican.logthrottle import Throttle
from omnican.odometry import Odometry, Pose2D
from omnican.sdocycle import SDO_REQUEST_BASE, download_request

logger = logging.getLogger(__name__)

BUS_DOWN_AFTER_S = 0.05  # sends or receives failing for this long: the bus is down
BUS_UP_AFTER_S = 0.2  # and working again for this long: it is back up
LATE_FRACTION_OF_PERIOD = 0.2  # a cycle starting later than this is late
STALE_AFTER_S = 0.1  # a wheel with no position sample for this long reads as unknown
NMT_RESTART_S = 0.5  # a started node reporting PRE-OPERATIONAL is started again this often
RECONFIGURE_ATTEMPTS = 2  # a node configured again (reboot, bus back) that fails once
STARTUP_ATTEMPTS = 3  # configurations of a node that reboots while being configured
# Enum members as plain names: each State.X costs a descriptor call on Python 3.11.
_ENABLED, _FAULT, _FAULT_REACTION, _UNKNOWN = (State.OPERATION_ENABLED, State.FAULT,
                                               State.FAULT_REACTION_ACTIVE, State.UNKNOWN)
_PRE_OPERATIONAL, _OPERATIONAL = NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL
_NMT_LOG = Throttle(logger)
HEALTH_CHECK_HZ = 250.0  # faster loops check the drives' health every few cycles (below)
SIGNAL_GRACE_S = 3.0  # repeated signals this soon after the first do not cut the stop short


@dataclass(frozen=True)
class WheelState:
    """One wheel, as of one control cycle. Speeds in m/s at the rim, travel in m."""

    index: int
    node_id: int
    axis: int
    state: State
    statusword: int | None
    mode: int | None
    target_speed: float
    actual_speed: float
    travel: float
    online: bool
    fault: str | None
    error: str | None
    stale: bool = False  # no fresh position sample: actual_speed reads 0.0, not a stale value


@dataclass(frozen=True)
class ChassisStatus:
    """The loop and the bus, as of one control cycle."""

    enabled: bool  # every drive in OPERATION ENABLED and nothing latched
    stopped_reason: str | None  # why the base is held stopped (needs recover())
    command_age_s: float
    loop_hz: float
    late_fraction: float
    cycles: int
    bus_load: float | None  # fraction of the bitrate (None: bitrate unknown)
    bus_bits_per_s: float
    bus_error: str | None
    warnings: tuple[str, ...]
    bus_up: bool = True  # False while sends or receives fail, and until the bus is reopened


class _Snapshot:
    """What one cycle published, as plain numbers and tuples: the objects (Pose2D,
    Twist, WheelState, ChassisStatus) are made on first read, by the reader. The loop
    only packs tuples, which keeps it cheap at 1 kHz."""

    __slots__ = ("_command", "_info", "_pose", "_status", "_twist", "_values", "_wheel_values",
                 "_wheels")

    def __init__(self, pose: tuple[float, float, float], twist: tuple[float, float, float],
                 command: tuple[float, float, float], wheels: tuple[Any, ...],
                 status: tuple[Any, ...], info: tuple[tuple[int, int, int, float], ...]) -> None:
        self._values = (pose, twist, command, status)
        self._wheel_values = wheels
        self._info = info
        self._pose: Pose2D | None = None
        self._twist: Twist | None = None
        self._command: Twist | None = None
        self._status: ChassisStatus | None = None
        self._wheels: tuple[WheelState, ...] | None = None

    @property
    def pose(self) -> Pose2D:
        if self._pose is None:
            self._pose = Pose2D(*self._values[0])
        return self._pose

    @property
    def twist(self) -> Twist:
        if self._twist is None:
            self._twist = Twist(*self._values[1])
        return self._twist

    @property
    def command(self) -> Twist:
        if self._command is None:
            self._command = Twist(*self._values[2])
        return self._command

    @property
    def status(self) -> ChassisStatus:
        if self._status is None:
            self._status = ChassisStatus(*self._values[3])
        return self._status

    @property
    def wheels(self) -> tuple[WheelState, ...]:
        if self._wheels is None:
            targets, speeds, flags, drives = self._wheel_values
            out = []
            for i, ((index, node_id, axis, scale), (online, stale),
                    (counts, statusword, mode, error_value, error, fault_text)) in enumerate(
                        zip(self._info, flags, drives, strict=True)):
                state = cia402.decode_state(statusword)
                fault = None
                if state is State.FAULT or state is State.FAULT_REACTION_ACTIVE:
                    fault = fault_text or (describe_emcy(error_value) if error_value
                                           else "fault")
                out.append(WheelState(index, node_id, axis, state, statusword, mode, targets[i],
                                      0.0 if stale else speeds[i], counts / scale, online,
                                      fault, error, stale))
            self._wheels = tuple(out)
        return self._wheels


_open_chassis: weakref.WeakSet[Chassis] = weakref.WeakSet()


class _SignalGuard:
    """SIGINT and SIGTERM while a base is open, in the main thread.

    The first signal ends the program as usual (KeyboardInterrupt, or SystemExit for
    SIGTERM), and the ``with`` block's exit stops and disables the drives. A second
    signal right behind it (an impatient double Ctrl-C, or ``timeout``, which signals the
    child and then its whole process group) would otherwise raise inside that stop and
    cut it short, leaving drives enabled with a target. So signals that come while a
    base is closing, or within ``SIGNAL_GRACE_S`` of the first, are logged and ignored;
    the stop-and-disable sequence is bounded, so the program still ends.

    The grace outlives the base: a stop that ends within it leaves the handlers in place
    until it is over, so the second Ctrl-C cannot cut short what the program does after
    the stop either (a front end printing the final pose, a simulator shutting down).
    The first signal after the grace restores the program's own handlers and acts as
    they would."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self._users = 0
        self._closing = 0
        self._saved: dict[int, Any] = {}
        self._first_at = -math.inf
        self._lingering = False  # released within the grace: handlers still installed

    def acquire(self) -> bool:
        """Install the handlers (main thread only); False where that is impossible."""
        if threading.current_thread() is not threading.main_thread():
            return False
        if self._users == 0:
            if self._lingering:
                self._lingering = False  # still installed, the program's ones saved
            else:
                self._saved = {int(sig): signal.signal(sig, self._handle)
                               for sig in self.SIGNALS}
            self._first_at = -math.inf
        self._users += 1
        return True

    def release(self) -> None:
        if self._users == 0:
            return
        self._users -= 1
        if self._users == 0:
            if time.monotonic() - self._first_at < SIGNAL_GRACE_S:
                self._lingering = True
                return
            self._restore()

    def _restore(self) -> None:
        self._lingering = False
        for sig, old in self._saved.items():
            with contextlib.suppress(ValueError, TypeError):  # not the main thread now
                signal.signal(sig, old if old is not None else signal.SIG_DFL)
        self._saved = {}

    def at_exit(self) -> None:
        """The interpreter is ending within the grace: ignore the signals from here on.
        Python puts back the default SIGINT as it finalises, and a second Ctrl-C landing
        then would end the program by the signal, after it did all it had to."""
        if self._lingering and time.monotonic() - self._first_at < SIGNAL_GRACE_S:
            for sig in self.SIGNALS:
                with contextlib.suppress(ValueError, TypeError, OSError):
                    signal.signal(sig, signal.SIG_IGN)

    @contextlib.contextmanager
    def closing(self) -> Iterator[None]:
        self._closing += 1
        try:
            yield
        finally:
            self._closing -= 1

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        now = time.monotonic()
        if self._closing or now - self._first_at < SIGNAL_GRACE_S:
            logger.warning("%s ignored: %s", name, "the drives are stopped and disabled; "
                           "finishing" if self._lingering else
                           "stopping the wheels and disabling the drives")
            return
        self._first_at = now
        old = self._saved.get(signum)
        if self._lingering:  # the base is gone and the grace over: the program's own again
            self._restore()
        if old is signal.SIG_IGN:
            return
        if callable(old) and old is not signal.default_int_handler:
            old(signum, frame)  # the program's own handler decides
            return
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)


_signals = _SignalGuard()


@atexit.register
def _close_all() -> None:
    for base in list(_open_chassis):
        base.close()
    _signals.at_exit()


class Chassis:
    """A running base. Use :meth:`open` (a context manager)."""

    def __init__(self, cfg: ChassisConfig, bus: CanBus, nodes: list[DriveNode],
                 clock: Clock = REAL_TIME) -> None:
        self.cfg = cfg
        self.clock = clock
        self._lockstep = clock.lockstep
        self._task: object | None = None  # the clock's handle on step() (lock-step)
        self._bus = bus
        self.nodes = nodes
        self._kin = cfg.kinematics()
        self._odo = Odometry(self._kin)
        self._limiter = VelocityLimiter(cfg.limits(), self._kin)
        self._period = 1.0 / cfg.chassis.rate_hz
        # Above HEALTH_CHECK_HZ the latches (fault, heartbeat, reboot, SDO aborts) are
        # checked every few cycles: a drive leaving OPERATION ENABLED still zeroes every
        # target in the cycle that sees it (``all_enabled`` below), the latch only makes
        # that stop stick, a few ms later (4 ms at 1 kHz, 8 ms at most).
        self._health_every = max(1, math.ceil(cfg.chassis.rate_hz / HEALTH_CHECK_HZ))
        self._heartbeat = HeartbeatSchedule(cfg.chassis.heartbeat_ms / 1000.0, self._period)
        self._cmd_timeout = cfg.chassis.cmd_timeout_s
        self._max_wheel_speed = cfg.chassis.max_wheel_speed
        self._axes: list[AxisIO] = sorted((a for n in nodes for a in n.axes),
                                          key=lambda a: a.wheel_index)
        self._node_of = {id(a): n for n in nodes for a in n.axes}
        self._axis_nodes = [(a, self._node_of[id(a)]) for a in self._axes]
        self._all_ok_flags = ((True, False),) * len(self._axes)
        # Per wheel, what never changes: index, node id, axis, position scale.
        self._wheel_info = tuple((a.wheel_index, n.node_id, a.wheel.axis, a.wheel.position_scale)
                                 for a, n in self._axis_nodes)
        self._all_enabled = False  # every stage OPERATION ENABLED, as of the last cycle
        self._stages = [s for n in nodes for s in n.stages]
        self._cmd: tuple[Twist, float] = (Twist(), -math.inf)
        self._latched: str | None = None
        self._recovering = False
        self._config_failed: set[int] = set()  # nodes whose re-configuration failed
        self._nmt_started: dict[int, float] = {}  # when NMT start was last re-sent, by node
        self._sdo_stop_sent: dict[int, float] = {}  # a quick stop by SDO, by node
        # NMT commands heard on the bus (receive thread appends, loop pops): never ours,
        # since a bus does not hand a sender its own frames. Another master's.
        self._foreign_nmt: collections.deque[tuple[int, int]] = collections.deque(maxlen=64)
        self._node_ids = frozenset(n.node_id for n in nodes)
        bus.network.subscribe(NMT_COB_ID, self._on_nmt)
        self._sdo_aborts: dict[int, int] = {}  # per-cycle SDO aborts seen, by node
        self._want_enabled = True
        self._requests: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._configuring: set[int] = set()
        self._offline: set[int] = set()
        n = len(self._axes)
        self._speeds = [0.0] * n  # measured rim speeds, m/s, by wheel index
        self._targets = [0.0] * n  # commanded rim speeds, m/s, by wheel index
        self._travel = [0.0] * n
        self._history: collections.deque[tuple[float, list[float]]] = collections.deque()
        self._measured = (0.0, 0.0, 0.0)
        self._stale: tuple[int, ...] = ()  # wheels (by index) without a fresh sample
        self._stale_cycles = max(3, math.ceil(STALE_AFTER_S * cfg.chassis.rate_hz))
        self._last_sync_time = 0.0
        self._sample_time = 0.0
        self._stop = threading.Event()
        self._cycles = 0
        self._late = 0
        self._bus_fail_since: float | None = None
        self._bus_ok_since: float | None = None
        self._load_mark = (clock.now(), 0)
        self._bus_bits_per_s = 0.0
        self._rate_mark = (clock.now(), 0)
        self._loop_hz = 0.0
        self.warnings: list[str] = []
        self._warnings_list: list[str] = []
        self._warnings: tuple[str, ...] = ()
        self._workers: list[threading.Thread] = []
        self._closed = False
        self._close_lock = threading.Lock()
        self._guards_signals = False
        self._bus_down = False
        self._reconnect_asked_at = -math.inf
        self._loop_cpu_at_end = 0.0
        self._failing: str | None = None  # the bus's trouble, as this cycle's _check_bus saw it
        self._bitrate = self._bus.bitrate
        self._snapshot = self._make_snapshot(clock.now())
        self._thread = threading.Thread(target=self._run, name="omnican-loop", daemon=True)

    # ------------------------------------------------------------ opening

    @classmethod
    def open(
        cls,
        cfg: ChassisConfig,
        *,
        bus: Mapping[str, Any] | None = None,
        record: str | Path | None = None,
        handle_signals: bool = True,
        clock: Clock | None = None,
    ) -> Chassis:
        """Open the bus, configure and enable every drive, start the loop.

        Args:
            cfg: the robot config.
            bus: ``can.Bus`` arguments overriding ``cfg.bus``.
            record: write all bus traffic to this python-can log file (.log/.asc/.blf).
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
        layouts = node_layouts(cfg)  # EDS problems surface before the bus is touched
        can_bus = CanBus(bus if bus is not None else cfg.bus, record=record, clock=clock)
        nodes: list[DriveNode] = []
        try:
            for layout in layouts:
                nodes.append(DriveNode(can_bus.network, layout, can_bus, clock))
            base = cls(cfg, can_bus, nodes, clock)
        except BaseException:
            for n in nodes:
                n.detach()
            can_bus.close()
            raise
        try:
            attach = getattr(can_bus.recorder, "attach", None)
            if attach is not None:  # an MCAP recording samples the base's state too (its
                attach(base)        # set-up costs CPU: before the control loop runs)
            base._start(handle_signals)
        except BaseException:
            base.close(controlled=False)
            raise
        return base

    def _start(self, handle_signals: bool) -> None:
        warnings: list[str] = []
        pending = list(self.nodes)
        for _attempt in range(STARTUP_ATTEMPTS):
            self._configure_all(pending, warnings)
            # A drive that booted again while it was being configured lost part of it.
            pending = [n for n in self.nodes if n.rebooted]
            if not pending:
                break
            logger.info("nodes %s rebooted during their configuration; configuring again",
                        [n.node_id for n in pending])
        else:
            raise DriveError(f"nodes {[n.node_id for n in pending]} keep rebooting while "
                             "being configured (power supply? a watchdog of their own?)")
        for node in self.nodes:
            self._seed_statuswords(node)
        for w in warnings:
            logger.warning("%s", w)
        self.warnings = warnings
        for stage in self._stages:
            stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=True)
        _open_chassis.add(self)
        if handle_signals:
            self._guards_signals = _signals.acquire()
        if self._lockstep:
            self._task = self.clock.every(self._period, self.step, first_s=self.clock.now())
        else:
            self._bus.start_polling()  # the loop reads the bus itself: one wake-up a cycle
            self._thread.start()
        self._wait_enabled(self.cfg.chassis.enable_timeout_s + 4 * self._period, "startup")
        for stage in self._stages:
            stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=False)

    def _configure_all(self, nodes: list[DriveNode], warnings: list[str]) -> None:
        errors: list[str] = []

        def note(node: DriveNode, exc: Exception) -> None:
            errors.append(str(exc) if isinstance(exc, OmnicanError) else
                          f"node {node.node_id}: {exc}")

        if self._lockstep:  # one thread, in order: deterministic
            for node in nodes:
                try:
                    node.configure(warnings)
                except Exception as exc:
                    note(node, exc)
        else:
            with ThreadPoolExecutor(len(nodes), thread_name_prefix="omnican-cfg") as ex:
                futures = {ex.submit(n.configure, warnings): n for n in nodes}
                for fut, node in futures.items():
                    try:
                        fut.result()
                    except Exception as exc:
                        note(node, exc)
        if errors:
            raise DriveError(_combine_node_errors(errors, len(self.nodes)))

    def _seed_statuswords(self, node: DriveNode) -> None:
        """Read each statusword once by SDO: a drive need not send its event TPDO at start."""
        for stage in node.stages:
            sw = stage.statusword
            try:
                raw = node.remote.sdo.upload(sw.index, sw.subindex)
            except Exception as exc:  # the TPDO will tell; this is only a head start
                logger.debug("node %d: statusword read failed: %s", node.node_id, exc)
                continue
            if stage.statusword_value is None:
                stage.statusword_value = sw.decode(raw) & 0xFFFF

    def _wait_enabled(self, timeout: float, what: str) -> None:
        clock = self.clock
        deadline = clock.now() + timeout
        while clock.now() < deadline:
            snap = self._snapshot
            if snap.status.enabled and snap.status.cycles > 0:
                return
            if self._closed:
                raise DriveError(f"{what}: the base was closed")
            clock.sleep(self._period if self._lockstep else 0.002)
        problems = [f"node {nid} heartbeat lost" for nid in sorted(self._offline)]
        problems += [s.error for s in self._stages if s.error]
        states = ", ".join(f"node {s.node_id}: {s.state}" for s in self._stages
                           if s.state is not State.OPERATION_ENABLED)
        reason = self._latched or "; ".join(problems) or states or "not enabled"
        raise DriveError(f"{what}: drives not enabled within {timeout:.2g} s ({reason})")

    # ------------------------------------------------------------ public API

    def set_velocity(self, vx: float, vy: float, wz: float) -> None:
        """Command a body velocity (m/s, m/s, rad/s); it lapses after ``cmd_timeout_s``.

        Raises ValueError for NaN/inf (nothing changes); DriveError if the base is closed."""
        twist = Twist(float(vx), float(vy), float(wz))
        if not twist.is_finite():
            raise ValueError(f"velocity command must be finite, got {twist}")
        if self._closed:
            raise DriveError("the base is closed")
        self._cmd = (twist, self.clock.now())

    def stop(self) -> None:
        """Controlled stop now (at the stop deceleration); a new command moves again."""
        self._cmd = (Twist(), self.clock.now())

    def recover(self, timeout_s: float | None = None) -> None:
        """Clear a latched stop: reset faulted drives, re-enable every drive, and wait
        (bounded) until all are enabled. The base stays still until the next command.

        Raises DriveError naming what could not be recovered."""
        if self._closed:
            raise DriveError("the base is closed")
        if self._bus_down:
            raise DriveError(f"{self._latched or 'the CAN bus is down'}: recover once it is "
                             "back (status.bus_up)")
        timeout = timeout_s if timeout_s is not None else (
            self.cfg.chassis.enable_timeout_s + self.cfg.chassis.boot_timeout_s)

        def begin() -> None:
            now = self.clock.now()
            self._cmd = (Twist(), now)
            self._want_enabled = True
            self._recovering = True  # a silent node may come back meanwhile
            for node in self.nodes:  # a failed configuration gets another go
                if node.node_id in self._config_failed and node.node_id not in self._configuring:
                    self._reconfigure(node, "recover()")
            for node in self.nodes:
                if node.node_id in self._offline and not node.heartbeat_lost(now):
                    self._offline.discard(node.node_id)
                if (node.node_id not in self._configuring and node.nmt_state is not None
                        and node.nmt_state != _OPERATIONAL):
                    node.seen_operational = False  # left OPERATIONAL: start it again
                    self._start_node(node, now)
            for stage in self._stages:
                stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=True)
            self._latched = None

        self._requests.put(begin)
        self.clock.sleep(2 * self._period)
        try:
            self._wait_enabled(timeout, "recover")
            logger.info("recovered: every drive enabled")
        finally:
            def done() -> None:
                self._recovering = False
                for stage in self._stages:
                    stage.set_goal(stage.goal, allow_fault_reset=False)
                for nid in sorted(self._offline):
                    self._latch(f"node {nid} heartbeat lost")
            self._requests.put(done)
        self._cmd = (Twist(), self.clock.now())

    def reset_pose(self, pose: Pose2D | None = None) -> None:
        """Set the odometry pose (default: origin)."""
        target = pose if pose is not None else Pose2D()
        self._requests.put(lambda: self._odo.reset(target))
        deadline = self.clock.now() + 1.0
        while self._snapshot.pose != target and self.clock.now() < deadline:
            if not self._loop_running():
                self._odo.reset(target)
                break
            self.clock.sleep(self._period if self._lockstep else self._period / 2)

    @property
    def pose(self) -> Pose2D:
        return self._snapshot.pose

    @property
    def twist(self) -> Twist:
        """Measured body velocity from the encoders, averaged over the last 0.1 s."""
        return self._snapshot.twist

    @property
    def command(self) -> Twist:
        """The limited twist being applied this cycle."""
        return self._snapshot.command

    @property
    def wheels(self) -> tuple[WheelState, ...]:
        return self._snapshot.wheels

    @property
    def status(self) -> ChassisStatus:
        return self._snapshot.status

    @property
    def bus(self) -> CanBus:
        return self._bus

    # ------------------------------------------------------------ loop

    def _loop_running(self) -> bool:
        if self._lockstep:
            return self._task is not None
        return self._thread.is_alive()

    def step(self, now: float) -> None:
        """One control cycle at ``now`` (lock-step: the clock calls this every period)."""
        if not self._lockstep:
            raise RuntimeError("step() is for lock-step simulation: a real-time base runs "
                               "its own loop thread")
        try:
            self._cycle(now)
        except Exception:  # keep stopping the base whatever went wrong
            logger.exception("control cycle failed")
            self._latch("internal error in the control loop (see log)")

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now - next_t > self._period * LATE_FRACTION_OF_PERIOD:
                self._late += 1
            try:
                self._cycle(now)
            except Exception:  # keep stopping the base whatever went wrong
                logger.exception("control cycle failed")
                self._latch("internal error in the control loop (see log)")
            next_t += self._period
            delay = next_t - time.monotonic()
            if delay < -self._period:
                next_t = time.monotonic()  # fell far behind: do not burst to catch up
                delay = 0.0
            if delay > 0:
                time.sleep(delay)  # finer than Event.wait's timed lock: fewer late cycles
        self._loop_cpu_at_end = time.thread_time()

    @property
    def loop_cpu_s(self) -> float:
        """CPU seconds the loop thread has used, its wake-ups included (for benchmarks;
        0.0 in lock-step, where there is no such thread). Read from the thread's own
        clock, so the loop pays nothing for it."""
        thread = self._thread
        ident = thread.ident
        if ident is not None and thread.is_alive() and hasattr(time, "pthread_getcpuclockid"):
            try:
                return time.clock_gettime(time.pthread_getcpuclockid(ident))
            except OSError:  # it ended meanwhile
                pass
        return self._loop_cpu_at_end

    def _latch(self, reason: str) -> None:
        if self._latched is None:
            self._latched = reason
            logger.warning("base stopped: %s", reason)

    def _cycle(self, now: float) -> None:
        # Read what arrived, decide, then the RPDOs and SYNC, then the bookkeeping.
        self._bus.poll()
        requests = self._requests
        while not requests.empty():
            requests.get_nowait()()
        if not self._cycles % self._health_every:
            self._check_health(now)
        self._integrate_samples()
        # Command -> limits -> wheel speeds.
        cmd, t_cmd = self._cmd
        all_enabled = True
        for stage in self._stages:
            if stage.state is not _ENABLED:
                all_enabled = False
                break
        self._all_enabled = all_enabled
        if self._latched or not all_enabled or now - t_cmd > self._cmd_timeout:
            vx = vy = wz = 0.0
        else:
            vx, vy, wz = cmd.vx, cmd.vy, cmd.wz
        if not all_enabled:
            self._limiter.reset()
        dt = now - self._last_sync_time if self._last_sync_time else self._period
        limited = self._limiter.step_xyz(vx, vy, wz, min(dt, 5 * self._period))
        speeds = self._kin.wheel_speeds_of(*limited)
        peak = max(map(abs, speeds))
        if peak > self._max_wheel_speed:  # the limiter keeps this from happening
            speeds = [v * self._max_wheel_speed / peak for v in speeds]
        self._targets = speeds
        # State machines, then the cycle's RPDOs, then SYNC.
        send = self._bus.send_prepared
        for node in self.nodes:
            if node.node_id in self._configuring:
                continue
            if node.node_id not in self._offline:  # a silent node's statusword is stale
                for stage in node.stages:
                    if stage.step(now) is not None:
                        frame = node.controlword_frame(stage)
                        if frame is not None:
                            send(*frame)
            # Targets go to every node, a silent one too: it may still listen, and stop.
            for msg, bits in node.cyclic_frames(speeds):
                send(msg, bits)
        self._bus.sync()
        self._last_sync_time = self._bus.sync_time
        heartbeat = self._heartbeat
        if now >= heartbeat.send_at:  # on a fixed schedule: never a cycle late per period
            heartbeat.sent(now)
            self._bus.send(HEARTBEAT_BASE + self.cfg.chassis.host_node_id,
                           bytes([NmtState.OPERATIONAL]))
        self._check_bus(now)
        self._cycles += 1
        self._snapshot = self._make_snapshot(now, limited)

    def _left_operational(self, node: DriveNode, nmt: int, now: float) -> None:
        """It ran and left OPERATIONAL (another master, the drive itself): it ignores
        every PDO now, the zero targets of a stop included, and sends none (its statuswords
        are no longer news). Nothing moves again without recover(); a drive in
        PRE-OPERATIONAL still takes SDO, so it is told to quick-stop that way."""
        nid = node.node_id
        self._latch(f"node {nid} left OPERATIONAL (now {nmt_state_name(nmt)})")
        for stage in node.stages:
            stage.statusword_value = None
        if nmt == _PRE_OPERATIONAL and now - self._sdo_stop_sent.get(nid, -math.inf) >= \
                NMT_RESTART_S:
            self._sdo_stop_sent[nid] = now
            for stage in node.stages:
                cw = stage.controlword
                quick_stop = cia402.apply_command(stage.cw, Command.QUICK_STOP)
                self._bus.send(SDO_REQUEST_BASE + nid,
                               download_request(cw.index, cw.subindex, cw.encode(quick_stop)))

    def _start_node(self, node: DriveNode, now: float) -> None:
        self._nmt_started[node.node_id] = now
        logger.info("node %d reports %s: starting it", node.node_id,
                    nmt_state_name(node.nmt_state or 0))
        self._bus.send(NMT_COB_ID, bytes([NmtCommand.START, node.node_id]))

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """An NMT command on the bus (receive thread): another master's."""
        if len(data) >= 2 and (data[1] == 0 or data[1] in self._node_ids):
            self._foreign_nmt.append((data[0], data[1]))

    def _foreign_nmt_seen(self) -> None:
        while self._foreign_nmt:
            command, target = self._foreign_nmt.popleft()
            name = NMT_COMMAND_NAMES.get(command, f"0x{command:02X}")
            whom = "all nodes" if target == 0 else f"node {target}"
            if command == NmtCommand.START:  # changes nothing for a node that runs
                _NMT_LOG.warning(("start", target), "another master sent NMT %s to %s",
                                 name, whom)
                continue
            self._latch(f"another master sent NMT {name} to {whom}")

    def _check_health(self, now: float) -> None:
        configuring, offline, sdo_aborts = self._configuring, self._offline, self._sdo_aborts
        if self._foreign_nmt:
            self._foreign_nmt_seen()
        for node in self.nodes:
            nid = node.node_id
            if nid in configuring:
                continue
            if node.boot_count != node.configured_boot:  # node.rebooted
                self._latch(f"node {nid} rebooted")
                self._reconfigure(node, "its reboot")
                continue
            nmt = node.nmt_state
            if nmt is not None and nmt != _OPERATIONAL and not self._closed:
                if node.seen_operational:
                    self._left_operational(node, nmt, now)
                elif now - self._nmt_started.get(nid, -math.inf) >= NMT_RESTART_S:
                    # Configured and started, yet its heartbeat has never said OPERATIONAL:
                    # the start was lost. Start it.
                    self._start_node(node, now)
            aborts = node.sdo_counts.aborts
            if aborts != sdo_aborts.get(nid, 0):
                # A drive that refuses the target written by SDO each cycle keeps turning
                # at the last one it took: stop the base.
                sdo_aborts[nid] = aborts
                if aborts:
                    self._latch(f"node {nid} refuses its per-cycle SDO transfers "
                                f"({node.sdo_counts.last_abort})")
            if node.heartbeat_lost(now):
                offline.add(nid)
                if not self._recovering:  # recover() waits for it, and says if it never came
                    self._latch(f"node {nid} heartbeat lost")
            elif nid in offline:  # its heartbeat is back: online again (a stop stays)
                offline.discard(nid)
            latched = self._latched is not None and not self._recovering
            for stage in node.stages:
                state = stage.state
                if state is _ENABLED or stage.allow_fault_reset:
                    continue  # all is well, or the stage driver resets faults (starting up)
                if latched and stage.goal is _ENABLED and state is not _UNKNOWN:
                    # Stopped and out of OPERATION ENABLED (a quick stop, a fault): left
                    # de-energised until recover(), not walked back up meanwhile.
                    stage.set_goal(State.SWITCH_ON_DISABLED)
                if state is _FAULT or state is _FAULT_REACTION:
                    text = node.fault_text or (describe_emcy(stage.error_value)
                                               if stage.error_value else "no EMCY")
                    self._latch(f"node {nid} fault: {text}")
                elif stage.goal is _ENABLED and state is not _UNKNOWN:
                    self._latch(f"node {nid} left OPERATION ENABLED (now {state})")

    def _reconfigure(self, node: DriveNode, why: str) -> None:
        """Configure ``node`` again on a worker thread (the loop goes on meanwhile, and
        leaves that node's state machine alone until it is done)."""
        self._configuring.add(node.node_id)
        for stage in node.stages:
            stage.forget()
            stage.set_goal(State.SWITCH_ON_DISABLED)
        for ax in node.axes:
            ax.reseed()

        def work() -> None:
            try:
                for attempt in range(RECONFIGURE_ATTEMPTS):
                    try:
                        node.configure()
                        break
                    except DriveError as exc:  # a drive still booting, an SDO lost
                        if attempt + 1 == RECONFIGURE_ATTEMPTS or self._closed:
                            raise
                        logger.info("re-configuring node %d: %s; trying again", node.node_id,
                                    exc)
                self._seed_statuswords(node)
                logger.info("node %d re-configured after %s", node.node_id, why)
                self._requests.put(lambda: self._configured(node))
            except Exception as exc:
                logger.error("re-configuring node %d failed: %s", node.node_id, exc)
                self._requests.put(lambda: self._config_failed.add(node.node_id))
                # Not again until the drive boots once more (it announces that itself).
                node.configured_boot = node.boot_count
                reason = f"re-configuring node {node.node_id} failed: {exc}"
                self._requests.put(lambda: self._latch(reason))
            finally:
                self._requests.put(lambda: self._configuring.discard(node.node_id))

        if self._lockstep:  # the simulated drives answer at once: no thread, no waiting
            work()
            return
        t = threading.Thread(target=work, name=f"omnican-reconfigure-{node.node_id}", daemon=True)
        self._workers = [w for w in self._workers if w.is_alive()]
        self._workers.append(t)
        t.start()

    def _configured(self, node: DriveNode) -> None:
        """A re-configuration ended well (loop thread): a recover() waiting for it wants
        the node enabled."""
        self._config_failed.discard(node.node_id)
        if self._recovering:
            for stage in node.stages:
                stage.set_goal(State.OPERATION_ENABLED, allow_fault_reset=True)

    def _integrate_samples(self) -> None:
        epoch = self._bus.sync_epoch
        axes = self._axes
        raws: list[int] = []
        for a in axes:
            raw = a.raw
            if raw is None or a.epoch != epoch:
                raws = []
                break
            raws.append(raw)
        if not raws:
            # Not every wheel has answered the last SYNC: wait for a complete set. A wheel
            # silent for STALE_AFTER_S has no known speed: report none rather than the
            # last one (a drive gone offline must not look as if it were still turning).
            self._mark_stale(epoch)
            return
        if self._stale:
            self._stale = ()
        travel = [a.travel_from_sample(raw) for a, raw in zip(axes, raws, strict=True)]
        t = self._last_sync_time
        history = self._history
        if not self._odo.seeded:
            self._odo.step(travel)
            history.clear()
            history.append((t, travel))
            return
        self._odo.step(travel)
        history.append((t, travel))
        while len(history) > 2 and t - history[1][0] >= SPEED_WINDOW_S:
            history.popleft()
        t0, travel0 = history[0]
        if t > t0:  # speeds over the window: SYNC timing jitter averages out
            span = t - t0
            self._speeds = [(a - b) / span for a, b in zip(travel, travel0, strict=True)]
            x, y, w = self._kin.body_of_change(travel, travel0)
            self._measured = (x / span, y / span, w / span)

    def _mark_stale(self, epoch: int) -> None:
        stale = tuple(i for i, a in enumerate(self._axes)
                      if a.raw is None or epoch - a.epoch > self._stale_cycles)
        if stale == self._stale:
            return
        self._stale = stale
        if stale:
            self._speeds = [0.0 if i in stale else v for i, v in enumerate(self._speeds)]
            self._measured = (0.0, 0.0, 0.0)
            self._history.clear()  # the speed window restarts with the next complete set

    def _check_bus(self, now: float) -> None:
        """Bus down: sends or receives failing for ``BUS_DOWN_AFTER_S``. Then the bus is
        reopened on a thread of its own (this loop never waits for it) and the base stays
        stopped. Back up: sends and receives working for ``BUS_UP_AFTER_S`` (on a reopened
        bus, or the old one where the link came back); every drive is configured anew,
        since the drives stopped (or rebooted) meanwhile, and recover() starts them."""
        bus = self._bus
        failing = self._failing = bus.failing
        if not self._bus_down:
            if failing is None:
                self._bus_fail_since = None
                return
            if self._bus_fail_since is None:
                self._bus_fail_since = now
            if now - self._bus_fail_since < BUS_DOWN_AFTER_S:
                return
            self._bus_down = True
            reason = f"CAN bus down ({failing})"
            if self._latched is not None and not self._latched.startswith("CAN bus down"):
                logger.warning("base stopped: %s", reason)
                self._latched = reason  # the cause of the lost heartbeats & co.
            self._latch(reason)
        if failing is not None:
            self._bus_ok_since = None
            if (not bus.reconnecting and
                    now - self._reconnect_asked_at >= bus_module.RECONNECT_EVERY_S):
                self._reconnect_asked_at = now
                bus.request_reconnect()
            return
        if self._bus_ok_since is None:
            self._bus_ok_since = now
        if now - self._bus_ok_since < BUS_UP_AFTER_S:
            return  # one frame through a filling queue is not a bus that works
        self._bus_down = False
        self._bus_fail_since = self._bus_ok_since = None
        logger.warning("CAN bus back up; configuring every drive again")
        for node in self.nodes:
            if node.node_id not in self._configuring:
                self._reconfigure(node, "the bus came back")

    def _make_snapshot(self, now: float,
                       command: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> _Snapshot:
        mark_t, mark_bits = self._load_mark
        if now - mark_t >= 0.5:
            bits = self._bus.traffic.bits
            self._bus_bits_per_s = (bits - mark_bits) / (now - mark_t)
            self._load_mark = (now, bits)
            rate_t, rate_n = self._rate_mark
            self._loop_hz = (self._cycles - rate_n) / (now - rate_t)
            self._rate_mark = (now, self._cycles)
        offline, configuring, bus_down = self._offline, self._configuring, self._bus_down
        stale_set = self._stale
        axes = self._axis_nodes
        if offline or configuring or bus_down or stale_set:
            flags = []
            for i, (_, node) in enumerate(axes):
                online = node.node_id not in offline and node.node_id not in configuring
                flags.append((online, bus_down or not online or i in stale_set))
            wheel_flags = tuple(flags)
        else:
            wheel_flags = self._all_ok_flags
        # What the wheels were this cycle, as plain values; WheelState is made on read.
        wheels = (self._targets, self._speeds, wheel_flags,
                  tuple([(ax.counts, ax.stage.statusword_value, ax.stage.mode_value,
                          ax.stage.error_value, ax.stage.error, node.fault_text)
                         for ax, node in axes]))
        enabled = (self._latched is None and not offline and not configuring and
                   not bus_down and self._all_enabled)
        bus = self._bus
        bitrate = self._bitrate
        failing = self._failing  # as _check_bus found it this cycle
        cycles = self._cycles
        if self.warnings != self._warnings_list:
            self._warnings_list, self._warnings = list(self.warnings), tuple(self.warnings)
        status = (
            enabled,
            self._latched,
            now - self._cmd[1],
            self._loop_hz,
            self._late / cycles if cycles else 0.0,
            cycles,
            self._bus_bits_per_s / bitrate if bitrate else None,
            self._bus_bits_per_s,
            failing or (bus.reconnect_error if bus_down else None),
            self._warnings,
            not bus_down,
        )
        unknown = offline or configuring or bus_down
        return _Snapshot(self._odo.xyt, (0.0, 0.0, 0.0) if unknown else self._measured,
                         command, wheels, status, self._wheel_info)

    def cycle_bits(self) -> int:
        """Worst-case bits per control cycle: every node's cyclic PDOs plus the SYNC."""
        return cycle_bits(n.plan for n in self.nodes)  # the plans in use (maybe adopted)

    # ------------------------------------------------------------ closing

    def close(self, controlled: bool = True) -> None:
        """Stop the wheels (controlled), disable every drive, release the bus. Idempotent."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        _open_chassis.discard(self)
        with _signals.closing():
            try:
                if self._loop_running():
                    # Disabled whatever the way out: a failed open too (controlled=False
                    # only skips the deceleration).
                    self._controlled_shutdown(decelerate=controlled)
                    if self._task is not None:
                        self.clock.cancel(self._task)
                        self._task = None
                    self._stop.set()
                    if self._thread.is_alive():
                        self._thread.join(timeout=2.0)
                self._bus.stop_polling()  # a Notifier again, for the SDOs of the stop
                for t in self._workers:
                    t.join(timeout=self.cfg.chassis.boot_timeout_s + 1.0)
                for node in self.nodes:
                    if (node.node_id not in self._offline and not self._bus_down
                            and self._bus.failing is None):
                        node.stop()
            finally:
                for node in self.nodes:
                    node.detach()
                self._bus.close()
                if self._guards_signals:
                    self._guards_signals = False
                    _signals.release()
        powered = [f"node {st.node_id} ({st.state})" for st in self._stages
                   if st.state in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)]
        if powered:
            logger.error("base closed; not confirmed disabled: %s", ", ".join(powered))
        else:
            logger.info("base closed; drives disabled")

    def _controlled_shutdown(self, decelerate: bool = True) -> None:
        self._cmd = (Twist(), -math.inf)
        s = self.cfg.chassis
        clock = self.clock
        speed = max(abs(self._limiter.output.linear_speed),
                    abs(self._limiter.output.wz) * max(self._kin.base_radius))
        deadline = clock.now() + speed / s.stop_decel + 0.5
        while decelerate and clock.now() < deadline:
            if self._limiter.output.is_zero() and all(abs(v) < 0.005 for v in self._speeds):
                break
            clock.sleep(self._period)

        def disable() -> None:
            self._want_enabled = False
            for stage in self._stages:
                stage.set_goal(State.SWITCH_ON_DISABLED)

        self._requests.put(disable)
        deadline = clock.now() + 0.5
        while clock.now() < deadline:
            if all(s.state in (State.SWITCH_ON_DISABLED, State.FAULT, State.UNKNOWN)
                   for s in self._stages):
                break
            clock.sleep(self._period)

    def __enter__(self) -> Chassis:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<Chassis {len(self._axes)} wheels on nodes {[n.node_id for n in self.nodes]}>"


def _combine_node_errors(errors: list[str], nodes: int) -> str:
    """``node 1: X; node 2: X`` as ``nodes 1, 2: X``: one reason said once; when no node
    at all sent its boot-up, say there is no drive on the bus."""
    groups: dict[str, list[str]] = {}
    for error in errors:
        head, sep, reason = error.partition(": ")
        if sep and head.startswith("node ") and head[5:].isdigit():
            groups.setdefault(reason, []).append(head[5:])
        else:
            groups.setdefault(error, [])
    parts = []
    for reason, ids in groups.items():
        if len(ids) > 1:
            parts.append(f"nodes {', '.join(ids)}: {reason}")
        else:
            parts.append(f"node {ids[0]}: {reason}" if ids else reason)
    text = "; ".join(parts)
    if len(groups) == 1 and len(errors) == nodes and "no boot-up" in text:
        text = f"no drive answered on the bus: {text}"
    return text

