"""Config: the TOML schema, and one clear ConfigError per problem."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path
from typing import Any

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from omnican import WHEEL_EDS, ConfigError, load_config
from omnican.config import default_config, derive_scales
from omnican.protocol.cia402 import Mode
from tests.support.helpers import VENDOR_EDS

GOOD = """
[bus]
interface = "virtual"
channel = "x"

[chassis]
layout = "b21"
base_radius = 0.19
rate_hz = 100
cmd_timeout_s = 0.5
max_wheel_speed = 1.0
max_accel = 1.0
max_angular_accel = 3.0

[[wheel]]
node_id = 1
velocity_scale = -4772.44
position_scale = 48000.0

[[wheel]]
node_id = 2
velocity_scale = -4772.44
position_scale = 48000.0

[[wheel]]
node_id = 3
gear_ratio = 16
encoder_cpr = 4096
wheel_radius = 0.05
"""


def write(tmp_path: Path, text: str, name: str = "robot.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def test_good_config(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, GOOD))
    assert cfg.bus == {"interface": "virtual", "channel": "x"}
    assert [w.node_id for w in cfg.wheels] == [1, 2, 3]
    assert cfg.wheels[0].velocity_scale == -4772.44
    assert cfg.wheels[0].eds == WHEEL_EDS
    vs, ps = derive_scales(16, 4096, 0.05)
    assert cfg.wheels[2].position_scale == pytest.approx(4096 * 16 / (2 * math.pi * 0.05))
    assert (cfg.wheels[2].velocity_scale, cfg.wheels[2].position_scale) == (vs, ps)
    assert cfg.chassis.stop_decel == 2.0  # default: 2 x max_accel
    assert cfg.kinematics().angles_deg == (180.0, -60.0, 60.0)
    assert cfg.limits().max_wheel_speed == 1.0


def test_without_bus_section_uses_python_can_config(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, GOOD.replace('[bus]\ninterface = "virtual"\nchannel = "x"\n', "")))
    assert cfg.bus is None


def test_derived_velocity_units() -> None:
    vs_rpm, ps = derive_scales(1, 4096, 0.1, "rpm")
    assert vs_rpm == pytest.approx(60 / (2 * math.pi * 0.1))  # wheel rpm per m/s
    vs_inv, ps_inv = derive_scales(1, 4096, 0.1, "rpm", invert=True)
    assert (vs_inv, ps_inv) == (-vs_rpm, -ps)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("rate_hz = 100", "rate = 100", r"chassis\.rate: unknown key"),
        ("rate_hz = 100", "rate_hz = -5", r"chassis\.rate_hz: must be 1-5000, got -5"),
        ("rate_hz = 100", 'rate_hz = "fast"', r"chassis\.rate_hz: must be int or float"),
        ("rate_hz = 100", "rate_hz = true", r"chassis\.rate_hz: must be a number"),
        ("rate_hz = 100", "rate_hz = nan", r"chassis\.rate_hz: must be a number, got nan"),
        ("base_radius = 0.19", "", r"chassis\.base_radius: missing required key"),
        ("base_radius = 0.19", "base_radius = 0", r"chassis\.base_radius: must be 0\.01-10, got 0"),
        ('layout = "b21"', 'layout = "c33"', r"chassis\.layout: unknown layout 'c33'"),
        ("node_id = 2", "node_id = 200", r"wheel\[1\]\.node_id: must be 1-127, got 200"),
        ("node_id = 2", "node_id = 1", r"wheel\[1\]: node 1 axis 0 is already wheel\[0\]"),
        ("node_id = 2", 'node_id = "2"', r"wheel\[1\]\.node_id: must be int"),
        ("gear_ratio = 16\n", "", r"wheel\[2\]\.gear_ratio: missing"),
        ("[[wheel]]\nnode_id = 3", "[[wheel]]\nnode_id = 3\nvelocity_scale = 1.0",
         r"wheel\[2\]: give either velocity_scale and position_scale or gear_ratio"),
        ("position_scale = 48000.0\n\n[[wheel]]\nnode_id = 2", "\n[[wheel]]\nnode_id = 2",
         r"wheel\[0\]\.position_scale: missing"),
        ("velocity_scale = -4772.44\nposition_scale = 48000.0\n\n[[wheel]]\nnode_id = 2",
         "velocity_scale = 0\nposition_scale = 48000.0\n\n[[wheel]]\nnode_id = 2",
         r"wheel\[0\]\.velocity_scale: must be 1e-06 to 1e\+12 in magnitude \(either "
         r"sign\), got 0"),
        ("wheel_radius = 0.05", 'wheel_radius = 0.05\nvelocity_unit = "furlongs"',
         r"wheel\[2\]\.velocity_unit: unknown unit 'furlongs'"),
        ("node_id = 3", "node_id = 3\neds = \"missing.eds\"",
         r"wheel\[2\]\.eds: EDS file not found: .*missing\.eds"),
        ("node_id = 3", "node_id = 3\nangle_deg = 60",
         r"chassis\.layout: give either a layout or angle_deg"),
        ("node_id = 3", "node_id = 3\naxis = 1", r"wheel\[2\]\.eds: omnican_wheel\.eds has 1 "
         r"axis\(es\), no axis 1"),
        ("[chassis]", "[chasis]\n[chassis]", r"chasis: unknown section"),
        ("node_id = 3", "node_id = 3\nmode = \"torque\"", r"wheel\[2\]\.mode: unknown mode"),
        ("node_id = 1", "node_id = 127", r"wheel\[0\]\.node_id: 127 is the host's node id"),
        ("rate_hz = 100", 'rate_hz = 100\npdo_mapping = "always"',
         r"chassis\.pdo_mapping: must be one of try, eds, sdo, got 'always'"),
    ],
)
def test_bad_config_names_key_and_problem(tmp_path: Path, old: str, new: str, message: str) -> None:
    assert old in GOOD
    with pytest.raises(ConfigError, match=message):
        load_config(write(tmp_path, GOOD.replace(old, new, 1)))


def test_error_is_one_line_and_names_the_file(tmp_path: Path) -> None:
    p = write(tmp_path, GOOD.replace("rate_hz = 100", "rate = 100"))
    with pytest.raises(ConfigError) as info:
        load_config(p)
    assert "\n" not in str(info.value)
    assert str(p) in str(info.value)


def test_unreadable_and_invalid_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[chassis\n"))
    with pytest.raises(ConfigError, match="wheel: missing"):
        load_config(write(tmp_path, "[chassis]\nbase_radius = 0.2\n"))
    with pytest.raises(ConfigError, match="at least 3 wheels"):
        load_config(write(tmp_path, "[chassis]\nbase_radius = 0.2\n[[wheel]]\nnode_id = 1\n"
                          "velocity_scale = 1.0\nposition_scale = 1.0\n"))


def test_custom_angles_need_every_wheel(tmp_path: Path) -> None:
    text = GOOD.replace('layout = "b21"\n', "")
    with pytest.raises(ConfigError, match=r"wheel\[0\]\.angle_deg: missing"):
        load_config(write(tmp_path, text))
    for n, a in ((1, 0), (2, 120), (3, -120)):
        text = text.replace(f"node_id = {n}\n", f"node_id = {n}\nangle_deg = {a}\n")
    cfg = load_config(write(tmp_path, text))
    assert cfg.kinematics().angles_deg == (0.0, 120.0, -120.0)


def test_degenerate_custom_geometry(tmp_path: Path) -> None:
    text = GOOD.replace('layout = "b21"\n', "")
    for n in (1, 2, 3):
        text = text.replace(f"node_id = {n}\n", f"node_id = {n}\nangle_deg = 0\n")
    with pytest.raises(ConfigError, match="degenerate wheel geometry"):
        load_config(write(tmp_path, text))


def test_eds_relative_to_config_file(tmp_path: Path) -> None:
    (tmp_path / "drives").mkdir()
    (tmp_path / "drives" / "wheel.eds").write_bytes(WHEEL_EDS.read_bytes())
    cfg = load_config(write(tmp_path, GOOD.replace("node_id = 3\n", 'node_id = 3\neds = "drives/wheel.eds"\n')))
    assert cfg.wheels[2].eds == tmp_path / "drives" / "wheel.eds"


def test_vendor_layouts(tmp_path: Path) -> None:
    zlac = VENDOR_EDS / "zlac8015d.eds"
    text = GOOD.replace("node_id = 1\n", f'node_id = 1\naxis = 0\neds = "{zlac}"\nmode = "pv"\n')
    text = text.replace("node_id = 2\n", f'node_id = 1\naxis = 1\neds = "{zlac}"\n')
    cfg = load_config(write(tmp_path, text))
    assert [(w.node_id, w.axis) for w in cfg.wheels] == [(1, 0), (1, 1), (3, 0)]
    assert cfg.wheels[0].mode is Mode.PROFILE_VELOCITY
    # ZLAC8015D has no vl target (6042h): asking for vl mode names the missing object.
    bad = text.replace('mode = "pv"', 'mode = "vl"')
    with pytest.raises(ConfigError, match=r"lacks vl target \(0x6042\) for axis 0, needed in vl"):
        load_config(write(tmp_path, bad))


def test_default_config_is_valid() -> None:
    cfg = default_config()
    assert len(cfg.wheels) == 3
    assert cfg.kinematics().num_wheels == 3
    assert WHEEL_EDS.is_file()


def test_every_key_of_the_reference_is_documented() -> None:
    """The configuration reference (docs/reference/config.md, generated from these rows at
    build time; check-config --help) names every key of the schema and of [gamepad] once,
    each with its default and a meaning."""
    from omnican.command.gamepad import TABLE_KEYS
    from omnican.config import SCHEMA, reference_rows

    rows = reference_rows()
    keys = [key for key, _, _ in rows]
    assert len(keys) == len(set(keys))
    assert set(keys) == ({f"{section}.{name}" for section, names in SCHEMA.items()
                          for name in names} | {f"gamepad.{name}" for name in TABLE_KEYS})
    for key, default, doc in rows:
        assert default.strip(), key
        assert len(doc.split()) >= 2 and doc == doc.strip() and "|" not in doc, (key, doc)


def test_bundled_data_found_from_the_installed_package(tmp_path: Path) -> None:
    """Run from outside the source tree: the installed package finds its EDS and DBC."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    code = ("import omnican, pathlib; p = omnican.WHEEL_EDS; "
            "print(isinstance(p, pathlib.Path), p.is_file(), (p.parent.parent / 'dbc' / "
            "'omnican.dbc').is_file())")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, text=True,
                         capture_output=True, check=True).stdout
    assert out.split() == ["True", "True", "True"]


# ---------------------------------------------------------------- defaults: written once


def test_dataclass_defaults_are_the_schemas() -> None:
    """Every field of ChassisSettings and WheelConfig named after a schema key defaults to
    that key's default: the demo base's values where a config must give one, NaN (derived
    when made) where the schema scales the key from another."""
    from dataclasses import MISSING, fields

    from omnican.config import (
        DEMO_CHASSIS,
        SCHEMA,
        ChassisSettings,
        EstopSettings,
        PowerSettings,
        WheelConfig,
    )

    assert {f.name for f in fields(ChassisSettings)} == set(SCHEMA["chassis"])
    assert {f.name for f in fields(PowerSettings)} == set(SCHEMA["power"])
    assert {f.name for f in fields(EstopSettings)} == set(SCHEMA["estop"])
    checked = 0
    for cls, section in ((ChassisSettings, "chassis"), (WheelConfig, "wheel"),
                         (PowerSettings, "power"), (EstopSettings, "estop")):
        for f in fields(cls):
            spec = SCHEMA[section].get(f.name)
            if spec is None or f.default is MISSING:
                continue
            where = f"{cls.__name__}.{f.name}"
            if cls is ChassisSettings and f.name in DEMO_CHASSIS:
                assert spec.required or spec.default is None, where
                assert f.default == DEMO_CHASSIS[f.name], where
            elif spec.scaled is not None:
                assert math.isnan(f.default), where
            elif f.name == "mode":
                assert f.default == (spec.default and Mode.from_name(spec.default)), where
            else:
                assert f.default == spec.default, where
                assert type(f.default) is type(spec.default), where
            checked += 1
    # and the wheel's optional fields (not node_id, axis, eds, the scales and what derives
    # them, nor its [[wheel.sdo]] list), [power], [estop] but its bit
    assert checked == (len(SCHEMA["chassis"]) + len(SCHEMA["wheel"]) - 10 + len(SCHEMA["power"])
                       + len(SCHEMA["estop"]) - 1)


def test_a_config_that_gives_only_what_it_must_is_the_code_default(tmp_path: Path) -> None:
    """ChassisSettings() is what a [chassis] table with the demo base's required keys
    parses to, and a wheel given only its id and scales is WheelConfig's defaults."""
    from omnican.config import DEMO_CHASSIS, ChassisSettings, WheelConfig

    chassis = "".join(f"{key} = {value!r}\n".replace("'", '"')
                      for key, value in DEMO_CHASSIS.items())
    wheels = "".join(f"[[wheel]]\nnode_id = {n}\nvelocity_scale = 1.0\nposition_scale = 2.0\n"
                     for n in (1, 2, 3))
    cfg = load_config(write(tmp_path, f"[chassis]\n{chassis}\n{wheels}"))
    assert cfg.chassis == ChassisSettings()
    assert cfg.wheels[1] == WheelConfig(node_id=2, axis=0, eds=WHEEL_EDS, velocity_scale=1.0,
                                        position_scale=2.0)
    assert default_config().chassis == ChassisSettings()


def test_derive_scales_defaults_are_the_wheel_keys() -> None:
    import inspect

    from omnican.config import SCHEMA

    params = inspect.signature(derive_scales).parameters
    for key in ("velocity_unit", "invert"):
        assert params[key].default == SCHEMA["wheel"][key].default, key


_POSITIVE = st.one_of(st.integers(1, 60), st.floats(1e-3, 60.0))  # within every range
_WAIT = st.one_of(st.integers(1, 60), st.floats(0.1, 60.0))
_CHASSIS_VALUES = {
    "rate_hz": st.floats(60.0, 5000.0),
    "heartbeat_ms": st.integers(20, 65535),
    "heartbeat_timeout_factor": st.floats(1.0, 100.0),
    **{key: _POSITIVE for key in ("max_wheel_speed", "max_accel", "max_angular_accel",
                                  "stop_decel", "stop_angular_decel")},
    **{key: _WAIT for key in ("cmd_timeout_s", "sdo_timeout_s", "boot_timeout_s",
                              "enable_timeout_s")},
    **{key: st.one_of(_POSITIVE, st.just(math.inf)) for key in ("max_speed",
                                                                "max_angular_speed")},
    "host_node_id": st.integers(4, 127),
    "sdo_retries": st.integers(0, 20),
    "rt_priority": st.integers(0, 99),
    "pdo_mapping": st.sampled_from(["try", "eds", "sdo"]),
    "mode": st.sampled_from(["pv", "csv", "vl"]),
}


def _stops_in_time(table: dict[str, Any]) -> bool:
    """A b21 [chassis] table's stop decelerations end a stop from its top speed within
    2 s. At the wheel limit w, b21's fastest translation is 4/3 w (two wheels at +w,
    one at -w: the forward map is 2/3 of the sum of the drive directions), whatever the
    radius; its fastest spin w / base_radius."""
    w = table.get("max_wheel_speed", 1.0)
    lin = min(table.get("max_speed", math.inf), 4.0 / 3.0 * w)
    ang = min(table.get("max_angular_speed", math.inf), w / table["base_radius"])
    stop = table.get("stop_decel", 2.0 * table.get("max_accel", 1.0))
    stop_ang = table.get("stop_angular_decel", 2.0 * table.get("max_angular_accel", 3.0))
    return bool(stop >= lin / 2.0 * (1 + 1e-6) and stop_ang >= ang / 2.0 * (1 + 1e-6))


@given(table=st.fixed_dictionaries({"base_radius": st.floats(0.05, 2.0)},
                                   optional=_CHASSIS_VALUES))
def test_a_parsed_chassis_table_is_the_settings_made_in_code(table: dict[str, Any]) -> None:
    """Whatever a [chassis] table leaves out, parsing it gives what ChassisSettings made
    with the same keys gives; a stop deceleration left out scales as the schema says."""
    from omnican.config import SCHEMA, ChassisSettings, parse_config

    assume(_stops_in_time(table))  # else refused (test_a_stop_that_takes_too_long_...)
    wheels = [{"node_id": n, "velocity_scale": 1.0, "position_scale": 2.0} for n in (1, 2, 3)]
    data = {"chassis": {"layout": "b21", **table}, "wheel": wheels}
    parsed = parse_config(data, check_eds=False).chassis
    mode = table.get("mode")
    made = ChassisSettings(**{**table, "mode": mode and Mode.from_name(mode)})
    assert parsed == made
    for key, spec in SCHEMA["chassis"].items():
        if key not in table and key != "layout":
            assert getattr(parsed, key) == parsed.default_of(key), key
            if spec.scaled is not None:
                of, factor = spec.scaled
                assert getattr(parsed, key) == factor * getattr(parsed, of), key


def test_ros2_settings_defaults_are_the_schemas(tmp_path: Path) -> None:
    """Ros2Settings' defaults are the [ros2] schema's (where it has none: not given), so
    a config without a [ros2] table runs omnican ros2 as one with an empty table."""
    from dataclasses import fields

    from omnican.config import SCHEMA
    from omnican.ros2.settings import Ros2Settings, from_table

    assert {f.name for f in fields(Ros2Settings)} == set(SCHEMA["ros2"])
    not_given: tuple[object, ...] = (None, (), 0)  # 0: domain_id, ROS_DOMAIN_ID's fallback
    for f in fields(Ros2Settings):
        spec = SCHEMA["ros2"][f.name]
        if spec.default is None:
            assert f.default in not_given, f.name
        else:
            assert f.default == spec.default, f.name
            assert type(f.default) is type(spec.default), f.name
    cfg = load_config(write(tmp_path, GOOD + "\n[ros2]\n"))
    assert cfg.front_ends.get("ros2") is not None
    assert from_table(cfg.front_ends["ros2"]) == from_table({})


# ---------------------------------------------------------------- numbers beyond sense


@pytest.mark.parametrize(("table", "message"), [
    ("position_scale = [1.0, 2.0]", r"sim\.position_scale: give one number for every wheel "
     r"or one per wheel \(3\), got 2"),
    ('position_scale = [1.0, "2", 3.0]', r"sim\.position_scale\[1\]: must be a number, got '2'"),
    ("position_scale = [1.0, 2.0, -3.0]", r"sim\.position_scale\[2\]: must be 1e-06-1e\+12, "
     r"got -3"),
    ("position_scale = -3.0", r"sim\.position_scale: must be 1e-06-1e\+12, got -3"),
    ("radius = 0.2", r"sim\.radius: unknown key 'radius'"),
])
def test_bad_sim_table_names_key_and_problem(tmp_path: Path, table: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(write(tmp_path, GOOD + f"\n[sim]\n{table}\n"))


def test_sim_table_one_number_is_every_wheel_and_not_the_robot(tmp_path: Path) -> None:
    from omnican.config import SimTruth

    cfg = load_config(write(tmp_path, GOOD + "\n[sim]\nposition_scale = 5e4\n"))
    assert cfg.sim == SimTruth(None, (5e4, 5e4, 5e4))
    assert cfg == load_config(write(tmp_path, GOOD))  # the simulated base is not the robot


SLIP = """
[sim.slip]
ratio = [0.0, 0.15, 0.0]
roller = 0.05
ramp_grade_deg = 5

[[sim.slip.surface]]
x0 = 1.0
y0 = -1.0
x1 = 2.0
y1 = 1.0
ratio = 0.3
"""


def test_sim_slip_table_is_the_simulated_grounds_slip(tmp_path: Path) -> None:
    """[sim.slip] and its [[sim.slip.surface]] patches, one number or one per wheel, as
    the simulator's SimSlip takes them; the robot's own numbers untouched."""
    from omnican.config import SimSlipSettings, SimSurface
    from omnican.sim.slip import SimSlip

    cfg = load_config(write(tmp_path, GOOD + SLIP))
    assert cfg.sim is not None and cfg.sim.slip == SimSlipSettings(
        (0.0, 0.15, 0.0), (0.05, 0.05, 0.05), 5.0, 0.0, 0.005,
        (SimSurface(1.0, -1.0, 2.0, 1.0, (0.3, 0.3, 0.3)),))
    slip = SimSlip.of(cfg.sim.slip)
    assert [slip.ratio(i, 0.0, 0.0) for i in range(3)] == [0.0, 0.15, 0.0]
    assert [slip.ratio(i, 1.5, 0.0) for i in range(3)] == [0.3, 0.3, 0.3]  # on the patch
    assert slip.roller == {0: 0.05, 1: 0.05, 2: 0.05} and slip.ramp_grade_deg == 5.0
    assert cfg == load_config(write(tmp_path, GOOD))  # the simulated ground is not the robot
    bare = load_config(write(tmp_path, GOOD + "\n[sim.slip]\n"))
    assert bare.sim is not None and bare.sim.slip is not None
    assert SimSlip.of(bare.sim.slip).ratio(1, 0.0, 0.0) == 0.0  # every key optional: grips


@pytest.mark.parametrize(("table", "message"), [
    ("[sim.slip]\nratio = 1.5", r"sim\.slip\.ratio: must be 0-1, got 1\.5"),
    ("[sim.slip]\nratio = [0.1, 0.2]", r"sim\.slip\.ratio: give one number for every wheel "
     r"or one per wheel \(3\), got 2"),
    ("[sim.slip]\nroller = [0.1, -0.2, 0.0]", r"sim\.slip\.roller\[1\]: must be 0-1, got -0\.2"),
    ('[sim.slip]\nratio = [0.1, "x", 0.0]', r"sim\.slip\.ratio\[1\]: must be a number, got 'x'"),
    ("[sim.slip]\nramp_grade_deg = 80", r"sim\.slip\.ramp_grade_deg: must be -60 to 60, got 80"),
    ("[sim.slip]\nratios = 0.1", r"sim\.slip\.ratios: unknown key 'ratios'.*'ratio'"),
    ("[[sim.slip.surface]]\nx0 = 0\ny0 = 0\nx1 = 1\ny1 = 1",
     r"sim\.slip\.surface\[0\]\.ratio: missing required key"),
    ("[[sim.slip.surface]]\nx0 = 0\ny0 = 0\nx1 = 1\ny1 = 1\nratio = [0.1, 0.2, 1.1]",
     r"sim\.slip\.surface\[0\]\.ratio\[2\]: must be 0-1, got 1\.1"),
    ("[sim.slip]\nsurface = 3", r"sim\.slip\.surface: must be an array of tables"),
])
def test_bad_sim_slip_table_names_key_and_problem(tmp_path: Path, table: str,
                                                  message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(write(tmp_path, GOOD + f"\n{table}\n"))


@given(st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3), st.floats(0.0, 1.0))
def test_a_slip_per_wheel_or_one_for_all_reaches_the_simulator(ratios: list[float],
                                                               one: float) -> None:
    import tomllib

    from omnican.config import parse_config
    from omnican.sim.slip import SimSlip
    base = tomllib.loads(GOOD)
    per_wheel = parse_config({**base, "sim": {"slip": {"ratio": ratios, "roller": one}}},
                             "test", check_eds=False)
    assert per_wheel.sim is not None and per_wheel.sim.slip is not None
    slip = SimSlip.of(per_wheel.sim.slip)
    assert [slip.ratio(i, 0.0, 0.0) for i in range(3)] == ratios
    assert slip.roller == ({i: one for i in range(3)} if one else {})


def _with_key(section: str, key: str, value: str) -> str:
    """GOOD with ``key = value`` in ``section`` (the first wheel for [[wheel]])."""
    import re

    if section == "chassis":
        head, rest = GOOD.split("[[wheel]]", 1)
        head = re.sub(rf"^{key} = .*\n", "", head, flags=re.M)
        return head.replace("[chassis]\n", f"[chassis]\n{key} = {value}\n") + "[[wheel]]" + rest
    if section == "wheel":
        text = GOOD
        if key in ("velocity_scale", "position_scale"):  # wheel[0] has them: its own
            text = re.sub(rf"^{key} = .*\n", "", text, count=1, flags=re.M)
        return text.replace("[[wheel]]\nnode_id = 1\n", f"[[wheel]]\n{key} = {value}\n"
                            + ("node_id = 1\n" if key != "node_id" else ""), 1)
    required = {"estop": "bit = 16\n", "imu": "source = \"ros2\"\n"}.get(section, "")
    if key in required:
        required = ""
    return GOOD + f"\n[{section}]\n{required}{key} = {value}\n"


def _ranged_keys() -> list[tuple[str, str, Any]]:
    from omnican.config import SCHEMA

    return [(section, key, spec) for section, keys in SCHEMA.items() if "." not in section
            for key, spec in keys.items() if spec.range is not None]


@pytest.mark.parametrize(("section", "key", "spec"), _ranged_keys(),
                         ids=[f"{s}.{k}" for s, k, _ in _ranged_keys()])
def test_a_number_beyond_its_range_is_refused_with_the_range(
        tmp_path: Path, section: str, key: str, spec: Any) -> None:
    """Every numeric key of the schema: far below and far above its range (1e-300 and
    1e300, the largest and most negative TOML integers) is refused by load_config in one
    line naming the key and the range, not accepted to fail at run time."""
    floats = int not in spec.types
    values = (["1e-300", "1e300", "-1e300"] if floats else
              ["-9223372036854775808", "9223372036854775807"])
    where = "wheel[0]" if section == "wheel" else section
    lo, hi = spec.range
    checked = 0
    for text in values:
        value = float(text)
        if lo <= (abs(value) if spec.signed else value) <= hi:
            continue  # within (1e-300 for a key whose range starts at 0)
        with pytest.raises(ConfigError) as info:
            load_config(write(tmp_path, _with_key(section, key, text)))
        message = str(info.value)
        assert "\n" not in message
        assert f"{where}.{key}: must be {spec.range_text()}, got " in message, message
        checked += 1
    assert checked >= 2


def test_check_config_refuses_out_of_range_numbers_in_one_line(tmp_path: Path) -> None:
    """The command a user runs says the same, exit 2, and never "OK" (issue: 1e-300 and
    1e300 timeouts were accepted, then failed at run time or at close)."""
    for key, text, expected in (
            ("sdo_timeout_s", "1e-300", "chassis.sdo_timeout_s: must be 0.01-60, got 1e-300"),
            ("boot_timeout_s", "1e300", "chassis.boot_timeout_s: must be 0.1-60, got 1e+300"),
            ("heartbeat_timeout_factor", "1e300",
             "chassis.heartbeat_timeout_factor: must be 1-100, got 1e+300")):
        path = write(tmp_path, _with_key("chassis", key, text))
        proc = _run_cli(["check-config", str(path)])
        assert proc.returncode == 2, proc
        assert proc.stdout == ""
        assert proc.stderr.strip().splitlines() == [f"omnican: error: {path}: {expected}"]


def _run_cli(argv: list[str]) -> Any:
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "omnican", *argv], capture_output=True,
                          text=True, timeout=120, check=False)


@pytest.mark.parametrize(("decel", "message"), [
    ("stop_decel = 0.001", "chassis.stop_decel: 0.001 would stop the base from its top speed "
     "1.33 m/s in 1.33e+03 s; every stop must end within 2 s: at least 0.667 m/s^2 (or lower "
     "max_speed or max_wheel_speed)"),
    ("max_angular_accel = 0.5", "chassis.stop_angular_decel: 1 (2 x max_angular_accel) would "
     "stop the base from its top speed 5.26 rad/s in 5.26 s; every stop must end within 2 s: "
     "at least 2.63 rad/s^2 (or lower max_angular_speed or max_wheel_speed)"),
])
def test_a_stop_that_takes_too_long_is_refused(tmp_path: Path, decel: str,
                                               message: str) -> None:
    """A deceleration below the floor (the top speed over MAX_STOP_S) is refused, a
    derived one too, and the message says the floor and how to get there."""
    text = GOOD.replace("max_angular_accel = 3.0\n", "") if "angular" in decel else GOOD
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text.replace("[chassis]\n", f"[chassis]\n{decel}\n")))
    assert str(info.value).endswith(message), str(info.value)


def test_the_stop_floor_follows_the_speed_limits(tmp_path: Path) -> None:
    """A lower speed limit lowers the floor: a gentle stop is fine on a slow base."""
    slow = GOOD.replace("[chassis]\n", "[chassis]\nstop_decel = 0.2\nmax_speed = 0.4\n")
    assert load_config(write(tmp_path, slow)).chassis.stop_decel == 0.2
    with pytest.raises(ConfigError, match=r"at least 0\.25 m/s"):
        load_config(write(tmp_path, slow.replace("max_speed = 0.4", "max_speed = 0.5")))


@pytest.mark.parametrize("value", ['"500k"', '"abc"', "nan", "inf", "[500000]", "-1", "0",
                                   "true", "5e5", "2000000", "{ a = 1 }"])
def test_a_bitrate_that_is_not_one_is_one_line_and_exit_2(tmp_path: Path, value: str) -> None:
    """[bus] bitrate: only an integer number of bit/s in CAN's range; check-config says
    so in one line, exit 2, before any "OK" (it crashed on int("500k") after "OK")."""
    path = write(tmp_path, GOOD.replace('channel = "x"\n', f'channel = "x"\nbitrate = {value}\n'))
    with pytest.raises(ConfigError, match=r"bus\.bitrate: must be "):
        load_config(path)
    proc = _run_cli(["check-config", str(path)])
    assert proc.returncode == 2
    assert proc.stdout == ""
    [line] = proc.stderr.strip().splitlines()
    assert line.startswith(f"omnican: error: {path}: bus.bitrate: must be "), line


def test_a_good_bitrate_still_counts_the_bus_load(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD.replace('channel = "x"\n', 'channel = "x"\nbitrate = 250000\n'))
    assert load_config(path).bus == {"interface": "virtual", "channel": "x", "bitrate": 250000}
    proc = _run_cli(["check-config", str(path)])
    assert proc.returncode == 0 and "bus load at 250 kbit/s" in proc.stdout


def test_deep_nesting_and_an_impossible_eds_path_are_one_line(tmp_path: Path) -> None:
    """TOML nested 2,000 deep (a RecursionError in the parser) and an EDS path longer
    than the file system allows (an OSError from stat) are one-line errors, exit 2."""
    deep = write(tmp_path, "x = " + "[" * 2000 + "]" * 2000 + "\n", "deep.toml")
    with pytest.raises(ConfigError, match="nested too deeply"):
        load_config(deep)
    long = write(tmp_path, GOOD.replace("[[wheel]]\nnode_id = 3\n",
                                        f'[[wheel]]\nnode_id = 3\neds = "{"e" * 5000}.eds"\n'),
                 "long.toml")
    with pytest.raises(ConfigError, match=r"wheel\[2\]\.eds: cannot read EDS file .*\.\.\. "
                       r"\(50\d\d characters\): File name too long"):
        load_config(long)
    for path in (deep, long):
        proc = _run_cli(["check-config", str(path)])
        assert proc.returncode == 2 and proc.stdout == ""
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert "Traceback" not in proc.stderr
