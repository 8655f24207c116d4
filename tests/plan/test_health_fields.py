"""The table of what a drive reports (omnican.plan.health_fields) drives every front end:
each value of it, given to a wheel, shows wherever its declaration says, by its name and
in its unit, so that a value added to the table cannot be forgotten by one of them."""

from __future__ import annotations

import dataclasses
import io
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from rich.console import Console

from omnican import default_config
from omnican.chassis.state import ChassisStatus, WheelState
from omnican.cli import check_config, dashboard, drive, plot, terminal
from omnican.command.teleop import TeleopModel
from omnican.core.kinematics import Twist
from omnican.core.odometry import Pose2D
from omnican.plan import dbc
from omnican.plan import health as plan_health
from omnican.plan.health_fields import (
    BY_QUANTITY,
    HEALTH_FIELDS,
    NO_WHEEL_HEALTH,
    HealthField,
    WheelHealth,
    health_values,
)
from omnican.plan.node import node_layouts
from omnican.protocol.cia402 import State
from omnican.record import replay
from omnican.sim import SimulatedBase
from omnican.sim import health as sim_health
from omnican.telemetry import TelemetrySettings
from omnican.telemetry import messages as telemetry
from tests.support.helpers import drive_for, lockstep_rig, sim_config

SERIES = [f for f in HEALTH_FIELDS if not f.register]


def values() -> dict[str, Any]:
    """A distinct value per field: 0x2B-ish integers for a register, else k.25 * 3."""
    return {f.name: 0x20 + k if f.register else 3.25 * (k + 1)
            for k, f in enumerate(HEALTH_FIELDS)}


def wheel(index: int = 0, **health: Any) -> WheelState:
    return WheelState(index, index + 1, 0, State.OPERATION_ENABLED, 0x1637, 3, 0.1, 0.1, 0.5,
                      True, None, None, **health)


def test_the_table_is_wheel_healths_fields_and_wheel_state_has_them() -> None:
    names = [f.name for f in HEALTH_FIELDS]
    assert names == [f.name for f in dataclasses.fields(WheelHealth)]
    assert len(set(names)) == len(names) == len({f.quantity for f in HEALTH_FIELDS})
    assert set(names) <= {f.name for f in dataclasses.fields(WheelState)}
    assert all(isinstance(f, HealthField) and BY_QUANTITY[f.quantity] is f
               for f in HEALTH_FIELDS)
    assert health_values(NO_WHEEL_HEALTH) == dict.fromkeys(names)
    # Declared with how the front ends show it: a column has its legend, a unit but for
    # a register.
    for f in HEALTH_FIELDS:
        assert (f.column is None) == (not f.legend), f
        assert bool(f.unit) != f.register, f


def test_the_health_plan_reads_in_the_tables_order() -> None:
    quantities = [f.quantity for f in HEALTH_FIELDS]
    assert list(plan_health.QUANTITIES[:len(quantities)]) == quantities
    assert {f.quantity for f in HEALTH_FIELDS if f.per_axis} <= plan_health.PER_AXIS
    assert not {f.quantity for f in HEALTH_FIELDS if not f.per_axis} & plan_health.PER_AXIS
    # The config names the object of each value it has a key for, and the scale where
    # it has that key too; the DBC and calibrate follow.
    assert set(plan_health.CONFIG_SCALED) <= set(BY_QUANTITY)
    assert {q: BY_QUANTITY[q].unit for q in plan_health.CONFIG_SCALED} == dbc.HEALTH_UNITS
    assert all(k.removesuffix("_scale") in BY_QUANTITY for k in plan_health.CONFIG_KEYS)


@given(st.dictionaries(st.sampled_from([f.name for f in HEALTH_FIELDS]),
                       st.none() | st.integers(0, 255)))
def test_a_wheel_states_health_is_its_wheel_health(given_values: dict[str, Any]) -> None:
    health = WheelHealth(**given_values)
    w = wheel(**health_values(health))
    assert health_values(w) == health_values(health)
    assert {k: v for k, v in health_values(w).items() if v is not None} == {
        k: v for k, v in given_values.items() if v is not None}


@given(st.dictionaries(st.sampled_from([f.name for f in HEALTH_FIELDS]),
                       st.none() | st.integers(0, 255) | st.floats(allow_nan=False)))
def test_wheel_health_of_is_the_records_init(given_values: dict[str, Any]) -> None:
    made = WheelHealth.of(given_values)
    assert made == WheelHealth(**given_values) and type(made) is WheelHealth
    assert health_values(made) == {**dict.fromkeys(health_values(made)), **given_values}
    assert hash(made) == hash(WheelHealth(**given_values))
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.current_a = 1.0  # type: ignore[misc]


def test_diagnostics_give_every_value_by_its_name() -> None:
    shown = values()
    status = telemetry.wheel_status(wheel(**shown), "omnican", "wheel_0_joint")
    got = {v["key"]: v["value"] for v in status["values"]}
    for f in HEALTH_FIELDS:
        value = shown[f.name]
        assert got[f.name] == (f"0x{value:02X}" if f.register else format(value, ".6g")), f
    nothing = telemetry.wheel_status(wheel(), "omnican", "wheel_0_joint")
    assert all(v["value"] == "" for v in nothing["values"] if v["key"] in shown)


def test_the_wheels_topic_and_its_schema_carry_every_value_but_a_register() -> None:
    shown = values()
    sample = telemetry.TelemetrySample(stamp_ns=1, pose=Pose2D(), twist=Twist(), command=Twist(),
                              wheels=(wheel(**shown), wheel(1)), status=None)
    with_values, without = telemetry.wheels(sample)["wheels"]
    schema = telemetry.JSON_SCHEMAS["omnican.Wheels"]["properties"]["wheels"]["items"]
    for f in HEALTH_FIELDS:
        assert (f.name in with_values) == (not f.register), f
        assert (f.name in schema["properties"]) == (not f.register), f
        assert f.name not in without  # absent when the drive does not give it
        if not f.register:
            assert with_values[f.name] == shown[f.name]
            assert f.name not in schema.get("required", ())


def telemetry_status() -> ChassisStatus:
    return ChassisStatus(enabled=True, stopped_reason=None, command_age_s=0.0, loop_hz=100.0,
                         late_fraction=0.0, cycles=1, bus_load=None, bus_bits_per_s=0.0,
                         bus_error=None, warnings=())


def test_the_dashboard_has_a_column_per_value_with_one(channel: str) -> None:
    columns = [f for f in HEALTH_FIELDS if f.column is not None]
    assert dashboard.WHEEL_COLUMNS[-len(columns):] == tuple(f.column for f in columns)
    assert all(f.legend in dashboard.WHEEL_UNITS for f in columns)
    with lockstep_rig(channel) as (_clock, _sim, base):
        drive_for(base, 1.0, vx=0.3)
        keys = TeleopModel.for_config(base.cfg, 0.3, 1.0, 0.6)
        console = Console(width=120, record=True, color_system=None, file=io.StringIO())
        console.print(dashboard.dashboard(base, keys, Twist(), "omnican teleop", terminal.RecentEvents(),
                                       "", 120, 30))
        lines = console.export_text().splitlines()
        header = next(line for line in lines if "wheel" in line and "state" in line)
        parts = header.split()
        after = parts.index("travel") + 1
        assert parts[after:after + len(columns)] == [f.column for f in columns]
        for w in base.wheels:
            row = next(line for line in lines if line.startswith(f"│ {w.index} "))
            cells = row.split()
            for f in columns:
                value = getattr(w, f.name)
                assert value is not None, f
                text = dashboard.fixed(value, f.places, sign=f.signed)
                assert text in cells and text.startswith(("+", "-")) == f.signed, (f, row)


def test_drive_json_gives_the_values_its_table_says_rounded() -> None:
    shown = values()
    (out,) = drive.wheels_json([wheel(**shown)])
    assert set(out) == {"node_id", "axis", "state"} | {
        f.name for f in HEALTH_FIELDS if f.in_drive_json}
    assert all(out[f.name] == shown[f.name] for f in HEALTH_FIELDS if f.in_drive_json)
    (empty,) = drive.wheels_json([wheel()])
    assert all(empty[f.name] is None for f in HEALTH_FIELDS if f.in_drive_json)


def test_replay_records_and_plot_draws_the_values_the_table_says() -> None:
    assert tuple(f.quantity for f in SERIES) == replay._HealthSeries.QUANTITIES
    assert tuple(f for f in HEALTH_FIELDS if f.plotted) == plot.HEALTH_PANELS
    assert all(not f.register for f in plot.HEALTH_PANELS)
    layouts = node_layouts(default_config())
    series = replay._HealthSeries(layouts, 3)
    assert set(series.arrays()) == {f.quantity for f in SERIES}


def test_check_config_names_each_value_a_wheel_reports_in_its_unit() -> None:
    layouts = node_layouts(default_config())  # the demo: a temperature at 0.1 degC
    text = "\n".join(line for layout in layouts for line in check_config.health_lines(layout))
    for f in SERIES:
        assert f"{f.quantity.replace('_', ' ')} 0x" in text, (f, text)
    scaled = [r for layout in layouts for r in layout.health.reads
              if r.quantity in plan_health.CONFIG_SCALED and r.scale is not None]
    assert {r.quantity for r in scaled} == {"voltage", "temperature"}  # the demo's
    for r in scaled:
        assert f"{r.entry.address} x {r.scale:g} {BY_QUANTITY[r.quantity].unit}" in text


@pytest.mark.parametrize("reported", SERIES, ids=lambda f: f.name)
def test_the_simulator_has_a_model_of_every_value(channel: str,
                                                   reported: HealthField) -> None:
    assert reported.quantity in sim_health.QUANTITIES
    with SimulatedBase.from_config(sim_config(channel)) as sim:
        drive0 = sim.drives[0]
        assert isinstance(drive0.health.si_value(reported.quantity, drive0.axes[0]), float)
        with pytest.raises(ValueError, match="no model"):
            drive0.health.si_value("humidity", drive0.axes[0])


def test_settings_still_make_every_message() -> None:
    """The messages made of a wheel with every value still build (and round-trip the
    values): a smoke test of the whole Telemetry path."""
    settings = TelemetrySettings.from_config(default_config())
    sample = telemetry.TelemetrySample(stamp_ns=1, pose=Pose2D(), twist=Twist(), command=Twist(),
                              wheels=tuple(wheel(i, **values()) for i in range(3)),
                              status=telemetry_status())
    assert len(telemetry.diagnostics(sample, settings)["status"]) == 2 + 3
