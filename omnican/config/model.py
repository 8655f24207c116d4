"""The configuration's model: the frozen dataclasses a config is (:class:`ChassisConfig`
the whole robot), whose defaults are :data:`omnican.config.schema.SCHEMA`'s, and the demo
base that ``--sim`` runs without a config (:func:`default_config`).

Pure: no I/O. A TOML document becomes these in :mod:`omnican.config.parsing`.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from omnican.config.front_ends import FrontEndTable, FrontEndTables, read_table
from omnican.config.front_ends import moved as moved_table
from omnican.config.schema import (
    CHASSIS_SCALED,
    VELOCITY_UNITS,
    WHEEL_EDS,
    schema_defaults,
)
from omnican.core.kinematics import LAYOUTS, OmniKinematics
from omnican.core.limits import VelocityLimits
from omnican.errors import ConfigError
from omnican.layers import FRONT_ENDS
from omnican.protocol.cia402 import Mode


def _field_defaults(section: str, **overrides: Any) -> dict[str, Any]:
    """A section's defaults as the values of its dataclass's fields (a mode named is a
    :class:`Mode`), ``overrides`` applied."""
    out = {**schema_defaults(section), **overrides}
    if out.get("mode") is not None:
        out["mode"] = Mode.from_name(out["mode"])
    return out


_WHEEL = _field_defaults("wheel")


@dataclass(frozen=True)
class WheelConfig:
    """One wheel: an axis of a CANopen node and its unit conversions. Optional fields
    default as :data:`SCHEMA` says for the ``[[wheel]]`` key of the same name."""

    node_id: int
    axis: int
    eds: Path
    velocity_scale: float  # drive velocity units per m/s at the rim
    position_scale: float  # encoder units per m of rim travel
    angle_deg: float | None = _WHEEL["angle_deg"]
    drive_angle_deg: float | None = _WHEEL["drive_angle_deg"]
    base_radius: float | None = _WHEEL["base_radius"]
    mode: Mode | None = _WHEEL["mode"]
    # m, when the config gave it (omnican ros2's joint angles need it). Not part of equality:
    # the scales define the wheel; a config rewritten with scales only is the same wheel.
    wheel_radius: float | None = field(default=_WHEEL["wheel_radius"], compare=False)
    # What the drive reports of this wheel: objects as the config names them ("" none),
    # resolved against the EDS by omnican.plan.health.
    current: str | None = _WHEEL["current"]
    current_scale: float | None = _WHEEL["current_scale"]
    torque: str | None = _WHEEL["torque"]
    voltage: str | None = _WHEEL["voltage"]
    voltage_scale: float = _WHEEL["voltage_scale"]
    temperature: str | None = _WHEEL["temperature"]
    temperature_scale: float = _WHEEL["temperature_scale"]
    sdo_writes: tuple[SdoWrite, ...] = ()  # [[wheel.sdo]]
    # The drive's serial number (1018h sub 4): what `omnican commission` finds it by.
    serial: int | None = _WHEEL["serial"]

    @property
    def name(self) -> str:
        return f"node {self.node_id}" + (f" axis {self.axis}" if self.axis else "")

    @property
    def settings(self) -> tuple[SdoWrite, ...]:
        """Deprecated: :attr:`sdo_writes` (the next release drops it)."""
        _moved_writes("WheelConfig.settings")
        return self.sdo_writes


_wheel_init = WheelConfig.__init__


@functools.wraps(_wheel_init)  # its signature, for help() and the API page
def _wheel_init_moved(self: WheelConfig, *args: Any, **kwargs: Any) -> None:
    """``WheelConfig(settings=...)`` (and ``replace(wheel, settings=...)``), the
    ``[[wheel.sdo]]`` writes under their old name, for one release."""
    if "settings" in kwargs:
        _moved_writes("WheelConfig(settings=)")
        kwargs["sdo_writes"] = kwargs.pop("settings")
    _wheel_init(self, *args, **kwargs)


WheelConfig.__init__ = _wheel_init_moved  # type: ignore[method-assign]


def _moved_writes(old: str) -> None:
    warnings.warn(f"{old} moved to WheelConfig.sdo_writes (the [[wheel.sdo]] writes are no "
                  "settings); the old name goes in the next release", DeprecationWarning,
                  stacklevel=3)


@dataclass(frozen=True)
class SdoWrite:
    """One ``[[wheel.sdo]]`` table: ``value`` written to ``object`` (as the config names
    it) in PRE-OPERATIONAL; ``type`` None: the EDS's."""

    object: str
    value: int | float | bool
    type: str | None = None


_POWER = schema_defaults("power")
_ESTOP = schema_defaults("estop")
_IMU = schema_defaults("imu")
_GYRO = schema_defaults("sim.gyro")
_SLIP = schema_defaults("sim.slip")


@dataclass(frozen=True)
class PowerSettings:
    """The ``[power]`` table: DC link thresholds with hysteresis (V, s)."""

    warn_v: float | None = _POWER["warn_v"]
    cutoff_v: float | None = _POWER["cutoff_v"]
    hysteresis_v: float = _POWER["hysteresis_v"]
    delay_s: float = _POWER["delay_s"]


@dataclass(frozen=True)
class EstopSettings:
    """The ``[estop]`` table: bit ``bit`` of ``object`` on ``node_id`` (None: every
    node) shows the e-stop pressed (clear when ``active_low``)."""

    bit: int
    object: str = _ESTOP["object"]
    active_low: bool = _ESTOP["active_low"]
    node_id: int | None = _ESTOP["node_id"]


_FUSION = schema_defaults("fusion")


@dataclass(frozen=True)
class FusionSettings:
    """The ``[fusion]`` table: how an attached IMU's gyro is fused with the wheels
    (:mod:`omnican.core.fusion`) and what a slip or a silent IMU does."""

    gyro_noise: float = _FUSION["gyro_noise"]
    bias_walk: float = _FUSION["bias_walk"]
    wheel_slip: float = _FUSION["wheel_slip"]
    slip_warn_s: float = _FUSION["slip_warn_s"]
    stop_on_slip: bool = _FUSION["stop_on_slip"]
    stop_on_imu_stale: bool = _FUSION["stop_on_imu_stale"]


@dataclass(frozen=True)
class ImuSettings:
    """The ``[imu]`` table: where the IMU's readings come from (``source``: "can", "ros2"
    or "zenoh"), how to read them, how the IMU sits on the base, and after how long
    without a reading it counts as silent (``stale_s``). ``dbc`` is a whole path."""

    source: str
    dbc: Path | None = None
    message: str | None = _IMU["message"]
    yaw_rate: str | None = _IMU["yaw_rate"]
    yaw_rate_unit: str | None = _IMU["yaw_rate_unit"]
    accel_message: str | None = _IMU["accel_message"]
    accel_x: str | None = _IMU["accel_x"]
    accel_y: str | None = _IMU["accel_y"]
    accel_unit: str | None = _IMU["accel_unit"]
    topic: str = _IMU["topic"]
    mount_yaw_deg: float = _IMU["mount_yaw_deg"]
    upside_down: bool = _IMU["upside_down"]
    stale_s: float = _IMU["stale_s"]


@dataclass(frozen=True)
class SimGyro:
    """The ``[sim.gyro]`` table: the simulated base's gyro (deg/s, Hz)."""

    enabled: bool = _GYRO["enabled"]
    rate_hz: float = _GYRO["rate_hz"]
    bias_deg_s: float = _GYRO["bias_deg_s"]
    drift_deg_s: float = _GYRO["drift_deg_s"]
    noise_deg_s: float = _GYRO["noise_deg_s"]
    mount_yaw_deg: float | None = _GYRO["mount_yaw_deg"]
    noise_stream: int = _GYRO["noise_stream"]


@dataclass(frozen=True)
class SimSurface:
    """A ``[[sim.slip.surface]]``: a rectangle of floor between two corners (world frame,
    m) where each wheel loses ``ratio`` of its rim travel (one per wheel)."""

    x0: float
    y0: float
    x1: float
    y1: float
    ratio: tuple[float, ...]


@dataclass(frozen=True)
class SimSlipSettings:
    """The ``[sim.slip]`` table: what the simulated ground takes of the wheels' motion
    (:class:`omnican.sim.slip.SimSlip`), one value per wheel where a wheel has one."""

    ratio: tuple[float, ...]
    roller: tuple[float, ...]
    ramp_grade_deg: float = _SLIP["ramp_grade_deg"]
    ramp_downhill_deg: float = _SLIP["ramp_downhill_deg"]
    ramp_creep: float = _SLIP["ramp_creep"]
    surfaces: tuple[SimSurface, ...] = ()


@dataclass(frozen=True)
class SimTruth:
    """The ``[sim]`` table: the true geometry of the simulated base ``omnican calibrate
    --sim`` drives; None: as configured. ``gyro``: its ``[sim.gyro]`` table; ``slip``: its
    ``[sim.slip]`` table (None: the ground grips)."""

    base_radius: float | None = None
    position_scale: tuple[float, ...] | None = None  # one per wheel, counts per m
    gyro: SimGyro | None = None
    slip: SimSlipSettings | None = None


#: What a ``[chassis]`` table must give (or may leave to the wheels' angle_deg), for a
#: ChassisSettings made in code: the demo base's (:func:`default_config`).
DEMO_CHASSIS: dict[str, Any] = {"layout": "b21", "base_radius": 0.19}
_CHASSIS = _field_defaults("chassis", **DEMO_CHASSIS)
_SCALED = CHASSIS_SCALED


@dataclass(frozen=True)
class ChassisSettings:
    """The ``[chassis]`` table. Defaults are :data:`SCHEMA`'s, but for the keys a config
    must give (:data:`DEMO_CHASSIS`); a stop deceleration not given (NaN) is derived from
    the acceleration as SCHEMA says (``Key.scaled``)."""

    layout: str | None = _CHASSIS["layout"]
    base_radius: float = _CHASSIS["base_radius"]
    rate_hz: float = _CHASSIS["rate_hz"]
    rt_priority: int = _CHASSIS["rt_priority"]
    cmd_timeout_s: float = _CHASSIS["cmd_timeout_s"]
    max_wheel_speed: float = _CHASSIS["max_wheel_speed"]
    max_speed: float = _CHASSIS["max_speed"]
    max_angular_speed: float = _CHASSIS["max_angular_speed"]
    max_accel: float = _CHASSIS["max_accel"]
    max_angular_accel: float = _CHASSIS["max_angular_accel"]
    stop_decel: float = math.nan  # not given: scaled from max_accel
    stop_angular_decel: float = math.nan  # not given: scaled from max_angular_accel
    mode: Mode | None = _CHASSIS["mode"]
    host_node_id: int = _CHASSIS["host_node_id"]
    heartbeat_ms: int = _CHASSIS["heartbeat_ms"]
    heartbeat_timeout_factor: float = _CHASSIS["heartbeat_timeout_factor"]
    sdo_timeout_s: float = _CHASSIS["sdo_timeout_s"]
    sdo_retries: int = _CHASSIS["sdo_retries"]
    boot_timeout_s: float = _CHASSIS["boot_timeout_s"]
    enable_timeout_s: float = _CHASSIS["enable_timeout_s"]
    pdo_mapping: str = _CHASSIS["pdo_mapping"]  # see pdoplan.MAPPING_POLICIES
    cyclic_controlword: bool = _CHASSIS["cyclic_controlword"]
    health_rate_hz: float = _CHASSIS["health_rate_hz"]
    tracking_error: float = _CHASSIS["tracking_error"]
    tracking_ratio: float = _CHASSIS["tracking_ratio"]
    tracking_time_s: float = _CHASSIS["tracking_time_s"]
    tracking_lag_s: float = _CHASSIS["tracking_lag_s"]
    lifted_wheel: str = _CHASSIS["lifted_wheel"]  # see LIFTED_WHEEL

    def __post_init__(self) -> None:
        for key in _SCALED:
            if math.isnan(getattr(self, key)):
                object.__setattr__(self, key, self.default_of(key))

    def default_of(self, key: str) -> Any:
        """What ``key`` defaults to, the other settings as they are here: SCHEMA's default
        (DEMO_CHASSIS's for a key a config must give), for a scaled key its factor times
        the key it scales."""
        if key in _SCALED:
            of, factor = _SCALED[key]
            return factor * getattr(self, of)
        return _CHASSIS[key]


@dataclass(frozen=True, init=False)
class ChassisConfig:
    """The whole robot. ``bus`` is passed to ``can.Bus``; None = python-can's own config.
    ``front_ends``: the front ends' tables the config gave (``[ros2]``, ``[foxglove]``,
    ``[zenoh]``...), each its front end's own type (a table given as a mapping of its
    keys is read as a config file's is)."""

    chassis: ChassisSettings
    wheels: tuple[WheelConfig, ...]
    bus: Mapping[str, Any] | None = None
    source: Path | None = field(default=None, compare=False)
    power: PowerSettings | None = None  # the [power] table
    estop: EstopSettings | None = None  # the [estop] table
    fusion: FusionSettings = field(default_factory=FusionSettings)  # the [fusion] table
    # The [sim] table: not the robot's description, so not part of equality.
    sim: SimTruth | None = field(default=None, compare=False)
    # The [gamepad] table as given, checked (omnican.command.gamepad maps a pad with it).
    gamepad: Mapping[str, Any] | None = None
    front_ends: FrontEndTables = field(default_factory=FrontEndTables)
    imu: ImuSettings | None = None  # the [imu] table

    def __init__(self, chassis: ChassisSettings, wheels: tuple[WheelConfig, ...],
                 bus: Mapping[str, Any] | None = None, source: Path | None = None,
                 power: PowerSettings | None = None, estop: EstopSettings | None = None,
                 sim: SimTruth | None = None, gamepad: Mapping[str, Any] | None = None,
                 front_ends: Mapping[str, Any] | None = None, imu: ImuSettings | None = None,
                 fusion: FusionSettings | None = None, **moved: Any) -> None:
        tables = {name: table if isinstance(table, FrontEndTable) else read_table(name, table)
                  for name, table in (front_ends or {}).items()}
        for name, given in moved.items():  # ros2=, zenoh=...: the tables' old names
            if name not in FRONT_ENDS:
                raise TypeError(f"ChassisConfig() got an unexpected keyword argument {name!r}")
            if given is None:
                tables.pop(name, None)
                continue
            table = given if isinstance(given, FrontEndTable) else read_table(name, given)
            tables[name] = moved_table("ChassisConfig", name, table)
        for name, value in (("chassis", chassis), ("wheels", wheels), ("bus", bus),
                            ("source", source), ("power", power), ("estop", estop),
                            ("sim", sim), ("gamepad", gamepad),
                            ("fusion", fusion if fusion is not None else FusionSettings()),
                            ("front_ends", FrontEndTables(tables)), ("imu", imu)):
            object.__setattr__(self, name, value)

    def __getattr__(self, name: str) -> Any:
        """``cfg.zenoh`` & co.: a front end's table under its name before the tables were
        one (``cfg.front_ends``), for one release."""
        if name in FRONT_ENDS:
            return moved_table("ChassisConfig", name, self.front_ends.get(name))
        raise AttributeError(f"'ChassisConfig' object has no attribute {name!r}")

    def kinematics(self) -> OmniKinematics:
        c = self.chassis
        radii = [w.base_radius if w.base_radius is not None else c.base_radius for w in self.wheels]
        if c.layout is not None:
            angles: list[float] = list(LAYOUTS[c.layout])
        else:
            angles = [float(w.angle_deg) for w in self.wheels if w.angle_deg is not None]
        drive = [w.drive_angle_deg for w in self.wheels]
        drive_angles = (
            None
            if all(d is None for d in drive)
            else [d if d is not None else a + 90.0 for d, a in zip(drive, angles, strict=True)]
        )
        return OmniKinematics(angles, radii, drive_angles)

    def limits(self) -> VelocityLimits:
        c = self.chassis
        return VelocityLimits(
            max_linear=c.max_speed,
            max_angular=c.max_angular_speed,
            max_linear_accel=c.max_accel,
            max_angular_accel=c.max_angular_accel,
            stop_linear_decel=c.stop_decel,
            stop_angular_decel=c.stop_angular_decel,
            max_wheel_speed=c.max_wheel_speed,
        )

    def with_bus(self, **bus: Any) -> ChassisConfig:
        """A copy on another bus (e.g. a virtual channel for the simulator)."""
        return replace(self, bus=dict(bus))

    def nodes(self) -> dict[int, list[WheelConfig]]:
        """Wheels grouped by node id, in wheel order."""
        out: dict[int, list[WheelConfig]] = {}
        for w in self.wheels:
            out.setdefault(w.node_id, []).append(w)
        return out


def derive_scales(
    gear_ratio: float,
    encoder_cpr: float,
    wheel_radius: float,
    velocity_unit: str = _WHEEL["velocity_unit"],
    invert: bool = _WHEEL["invert"],
) -> tuple[float, float]:
    """(velocity_scale, position_scale) from a drive's physical parameters.

    position_scale = counts per m of rim travel = cpr * gear / (2 pi r);
    velocity_scale = drive velocity units per m/s at the rim."""
    if velocity_unit not in VELOCITY_UNITS:
        raise ConfigError(
            f"velocity_unit: unknown unit {velocity_unit!r}; use one of {', '.join(VELOCITY_UNITS)}"
        )
    motor_rev_per_m = gear_ratio / (2.0 * math.pi * wheel_radius)
    position_scale = encoder_cpr * motor_rev_per_m
    per_unit = VELOCITY_UNITS[velocity_unit]
    velocity_scale = position_scale if per_unit == 0.0 else motor_rev_per_m / per_unit
    sign = -1.0 if invert else 1.0
    return sign * velocity_scale, sign * position_scale


# A simulated demo base: the bundled drive, 16:1 gear, 4096-count encoder, 50 mm wheels.
_DEMO_WHEEL_RADIUS = 0.05
_DEMO_SCALES = derive_scales(16.0, 4096.0, _DEMO_WHEEL_RADIUS)


#: The demo base's health wiring: the bundled drive's temperature object (0.1 degC), its
#: e-stop on digital input 1 (60FDh bit 16, where the simulator's e-stop is wired), and a
#: 24 V battery (the simulator's nominal supply) that warns below 22 V and stops the base
#: below 20 V.
DEMO_TEMPERATURE = ("0x2100", 0.1)
DEMO_ESTOP = EstopSettings(bit=16)
DEMO_POWER = PowerSettings(warn_v=22.0, cutoff_v=20.0)


def default_config(bus: Mapping[str, Any] | None = None) -> ChassisConfig:
    """The demo base that ``--sim`` runs without a config: three bundled drives,
    node ids 1-3, the :data:`SCHEMA` defaults and :data:`DEMO_CHASSIS`, the bundled
    drive's temperature, an e-stop and a battery (:data:`DEMO_ESTOP`,
    :data:`DEMO_POWER`)."""
    vs, ps = _DEMO_SCALES
    temperature, scale = DEMO_TEMPERATURE
    wheels = tuple(
        WheelConfig(node_id=n, axis=0, eds=WHEEL_EDS, velocity_scale=vs, position_scale=ps,
                    wheel_radius=_DEMO_WHEEL_RADIUS, temperature=temperature,
                    temperature_scale=scale)
        for n in (1, 2, 3)
    )
    return ChassisConfig(chassis=ChassisSettings(), wheels=wheels, bus=bus, power=DEMO_POWER,
                         estop=DEMO_ESTOP)


