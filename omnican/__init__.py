"""omnican: drive a three-omni-wheel robot base whose wheel motors are CANopen CiA 402 drives.

Public API (see DESIGN.md)::

    from omnican import Twist, Pose2D, OmniKinematics, Odometry, Chassis, load_config
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from omnican.config import WHEEL_EDS, ChassisConfig, WheelConfig, default_config, load_config
from omnican.errors import BusError, ConfigError, DriveError, OmnicanError
from omnican.kinematics import OmniKinematics, Twist
from omnican.limits import VelocityLimiter, VelocityLimits
from omnican.odometry import Odometry, Pose2D

__version__ = "0.1.0"

if TYPE_CHECKING:
    from omnican.chassis import Chassis, WheelState

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
    # The I/O layer (python-can, canopen) loads only when it is asked for.
    if name in ("Chassis", "WheelState"):
        from omnican import chassis

        return getattr(chassis, name)
    raise AttributeError(f"module 'omnican' has no attribute {name!r}")
