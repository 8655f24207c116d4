"""omnican commission against simulated drives (issue 38 items 1, 2): node ids by LSS for
the serials the config names, kept across a power cycle, a clean scan afterwards; and
each way it can go wrong, one line and the table all the same."""

from __future__ import annotations

import contextlib
import io
import struct
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import can
import canopen
import pytest

from omnican.cli import main
from omnican.config import load_config
from omnican.sim import SimulatedBase
from omnican.sim.memory import UNCONFIGURED

SDO = '[[wheel.sdo]]\nobject = "0x607F"\nvalue = {value}\n'


def robot_toml(tmp_path: Path, serials: Mapping[int, int | None], sdo: str = "") -> Path:
    wheels = "".join(
        f"[[wheel]]\nnode_id = {n}\n" + ("" if s is None else f"serial = {s}\n")
        + "velocity_scale = -4772.44\nposition_scale = 48000.0\n" + sdo + "\n"
        for n, s in serials.items())
    toml = tmp_path / "robot.toml"
    toml.write_text(f'[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n{wheels}')
    return toml


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


@contextlib.contextmanager
def drives(toml: Path, channel: str, **options: Any) -> Iterator[SimulatedBase]:
    """Simulated drives of ``toml`` without node ids on ``channel``."""
    cfg = load_config(toml).with_bus(interface="virtual", channel=channel)
    with SimulatedBase.from_config(cfg, unconfigured=True, **options) as sim:
        yield sim


def commission(toml: Path, channel: str, *more: str) -> tuple[int, str, str]:
    return run_main(["commission", str(toml), "-i", "virtual", "-c", channel, *more])


def table_rows(out: str) -> dict[str, list[str]]:
    """Serial -> the cells of its row in the final table."""
    rows = {}
    for line in out.splitlines():
        cells = [c.strip() for c in line.strip("│ ").split("│")]
        if len(cells) == 6 and cells[0].startswith("0x"):
            rows[str(int(cells[0], 16))] = cells
    return rows


def test_three_drives_without_ids_get_the_configs_and_keep_them_across_a_power_cycle(
        tmp_path: Path, channel: str) -> None:
    toml = robot_toml(tmp_path, {1: 0x5A01, 2: 0x5A02, 3: 0x5A03})
    with drives(toml, channel, serials={1: 0x5A03, 2: 0x5A01, 3: 0x5A02}) as sim:
        code, out, err = commission(toml, channel)
        assert code == 0, err
        rows = table_rows(out)
        assert {s: (r[2], r[3], r[4]) for s, r in rows.items()} == {
            str(0x5A01): ("none (FFh)", "1", "1"), str(0x5A02): ("none (FFh)", "2", "2"),
            str(0x5A03): ("none (FFh)", "3", "3")}
        assert "fast scan" in err  # the progress
        assert sim.lss is not None
        assert sorted(sim.lss.node_ids()) == [(0x5A01, 1), (0x5A02, 2), (0x5A03, 3)]
        sim.power_cycle()
        assert sorted(sim.lss.node_ids()) == [(0x5A01, 1), (0x5A02, 2), (0x5A03, 3)]
        code, out, err = run_main(["scan", "--config", str(toml), "-i", "virtual",
                                   "-c", channel])
        assert code == 0, out + err
        assert "3 node(s) found; 0 configured node(s) missing" in out
        # Run again: every drive already has its id; nothing changes.
        code, out, err = commission(toml, channel)
        assert code == 0, err
        assert {r[3] for r in table_rows(out).values()} == {"1", "2", "3"}


def test_drives_running_with_anothers_node_id_are_given_their_own(tmp_path: Path,
                                                                   channel: str) -> None:
    """Drives that have node ids, but not those the config gives their serials (found by
    their identity over SDO, selected by it over LSS, reset): two swapped, one right."""
    toml = robot_toml(tmp_path, {1: 82, 2: 81, 3: 83})
    cfg = load_config(toml).with_bus(interface="virtual", channel=channel)
    with SimulatedBase.from_config(cfg, serials={1: 81, 2: 82, 3: 83}) as sim:
        code, out, err = commission(toml, channel)
        assert code == 0, err
        rows = table_rows(out)
        assert {s: (r[2], r[3]) for s, r in rows.items()} == {
            "81": ("1", "2"), "82": ("2", "1"), "83": ("3", "3")}
        assert rows["83"][5] == "had its node id"
        assert sim.lss is not None
        sim.power_cycle()
        assert sorted(sim.lss.node_ids()) == [(81, 2), (82, 1), (83, 3)]
        code, out, err = run_main(["scan", "--config", str(toml), "-i", "virtual",
                                   "-c", channel])
        assert code == 0, out + err
        assert "0x00000052" in out  # serial 82, now node 1


def test_two_drives_with_one_serial_are_named_and_left_without_ids(tmp_path: Path,
                                                                  channel: str) -> None:
    toml = robot_toml(tmp_path, {1: 11, 2: 12, 3: 13})
    with drives(toml, channel, serials={1: 11, 2: 12, 3: 12}) as sim:
        code, out, err = commission(toml, channel)
        assert code == 1
        assert "omnican: error: two drives answer as serial 0x0000000C" in err
        assert "Traceback" not in err
        rows = table_rows(out)
        assert rows["11"][3] == "1"
        assert rows["12"][3] == "?" and "two drives" in rows["12"][5]
        assert rows["13"][5] == "not found"
        assert sim.lss is not None
        assert sorted(sim.lss.node_ids()) == [(11, 1), (12, UNCONFIGURED), (12, UNCONFIGURED)]


def test_a_drive_that_refuses_to_store_is_named_and_loses_its_id_at_power_off(
        tmp_path: Path, channel: str) -> None:
    toml = robot_toml(tmp_path, {1: 21, 2: 22, 3: 23})
    with drives(toml, channel, refuse_store=frozenset({2})) as sim:
        code, out, err = commission(toml, channel)
        assert code == 1
        lines = [line for line in err.splitlines() if line.startswith("omnican: error")]
        assert lines == ["omnican: error: the drive with serial 0x00000016 refused to store node id 2 "
                         "(LSS error 2: storage media access error): it has it until its next "
                         "power-on, no longer"]
        assert "NOT STORED" in table_rows(out)["22"][5]
        assert table_rows(out)["22"][3] == "2"
        assert sim.lss is not None
        sim.power_cycle()
        assert sorted(sim.lss.node_ids()) == [(21, 1), (22, UNCONFIGURED), (23, 3)]


@pytest.mark.parametrize(("cob_id", "data", "named"), [
    (0x7E5, bytes([0x5E]) + bytes(7), "LSS requests (7E5h)"),  # another tool's inquiries
    (0x080, b"", "SYNC (080h: a base running)"),  # a base driving
])
def test_another_master_on_the_bus_stops_it_before_anything_changes(
        tmp_path: Path, channel: str, cob_id: int, data: bytes, named: str) -> None:
    toml = robot_toml(tmp_path, {1: 31, 2: 32, 3: 33})
    stop = threading.Event()

    def other_master() -> None:
        with can.Bus(interface="virtual", channel=channel) as bus:
            while not stop.is_set():
                bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))
                stop.wait(0.02)

    with drives(toml, channel) as sim:
        thread = threading.Thread(target=other_master)
        thread.start()
        try:
            code, _out, err = commission(toml, channel)
        finally:
            stop.set()
            thread.join()
        assert code == 1
        assert err.strip().splitlines()[-1] == (
            f"omnican: error: another master is on the bus ({named} this command did not "
            "send): commission with the bus to yourself")
        assert sim.lss is not None
        assert [n for _, n in sim.lss.node_ids()] == [UNCONFIGURED] * 3


def test_no_drive_found_is_one_line_and_the_table_lists_the_configs_serials(
        tmp_path: Path, channel: str) -> None:
    toml = robot_toml(tmp_path, {1: 41, 2: 42, 3: 43})
    with can.Bus(interface="virtual", channel=channel):  # an empty bus
        code, out, err = commission(toml, channel)
    assert code == 1
    assert "omnican: error: no drive with serial 0x00000029 (node 1 in the config) answered" in err
    assert {s: r[5] for s, r in table_rows(out).items()} == {
        "41": "not found", "42": "not found", "43": "not found"}


@pytest.mark.parametrize(("argv", "says"), [
    (["--new-bitrate", "300000"], "LSS sets the bit rates"),
    (["--restore-defaults"], "--restore-defaults asks before it acts: add --yes"),
    (["--restore-defaults", "--store", "--yes"], "--restore-defaults is an action of its own"),
])
def test_bad_usage_is_one_line_and_exit_2(tmp_path: Path, channel: str, argv: list[str],
                                          says: str) -> None:
    toml = robot_toml(tmp_path, {1: 51, 2: 52, 3: 53})
    code, _out, err = commission(toml, channel, *argv)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and says in err, err


def test_a_config_without_serials_says_what_to_add(tmp_path: Path, channel: str) -> None:
    toml = robot_toml(tmp_path, {1: None, 2: None, 3: None})
    code, _out, err = commission(toml, channel)
    assert code == 2
    assert err.strip() == ("omnican: error: the config gives no drive's serial: add `serial = "
                           "N` (the drive's 1018h sub 4, on its label) to each [[wheel]]")


def test_store_writes_the_settings_and_they_survive_a_power_cycle_until_restored(
        tmp_path: Path, channel: str) -> None:
    toml = robot_toml(tmp_path, {1: 61, 2: 62, 3: 63}, SDO.format(value=4321))
    with drives(toml, channel) as sim:
        code, out, err = commission(toml, channel, "--store")
        assert code == 0, err
        for n in (1, 2, 3):
            assert f"node {n}: 1 setting(s) stored (1010h) and read back the same" in out
        sim.power_cycle()
        network = canopen.Network()
        network.connect(interface="virtual", channel=channel)
        try:
            node = network.add_node(2, canopen.ObjectDictionary())
            assert struct.unpack("<I", node.sdo.upload(0x607F, 0))[0] == 4321
            code, out, err = commission(toml, channel, "--restore-defaults", "--yes")
            assert code == 0, err
            assert "node 2: defaults restored (1011h) and reset" in out
            sim.power_cycle()
            assert struct.unpack("<I", node.sdo.upload(0x607F, 0))[0] != 4321
            assert sim.lss is not None  # the LSS node ids are no parameters: they stay
            assert sorted(n for _, n in sim.lss.node_ids()) == [1, 2, 3]
        finally:
            network.disconnect()


def test_sim_commissions_drives_of_its_own(tmp_path: Path) -> None:
    toml = robot_toml(tmp_path, {1: 71, 2: 72, 3: 73})
    code, out, err = run_main(["commission", str(toml), "--sim"])
    assert code == 0, err
    assert {s: r[3] for s, r in table_rows(out).items()} == {"71": "1", "72": "2", "73": "3"}
