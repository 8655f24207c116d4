"""The controlword every cycle (issue 36, item 4), end to end in lock-step against drives
that act on a controlword only as one arrives (ros2_canopen's fake CiA 402 slave, and
some real drives): in OPERATION ENABLED their motors start only at a controlword that
arrives there. Written only when it changes, the controlword that enabled the drive is
the last one it gets: enabled, it takes every target and never moves. Written every
cycle (the default), on the cyclic RPDO beside the targets, on a second cyclic RPDO for
a drive with one mapping entry per PDO or two controlwords, on the drive's own PDO for a
drive that refuses remapping, and by SDO where nothing else carries it."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import can
import pytest

from omnican import WHEEL_EDS, Chassis, ChassisConfig
from omnican.clock import SimClock
from omnican.protocol import cia402
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from tests.drive.test_understated_eds import CONTROLWORD, understated_eds, with_eds
from tests.plan.test_pdo import single_entry_eds
from tests.support.helpers import drive_for, sim_config, still, vendor_config, wait_for

ENABLE_OPERATION = 0x000F


def _config(kind: str, channel: str, tmp_path: Path, **chassis: object) -> ChassisConfig:
    if kind in ("zlac", "roboteq", "epos4"):
        return vendor_config(channel, kind, **chassis)
    cfg = sim_config(channel, **chassis)
    if kind == "single-entry":
        return with_eds(cfg, single_entry_eds(tmp_path / "single.eds"))
    if kind == "controlword-by-sdo":  # refused, and its own mapping lacks the controlword
        return with_eds(cfg, understated_eds(tmp_path / "no-cw.eds", {CONTROLWORD},
                                             drop={CONTROLWORD}))
    return cfg


@pytest.fixture
def clock() -> Iterator[SimClock]:
    yield SimClock()


@pytest.mark.parametrize(("kind", "options"), [
    ("bundled", {}), ("zlac", {}), ("roboteq", {}), ("epos4", {}), ("single-entry", {}),
    ("bundled", {"remappable": False}), ("controlword-by-sdo", {})],
    ids=["bundled", "zlac8015d", "roboteq", "epos4", "single-entry", "refuses-remapping",
         "controlword-by-sdo"])
def test_drives_acting_on_arrival_move(channel: str, tmp_path: Path, clock: SimClock,
                                       kind: str, options: dict[str, object]) -> None:
    cfg = _config(kind, channel, tmp_path)
    with SimulatedBase.from_config(cfg, clock=clock, **options) as sim:
        for drive in sim.drives:
            drive.act_on_arrival()
        with Chassis.open(cfg, clock=clock) as base:
            drive_for(base, 1.0, vx=0.2, wz=0.3)
            assert base.status.stopped_reason is None, base.status
            if options:  # its own mapping: RPDO1 the controlword, RPDO2 the target
                assert any("refuses remapping" in w for w in base.status.warnings)
                assert all(r.cyclic for r in base.nodes[0].plan.rpdos)
            assert sim.true_pose.x > 0.1
            assert all(stage.running for d in sim.drives for stage in d.stages)
            base.stop()
            assert wait_for(lambda: still(sim), 2.0, clock=clock)


def test_on_change_leaves_such_a_drive_enabled_and_still(channel: str, tmp_path: Path,
                                                         clock: SimClock) -> None:
    """cyclic_controlword = false (for a drive that dislikes the repeat): the controlword
    goes on an RPDO of its own, when it changes; a drive acting on arrival then never
    moves, and the base says which wheel does not follow."""
    cfg = _config("bundled", channel, tmp_path, cyclic_controlword=False)
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        for drive in sim.drives:
            drive.act_on_arrival()
        with Chassis.open(cfg, clock=clock) as base:
            assert [[e.address for e in r.entries] for r in base.nodes[0].plan.rpdos] == [
                ["0x6040:00"], ["0x60FF:00"]]
            assert not base.nodes[0].plan.rpdos[0].cyclic
            assert base.status.enabled
            drive_for(base, 1.0, vx=0.2)
            assert "wheel 1 (node 2) not following its target" in (
                base.status.stopped_reason or "")
            assert sim.true_pose.x == 0.0


def _controlwords(log: Path, cob_id: int, since: float) -> list[int]:
    """The controlword of every RPDO ``cob_id`` sent after ``since`` (wall-clock time;
    its bytes 4-5: target, then controlword)."""
    return [int.from_bytes(m.data[4:6], "little") for m in can.LogReader(str(log))
            if m.arbitration_id == cob_id and not m.is_rx and m.timestamp > since]


def test_every_cycle_carries_the_controlword_with_its_halt_and_mode_bits(
        channel: str, tmp_path: Path, clock: SimClock) -> None:
    """One RPDO a cycle per node, each with the controlword as the stage driver holds it:
    enable operation, the halt bit (8) when set, never a clobbered word."""
    cfg = sim_config(channel)
    log = tmp_path / "run.log"
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock, record=FileRecording(log)) as base:
        drive_for(base, 0.3, vx=0.2)
        t0 = clock.wall()
        drive_for(base, 0.5, vx=0.2)
        stage = base.nodes[1].stages[0]
        stage.set_halt(True)  # an operator's halt: the wheel ramps down in pv
        t1 = clock.wall()
        drive_for(base, 0.5, vx=0.2)
        assert sim.drives[1].stages[0].halted
        assert abs(sim.drives[1].velocity_counts()) < 1.0
        stage.set_halt(False)
        t2 = clock.wall()
        drive_for(base, 0.5, vx=0.2)
        assert not sim.drives[1].stages[0].halted
        cycles = round(0.5 * cfg.chassis.rate_hz)
    before, halted, after = (_controlwords(log, 0x202, t) for t in (t0, t1, t2))
    enabled, halt = ENABLE_OPERATION, ENABLE_OPERATION | cia402.CW_HALT
    assert len(before) >= 3 * cycles - 3  # every cycle
    assert before[:cycles - 1] == [enabled] * (cycles - 1)
    assert halted[:cycles - 1] == [halt] * (cycles - 1)
    assert after[:cycles - 1] == [enabled] * (cycles - 1)


def test_the_switch_is_a_config_key(tmp_path: Path) -> None:
    from omnican import load_config

    toml = tmp_path / "robot.toml"
    toml.write_text('[chassis]\nlayout = "b21"\nbase_radius = 0.19\ncyclic_controlword = false\n'
                    + "".join(f"[[wheel]]\nnode_id = {n}\nvelocity_scale = 1000.0\n"
                              "position_scale = 10000.0\n" for n in (1, 2, 3)))
    assert load_config(toml).chassis.cyclic_controlword is False
    assert replace(load_config(toml).chassis, cyclic_controlword=True).cyclic_controlword
    toml.write_text(toml.read_text().replace("false", '"no"'))
    with pytest.raises(ValueError, match="cyclic_controlword"):
        load_config(toml)
    assert WHEEL_EDS.is_file()


def test_the_sim_console_makes_a_drive_act_on_arrival(channel: str, clock: SimClock) -> None:
    from omnican.sim.console import command

    with SimulatedBase.from_config(sim_config(channel), clock=clock) as sim:
        stage = sim.drives[1].stages[0]
        assert command(sim, "cwarrival 2 on") == "node 2: acts on a controlword only as one arrives"
        assert stage.on_arrival
        assert command(sim, "cwarrival 2 off") == "node 2: acts on the controlword it holds"
        assert not stage.on_arrival and stage.running
        assert command(sim, "cwarrival 2") == "error: cwarrival takes a node id and on or off"
        assert command(sim, "cwarrival 2 maybe") == (
            "error: cwarrival takes a node id and on or off")
