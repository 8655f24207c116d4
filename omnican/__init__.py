"""omnican: drive a three-omni-wheel robot base whose wheel motors are CANopen CiA 402 drives.

Public API (see DESIGN.md)::

    from omnican import Twist, Pose2D, OmniKinematics, Odometry, Chassis, load_config
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

if TYPE_CHECKING:
    from omnican.chassis import Chassis, WheelState
    from omnican.config import (
        WHEEL_EDS,
        ChassisConfig,
        WheelConfig,
        default_config,
        load_config,
    )
    from omnican.errors import BusError, ConfigError, DriveError, OmnicanError
    from omnican.kinematics import OmniKinematics, Twist
    from omnican.limits import VelocityLimiter, VelocityLimits
    from omnican.odometry import Odometry, Pose2D

# Each public name and the module it lives in. Nothing is imported with the package:
# `omnican --version` and `--help` must not pay for numpy, python-can or canopen.
_HOMES = {
    "WHEEL_EDS": "config", "ChassisConfig": "config", "WheelConfig": "config",
    "default_config": "config", "load_config": "config",
    "BusError": "errors", "ConfigError": "errors", "DriveError": "errors",
    "OmnicanError": "errors",
    "OmniKinematics": "kinematics", "Twist": "kinematics",
    "VelocityLimiter": "limits", "VelocityLimits": "limits",
    "Odometry": "odometry", "Pose2D": "odometry",
    "Chassis": "chassis", "WheelState": "chassis",
}

__all__ = [
    "WHEEL_EDS",
    "BusError",
    "Chassis",
    "ChassisConfig",
    "ConfigError",
    "DriveError",
    "Odometry",
    "OmniKinematics",
    "OmnicanError",
    "Pose2D",
    "Twist",
    "VelocityLimiter",
    "VelocityLimits",
    "WheelConfig",
    "WheelState",
    "__version__",
    "default_config",
    "load_config",
]


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'omnican' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"omnican.{home}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
