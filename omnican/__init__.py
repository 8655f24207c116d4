"""omnican: drive a three-omni-wheel robot base whose wheel motors are CANopen CiA 402 drives.

Public API (README's Python API section; the layers: docs/architecture.md)::

    from omnican import Twist, Pose2D, OmniKinematics, Odometry, Chassis, load_config
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from omnican.lazy import lazy_names

__version__ = "0.1.0"

if TYPE_CHECKING:  # the same names for type checkers and editors ("X as X": re-exported)
    from omnican.chassis import Chassis as Chassis
    from omnican.chassis import WheelState as WheelState
    from omnican.config import WHEEL_EDS as WHEEL_EDS
    from omnican.config import ChassisConfig as ChassisConfig
    from omnican.config import WheelConfig as WheelConfig
    from omnican.config import default_config as default_config
    from omnican.config import load_config as load_config
    from omnican.core.kinematics import OmniKinematics as OmniKinematics
    from omnican.core.kinematics import Twist as Twist
    from omnican.core.limits import VelocityLimiter as VelocityLimiter
    from omnican.core.limits import VelocityLimits as VelocityLimits
    from omnican.core.odometry import Displacement as Displacement
    from omnican.core.odometry import Odometry as Odometry
    from omnican.core.odometry import Pose2D as Pose2D
    from omnican.errors import BusError as BusError
    from omnican.errors import ConfigError as ConfigError
    from omnican.errors import DriveError as DriveError
    from omnican.errors import OmnicanError as OmnicanError

# The public API, one table: each name and the module it lives in. ``__all__`` and the
# lazy imports below are made from it (the TYPE_CHECKING imports above are for type
# checkers and editors; a test holds them to this table). Nothing is imported with the
# package: `omnican --version` and `--help` must not pay for numpy, python-can or canopen.
_HOMES = {
    "WHEEL_EDS": "config", "ChassisConfig": "config", "WheelConfig": "config",
    "default_config": "config", "load_config": "config",
    "BusError": "errors", "ConfigError": "errors", "DriveError": "errors",
    "OmnicanError": "errors",
    "OmniKinematics": "core.kinematics", "Twist": "core.kinematics",
    "VelocityLimiter": "core.limits", "VelocityLimits": "core.limits",
    "Odometry": "core.odometry", "Pose2D": "core.odometry", "Displacement": "core.odometry",
    "Chassis": "chassis", "WheelState": "chassis",
}

__all__ = ["__version__", *_HOMES]  # noqa: PLE0604 (made from the table)


__getattr__ = lazy_names(__name__, _HOMES, globals())


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
