"""Scanning a bus for CANopen nodes and checking them against the config."""

from __future__ import annotations

from dataclasses import replace

from omnican.analysis.scan import FoundNode, check, flags, scan
from omnican.plan.node import node_layouts
from omnican.sim import SimulatedBase
from tests.support.helpers import sim_config


def test_scan_finds_the_simulated_drives(channel: str) -> None:
    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg):
        found = scan(cfg, listen_s=0.2, sdo_timeout_s=0.2)
    assert [f.node_id for f in found] == [1, 2, 3]
    for f in found:
        assert f.device_type == 0x00020192
        assert f.identity[1] == 0x402  # the bundled EDS's product number
        assert {2, 3, 9} <= f.supported_modes
    report = check(found, node_layouts(cfg))
    assert report.ok and report.missing == () and all(f.flags == () for f in report.found)


def test_scan_reads_what_configured_nodes_report(channel: str) -> None:
    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg) as sim:
        sim.set_battery(22.5)
        found = scan(cfg, listen_s=0.2, sdo_timeout_s=0.2, layouts=node_layouts(cfg))
    assert [(f.voltage_v, f.temperature_c, f.error_register) for f in found] == [
        (22.5, 25.0, 0)] * 3


def test_check_flags_what_disagrees(channel: str) -> None:
    cfg = sim_config(channel)
    layouts = node_layouts(cfg)
    good = FoundNode(1, device_type=0x00020192, identity=(0, 0x402, 0x10000, 0), modes=0b1_0000_0110)
    assert flags(good, layouts[0]) == ()
    assert flags(good, None) == ("not in the config",)
    assert flags(replace(good, device_type=0x191), layouts[0]) == (
        "device profile 401, not CiA 402",)
    assert flags(replace(good, identity=(0, 0x999, 0, 0)), layouts[0]) == (
        "product 0x00000999, EDS says 0x00000402",)
    assert flags(replace(good, modes=0b1), layouts[0]) == ("does not offer pv mode",)
    report = check([good, replace(good, node_id=9)], layouts)
    assert report.missing == (2, 3) and not report.ok
    # A stranger on the bus is flagged, but only configured nodes make the check fail.
    report = check([replace(good, node_id=n) for n in (1, 2, 3, 9)], layouts)
    assert report.found[-1].flags == ("not in the config",) and report.ok


def test_scan_reports_two_devices_answering_as_one_node(channel: str) -> None:
    import canopen

    from omnican.sim import SimulatedDrive

    cfg = sim_config(channel)
    with SimulatedBase.from_config(cfg):
        net = canopen.Network()
        net.connect(interface="virtual", channel=channel)
        twin = SimulatedDrive(net, 3)  # a second drive with node 3's settings
        try:
            found = scan(cfg, listen_s=0.2, sdo_timeout_s=0.2)
        finally:
            twin.close()
            net.disconnect()
    by_id = {f.node_id: f for f in found}
    assert by_id[3].answers == 2 and by_id[1].answers == 1
    report = check(found, node_layouts(cfg))
    assert not report.ok
    (three,) = [f for f in report.found if f.node_id == 3]
    assert any("2 devices answer as node 3" in flag for flag in three.flags), three.flags
