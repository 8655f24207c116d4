"""The [imu] and [sim.gyro] tables: four lines name a CAN IMU's DBC message; what does
not match the DBC is one line naming the key, from load_config and check-config alike."""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path

import pytest

from omnican import ConfigError, load_config
from omnican.config import SCHEMA, ImuSettings, SimGyro
from omnican.config.imu import BUNDLED_DBC
from tests.cli.test_first_use import run_main
from tests.config.test_config import GOOD, write
from tests.support.helpers import one_error_line

FOUR_LINES = """
[imu]
source = "can"
dbc = "openimu300ri.dbc"
message = "ARI"
yaw_rate = "AngularRateZ"
"""

OPENIMU = BUNDLED_DBC / "openimu300ri.dbc"


def test_four_lines_name_a_can_imu_of_the_bundled_dbc(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, GOOD + FOUR_LINES))
    assert cfg.imu == ImuSettings("can", dbc=OPENIMU, message="ARI", yaw_rate="AngularRateZ")
    assert cfg.imu.stale_s == 0.5 and cfg.imu.mount_yaw_deg == 0.0
    assert not cfg.imu.upside_down


def test_a_dbc_relative_to_the_config_file(tmp_path: Path) -> None:
    (tmp_path / "dbc").mkdir()
    (tmp_path / "dbc" / "mine.dbc").write_text(OPENIMU.read_text())
    text = GOOD + FOUR_LINES.replace("openimu300ri.dbc", "dbc/mine.dbc") + """
accel_message = "ACCS"
accel_x = "AccelerationX"
accel_y = "AccelerationY"
mount_yaw_deg = -90
upside_down = true
stale_s = 0.2
"""
    imu = load_config(write(tmp_path, text)).imu
    assert imu is not None
    assert imu.dbc == tmp_path / "dbc" / "mine.dbc"
    assert (imu.accel_message, imu.accel_x, imu.accel_y) == ("ACCS", "AccelerationX",
                                                              "AccelerationY")
    assert (imu.mount_yaw_deg, imu.upside_down, imu.stale_s) == (-90.0, True, 0.2)


def test_a_topic_imu(tmp_path: Path) -> None:
    for source in ("ros2", "zenoh"):
        text = GOOD + f'[imu]\nsource = "{source}"\ntopic = "/base/imu"\n'
        imu = load_config(write(tmp_path, text)).imu
        assert imu == ImuSettings(source, topic="/base/imu")
    assert load_config(write(tmp_path, GOOD + '[imu]\nsource = "ros2"\n')).imu.topic == \
        "/imu/data"  # type: ignore[union-attr]


NO_UNIT_DBC = """VERSION ""
BS_:
BU_: Imu
BO_ 2565876352 RATE: 8 Imu
 SG_ Yaw : 0|16@1- (0.01,0) [-327.68|327.67] "" Vector__XXX
 SG_ Odd : 16|16@1- (1,0) [-32768|32767] "rpm" Vector__XXX
"""


@pytest.mark.parametrize(("lines", "key", "message"), [
    ('dbc = "nowhere.dbc"', "imu.dbc", "no such DBC file"),
    ('dbc = "bad.dbc"', "imu.dbc", "is not a DBC file cantools reads"),
    ('message = "ARY"', "imu.message", "no message 'ARY' in the DBC (it has: ARI, ACCS)"),
    ('yaw_rate = "AngularRatZ"', "imu.yaw_rate",
     "no signal 'AngularRatZ' in message ARI (did you mean 'AngularRateZ'?)"),
    ('yaw_rate_unit = "rpm"', "imu.yaw_rate_unit", "unknown unit 'rpm'"),
    ('accel_x = "AccelerationX"', "imu.accel_y", "give both accelerations' signals"),
    ('accel_x = "AccelerationX"\naccel_y = "AccelerationY"', "imu.accel_x",
     "no signal 'AccelerationX' in message ARI"),
    ('accel_message = "ACCS"\naccel_x = "AccelerationX"\naccel_y = "Lateral"', "imu.accel_y",
     "no signal 'Lateral' in message ACCS"),
    ('topic = "/imu"', "imu.topic", "not read for source 'can'"),
    ('source = "serial"', "imu.source", "must be one of can, ros2, zenoh"),
    ('stale_s = 0', "imu.stale_s", "must be 0.01-60"),
    ('mount_yaw = 90', "imu.mount_yaw", "did you mean 'mount_yaw_deg'?"),
])
def test_what_does_not_match_the_dbc_is_one_line(tmp_path: Path, lines: str, key: str,
                                                 message: str) -> None:
    (tmp_path / "bad.dbc").write_text("this is not a DBC\n{")
    table = FOUR_LINES
    for line in lines.splitlines():
        name = line.split("=")[0].strip()
        if f"\n{name} = " in table:
            table = "\n".join(line if x.startswith(f"{name} = ") else x
                              for x in table.splitlines())
        else:
            table += line + "\n"
    path = write(tmp_path, GOOD + table)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    text = str(err.value)
    assert text.startswith(f"{path}: {key}: "), text
    assert message in text
    assert "\n" not in text
    code, _, out = run_main(["check-config", str(path)])
    assert code == 2
    assert one_error_line(out) == f"omnican: error: {text}"


def test_a_signal_without_a_unit_needs_one_from_the_config(tmp_path: Path) -> None:
    (tmp_path / "imu.dbc").write_text(NO_UNIT_DBC)
    table = '[imu]\nsource = "can"\ndbc = "imu.dbc"\nmessage = "RATE"\nyaw_rate = "Yaw"\n'
    with pytest.raises(ConfigError, match=r"imu.yaw_rate_unit: the DBC's signal Yaw: it has "
                                          r"no unit; give yaw_rate_unit \(deg/s or rad/s\)"):
        load_config(write(tmp_path, GOOD + table))
    with pytest.raises(ConfigError, match="its unit 'rpm' is not one omnican knows"):
        load_config(write(tmp_path, GOOD + table.replace('"Yaw"', '"Odd"')))
    imu = load_config(write(tmp_path, GOOD + table + 'yaw_rate_unit = "deg/s"\n')).imu
    assert imu is not None and imu.yaw_rate_unit == "deg/s"


def test_a_topic_imu_refuses_the_can_keys(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"imu.message: not read for source 'zenoh'"):
        load_config(write(tmp_path, GOOD + '[imu]\nsource = "zenoh"\nmessage = "ARI"\n'))
    with pytest.raises(ConfigError, match=r"imu.topic: must be a topic's full name"):
        load_config(write(tmp_path, GOOD + '[imu]\nsource = "ros2"\ntopic = "imu"\n'))


def test_sim_gyro_table(tmp_path: Path) -> None:
    text = GOOD + FOUR_LINES + """
[sim.gyro]
rate_hz = 200
bias_deg_s = 0.5
drift_deg_s = 0.01
noise_deg_s = 0.1
mount_yaw_deg = 10
noise_stream = 7
"""
    cfg = load_config(write(tmp_path, text))
    assert cfg.sim is not None
    assert cfg.sim.gyro == SimGyro(True, 200.0, 0.5, 0.01, 0.1, 10.0, 7)
    with pytest.raises(ConfigError, match=r"sim.gyro.rate_hz: must be 1-1000, got 0"):
        load_config(write(tmp_path, text.replace("rate_hz = 200", "rate_hz = 0")))
    with pytest.raises(ConfigError, match=r"sim.gyro.bias: unknown key"):
        load_config(write(tmp_path, text.replace("bias_deg_s", "bias")))


def test_the_dataclasses_default_as_the_schema() -> None:
    for cls, section in ((ImuSettings, "imu"), (SimGyro, "sim.gyro")):
        for f in fields(cls):
            spec = SCHEMA[section][f.name]
            if f.name in ("source", "dbc"):
                continue  # required, and a path made whole
            assert f.default == spec.default or (
                isinstance(f.default, float) and math.isnan(f.default)), f.name
        assert {f.name for f in fields(cls)} == set(SCHEMA[section])


def test_check_config_says_what_the_imu_reads(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD + FOUR_LINES + 'accel_message = "ACCS"\naccel_x = '
                 '"AccelerationX"\naccel_y = "AccelerationY"\nupside_down = true\n')
    code, out, err = run_main(["check-config", str(path)])
    assert code == 0, err
    assert ("  imu: CAN message ARI (0x18F02A80, 29-bit) of openimu300ri.dbc, yaw rate "
            "AngularRateZ in deg/s, accelerations AccelerationX, AccelerationY of ACCS; "
            "mounted 0 deg, upside down; silent after 0.5 s") in out.splitlines()
    path = write(tmp_path, GOOD + '[imu]\nsource = "zenoh"\nmount_yaw_deg = 45\n')
    code, out, err = run_main(["check-config", str(path)])
    assert code == 0, err
    assert ("  imu: sensor_msgs/Imu on /imu/data (zenoh), mounted 45 deg; silent after "
            "0.5 s") in out.splitlines()
