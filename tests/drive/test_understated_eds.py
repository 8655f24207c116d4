"""Drives whose EDS marks the target velocity (or the position) not PDO-mappable.

Each way the mapping can end, through Chassis.open against the simulated base:
the drive accepts the mapping anyway; it refuses and runs on its own mapping; its
own mapping lacks the object too, and the object goes by SDO every cycle."""

from __future__ import annotations

import math
import re
import time
from collections.abc import Collection
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from omnican import WHEEL_EDS, Chassis, ChassisConfig
from omnican.cli import main
from omnican.plan.pdo import frame_bits
from omnican.sim import SimulatedBase
from tests.support.helpers import VENDOR_EDS, drive_for, sim_config, still, vendor_config, wait_for

TARGET, POSITION, CONTROLWORD, STATUSWORD = 0x60FF, 0x6064, 0x6040, 0x6041


def understated_eds(dest: Path, unmappable: Collection[int], drop: Collection[int] = (),
                    source: Path = WHEEL_EDS) -> Path:
    """A copy of ``source`` whose objects ``unmappable`` say PDOMapping=0 and whose
    default PDO mapping lacks the objects ``drop``."""
    out: list[str] = []
    index: int | None = None
    for line in source.read_text().splitlines():
        text = line.strip()
        if text.startswith("["):
            m = re.fullmatch(r"\[([0-9A-Fa-f]{4})(sub[0-9A-Fa-f]+)?\]", text)
            index = int(m.group(1), 16) if m else None
        mapping_param = index is not None and (0x1600 <= index < 0x1800 or
                                               0x1A00 <= index < 0x1C00)
        value = text.split("=", 1)[1] if "=" in text else ""
        if index in unmappable and text.startswith("PDOMapping="):
            out.append("PDOMapping=0")
        elif (mapping_param and text.startswith("DefaultValue=") and value.startswith("0x")
              and int(value, 16) >> 16 in drop):
            out.append("DefaultValue=0x00000000")
        else:
            out.append(line)
    dest.write_text("\n".join(out) + "\n")
    return dest


def with_eds(cfg: ChassisConfig, eds: Path, **chassis: Any) -> ChassisConfig:
    return replace(cfg, wheels=tuple(replace(w, eds=eds) for w in cfg.wheels),
                   chassis=replace(cfg.chassis, **chassis))


def drives_and_tracks_truth(sim: SimulatedBase, base: Chassis) -> None:
    assert base.status.enabled
    drive_for(base, 0.8, vx=0.3, wz=0.4)
    base.stop()
    assert wait_for(lambda: still(sim), 2.0)
    time.sleep(0.05)
    truth, pose = sim.true_pose, base.pose
    assert truth.x > 0.1 and truth.theta > 0.1
    assert pose.distance_to(truth) < 0.005
    assert pose.theta == pytest.approx(truth.theta, abs=0.005)


def sdo_frames(base: Chassis) -> int:
    return sum(n.sdo_counts.requests for n in base.nodes)


def test_drive_accepts_the_mapping_its_eds_denies(channel: str, tmp_path: Path) -> None:
    """(a) Tried by default and accepted: the plan runs as designed, no SDO per cycle."""
    eds = understated_eds(tmp_path / "understated.eds", {TARGET})
    cfg = with_eds(sim_config(channel), eds)
    with SimulatedBase.from_config(cfg, accept_unmappable=True) as sim, \
            Chassis.open(cfg) as base:
        assert any("marks Target velocity (0x60FF:00) not PDO-mappable; mapping anyway" in w
                   for w in base.status.warnings)
        assert not any("refuses" in w for w in base.status.warnings)
        for node in base.nodes:
            assert node.plan == node.layout.plan  # the designed plan, not the drive's own
            assert node.plan.find(node.axes[0].target, tx=False) is not None
        drives_and_tracks_truth(sim, base)
        assert sdo_frames(base) == 0


def test_drive_refuses_and_its_own_mapping_serves(channel: str, tmp_path: Path) -> None:
    """(b) The drive refuses 60FFh (abort 0x06040041); its own default mapping has it."""
    eds = understated_eds(tmp_path / "understated.eds", {TARGET})
    cfg = with_eds(sim_config(channel), eds)
    with SimulatedBase.from_config(cfg, accept_unmappable=False) as sim, \
            Chassis.open(cfg) as base:
        refusals = [w for w in base.status.warnings if "refuses remapping" in w]
        assert len(refusals) == 3
        assert "0x06040041 object cannot be mapped to the PDO" in refusals[0]
        for node in base.nodes:
            assert node.plan.notes == ("fixed mapping (drive refuses remapping)",)
            assert node.plan.sdo == ()
            pdo, _ = node.plan.find(node.axes[0].target, tx=False) or (None, 0)
            assert pdo is not None and pdo.cyclic
        drives_and_tracks_truth(sim, base)
        assert sdo_frames(base) == 0


@pytest.mark.parametrize("by_sdo", [{TARGET}, {TARGET, POSITION},
                                    {TARGET, POSITION, CONTROLWORD, STATUSWORD}],
                         ids=["target", "target+position", "no-pdo-at-all"])
def test_no_mapping_at_all_goes_by_sdo_every_cycle(channel: str, tmp_path: Path,
                                                     by_sdo: set[int]) -> None:
    """(c) Refused, and the drive's own mapping lacks the object: expedited SDO each
    cycle (the target written; the position, where it is unmappable too, read; a
    controlword written every cycle, as on a PDO; a statusword read every cycle)."""
    eds = understated_eds(tmp_path / "understated.eds", by_sdo, drop=by_sdo)
    cfg = with_eds(sim_config(channel), eds)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        for node in base.nodes:
            assert {t.entry.index for t in node.plan.sdo} == by_sdo
            assert node.plan.find(node.axes[0].target, tx=False) is None
        assert any("by expedited SDO every cycle" in w for w in base.status.warnings)
        before = [n.sdo_counts.requests for n in base.nodes]
        cycles0 = base.status.cycles
        drives_and_tracks_truth(sim, base)
        cycles = base.status.cycles - cycles0  # what the loop ran, however loaded the host
        for node, n0 in zip(base.nodes, before, strict=True):
            counts = node.sdo_counts
            # About one request per object per cycle the loop ran, each answered (a few
            # may be on their way), none aborted.
            assert counts.requests - n0 >= 0.5 * len(by_sdo - {CONTROLWORD}) * cycles
            assert counts.answers >= counts.requests - 3 * len(by_sdo)
            assert counts.aborts == 0
        # The bus budget counts the SDO frames (270 bits per object per cycle) instead of
        # the cyclic PDOs they replace: the TPDO (95), the drive's own RPDO1 with the
        # controlword, every cycle (75).
        assert base.cycle_bits() == 55 + 3 * (95 * (POSITION not in by_sdo) +
                                              75 * (CONTROLWORD not in by_sdo) +
                                              270 * len(by_sdo))


def test_sdo_path_survives_a_reboot(channel: str, tmp_path: Path) -> None:
    """Configuration SDOs after a reboot work while the other nodes' SDO cycle runs,
    and the rebooted node comes back on the SDO path."""
    eds = understated_eds(tmp_path / "understated.eds", {TARGET, POSITION},
                          drop={TARGET, POSITION})
    cfg = with_eds(sim_config(channel), eds)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        drive_for(base, 0.3, vx=0.2)
        sim.drives[1].reboot()
        assert wait_for(lambda: base.status.stopped_reason == "node 2 rebooted", 1.0)
        assert wait_for(lambda: still(sim), 2.0)
        base.recover()
        assert {t.entry.index for t in base.nodes[1].plan.sdo} == {TARGET, POSITION}
        sim.reset_truth(base.pose)
        drives_and_tracks_truth(sim, base)


def test_eds_policy_goes_straight_to_sdo(channel: str, tmp_path: Path) -> None:
    """pdo_mapping = "eds": the EDS is believed; nothing is tried, nothing refused."""
    eds = understated_eds(tmp_path / "understated.eds", {TARGET})  # default mapping has it
    cfg = with_eds(sim_config(channel), eds, pdo_mapping="eds")
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        assert not any("refuses" in w or "mapping anyway" in w for w in base.status.warnings)
        assert all({t.entry.index for t in n.plan.sdo} == {TARGET} for n in base.nodes)
        drives_and_tracks_truth(sim, base)
        assert sdo_frames(base) > 0


def test_two_axes_of_one_node_by_sdo(channel: str) -> None:
    """pdo_mapping = "sdo" on the ZLAC8015D: both sub-indexed targets and positions of one
    node by SDO, four requests to the same node in one cycle."""
    cfg = vendor_config(channel, "zlac", pdo_mapping="sdo")
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        assert len(base.nodes[0].plan.sdo) == 4
        drives_and_tracks_truth(sim, base)
        assert base.nodes[0].sdo_counts.aborts == 0


def test_check_config_shows_the_sdo_load_and_highest_rate(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    eds = understated_eds(tmp_path / "understated.eds", {TARGET}, drop={TARGET})
    example = (Path(__file__).resolve().parents[2] / "examples" / "robot.toml").read_text()
    toml = tmp_path / "robot.toml"
    toml.write_text(example.replace("[[wheel]]", f'[[wheel]]\neds = "{eds}"'))
    assert main(["check-config", str(toml)]) == 0
    out = capsys.readouterr().out
    assert 'Target velocity (0x60FF:00) is not PDO-mappable in its EDS: mapped anyway' in out
    assert ("if the drive refuses: SDO every cycle: Target velocity (0x60FF:00) written by "
            "expedited SDO (request + answer, 270 bits)") in out
    # 3 x (RPDO 115, target and controlword, + TPDO 95) + SYNC 55 = 685 bits mapped; if
    # refused, the target by SDO (270) and the controlword on an RPDO of its own (75):
    # 3 x (270 + 75 + 95) + 55 = 1375.
    assert "685 worst-case bits per cycle" in out
    assert re.search(r"if the drives refuse .*: 1375 worst-case bits per cycle; bus load 28% at "
                     r"500 kbit/s, highest rate within 80 %: (\d+) Hz", out)
    toml.write_text(toml.read_text().replace("[chassis]", '[chassis]\npdo_mapping = "eds"'))
    assert main(["check-config", str(toml)]) == 0
    out = capsys.readouterr().out
    assert "1375 worst-case bits per cycle" in out
    m = re.search(r"SDO every cycle: 810 of those bits per cycle; bus load 28% at 500 kbit/s, "
                  r"highest rate within 80 %: (\d+) Hz", out)
    assert m is not None
    # 80 % of 500 kbit/s less the heartbeats (host + 3 nodes every 100 ms), over 1375 bits.
    assert int(m.group(1)) == math.floor((0.8 * 500_000 - 4 * frame_bits(1) / 0.1) / 1375)


def test_vendor_eds_understating_its_target(channel: str, tmp_path: Path) -> None:
    """The same with a real vendor file (EPOS4, CRLF): tried, accepted, drives."""
    eds = understated_eds(tmp_path / "epos4.eds", {TARGET}, source=VENDOR_EDS / "maxon_epos4.eds")
    cfg = with_eds(vendor_config(channel, "epos4"), eds)
    with SimulatedBase.from_config(cfg, accept_unmappable=True) as sim, \
            Chassis.open(cfg) as base:
        assert any("mapping anyway" in w for w in base.status.warnings)
        drives_and_tracks_truth(sim, base)


def test_a_drive_refusing_its_per_cycle_target_stops_the_base(channel: str,
                                                              tmp_path: Path) -> None:
    """Targets written by SDO that the drive aborts leave its wheel at the last target it
    took: the base stops, saying which node and why."""
    from canopen.sdo.exceptions import SdoAbortedError

    eds = understated_eds(tmp_path / "understated.eds", {TARGET}, drop={TARGET})
    cfg = with_eds(sim_config(channel), eds)
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg) as base:
        drive_for(base, 0.3, vx=0.2)
        drive = sim.drives[2]

        def refuse(value: int) -> None:
            raise SdoAbortedError(0x08000022)  # not in the present device state

        with drive.lock:
            drive._writers[(TARGET, 0)] = refuse
        assert wait_for(lambda: (base.status.stopped_reason or "").startswith(
            "node 3 refuses its per-cycle SDO transfers"), 1.0), base.status
        assert "0x08000022" in (base.status.stopped_reason or "")
