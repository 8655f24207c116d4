"""The base's state as of one control cycle: the value types every front end reads.

:class:`WheelState` and :class:`ChassisStatus` are what ``Chassis.wheels`` and
``Chassis.status`` return; :class:`Snapshot` is what the control loop publishes once a
cycle (plain numbers and tuples, each by name) and the objects are made from, on first
read, by the reader. :class:`CheckResults` is what the chassis checks
(:mod:`omnican.chassis.checks`) add to every snapshot, made at their rate. Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.plan.health_fields import NO_WHEEL_HEALTH, WheelHealth, health_values
from omnican.protocol import cia402
from omnican.protocol.cia402 import State, describe_emcy


@dataclass(frozen=True)
class WheelState(WheelHealth):
    """One wheel, as of one control cycle. Speeds in m/s at the rim, travel in m. What
    its drive reports (``current_a``, ``torque_pct``, ``voltage_v``, ``temperature_c``,
    ``error_register``: keyword arguments) are :class:`WheelHealth`'s fields, declared
    there with how the front ends show them."""

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
    # The CAN controller as SocketCAN's error frames tell it (None: no error frame yet).
    can_state: str | None = None  # "error-active", "error-warning", "error-passive", "bus-off"
    can_tx_errors: int | None = None  # the controller's transmit error counter
    can_rx_errors: int | None = None  # and its receive error counter
    can_error_frames: int = 0
    estop: bool = False  # an e-stop is pressed (the [estop] input)
    battery_v: float | None = None  # the base's DC link: the median of its drives'
    battery: str | None = None  # "ok", "low" or "cutoff" ([power]); None: no [power] table


class StatusChecks(NamedTuple):
    """What the chassis checks add to the status: :class:`ChassisStatus`'s fields of the
    same names (``warnings`` follow the loop's)."""

    can_state: str | None = None
    can_tx_errors: int | None = None
    can_rx_errors: int | None = None
    can_error_frames: int = 0
    estop: bool = False
    battery_v: float | None = None
    battery: str | None = None
    warnings: tuple[str, ...] = ()


class CheckResults(NamedTuple):
    """What the chassis checks found, carried by every snapshot until the next check:
    per wheel (by index) what its drive reports, and the status's part."""

    wheels: tuple[WheelHealth, ...]
    status: StatusChecks


def nothing_checked(wheels: int) -> CheckResults:
    """The checks' part of a snapshot before anything was read."""
    return CheckResults((NO_WHEEL_HEALTH,) * wheels, StatusChecks())


class Snapshot:
    """What one cycle published, by name, as plain numbers and tuples: the objects
    (Pose2D, Twist, WheelState, ChassisStatus) are made on first read, by the reader.

    The cycle makes it field by field (``Snapshot.__new__(Snapshot)``, then a store per
    field: :meth:`omnican.chassis.cycle.ControlCycle._make_snapshot`), which keeps it
    cheap at 1 kHz: cheaper than a constructor call with as many arguments, or than a
    record of the status apart. Once published it does not change (what is made on read
    is stored the first time)."""

    __slots__ = ("_command", "_pose", "_status", "_twist", "_wheels", "applied",
                 "bus_bits_per_s", "bus_error", "bus_load", "bus_up", "checked", "command_age_s",
                 "cycles", "enabled", "fusion", "info", "late_fraction", "loop_hz", "measured",
                 "stopped_reason", "warnings", "wheel_values", "xyt")

    xyt: tuple[float, float, float]  # the pose: x, y (m), theta (rad)
    measured: tuple[float, float, float]  # the measured twist: vx, vy (m/s), wz (rad/s)
    applied: tuple[float, float, float]  # the command applied (after the limits)
    #: (targets, the speed window, (online, stale) per wheel, the drives' values): see
    #: :attr:`wheels`
    wheel_values: tuple[Any, ...]
    info: tuple[tuple[int, int, int, float], ...]  # per wheel: index, node id, axis, scale
    checked: CheckResults  # made at the checks' rate, not by the cycle
    # The cycle's part of ChassisStatus, by the same names.
    enabled: bool
    stopped_reason: str | None
    command_age_s: float
    loop_hz: float
    late_fraction: float
    cycles: int
    bus_load: float | None
    bus_bits_per_s: float
    bus_error: str | None
    warnings: tuple[str, ...]
    bus_up: bool
    #: (:attr:`fused`, the fusion's warnings) where an IMU is attached, else None
    fusion: tuple[tuple[float, float, float, float, float, float, float, bool, bool],
                  tuple[str, ...]] | None
    # Made on first read (unset until then).
    _pose: Pose2D
    _twist: Twist
    _command: Twist
    _status: ChassisStatus
    _wheels: tuple[WheelState, ...]

    @property
    def pose(self) -> Pose2D:
        try:
            return self._pose
        except AttributeError:  # the first read
            self._pose = pose = Pose2D(*self.xyt)
            return pose

    @property
    def fused(self) -> tuple[float, float, float, float, float, float, float, bool, bool] | None:
        """The odometry fused with an IMU's gyro (None: no IMU attached): x, y (m), theta
        (rad), theta's variance (rad^2), the gyro's bias (rad/s) and its variance, the
        fused yaw rate (rad/s), the IMU live (False: the wheels alone), the wheels
        slipping (:class:`omnican.core.fusion.FusedOdometry`); :attr:`xyt` stays the
        wheels' own."""
        fusion = self.fusion
        return None if fusion is None else fusion[0]

    @property
    def fused_pose(self) -> Pose2D | None:
        """The pose fused with the IMU's gyro (None: no IMU); :attr:`pose` is the wheels'."""
        fused = self.fused
        return None if fused is None else Pose2D(fused[0], fused[1], fused[2])

    @property
    def twist(self) -> Twist:
        try:
            return self._twist
        except AttributeError:
            self._twist = twist = Twist(*self.measured)
            return twist

    @property
    def command(self) -> Twist:
        try:
            return self._command
        except AttributeError:
            self._command = command = Twist(*self.applied)
            return command

    @property
    def status(self) -> ChassisStatus:
        try:
            return self._status
        except AttributeError:
            h = self.checked.status
            warnings = self.warnings + h.warnings if h.warnings else self.warnings
            fusion = self.fusion
            if fusion is not None and fusion[1]:  # a slip, a silent IMU
                warnings += fusion[1]
            self._status = status = ChassisStatus(
                enabled=self.enabled, stopped_reason=self.stopped_reason,
                command_age_s=self.command_age_s, loop_hz=self.loop_hz,
                late_fraction=self.late_fraction, cycles=self.cycles, bus_load=self.bus_load,
                bus_bits_per_s=self.bus_bits_per_s, bus_error=self.bus_error,
                warnings=warnings,
                bus_up=self.bus_up, can_state=h.can_state, can_tx_errors=h.can_tx_errors,
                can_rx_errors=h.can_rx_errors, can_error_frames=h.can_error_frames,
                estop=h.estop, battery_v=h.battery_v, battery=h.battery)
            return status

    @property
    def wheels(self) -> tuple[WheelState, ...]:
        try:
            return self._wheels
        except AttributeError:
            pass
        # The measured rim speeds from the loop's speed window: (travel now, travel at the
        # window's start, its span).
        targets, (travel, travel0, span), flags, drives = self.wheel_values
        health = self.checked.wheels
        out = []
        for i, ((index, node_id, axis, scale), (online, stale),
                (counts, statusword, mode, error_value, error, fault_text)) in enumerate(
                    zip(self.info, flags, drives, strict=True)):
            state = cia402.decode_state(statusword)
            fault = None
            if state is State.FAULT or state is State.FAULT_REACTION_ACTIVE:
                fault = fault_text or (describe_emcy(error_value) if error_value
                                       else "fault")
            out.append(WheelState(index, node_id, axis, state, statusword, mode, targets[i],
                                  0.0 if stale else (travel[i] - travel0[i]) / span,
                                  counts / scale, online, fault, error, stale,
                                  **health_values(health[i])))
        self._wheels = wheels = tuple(out)
        return wheels
