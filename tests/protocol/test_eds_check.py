"""EDS files no drive could have are refused before anything touches the bus: the
objects CiA 301 makes mandatory, and every object omnican will read, write or map,
with the sub-indices and data types it uses. Real drives' files (which understate
their drives, but are not impossible) and the bundled EDS still pass."""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import replace
from pathlib import Path

import can
import pytest

from omnican import WHEEL_EDS, Chassis
from omnican.cli import main
from omnican.config import load_config
from omnican.errors import ConfigError
from omnican.plan.node import node_layouts
from omnican.protocol.cia402 import Mode
from omnican.protocol.object_map import load_dictionary
from tests.support.helpers import VENDOR_EDS, one_error_line, sim_config, vendor_config

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "robot.toml"


def edit_eds(dest: Path, drop: tuple[str, ...] = (), set_key: dict[str, tuple[str, str]] | None
             = None, source: Path = WHEEL_EDS) -> Path:
    """A copy of ``source`` without the sections ``drop`` (e.g. ``"1000"``,
    ``"1800sub0"``) and with ``set_key[section] = (key, value)`` changed."""
    set_key = set_key or {}
    out: list[str] = []
    section = ""
    for line in source.read_text().splitlines():
        m = re.fullmatch(r"\[(.+)\]", line.strip())
        if m:
            section = m.group(1)
        if section.lower() in (s.lower() for s in drop):
            continue
        changed = section in set_key and line.startswith(set_key[section][0] + "=")
        out.append("=".join(set_key[section]) if changed else line)
    dest.write_text("\n".join(out) + "\n")
    return dest


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


# (what is changed, what the one line must say besides the file's name)
BROKEN = {
    "no device type": (dict(drop=("1000",)), ("0x1000", "device type", "missing", "CiA 301")),
    "no error register": (dict(drop=("1001",)), ("0x1001", "error register", "missing")),
    "no identity": (dict(drop=("1018", "1018sub0", "1018sub1", "1018sub2", "1018sub3",
                               "1018sub4")), ("0x1018", "identity", "missing")),
    "identity without vendor id": (dict(drop=("1018sub1",)), ("0x1018", "sub-index 1",
                                                              "vendor")),
    "identity without sub 0": (dict(drop=("1018sub0",)), ("0x1018", "sub-index 0")),
    "device type a string": (dict(set_key={"1000": ("DataType", "0x0009")}),
                             ("0x1000", "0x0009", "UNSIGNED32")),
    "pdo communication without sub 0": (dict(drop=("1800sub0",)),
                                        ("0x1800", "TPDO1 communication parameter",
                                         "sub-index 0")),
    "pdo communication without COB-ID": (dict(drop=("1401sub1",)),
                                         ("0x1401", "RPDO2 communication parameter",
                                          "sub-index 1", "COB-ID")),
    "pdo communication without transmission type": (
        dict(drop=("1801sub2",)), ("0x1801", "sub-index 2", "transmission type")),
    "pdo mapping without sub 0": (dict(drop=("1A01sub0",)),
                                  ("0x1A01", "TPDO2 mapping parameter", "sub-index 0")),
    "pdo mapping entry 16 bits": (dict(set_key={"1600sub1": ("DataType", "0x0006")}),
                                  ("0x1600:01", "UNSIGNED16", "UNSIGNED32")),
    "pdo mapping without communication": (dict(drop=tuple(["1403"] + [f"1403sub{s}"
                                                                      for s in (0, 1, 2, 3, 5)])),
                                          ("0x1403", "RPDO4 communication parameter",
                                           "missing", "0x1603")),
    "pdo communication a variable": (
        dict(drop=tuple(f"1802sub{s}" for s in (0, 1, 2, 3, 5)),
             set_key={"1802": ("ObjectType", "0x7\nDataType=0x0007\nAccessType=rw")}),
        ("0x1802", "TPDO3 communication parameter", "VAR")),
    "no producer heartbeat": (dict(drop=("1017",)), ("0x1017", "producer heartbeat time",
                                                     "missing")),
    "consumer heartbeat without sub 1": (dict(drop=("1016sub1",)),
                                         ("0x1016", "sub-index 1")),
    "target velocity of a structure type": (dict(set_key={"60FF": ("DataType", "0x0020")}),
                                            ("0x60FF:00", "Target velocity", "0x0020",
                                             "integer")),
    "statusword of an unknown type": (dict(set_key={"6041": ("DataType", "0x0077")}),
                                      ("0x6041:00", "Statusword", "0x0077", "integer")),
    "position a float": (dict(set_key={"6064": ("DataType", "0x0008")}),
                         ("0x6064:00", "0x0008", "REAL32", "integer")),
    # issue 36: the simulator failed on its first statusword (ValueError: Value does not
    # fit in specified type), in a traceback of canopen's
    "statusword of 8 bits": (dict(set_key={"6041": ("DataType", "0x0005")}),
                             ("0x6041:00", "Statusword", "0x0005 UNSIGNED8",
                              "at least 16 bits")),
    "controlword of 8 bits": (dict(set_key={"6040": ("DataType", "0x0002")}),
                              ("0x6040:00", "Controlword", "0x0002 INTEGER8",
                               "at least 16 bits")),
}


def broken_config(tmp_path: Path, case: str) -> tuple[Path, Path]:
    """A copy of the example robot whose node 2 has the broken EDS ``case``."""
    changes, _ = BROKEN[case]
    eds = edit_eds(tmp_path / "broken.eds", **changes)  # type: ignore[arg-type]
    cfg = tmp_path / "robot.toml"
    cfg.write_text(EXAMPLE.read_text().replace("node_id = 2\n", 'node_id = 2\neds = "broken.eds"\n'))
    return cfg, eds


def says(line: str, eds: Path, case: str) -> None:
    assert str(eds) in line, line
    for part in BROKEN[case][1]:
        assert part.lower() in line.lower(), (part, line)


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_check_config_refuses_an_eds_no_drive_could_have(tmp_path: Path, case: str) -> None:
    cfg, eds = broken_config(tmp_path, case)
    code, out, err = run_main(["check-config", str(cfg)])
    assert code == 2
    says(one_error_line(err), eds, case)
    assert "OK" not in out


@pytest.mark.parametrize("case", ["no device type", "pdo communication without sub 0",
                                  "target velocity of a structure type",
                                  "statusword of 8 bits"])
def test_a_run_command_refuses_it_too(tmp_path: Path, case: str) -> None:
    cfg, eds = broken_config(tmp_path, case)
    for argv in (["drive", "--sim", "--config", str(cfg), "--vx", "0.2", "--duration", "0.3"],
                 ["sim", "--config", str(cfg), "--duration", "0.3"]):
        code, out, err = run_main(argv)
        assert code == 2
        says(one_error_line(err), eds, case)
        assert "pose" not in out and "serving" not in out


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_chassis_open_refuses_it_before_any_frame(tmp_path: Path, channel: str,
                                                  case: str) -> None:
    """A config built in code (no load_config) meets the same checks, before the bus."""
    changes, _ = BROKEN[case]
    eds = edit_eds(tmp_path / "broken.eds", **changes)  # type: ignore[arg-type]
    cfg = sim_config(channel)
    cfg = replace(cfg, wheels=(cfg.wheels[0], replace(cfg.wheels[1], eds=eds), cfg.wheels[2]))
    with can.Bus(interface="virtual", channel=channel, receive_own_messages=False) as watcher:
        with pytest.raises(ConfigError) as raised:
            Chassis.open(cfg)
        assert watcher.recv(0.2) is None  # not one frame: no NMT, no SDO, no SYNC
    message = str(raised.value)
    assert "\n" not in message
    says(message, eds, case)


# Each drive in each velocity mode it has the target of (ZLAC8015D and EPOS4 lack 6042h).
MODES = [(layout, mode) for layout in ("bundled", "zlac", "roboteq", "epos4")
         for mode in (None, Mode.PROFILE_VELOCITY, Mode.CYCLIC_SYNC_VELOCITY, Mode.VELOCITY)
         if not (mode is Mode.VELOCITY and layout in ("zlac", "epos4"))]


@pytest.mark.parametrize(("layout", "mode"), MODES)
def test_real_drives_files_pass(layout: str, mode: Mode | None) -> None:
    cfg = vendor_config("unused", layout)
    cfg = replace(cfg, wheels=tuple(replace(w, mode=mode) for w in cfg.wheels))
    assert len(node_layouts(cfg)) == len(cfg.nodes())


@pytest.mark.parametrize("eds", [WHEEL_EDS, VENDOR_EDS / "zlac8015d.eds",
                                 VENDOR_EDS / "roboteq_v80_21.eds",
                                 VENDOR_EDS / "maxon_epos4.eds"], ids=lambda p: p.name)
def test_check_config_passes_real_drives_files(tmp_path: Path, eds: Path) -> None:
    two_axes = eds.name.startswith(("zlac", "roboteq"))
    slots = [(1, 0), (1, 1), (2, 0)] if two_axes else [(1, 0), (2, 0), (3, 0)]
    cfg = tmp_path / "robot.toml"
    cfg.write_text('[chassis]\nlayout = "b21"\nbase_radius = 0.2\n' + "".join(
        f'[[wheel]]\nnode_id = {n}\naxis = {a}\neds = "{eds}"\nvelocity_scale = 100.0\n'
        "position_scale = 1000.0\n" for n, a in slots))
    load_config(cfg)
    code, out, err = run_main(["check-config", str(cfg)])
    assert code == 0, err
    assert f"{cfg}: OK" in out


# ---------------------------------------------------------------- one section less


def _sections(eds: Path) -> list[str]:
    return [m.group(1) for line in eds.read_text().splitlines()
            if (m := re.fullmatch(r"\[(1[0-9A-Fa-f]{3}(?:sub[0-9A-Fa-f]+)?)\]", line.strip()))]


def relied_on(section: str) -> bool:
    """Whether omnican relies on a communication-profile section of the bundled EDS."""
    index, _, sub = section.partition("sub")
    i, s = int(index, 16), int(sub, 16) if sub else None
    if s is None and any(x.startswith(f"{index}sub") for x in _sections(WHEEL_EDS)):
        return True  # the head of a record without the record: canopen cannot parse it
    if i in (0x1000, 0x1001, 0x1017):
        return True
    if i == 0x1018:
        return s in (None, 0, 1)
    if i == 0x1016:
        return s in (0, 1)
    if 0x1400 <= i < 0x1C00:  # either half of a PDO, or a sub-index it must have
        comm = i < 0x1600 or 0x1800 <= i < 0x1A00
        return s is None or s == 0 or (comm and s in (1, 2))
    return False


def test_one_section_less_is_refused_exactly_when_omnican_relies_on_it(tmp_path: Path) -> None:
    """Every communication-profile section of the bundled EDS, left out in turn."""
    sections = _sections(WHEEL_EDS)
    assert len(sections) > 100
    for section in sections:
        eds = edit_eds(tmp_path / f"without-{section}.eds", drop=(section,))
        if relied_on(section):
            with pytest.raises(ConfigError) as raised:
                load_dictionary(eds)
            assert f"0x{section[:4].upper()}" in str(raised.value), section
        else:
            load_dictionary(eds)
