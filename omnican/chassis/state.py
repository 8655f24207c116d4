"""The base's state as of one control cycle: the value types every front end reads.

:class:`WheelState` and :class:`ChassisStatus` are what ``Chassis.wheels`` and
``Chassis.status`` return; :class:`Snapshot` is what the control loop publishes once a
cycle (as plain numbers and tuples) and the objects are made from, on first read, by
the reader. Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.protocol import cia402
from omnican.protocol.cia402 import State, describe_emcy


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
    # What the drive reports, read a few times a second (chassis.health_rate_hz); None when
    # the drive does not give it, or nothing fresh came from it.
    current_a: float | None = None  # motor current, A
    torque_pct: float | None = None  # torque, % of the rated torque
    voltage_v: float | None = None  # the drive's DC link, V
    temperature_c: float | None = None  # the config's temperature object, degC
    error_register: int | None = None  # 1001h (bits: 0 generic, 1 current, 2 voltage, ...)


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


#: The health part of a snapshot before anything was read: per wheel (current, torque,
#: voltage, temperature, error register), then (CAN state, tx and rx counters, error
#: frames, e-stop, battery voltage and level, health warnings).
NO_STATUS_HEALTH: tuple[Any, ...] = (None, None, None, 0, False, None, None, ())


def no_health(wheels: int) -> tuple[tuple[tuple[Any, ...], ...], tuple[Any, ...]]:
    return ((None,) * 5,) * wheels, NO_STATUS_HEALTH


class Snapshot:
    """What one cycle published, as plain numbers and tuples: the objects (Pose2D,
    Twist, WheelState, ChassisStatus) are made on first read, by the reader. The loop
    only packs tuples, which keeps it cheap at 1 kHz."""

    __slots__ = ("_command", "_health", "_info", "_pose", "_status", "_twist", "_values",
                 "_wheel_values", "_wheels")

    def __init__(self, pose: tuple[float, float, float], twist: tuple[float, float, float],
                 command: tuple[float, float, float], wheels: tuple[Any, ...],
                 status: tuple[Any, ...], info: tuple[tuple[int, int, int, float], ...],
                 health: tuple[tuple[tuple[Any, ...], ...], tuple[Any, ...]] | None = None
                 ) -> None:
        self._values = (pose, twist, command, status)
        self._wheel_values = wheels
        self._info = info
        # Made at the health-check rate, not by the cycle: see no_health().
        self._health = health if health is not None else no_health(len(info))
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
            values = self._values[3]
            *extra, warnings = self._health[1]
            if warnings:
                values = (*values[:9], values[9] + warnings, *values[10:])
            self._status = ChassisStatus(*values, *extra)
        return self._status

    @property
    def wheels(self) -> tuple[WheelState, ...]:
        if self._wheels is None:
            # The measured rim speeds from the loop's speed window: (travel now, travel at
            # the window's start, its span).
            targets, (travel, travel0, span), flags, drives = self._wheel_values
            health = self._health[0]
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
                                      0.0 if stale else (travel[i] - travel0[i]) / span,
                                      counts / scale, online,
                                      fault, error, stale, *health[i]))
            self._wheels = tuple(out)
        return self._wheels

