"""Robot configuration: TOML -> validated, frozen dataclasses.

Three parts, data flowing one way:

- :mod:`omnican.config.schema`: every key of every table, its type, default, range and
  meaning (:data:`SCHEMA`), the one place a default is written; README's configuration
  reference is checked against it by a test.
- :mod:`omnican.config.model`: the frozen dataclasses a config is (:class:`ChassisConfig`
  and its tables), their defaults the schema's, and the demo base (:func:`default_config`).
- :mod:`omnican.config.parsing`: a TOML document checked against the schema into the
  model, table by table (:mod:`omnican.config.reader` checks one table's keys, types and
  ranges; :mod:`omnican.config.wheels` the ``[[wheel]]`` tables and their EDS files).
  Every problem is a :class:`~omnican.errors.ConfigError` whose message names the key, e.g.
  ``robot.toml: wheel[2].node_id: must be 1-127, got 200``.
- :mod:`omnican.config.front_ends`: the front ends' tables (``[ros2]``, ``[foxglove]``,
  ``[zenoh]``...), each declared by its front end and read through the front ends'
  registry; a config holds them as one typed table (``cfg.front_ends``).

The names below are the package's; import them from here.
"""

from __future__ import annotations

import sys
from typing import Any

from omnican.config.front_ends import FrontEndTable, FrontEndTables, TableSpec, moved_name
from omnican.config.model import (
    DEMO_CHASSIS,
    DEMO_ESTOP,
    DEMO_POWER,
    DEMO_TEMPERATURE,
    ChassisConfig,
    ChassisSettings,
    EstopSettings,
    FusionSettings,
    ImuSettings,
    PowerSettings,
    SdoWrite,
    SimGyro,
    SimSlipSettings,
    SimSurface,
    SimTruth,
    WheelConfig,
    default_config,
    derive_scales,
)
from omnican.config.parsing import (
    gamepad_values,
    load_config,
    parse_config,
    with_live_limits,
)
from omnican.config.schema import (
    BUS_KEYS,
    GAMEPAD_AXES,
    GAMEPAD_BUTTONS,
    GAMEPAD_PRESETS,
    LIFTED_WHEEL,
    LIVE_LIMITS,
    MAX_RT_PRIORITY,
    PDO_MAPPINGS,
    SCHEMA,
    SDO_TYPES,
    VELOCITY_UNITS,
    WHEEL_EDS,
    Key,
    defaults_of,
    reference_rows,
    schema_defaults,
)
from omnican.config.wheels import check_eds_files

if sys.version_info >= (3, 11):  # the TOML parser load_config uses (tests read TOML with it)
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]

__all__ = [
    "BUS_KEYS",
    "DEMO_CHASSIS",
    "DEMO_ESTOP",
    "DEMO_POWER",
    "DEMO_TEMPERATURE",
    "GAMEPAD_AXES",
    "GAMEPAD_BUTTONS",
    "GAMEPAD_PRESETS",
    "LIFTED_WHEEL",
    "LIVE_LIMITS",
    "MAX_RT_PRIORITY",
    "PDO_MAPPINGS",
    "SCHEMA",
    "SDO_TYPES",
    "VELOCITY_UNITS",
    "WHEEL_EDS",
    "ChassisConfig",
    "ChassisSettings",
    "EstopSettings",
    "FrontEndTable",
    "FrontEndTables",
    "FusionSettings",
    "ImuSettings",
    "Key",
    "PowerSettings",
    "SdoWrite",
    "SimGyro",
    "SimSlipSettings",
    "SimSurface",
    "SimTruth",
    "TableSpec",
    "WheelConfig",
    "check_eds_files",
    "default_config",
    "defaults_of",
    "derive_scales",
    "gamepad_values",
    "load_config",
    "parse_config",
    "reference_rows",
    "schema_defaults",
    "tomllib",
    "with_live_limits",
]


def __getattr__(name: str) -> Any:
    """Names that moved keep working for one release, with a DeprecationWarning naming
    their new home: to a front end's own table module (``ZenohTable``...), and
    ``VendorSetting`` (a ``[[wheel.sdo]]`` write is no setting: :class:`SdoWrite`)."""
    if name == "VendorSetting":
        import warnings

        warnings.warn("omnican.config.VendorSetting moved to omnican.config.SdoWrite; the "
                      "old name goes in the next release", DeprecationWarning, stacklevel=2)
        return SdoWrite
    return moved_name(name)
