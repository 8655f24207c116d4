"""What a drive reports of its health, declared once: each value's name, unit and label,
and how the front ends show it.

:class:`WheelHealth` is the record: one per wheel, made a few times a second by the
chassis checks (:mod:`omnican.chassis.checks`) and carried by every snapshot;
:class:`omnican.chassis.state.WheelState` has its fields. Each field is declared with
its :class:`HealthField`, and :data:`HEALTH_FIELDS`, the table of them in that order, is
what the rest reads: the health plan (:mod:`omnican.plan.health`: which objects, the
order the spare TPDOs are filled in), the checks, the teleop dashboard's columns,
``omnican drive --json``, the diagnostics, the ``/wheels`` topic (live view, MCAP,
ROS 2), replay and ``omnican plot``, check-config, the DBC's units, calibrate's config
and the simulator.

Adding a value a drive reports is one field here, plus where the value comes from: the
config keys naming its object (``<quantity>``, and ``<quantity>_scale`` for its units
per count: :mod:`omnican.config`), and the simulator's model of it
(:meth:`omnican.sim.health.DriveHealth.si_value`). tests/plan/test_health_fields.py
fails where a front end leaves it out.

Pure: the standard library only (cheap to import from any layer above).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

_KEY = "omnican.health_field"


@dataclass(frozen=True)
class HealthField:
    """One value a drive reports, and how the front ends show it (None where one does
    not)."""

    name: str  # WheelHealth's (and WheelState's) attribute, the key in every message
    quantity: str  # the health plan's word (HealthRead.quantity), the config's key
    unit: str  # SI, as text: "A", "%", "V", "degC" ("": a register)
    label: str  # what it is, in words
    per_axis: bool  # each axis has its own; else one per node, shown on each of its wheels
    register: bool = False  # bits, shown in hex; not a number to plot or record over time
    column: str | None = None  # the teleop dashboard's column heading
    legend: str = ""  # what the dashboard's title says of that column
    places: int = 1  # decimals the dashboard shows
    signed: bool = False  # the dashboard shows the sign
    in_drive_json: bool = False  # in each wheel of ``omnican drive --json``
    plotted: bool = False  # a panel of ``omnican plot``, where the recording has it

    @property
    def plot_title(self) -> str:
        return f"{self.label}, as the drives report it"

    @property
    def axis_label(self) -> str:
        return f"{self.quantity} ({self.unit})"

    def text(self, value: float | int | None) -> float | int | str | None:
        """The value as the diagnostics give it: a register in hex."""
        if self.register and value is not None:
            return f"0x{int(value):02X}"
        return value


def _reported(**how: Any) -> Any:
    """A WheelHealth field: None until the drive reports it, declared with ``how``."""
    return field(default=None, metadata={_KEY: HealthField(name="", **how)})


@dataclass(frozen=True, kw_only=True)
class WheelHealth:
    """What one wheel's drive reports, read a few times a second
    (``chassis.health_rate_hz``); None where the drive does not give it, or nothing
    fresh came from it. Its fields are the table :data:`HEALTH_FIELDS`."""

    current_a: float | None = _reported(  # motor current, A
        quantity="current", unit="A", label="motor current", per_axis=True, column="A",
        legend="motor current A", places=2, signed=True, in_drive_json=True, plotted=True)
    torque_pct: float | None = _reported(  # torque, % of the rated torque
        quantity="torque", unit="%", label="torque", per_axis=True)
    voltage_v: float | None = _reported(  # the drive's DC link, V
        quantity="voltage", unit="V", label="DC link voltage", per_axis=False, column="V",
        legend="DC link V", in_drive_json=True, plotted=True)
    temperature_c: float | None = _reported(  # the config's temperature object, degC
        quantity="temperature", unit="degC", label="temperature", per_axis=True,
        column="°C", legend="°C", in_drive_json=True)
    error_register: int | None = _reported(  # 1001h (bits: 0 generic, 1 current, 2 voltage...)
        quantity="error_register", unit="", label="error register", per_axis=False,
        register=True)

    @classmethod
    def of(cls, values: dict[str, float | int | None]) -> WheelHealth:
        """The values given by field name (of :data:`HEALTH_FIELDS`; one not given:
        None), made without the frozen ``__init__``: a store per field into the
        instance's dict, about a tenth of the instructions (the chassis checks make one
        per wheel a few times a second, on the loop thread)."""
        made = object.__new__(cls)
        made.__dict__.update(values)  # the class's defaults (None) stand for the rest
        return made


#: The table: every value a drive reports, in WheelHealth's order (the health plan's
#: too: the first fill the spare TPDOs first).
HEALTH_FIELDS: tuple[HealthField, ...] = tuple(
    replace(f.metadata[_KEY], name=f.name) for f in fields(WheelHealth))
#: The table by the health plan's word for each value.
BY_QUANTITY: dict[str, HealthField] = {f.quantity: f for f in HEALTH_FIELDS}
#: WheelHealth made of nothing: no drive reported anything yet.
NO_WHEEL_HEALTH = WheelHealth()


def health_values(health: WheelHealth) -> dict[str, Any]:
    """``health``'s fields by name (what a WheelState is made with)."""
    return {f.name: getattr(health, f.name) for f in HEALTH_FIELDS}
