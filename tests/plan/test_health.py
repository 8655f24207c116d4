"""Which health objects each drive has and how they are read (omnican.plan.health), and
the vendor settings checked against the EDS (omnican.plan.vendor): pure, from EDS files."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import WHEEL_EDS, default_config
from omnican.cli import main
from omnican.config import EstopSettings, SdoWrite
from omnican.errors import ConfigError
from omnican.plan.health import find_object, node_reads, plan_health
from omnican.plan.node import node_layouts
from omnican.plan.pdo import pdo_slots
from omnican.plan.vendor import resolve
from omnican.protocol.object_map import load_dictionary
from tests.support.helpers import VENDOR_EDS, one_error_line, vendor_config

ZLAC, EPOS4, ROBOTEQ = (load_dictionary(VENDOR_EDS / name) for name in
                        ("zlac8015d.eds", "maxon_epos4.eds", "roboteq_v80_21.eds"))
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_the_demo_base_reads_its_health_in_two_tpdos_every_tenth_sync() -> None:
    for layout in node_layouts(default_config()):
        plan = layout.health
        assert [p.number for p in plan.pdos] == [3, 4]
        assert all(p.trans_type == 20 for p in plan.pdos)  # 100 Hz loop, 5 Hz reads
        assert [e.index for e in plan.pdos[0].entries] == [0x6078, 0x6077, 0x6079]
        assert [e.index for e in plan.pdos[1].entries] == [0x2100, 0x1001, 0x60FD]
        assert plan.sdo == ()
        assert 3 not in layout.plan.unused_tpdos  # so they are not disabled
        # Two frames of 8 and 7 bytes, 5 times a second.
        assert plan.bits_per_s(100.0) == pytest.approx(5 * (135 + 125))


@pytest.mark.parametrize("rate", [50.0, 100.0, 1000.0, 5000.0])
def test_the_health_tpdos_go_at_the_health_rate_whatever_the_loop_rate(rate: float) -> None:
    cfg = default_config()
    cfg = replace(cfg, chassis=replace(cfg.chassis, rate_hz=rate))
    plan = node_layouts(cfg)[0].health
    assert all(p.trans_type == min(240, round(rate / 5.0)) for p in plan.pdos)


def test_objects_by_address_per_axis_and_by_name() -> None:
    assert find_object(ZLAC, "0x6077", 1).address == "0x6077:02"  # the axis's sub-index
    assert find_object(ZLAC, "0x2032", 0).address == "0x2032:01"  # a vendor array too
    assert find_object(ZLAC, "0x2035", 1).address == "0x2035:00"  # one per node
    assert find_object(ROBOTEQ, "0x6077", 1).address == "0x6877:00"  # CiA 402-2 offset
    assert find_object(ZLAC, "Right Motor Temperature", 0).address == "0x2032:02"
    assert find_object(EPOS4, "power supply voltage", 0).address == "0x2200:01"
    with pytest.raises(ConfigError, match=r"no object named 'Motor Temprature'.*did you mean"):
        find_object(ZLAC, "Motor Temprature", 0)
    with pytest.raises(ConfigError, match="no object 0x9999"):
        find_object(ZLAC, "0x9999", 0)


def test_vendor_drives_read_what_their_eds_lets_them_map_and_the_rest_by_sdo() -> None:
    cfg = vendor_config("c", "epos4")
    cfg = replace(cfg, wheels=tuple(replace(w, current="0x30D1:02", current_scale=0.001,
                                            voltage="0x2200:01", voltage_scale=0.1,
                                            temperature="0x3201:01", temperature_scale=0.1)
                                    for w in cfg.wheels))
    plan = node_layouts(cfg)[0].health
    mapped = {e.address for p in plan.pdos for e in p.entries}
    assert {"0x30D1:02", "0x6077:00"} <= mapped  # PDO-mappable in the EPOS4's EDS
    assert [r.entry.address for r in plan.sdo] == ["0x2200:01", "0x3201:01", "0x1001:00"]
    assert plan.pdos[0].event_timer_ms is None  # its EDS has no event timer: every n-th SYNC


def test_a_standard_object_the_drive_lacks_is_left_out_a_named_one_is_an_error() -> None:
    cfg = vendor_config("c", "zlac")  # no 6078h, no 6079h on the ZLAC8015D
    reads = node_layouts(cfg)[0].health.reads
    assert {r.quantity for r in reads} == {"torque", "error_register"}
    bad = replace(cfg, wheels=(replace(cfg.wheels[0], temperature="0x2099"), *cfg.wheels[1:]))
    with pytest.raises(ConfigError, match=r"node 1: EDS zlac8015d\.eds: temperature: the EDS has "
                                          r"no object 0x2099"):
        node_layouts(bad)
    no_scale = replace(cfg, wheels=(replace(cfg.wheels[0], current="0x6077:01"),
                                    *cfg.wheels[1:]))
    with pytest.raises(ConfigError, match="give current_scale"):
        node_layouts(no_scale)


def test_the_estop_reads_an_input_or_nothing_for_a_statusword_bit() -> None:
    cfg = replace(default_config(), estop=EstopSettings(bit=3, node_id=2))
    layouts = node_layouts(cfg)
    assert [any(r.quantity == "estop" for r in lay.health.reads) for lay in layouts] == \
        [False, True, False]
    sto = replace(default_config(), estop=EstopSettings(bit=14, object="0x6041"))
    assert not any(r.quantity == "estop" for lay in node_layouts(sto) for r in lay.health.reads)
    with pytest.raises(ConfigError, match=r"estop\.bit: Digital inputs .* has 32 bits, no bit 40"):
        node_layouts(replace(default_config(), estop=EstopSettings(bit=40)))


@given(spare=st.integers(0, 4), rate=st.sampled_from([100.0, 1000.0]))
def test_every_read_goes_once_by_pdo_or_sdo_within_the_drives_limits(spare: int,
                                                                      rate: float) -> None:
    d = load_dictionary(WHEEL_EDS)
    wheel = default_config().wheels[0]
    reads = node_reads(d, 1, [(0, wheel)], EstopSettings(bit=16))
    slots = pdo_slots(d, 1, tx=True)[4 - spare:] if spare else []
    plan = plan_health(1, d, reads, slots, rate, 10.0)
    in_pdos = [(e.index, e.subindex) for p in plan.pdos for e in p.entries]
    by_sdo = [r.key for r in plan.sdo]
    assert len(in_pdos) == len(set(in_pdos)) and not set(in_pdos) & set(by_sdo)
    for r in reads:
        assert r.key in in_pdos or r.key in by_sdo or r.pdo_only
    for p in plan.pdos:
        assert sum(e.bits for e in p.entries) <= 64 and p.number in {s.number for s in slots}


# ---------------------------------------------------------------- [[wheel.sdo]]


def test_vendor_settings_are_checked_against_the_eds() -> None:
    ok = resolve(ZLAC, SdoWrite("0x2000:00", 500), 0, "wheel[0].sdo[0]")
    assert ok.data == (500).to_bytes(2, "little")
    assert ok.describe() == "Offline Communication Parameter (0x2000:00) = 500 (wheel[0].sdo[0])"
    by_name = resolve(ZLAC, SdoWrite("Offline Communication Parameter", 7, "u16"), 0, "w")
    assert by_name.entry.address == "0x2000:00"
    cases = [
        (SdoWrite("0x2999:00", 1), "wheel[0].sdo[0].object: the EDS has no object"),
        (SdoWrite("0x2031:00", 1), "Software Version (0x2031:00) is not writable"),
        (SdoWrite("0x2000:00", 1, "u32"), "type u32 does not match the EDS's UNSIGNED16"),
        (SdoWrite("0x2000:00", 70000), "70000 is out of range 0-65535"),
        (SdoWrite("0x2001:00", 200), "200 is out of range 0-127"),  # the EDS's limits
        (SdoWrite("0x2000:00", 1.5), "is an integer, got 1.5"),
    ]
    for setting, message in cases:
        with pytest.raises(ConfigError) as err:
            resolve(ZLAC, setting, 0, "wheel[0].sdo[0]")
        assert message in str(err.value)


def test_check_config_names_a_bad_vendor_setting_in_one_line(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]
                                                             ) -> None:
    text = (EXAMPLES / "zlac8015d.toml").read_text().replace(
        "value = 500\n", "value = 70000\n", 1).replace('"eds/', f'"{EXAMPLES}/eds/')
    bad = tmp_path / "zlac.toml"
    bad.write_text(text)
    assert main(["check-config", str(bad)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "node 1: EDS zlac8015d.eds: wheel[0].sdo[0]: Offline Communication Parameter " \
           "(0x2000:00): 70000 is out of range 0-65535" in line


def test_check_config_prints_the_reads_the_estop_and_the_settings(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-config", str(EXAMPLES / "zlac8015d.toml")]) == 0
    out = capsys.readouterr().out
    assert ("wheel 0 reports: current 0x6077:01 x 0.1 A, voltage 0x2035:00 x 0.01 V, "
            "temperature 0x2032:01 x 0.1 degC") in out
    assert ("health by expedited SDO, one every 67 ms round robin (5 Hz each): Left Motor "
            "Temperature (0x2032:01), Right Motor Temperature (0x2032:02), Error Register "
            "(0x1001:00)") in out
    assert "vendor setting in PRE-OPERATIONAL: Offline Communication Parameter (0x2000:00) = " \
           "500 (wheel[0].sdo[0])" in out
    assert "health reads (5 Hz): 7.90 kbit/s of that, 1.58% of 500 kbit/s" in out
