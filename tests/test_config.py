"""Config: the TOML schema, and one clear ConfigError per problem."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import pytest

from omnican import WHEEL_EDS, ConfigError, load_config
from omnican.cia402 import Mode
from omnican.config import default_config, derive_scales

from .conftest import VENDOR_EDS

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
        ("rate_hz = 100", "rate_hz = -5", r"chassis\.rate_hz: must be a positive number"),
        ("rate_hz = 100", 'rate_hz = "fast"', r"chassis\.rate_hz: must be int or float"),
        ("rate_hz = 100", "rate_hz = true", r"chassis\.rate_hz: must be a number"),
        ("rate_hz = 100", "rate_hz = nan", r"chassis\.rate_hz: must be a number, got nan"),
        ("base_radius = 0.19", "", r"chassis\.base_radius: missing required key"),
        ("base_radius = 0.19", "base_radius = 0", r"chassis\.base_radius: must be a positive"),
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
         r"wheel\[0\]\.velocity_scale: must be a non-zero"),
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


def test_readme_reference_matches_the_schema() -> None:
    from omnican.config import reference_rows

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    rows = [line for line in readme.splitlines() if line.startswith("| `chassis.")
            or line.startswith("| `wheel.") or line.startswith("| `ros2.")
            or line.startswith("| `gamepad.")]
    expected = [f"| `{key}` | {default} | {doc} |" for key, default, doc in reference_rows()]
    assert rows == expected


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
