"""What every front end says the same way: frame names, joint names and the wheel
radius, the odometry's slip (its covariance), the diagnostics' name prefix and rate,
and how often the base is sampled. Read from the config once, for all of them.

They come from the front end's table that names them for every front end (``[ros2]``'s
``odom_frame``, ``base_frame``, ``joint_names``, ``wheel_radius``, ``odom_slip``,
``node_name``, ``diagnostics_rate_hz`` and the publish rates: its
:attr:`~omnican.config.front_ends.TableSpec.telemetry`), else its defaults; the ROS 2
bridge, the live view and the MCAP recorder all use them, so a recording names its
joints as the robot published them. Pure: no I/O.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from omnican.config import ChassisConfig
from omnican.core.wheel_odometry import SPEED_WINDOW_S
from omnican.errors import ConfigError

#: The base is sampled at least this often (Hz of the base's clock).
STATE_RATE_HZ = 50.0


@dataclass(frozen=True)
class TelemetrySettings:
    odom_frame: str
    base_frame: str
    joint_names: tuple[str, ...]  # one per wheel
    wheel_radii: tuple[float, ...] | None  # m, one per wheel; None: no joint states
    prefix: str  # of every diagnostic status's name ("omnican: chassis")
    odom_slip: float  # 1-sigma wheel slip per metre rolled (covariances)
    counts_per_m: tuple[float, ...]  # encoder resolution per wheel (the twist's floor)
    speed_window_s: float  # the window measured speeds average over
    state_rate_hz: float  # samples per second of the base's clock
    diagnostics_period_s: float  # and at once on a change
    channel: str  # the bus channel: CAN frames' frame_id, the bus's hardware_id

    @classmethod
    def from_config(cls, cfg: ChassisConfig, **overrides: Any) -> TelemetrySettings:
        """From ``cfg`` (the front ends' tables, else their defaults); ``overrides`` by
        field name (the command line's)."""
        table: Mapping[str, Any] = cfg.front_ends.telemetry()

        def get(key: str) -> Any:
            return table[key]

        n = len(cfg.wheels)
        names = tuple(get("joint_names") or (f"wheel_{i}_joint" for i in range(n)))
        if len(names) != n:
            raise ConfigError(f"ros2.joint_names: {len(names)} names for {n} wheels")
        radius = get("wheel_radius")
        radii = [radius if radius is not None else w.wheel_radius for w in cfg.wheels]
        rate = max(STATE_RATE_HZ, float(get("odom_rate_hz")),
                   float(get("joint_states_rate_hz")))
        settings = cls(
            odom_frame=str(get("odom_frame")), base_frame=str(get("base_frame")),
            joint_names=names,
            wheel_radii=(tuple(float(r) for r in radii if r is not None)
                         if all(r is not None and r > 0 for r in radii) else None),
            prefix=str(get("node_name")), odom_slip=float(get("odom_slip")),
            counts_per_m=tuple(float(w.position_scale) for w in cfg.wheels),
            speed_window_s=SPEED_WINDOW_S,
            state_rate_hz=min(rate, cfg.chassis.rate_hz),
            diagnostics_period_s=1.0 / float(get("diagnostics_rate_hz")),
            channel=str((cfg.bus or {}).get("channel", "")),
        )
        if "wheel_radius" in overrides:  # one radius for every wheel (--wheel-radius)
            r = overrides.pop("wheel_radius")
            if r is not None:
                overrides["wheel_radii"] = (float(r),) * n
        return dataclasses.replace(settings, **overrides) if overrides else settings
