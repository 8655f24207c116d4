"""An EDS or a vendor setting that would break the control loop is refused before any
frame (issue 30, item 7): types too narrow for the configured speed and travel, objects
omnican writes marked read-only, a 6502h without a velocity mode, [[wheel.sdo]] settings
that would overwrite what omnican configures. A drive that does not take the mode is
caught at run time by its mode display (6061h). Real drives' files still pass."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import Chassis, ChassisConfig
from omnican.clock import SimClock
from omnican.config import load_config
from omnican.core.wheel_odometry import fold_counter
from omnican.errors import ConfigError, DriveError
from omnican.protocol.eds_check import counter_problem, value_range, width_problem
from omnican.sim import SimulatedBase
from tests.protocol.test_eds_check import EXAMPLE, edit_eds, run_main
from tests.support.helpers import one_error_line, sim_config

# examples/robot.toml: velocity_scale and position_scale 208608 per m (derived), 1 m/s,
# 100 Hz. (what is changed in node 2's EDS, what the one line must say)
NARROW_OR_LOCKED = {
    "target velocity 16-bit": ({"60FF": ("DataType", "0x0003")},
                               ("0x60FF:00", "Target velocity", "16-bit", "208608",
                                "max_wheel_speed")),
    "target velocity 8-bit": ({"60FF": ("DataType", "0x0002")},
                              ("0x60FF:00", "8-bit", "too narrow")),
    "position 8-bit": ({"6064": ("DataType", "0x0002")},
                       ("0x6064:00", "Position actual value", "8-bit", "2086 counts a cycle",
                        "position_scale")),
    "mode read-only": ({"6060": ("AccessType", "ro")},
                       ("0x6060:00", "Modes of operation", "AccessType ro", "writes",
                        "mode of operation")),
    "producer heartbeat read-only": ({"1017": ("AccessType", "ro")},
                                     ("0x1017:00", "AccessType ro", "heartbeat")),
    "consumer heartbeat read-only": ({"1016sub1": ("AccessType", "ro")},
                                     ("0x1016:01", "AccessType ro", "host's heartbeat")),
    "RPDO1 COB-ID read-only": ({"1400sub1": ("AccessType", "ro")},
                               ("0x1400:01", "AccessType ro", "PDO")),
    "TPDO1 COB-ID read-only": ({"1800sub1": ("AccessType", "const")},
                               ("0x1800:01", "AccessType const", "PDO")),
    "no velocity mode": ({"6502": ("DefaultValue", "0x00000001")},
                         ("0x6502", "Supported drive modes", "no velocity mode")),
}


def broken_robot(tmp_path: Path, case: str) -> tuple[Path, Path]:
    """examples/robot.toml with node 2 on the changed EDS ``case``."""
    eds = edit_eds(tmp_path / "broken.eds", set_key=NARROW_OR_LOCKED[case][0])
    cfg = tmp_path / "robot.toml"
    cfg.write_text(EXAMPLE.read_text().replace("node_id = 2\n",
                                               'node_id = 2\neds = "broken.eds"\n'))
    return cfg, eds


def says(line: str, parts: tuple[str, ...]) -> None:
    for part in parts:
        assert part.lower() in line.lower(), (part, line)


@pytest.mark.parametrize("case", sorted(NARROW_OR_LOCKED))
def test_check_config_refuses_what_breaks_the_loop(tmp_path: Path, case: str) -> None:
    cfg, eds = broken_robot(tmp_path, case)
    code, out, err = run_main(["check-config", str(cfg)])
    assert code == 2
    line = one_error_line(err)
    assert "node 2" in line and str(eds) in line
    says(line, NARROW_OR_LOCKED[case][1])
    assert "OK" not in out


@pytest.mark.parametrize("case", sorted(NARROW_OR_LOCKED))
def test_chassis_open_refuses_it_before_any_frame(tmp_path: Path, channel: str,
                                                  case: str) -> None:
    _path, eds = broken_robot(tmp_path, case)
    cfg = _in_code(eds, channel)
    with can.Bus(interface="virtual", channel=channel, receive_own_messages=False) as watcher:
        with pytest.raises(ConfigError) as raised:
            Chassis.open(cfg)
        assert watcher.recv(0.2) is None  # not one frame: no NMT, no SDO, no SYNC
    assert "\n" not in str(raised.value)
    says(str(raised.value), NARROW_OR_LOCKED[case][1])


@pytest.mark.parametrize("case", ["target velocity 16-bit", "mode read-only"])
def test_a_run_command_refuses_it_too(tmp_path: Path, case: str) -> None:
    cfg, eds = broken_robot(tmp_path, case)
    for argv in (["drive", "--sim", "--config", str(cfg), "--vx", "0.2", "--duration", "0.3"],
                 ["sim", "--config", str(cfg), "--duration", "0.3"]):
        code, out, err = run_main(argv)
        assert code == 2
        line = one_error_line(err)
        assert str(eds) in line
        says(line, NARROW_OR_LOCKED[case][1])
        assert "pose" not in out and "serving" not in out


def _in_code(eds: Path, channel: str) -> ChassisConfig:
    """examples/robot.toml as a program builds it in code (no load_config of the broken
    file), node 2 on ``eds``, on a virtual channel."""
    good = load_config(EXAMPLE)
    wheels = list(good.wheels)
    wheels[1] = replace(wheels[1], eds=eds)
    return replace(good, wheels=tuple(wheels), bus={"interface": "virtual", "channel": channel})


def test_the_unchanged_robot_passes(tmp_path: Path) -> None:
    code, _out, err = run_main(["check-config", str(EXAMPLE)])
    assert code == 0, err


# ------------------------------------------------------------ vendor settings

OWNED = {
    "0x1800:01": ("65536", "the PDO configuration"),
    "0x1A00:00": ("0", "the PDO configuration"),
    "0x1017:00": ("500", "heartbeat producer"),
    "0x1016:01": ("0", "heartbeat consumer"),
    "0x6060:00": ("1", "mode of operation"),
    "0x6085:00": ("100", "quick stop decel"),
    "0x6007:00": ("0", "lost host"),
}


@pytest.mark.parametrize("obj", sorted(OWNED))
def test_a_vendor_setting_may_not_overwrite_what_omnican_configures(
        tmp_path: Path, obj: str) -> None:
    value, why = OWNED[obj]
    cfg = tmp_path / "robot.toml"
    # [[wheel.sdo]] follows the wheel's own keys: after wheel 1's (node 2's) last key
    text = EXAMPLE.read_text()
    head, sep, tail = text.partition("node_id = 2\n")
    body, sep2, rest = tail.partition("\n\n")
    cfg.write_text(head + sep + body + f'\n[[wheel.sdo]]\nobject = "{obj}"\nvalue = {value}\n'
                   + sep2 + rest)
    code, out, err = run_main(["check-config", str(cfg)])
    assert code == 2, out
    line = one_error_line(err)
    says(line, ("node 2", "wheel[1].sdo[0]", obj, "set by omnican", why, "overwrite"))


def test_a_vendor_setting_of_the_drive_s_own_passes(tmp_path: Path) -> None:
    """The ZLAC8015D's CAN watchdog (2000h), as examples/zlac8015d.toml sets it."""
    code, out, err = run_main(["check-config", str(EXAMPLE.parent / "zlac8015d.toml")])
    assert code == 0, err
    assert "vendor setting in PRE-OPERATIONAL: Offline Communication Parameter" in out


# ------------------------------------------------------------ the mode display at run time

def test_a_drive_that_does_not_take_the_mode_is_refused_at_open(channel: str) -> None:
    """6060h written, 6061h still shows another mode (a drive that ignores the write
    without an abort): the base does not open, and nothing moved."""
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        sim.drives[1].comm.readers[(0x6061, 0)] = lambda: 1  # stays in profile position
        with pytest.raises(DriveError) as raised:
            Chassis.open(cfg, clock=clock)
        line = str(raised.value).splitlines()[0]
        says(line, ("node 2", "0x6061:00", "shows 1 (profile position)", "mode pv (3)",
                    "0x6060:00", "did not take the mode"))
        assert all(d.state().name != "OPERATION_ENABLED" for d in sim.drives)
        assert sim.true_pose.x == 0.0 and sim.true_pose.y == 0.0


# ------------------------------------------------------------ the pure checks

@given(bits=st.sampled_from([8, 16, 24, 32]), signed=st.booleans(),
       largest=st.floats(0, 2.0**33, allow_nan=False))
def test_width_problem_exactly_when_the_type_cannot_hold_it(bits: int, signed: bool,
                                                            largest: float) -> None:
    lo, hi = value_range(bits, signed)
    problem = width_problem("0x60FF:00 Target velocity", bits, signed, largest, "why")
    assert (problem is None) == (lo <= -largest and largest <= hi)
    if problem is not None:
        assert f"{bits}-bit" in problem and "\n" not in problem


@given(bits=st.sampled_from([8, 16, 32]), per_cycle=st.floats(0, 2.0**20, allow_nan=False),
       cycles=st.integers(1, 8), direction=st.sampled_from([-1, 1]), start=st.integers(0, 2**32))
def test_a_counter_passing_is_folded_exactly(bits: int, per_cycle: float, cycles: int,
                                             direction: int, start: int) -> None:
    """What counter_problem lets through, fold_counter reads right: a step of up to
    ``cycles`` cycles' travel, either way, from anywhere on the counter."""
    if counter_problem("0x6064:00", bits, per_cycle, cycles, "why") is not None:
        return
    span = 1 << bits
    step = direction * int(per_cycle * cycles)
    raw0 = start % span
    raw1 = (raw0 + step) % span
    assert fold_counter(0.0, raw0, raw1, bits) == step
