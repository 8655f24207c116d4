"""One control cycle, what the loop does every period.

Read what arrived; run what other threads asked for; check the drives' health (every
few cycles above 250 Hz); integrate the encoder samples of the previous SYNC (all
wheels, same SYNC, or none); limit the newest command and turn it into wheel targets;
walk the CiA 402 state machines; send the cycle's RPDOs, then SYNC and the host
heartbeat; watch the bus; publish an immutable snapshot that any thread may read.

Every target is zero while the base is held stopped (a latched stop, a drive out of
OPERATION ENABLED) or when no command came for ``cmd_timeout_s``.
"""

from __future__ import annotations

import math
import queue
from collections.abc import Callable
from typing import Any

from omnican.chassis.sink import SnapshotSink
from omnican.chassis.state import Snapshot
from omnican.chassis.supervisor import NodeSupervisor
from omnican.clock import Clock
from omnican.config import ChassisConfig
from omnican.core.fusion import FusedOdometry
from omnican.core.imu import ImuInbox
from omnican.core.kinematics import Twist
from omnican.core.limits import VelocityLimiter
from omnican.core.odometry import Odometry, Pose2D
from omnican.core.wheel_odometry import EncoderCounters, WheelOdometry
from omnican.drive import AxisIO, DriveNode
from omnican.io.bus import CAME_BACK, WENT_DOWN, BusWatch, CanBus, prepared_message
from omnican.plan.node import cycle_bits
from omnican.plan.pdo import frame_bits
from omnican.protocol.cia301 import HEARTBEAT_BASE, NmtState
from omnican.protocol.cia402 import ENABLED_BITS as _ENABLED_BITS
from omnican.protocol.cia402 import ENABLED_MASK as _ENABLED_MASK
from omnican.protocol.heartbeat import HeartbeatSchedule

STALE_AFTER_S = 0.1  # a wheel with no position sample for this long reads as unknown
HEALTH_CHECK_HZ = 250.0  # faster loops check the drives' health every few cycles (below)
_bare = object.__new__  # an instance without its __init__ (the snapshot, made field by field)


class ControlCycle:
    """The control cycle of one base (see the module docstring). :meth:`run` is called
    on the loop thread only; :attr:`snapshot` and :attr:`command` are read and written
    whole from any thread."""

    def __init__(self, cfg: ChassisConfig, bus: CanBus, nodes: list[DriveNode],
                 supervisor: NodeSupervisor, clock: Clock) -> None:
        c = cfg.chassis
        self._bus = bus
        self.nodes = nodes
        self._sup = supervisor
        self.kinematics = cfg.kinematics()
        self.odometry = Odometry(self.kinematics)
        self.limiter = VelocityLimiter(cfg.limits(), self.kinematics)
        self.period_s = period = 1.0 / c.rate_hz
        self._dt_cap = 5 * period  # the longest step the limiter is given (a late cycle)
        # Above HEALTH_CHECK_HZ the latches (fault, heartbeat, reboot, SDO aborts) are
        # checked every few cycles: a drive leaving OPERATION ENABLED still zeroes every
        # target in the cycle that sees it (``all_enabled`` below), the latch only makes
        # that stop stick, a few ms later (4 ms at 1 kHz, 8 ms at most).
        self._health_every = max(1, math.ceil(c.rate_hz / HEALTH_CHECK_HZ))
        self._heartbeat = HeartbeatSchedule(c.heartbeat_ms / 1000.0, period)
        # The host's heartbeat: one frame made once, sent as it is (as the RPDOs are).
        self._heartbeat_frame = (prepared_message(HEARTBEAT_BASE + c.host_node_id,
                                                  bytes([NmtState.OPERATIONAL])), frame_bits(1))
        self._cmd_timeout = c.cmd_timeout_s
        self._max_wheel_speed = c.max_wheel_speed
        self.watch = BusWatch(bus)
        node_of = {id(a): n for n in nodes for a in n.axes}
        self.axes: list[AxisIO] = sorted((a for n in nodes for a in n.axes),
                                         key=lambda a: a.wheel_index)
        self._axis_nodes = [(a, node_of[id(a)]) for a in self.axes]
        # The encoders: counter fold, speed window and measured twist; they drive the pose.
        self.wheel_odometry = WheelOdometry(self.odometry, EncoderCounters(
            self.axes, [a.position.bits for a in self.axes],
            [a.wheel.position_scale for a in self.axes]))
        # Per wheel: its counter (the counts), stage and node.
        self._axis_parts = tuple((c, a.stage, node_of[id(a)]) for a, c in
                                 zip(self.axes, self.wheel_odometry.counters.wheels, strict=True))
        self._all_ok_flags = ((True, False),) * len(self.axes)
        # Per wheel, what never changes: index, node id, axis, position scale.
        self._wheel_info = tuple((a.wheel_index, n.node_id, a.wheel.axis, a.wheel.position_scale)
                                 for a, n in self._axis_nodes)
        self._stages = supervisor.stages
        self._configuring = supervisor.configuring  # the same sets, shared
        self._offline = supervisor.offline
        self._all_enabled = False  # every stage OPERATION ENABLED, as of the last cycle
        #: the newest command and when it came (set whole by any thread)
        self.command: tuple[Twist, float] = (Twist(), -math.inf)
        self._requests: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        n = len(self.axes)
        self._targets = [0.0] * n  # commanded rim speeds, m/s, by wheel index
        self._limited: tuple[float, float, float] | None = None  # what _targets were made of
        self._stale: tuple[int, ...] = ()  # wheels (by index) without a fresh sample
        self._stale_cycles = max(3, math.ceil(STALE_AFTER_S * c.rate_hz))
        self._last_sync_time = 0.0
        self.cycles = 0
        self.runner: Any = None  # what calls run(): its count of late cycles is in the status
        self._load_mark = (clock.now(), 0)
        self._bus_bits_per_s = 0.0
        self._rate_mark = (clock.now(), 0)
        self._loop_hz = 0.0
        self._warnings_list: list[str] = []
        self._warnings: tuple[str, ...] = ()
        self._bitrate = bus.bitrate
        # Every sink_every-th snapshot goes to sink (0: none; see offer_to).
        self.sink: Callable[[Snapshot], None] = _no_sink
        self.sink_every = 0
        #: where a configured IMU's samples wait for the cycle (None: no IMU; set by
        #: whoever attaches the IMU source before the loop starts)
        self.imu: ImuInbox | None = None
        self.fusion: FusedOdometry | None = None  # the gyro and the wheels (see _fuse)
        self._fused: tuple[Any, tuple[str, ...]] | None = None  # (its values, its warnings)
        self._fusion_settings = (cfg.fusion, getattr(cfg, "imu", None))  # [fusion], [imu]
        self.snapshot = self._make_snapshot(clock.now())

    def call_soon(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the loop thread, at the start of the next cycle."""
        self._requests.put(fn)

    def offer_to(self, sink: SnapshotSink | None, every: int = 1) -> None:
        """Hand every ``every``-th snapshot to ``sink`` from the next cycle on, on the
        loop thread (None: to none). Any thread: the sink is set before the count, and the
        count cleared first (a cycle under way may still hand the old sink one more).
        Raises ValueError while another sink is attached."""
        if sink is None:
            self.sink_every = 0
            return
        if every < 1:
            raise ValueError(f"every: a snapshot in 1 or more cycles, not {every}")
        if self.sink_every and self.sink != sink.offer:
            raise ValueError("the base offers its snapshots to one sink, and one is attached "
                             "(the telemetry feed, omnican.telemetry.attach.feed_of, is "
                             "the one to share)")
        self.sink = sink.offer  # one bound method: what the cycle calls
        self.sink_every = every

    def cycle_bits(self) -> int:
        """Worst-case bits per control cycle: every node's cyclic PDOs plus the SYNC."""
        return cycle_bits(n.plan for n in self.nodes)  # the plans in use (maybe adopted)

    # ------------------------------------------------------------ the cycle

    def run(self, now: float) -> None:
        """One cycle at ``now``."""
        sup = self._sup
        bus = self._bus
        # Read what arrived, decide, then the RPDOs and SYNC, then the bookkeeping.
        bus.poll()
        requests = self._requests
        while not requests.empty():
            requests.get_nowait()()
        all_enabled = True  # _every_stage_enabled, written out (each cycle)
        for stage in self._stages:
            sw = stage.statusword_value
            if sw is None or sw & _ENABLED_MASK != _ENABLED_BITS:
                all_enabled = False
                break
        if not self.cycles % self._health_every:
            sup.check(now, all_enabled)
            if all_enabled and sup.latched is not None:
                all_enabled = self._every_stage_enabled()  # a latch may have forgotten one
        self._all_enabled = all_enabled
        # The encoder samples of the last SYNC whose answers had a period to come (the
        # one sent last where the loop sends SYNC; the one before it where the kernel
        # does: the cycle starts as its SYNC comes, before the answers). Not every wheel
        # has answered it: wait for a complete set. A wheel silent for STALE_AFTER_S has
        # no known speed: report none rather than the last one (a drive gone offline
        # must not look as if it still turned).
        epoch = bus.settled_epoch
        if not self.wheel_odometry.integrate(epoch, self._last_sync_time):
            self._mark_stale(epoch)
        elif self._stale:
            self._stale = ()
        # ---- IMU fusion (issue 40): a base without an IMU pays this one test.
        imu = self.imu
        if imu is not None:
            self._fuse(now, imu)
        # Command -> limits -> wheel speeds.
        cmd, t_cmd = self.command
        if sup.latched or not all_enabled or now - t_cmd > self._cmd_timeout:
            vx = vy = wz = 0.0
        else:
            vx, vy, wz = cmd.vx, cmd.vy, cmd.wz
        limiter = self.limiter
        if not all_enabled:
            limiter.reset()
        dt = now - self._last_sync_time if self._last_sync_time else self.period_s
        cap = self._dt_cap
        limited = limiter.step_xyz(vx, vy, wz, cap if dt > cap else dt)  # min(dt, cap)
        if limited is self._limited:  # the limiter held its output: the same targets
            speeds = self._targets
        else:
            speeds = self.kinematics.wheel_speeds_of(*limited)
            peak = max(map(abs, speeds))
            if peak > self._max_wheel_speed:  # the limiter keeps this from happening
                speeds = [v * self._max_wheel_speed / peak for v in speeds]
            self._targets, self._limited = speeds, limited
        # State machines, then the cycle's RPDOs, then SYNC.
        send = bus.send_prepared
        configuring, offline = self._configuring, self._offline
        every_node = not configuring and not offline  # (the usual cycle: no look per node)
        for node in self.nodes:
            if not every_node and node.node_id in configuring:
                continue
            if every_node or node.node_id not in offline:  # a silent node's statusword is stale
                for stage in node.stages:
                    if stage.step(now) is not None:
                        frame = node.controlword_frame(stage)
                        if frame is not None:
                            send(*frame)
            # Targets go to every node, a silent one too: it may still listen, and stop.
            for msg, bits in node.cyclic_frames(speeds):
                send(msg, bits)
        bus.sync()
        self._last_sync_time = bus.sync_time
        heartbeat = self._heartbeat
        if now >= heartbeat.send_at:  # on a fixed schedule: never a cycle late per period
            heartbeat.sent(now)
            send(*self._heartbeat_frame)
        change = self.watch.check(now)
        if change is not None:
            if change is WENT_DOWN:
                sup.bus_went_down(self.watch.failing or "?")
            elif change is CAME_BACK:
                sup.bus_came_back()
        self.cycles += 1
        self.snapshot = self._make_snapshot(now, limited)
        every = self.sink_every
        if every and not self.cycles % every:
            self.sink(self.snapshot)  # the telemetry feed: a queue append (real time)

    def _every_stage_enabled(self) -> bool:
        """Every stage OPERATION ENABLED, tested on the statusword's bits."""
        for stage in self._stages:
            sw = stage.statusword_value
            if sw is None or sw & _ENABLED_MASK != _ENABLED_BITS:
                return False
        return True

    def _mark_stale(self, epoch: int) -> None:
        stale = tuple(i for i, a in enumerate(self.axes)
                      if a.raw is None or epoch - a.epoch > self._stale_cycles)
        if stale == self._stale:
            return
        self._stale = stale
        if stale:
            # The other wheels keep their last speeds, a stale one reads 0 (the snapshot).
            self.wheel_odometry.forget_speeds(stale)

    def _fuse(self, now: float, imu: ImuInbox) -> None:
        """The IMU's samples fused with the wheels' step (a slip may stop the base)."""
        fusion = self.fusion
        if fusion is None:  # the first cycle with an IMU
            fusion = self.fusion = FusedOdometry.configured(
                self.kinematics, self.odometry, self.wheel_odometry, *self._fusion_settings)
        stop = fusion.step(now, imu.drain(), self.limiter.output.is_zero())
        self._fused = (fusion.values, fusion.warnings)
        if stop is not None and not self._sup.latched:
            self._sup.latch(stop)

    @property
    def speeds_settled(self) -> bool:
        """The limiter's output is zero and every wheel below 5 mm/s."""
        return self.limiter.output.is_zero() and self.wheel_odometry.settled(0.005)

    # ------------------------------------------------------------ the snapshot

    def _make_snapshot(self, now: float,
                       command: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Snapshot:
        mark_t, mark_bits = self._load_mark
        if now - mark_t >= 0.5:
            bits = self._bus.traffic.bits
            self._bus_bits_per_s = (bits - mark_bits) / (now - mark_t)
            self._load_mark = (now, bits)
            rate_t, rate_n = self._rate_mark
            self._loop_hz = (self.cycles - rate_n) / (now - rate_t)
            self._rate_mark = (now, self.cycles)
        sup = self._sup
        offline, configuring, watch = self._offline, self._configuring, self.watch
        bus_down = watch.down
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
        encoders = self.wheel_odometry
        wheels = (self._targets, encoders.window, wheel_flags,
                  tuple([(ax.counts, stage.statusword_value, stage.mode_value,
                          stage.error_value, stage.error, node.fault_text)
                         for ax, stage, node in self._axis_parts]))
        latched = sup.latched
        bitrate = self._bitrate
        cycles = self.cycles
        if sup.warnings != self._warnings_list:
            self._warnings_list, self._warnings = list(sup.warnings), tuple(sup.warnings)
        unknown = offline or configuring or bus_down
        # Field by field into a bare snapshot (see Snapshot: cheaper than a constructor).
        snap = _bare(Snapshot)
        snap.xyt = self.odometry.xyt
        snap.measured = (0.0, 0.0, 0.0) if unknown else encoders.measured
        snap.applied = command
        snap.wheel_values = wheels
        snap.info = self._wheel_info
        snap.checked = sup.checks.values
        snap.enabled = (latched is None and not offline and not configuring and
                        not bus_down and self._all_enabled)
        snap.stopped_reason = latched
        snap.command_age_s = now - self.command[1]
        snap.loop_hz = self._loop_hz
        snap.late_fraction = self.runner.late / cycles if cycles else 0.0
        snap.cycles = cycles
        snap.bus_load = self._bus_bits_per_s / bitrate if bitrate else None
        snap.bus_bits_per_s = self._bus_bits_per_s
        snap.bus_error = watch.failing or (self._bus.reconnect_error if bus_down else None)
        snap.warnings = self._warnings
        snap.bus_up = not bus_down
        snap.fusion = self._fused  # None without an IMU
        return snap

    def wheel_speeds(self) -> tuple[list[float], list[float], tuple[int, ...], bool]:
        """(targets, measured speeds (m/s, by wheel index), wheels without a fresh sample,
        every drive enabled) as of the last cycle: what the chassis checks compare."""
        return self._targets, self.wheel_odometry.speeds(), self._stale, self._all_enabled


def reset_pose(cycle: ControlCycle, pose: Pose2D) -> None:
    """The pose of ``cycle``'s base is ``pose`` from now on: the wheels' and the fused (on
    the loop thread, or with the loop stopped)."""
    cycle.odometry.reset(pose)
    if cycle.fusion is not None:
        cycle.fusion.reset((pose.x, pose.y, pose.theta))


def _no_sink(snapshot: Snapshot) -> None:
    """What the cycle hands snapshots to before a sink is attached (never called)."""
