"""dbc/omnican.dbc: in step with the PDO plan of the bundled EDS, regenerable by
tools/gen_dbc.py, and usable by ``cantools decode`` on a ``drive --record`` log."""

from __future__ import annotations

import functools
import importlib.util
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import cantools
import pytest
from hypothesis import given, reject, settings
from hypothesis import strategies as st

from omnican import ConfigError, default_config
from omnican.cli import main
from omnican.plan.codec import PdoCodec
from omnican.plan.node import NodeLayout, node_layouts
from omnican.plan.pdo import MAPPING_POLICIES, PlannedPdo
from omnican.protocol.cia402 import Mode
from omnican.protocol.object_map import Obj
from tests.support.helpers import vendor_config

REPO = Path(__file__).resolve().parents[2]
DBC = REPO / "dbc" / "omnican.dbc"
BUNDLED_DBC = REPO / "omnican" / "dbc" / "omnican.dbc"


@pytest.fixture(scope="module")
def db() -> Any:
    return cantools.database.load_file(str(DBC))


def _gen_dbc() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gen_dbc", REPO / "tools" / "gen_dbc.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _planned() -> list[tuple[NodeLayout, str, PlannedPdo]]:
    out = []
    for layout in node_layouts(default_config()):
        out += [(layout, "RPDO", p) for p in layout.plan.rpdos]
        out += [(layout, "TPDO", p) for p in layout.plan.tpdos + layout.health.pdos]
    return out


def test_dbc_at_the_repo_root_is_the_bundled_one() -> None:
    assert DBC.resolve() == BUNDLED_DBC.resolve()
    assert BUNDLED_DBC.is_file()


def test_every_planned_pdo_of_nodes_1_to_3_is_in_the_dbc(db: Any) -> None:
    planned = _planned()
    assert {layout.node_id for layout, _, _ in planned} == {1, 2, 3}
    for layout, kind, pdo in planned:
        message = db.get_message_by_frame_id(pdo.cob_id)
        where = f"{kind}{pdo.number} of node {layout.node_id} (0x{pdo.cob_id:03X})"
        assert message.name == f"{kind}{pdo.number}_node{layout.node_id}", where
        assert message.length == pdo.data_bytes, where
        assert not message.is_extended_frame, where
        assert len(message.signals) == len(pdo.entries), where
        start = 0
        for signal, entry in zip(message.signals, pdo.entries, strict=True):
            what = f"{where}: {signal.name} for {entry.name} ({entry.address})"
            assert signal.start == start, what
            assert signal.length == entry.bits, what
            assert signal.is_signed == entry.signed, what
            assert signal.byte_order == "little_endian", what
            # raw values, but a vendor object the config gives a scale for (0x2100 in
            # 0.1 degC): in that unit
            scale = 0.1 if entry.index == 0x2100 else 1
            assert signal.scale == scale and signal.offset == 0, what
            start += entry.bits
        # 100 Hz SYNC: every SYNC 10 ms, the health TPDOs every 20th
        assert message.cycle_time == (10 * pdo.trans_type if pdo.cyclic else None), where


def test_the_dbc_has_no_pdo_the_plan_lacks(db: Any) -> None:
    planned = {pdo.cob_id for _, _, pdo in _planned()}
    in_dbc = {m.frame_id for m in db.messages if 0x180 <= m.frame_id < 0x580}
    assert in_dbc == planned


def test_pdo_signals_have_clear_names_and_units(db: Any) -> None:
    """The plan of the bundled EDS as the issue describes it, signal by signal."""
    expected = {
        # the controlword every cycle, beside the target (chassis.cyclic_controlword)
        0x200: ("RPDO1", [("TargetVelocity", 0, 32, True, "inc/s"),
                          ("Controlword", 32, 16, False, None)]),
        0x180: ("TPDO1", [("Statusword", 0, 16, False, None), ("ModeDisplay", 16, 8, True, None),
                          ("ErrorCode", 24, 16, False, None)]),
        0x280: ("TPDO2", [("PositionActual", 0, 32, True, "inc")]),
        0x380: ("TPDO3", [("CurrentActual", 0, 16, True, "permille"),
                          ("TorqueActual", 16, 16, True, "permille"),
                          ("DcLinkVoltage", 32, 32, False, "mV")]),
        0x480: ("TPDO4", [("MotorTemperature", 0, 16, True, "degC"),
                          ("ErrorRegister", 16, 8, False, None),
                          ("DigitalInputs", 24, 32, False, None)]),
    }
    for node in (1, 2, 3):
        for base, (kind, signals) in expected.items():
            message = db.get_message_by_frame_id(base + node)
            assert message.name == f"{kind}_node{node}"
            got = [(s.name, s.start, s.length, s.is_signed, s.unit or None)
                   for s in message.signals]
            assert got == signals, message.name
    mode = db.get_message_by_name("TPDO1_node1").get_signal_by_name("ModeDisplay")
    assert mode.choices[3] == "profile velocity"
    assert mode.choices[9] == "cyclic sync velocity"


def test_network_management_frames(db: Any) -> None:
    sync = db.get_message_by_frame_id(0x080)
    assert (sync.name, sync.length, sync.signals) == ("SYNC", 0, [])
    nmt = db.get_message_by_frame_id(0x000)
    assert nmt.name == "NMT"
    assert nmt.decode(bytes([0x01, 0x02])) == {"Command": "start", "NodeId": 2}
    for node, cob in ((1, 0x701), (2, 0x702), (3, 0x703), (None, 0x77F)):
        heartbeat = db.get_message_by_frame_id(cob)
        assert heartbeat.name == (f"Heartbeat_node{node}" if node else "Heartbeat_host")
        assert heartbeat.length == 1
        for raw, state in ((0, "boot-up"), (4, "stopped"), (5, "operational"),
                           (127, "pre-operational")):
            assert heartbeat.decode(bytes([raw]))["NmtState"] == state
    for node in (1, 2, 3):
        emcy = db.get_message_by_frame_id(0x80 + node)
        assert emcy.name == f"EMCY_node{node}"
        assert emcy.length == 8
        values = emcy.decode(bytes([0x10, 0x23, 0x01, 1, 2, 3, 4, 5]), decode_choices=False)
        assert values == {"ErrorCode": 0x2310, "ErrorRegister": 1,
                          "ManufacturerData": int.from_bytes(bytes([1, 2, 3, 4, 5]), "little")}


def _shape(database: Any) -> list[tuple[Any, ...]]:
    return sorted(
        (m.frame_id, m.name, m.length, tuple(m.senders), m.cycle_time,
         tuple((s.name, s.start, s.length, s.is_signed, s.byte_order, s.unit,
                tuple(sorted((int(k), str(v)) for k, v in (s.choices or {}).items())))
               for s in m.signals))
        for m in database.messages)


def test_the_dbc_is_what_tools_gen_dbc_generates(db: Any) -> None:
    gen = _gen_dbc()
    fresh = cantools.database.load_string(gen.dbc_text(), database_format="dbc")
    assert _shape(fresh) == _shape(db), "dbc/omnican.dbc is stale: run python tools/gen_dbc.py"


def test_gen_dbc_check_mode(tmp_path: Path) -> None:
    gen = _gen_dbc()
    out = tmp_path / "x.dbc"
    assert gen.main(["--check", "-o", str(out)]) == 1  # missing
    assert gen.main(["-o", str(out)]) == 0
    assert gen.main(["--check", "-o", str(out)]) == 0
    assert out.read_text().startswith('VERSION ""')


def test_signal_names_of_other_objects() -> None:
    from dataclasses import replace

    from omnican.plan.dbc import signal_name

    layout = node_layouts(default_config())[0]
    entry = layout.axes[0].objs[Obj.VELOCITY_ACTUAL]
    assert signal_name(entry) == "VelocityActual"
    assert signal_name(replace(entry, obj=None, name="Digital inputs (2)")) == "DigitalInputs2"


def test_a_vendor_config_gets_its_own_frames(tmp_path: Path) -> None:
    """omnican monitor --config decodes a ZLAC8015D's two-axis PDO under its own names."""
    from omnican import load_config
    from omnican.plan.dbc import build_database

    zlac = REPO / "examples" / "eds" / "zlac8015d.eds"
    cfg = tmp_path / "zlac.toml"
    cfg.write_text("[chassis]\nlayout = \"b21\"\nbase_radius = 0.2\n" + "".join(
        f'[[wheel]]\nnode_id = {n}\naxis = {a}\neds = "{zlac}"\nvelocity_scale = 100.0\n'
        "position_scale = 1000.0\n" for n, a in ((1, 0), (1, 1), (2, 0))))
    vendor = build_database(load_config(cfg))
    msg = vendor.get_message_by_frame_id(0x201)
    assert [s.name for s in msg.signals] == ["TargetVelocity", "TargetVelocity_60FFsub2"]
    assert msg.length == 8
    assert msg.decode(bytes.fromhex("e8030000" "18fcffff")) == {
        "TargetVelocity": 1000, "TargetVelocity_60FFsub2": -1000}


def test_cantools_decode_reads_a_drive_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                 ) -> None:
    log = tmp_path / "run.log"
    code = main(["drive", "--sim", "--fast", "--vx", "0.2", "--duration", "0.5",
                 "--record", str(log)])
    assert code == 0
    capsys.readouterr()
    text = log.read_text()
    # python-can's candump-format writer: "(time) channel ID#DATA R|T"
    assert re.search(r"^\(\d+\.\d+\) \S+ 202#[0-9A-F]{12} [RT]$", text, re.M), text[:500]
    result = subprocess.run(
        [sys.executable, "-m", "cantools", "decode", "--single-line", str(DBC)],
        input=text, capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    decoded = result.stdout.splitlines()
    assert len(decoded) == len(text.splitlines())
    assert any(line.endswith(":: SYNC()") for line in decoded)
    targets = [int(m.group(1)) for line in decoded
               if (m := re.search(r":: RPDO1_node2\(TargetVelocity: (-?\d+) inc/s, "
                                  r"Controlword: \d+\)", line))]
    assert targets and any(t != 0 for t in targets)
    # b21: the back wheel (node 1) does not turn when driving straight ahead
    node1 = [int(m.group(1)) for line in decoded
             if (m := re.search(r":: RPDO1_node1\(TargetVelocity: (-?\d+) inc/s, "
                                r"Controlword: \d+\)", line))]
    assert node1 and all(t == 0 for t in node1)
    assert any(re.search(r":: TPDO1_node1\(Statusword: \d+, ModeDisplay: profile velocity, "
                         r"ErrorCode: ", line) for line in decoded)
    assert any(re.search(r":: TPDO2_node3\(PositionActual: -?\d+ inc\)", line) for line in decoded)
    assert any(":: Heartbeat_node2(NmtState: operational)" in line for line in decoded)
    assert any(":: NMT(Command: " in line for line in decoded)
    # SDO frames are not in the DBC: cantools says so and goes on
    assert any(re.search(r" 601#\S+ T :: Unknown frame id 1537", line) for line in decoded)


def _check_message_is_the_codec(message: Any, codec: PdoCodec, values: list[int]) -> None:
    assert message.length == codec.length
    assert len(message.signals) == len(codec.fields)
    for signal, f in zip(message.signals, codec.fields, strict=True):
        where = f"{message.name}.{signal.name}"
        assert (signal.start, signal.length, signal.is_signed) == \
            (f.start_bit, f.bits, f.signed), where
        assert (signal.minimum, signal.maximum) == pytest.approx(
            (f.lo * signal.scale, f.hi * signal.scale)), where
        assert signal.byte_order == "little_endian", where
    packed = codec.pack(values)
    by_name = {s.name: v for s, v in zip(message.signals, values, strict=True)}
    assert message.encode(by_name, scaling=False) == packed
    assert message.decode(packed, decode_choices=False, scaling=False) == by_name


@functools.cache
def _vendor_database(kind: str, mapping: str, mode: str) -> tuple[list[NodeLayout], Any]:
    from dataclasses import replace

    from omnican.config import check_eds_files
    from omnican.plan.dbc import build_database

    cfg = vendor_config("unused", kind, pdo_mapping=mapping)
    cfg = replace(cfg, wheels=tuple(replace(w, mode=Mode.from_name(mode)) for w in cfg.wheels))
    check_eds_files(cfg)  # ConfigError: the drive lacks that mode's objects
    return node_layouts(cfg), build_database(cfg)


@settings(max_examples=60, deadline=None)
@given(kind=st.sampled_from(["bundled", "zlac", "roboteq", "epos4"]),
       mapping=st.sampled_from(MAPPING_POLICIES), mode=st.sampled_from(["pv", "csv", "vl"]),
       data=st.data())
def test_dbc_signals_are_the_codecs_fields(kind: str, mapping: str, mode: str,
                                            data: st.DataObject) -> None:
    """For the bundled and the vendor drives' plans, every PDO's DBC message has the
    codec's length and one signal per field at its place, size, sign and range; cantools
    encodes what the codec packs and decodes it back to the same values."""
    try:
        layouts, db = _vendor_database(kind, mapping, mode)
    except ConfigError:
        reject()  # a drive without that mode
    pdos = [pdo for layout in layouts
            for pdo in (*layout.plan.rpdos, *layout.plan.tpdos, *layout.health.pdos)]
    assert {m.frame_id for m in db.messages if 0x180 <= m.frame_id < 0x580} == \
        {pdo.cob_id for pdo in pdos}
    for pdo in pdos:
        codec = PdoCodec(pdo)
        _check_message_is_the_codec(db.get_message_by_frame_id(codec.cob_id), codec,
                                    [data.draw(st.integers(lo, hi)) for lo, hi in codec.ranges])


@given(fields=st.lists(st.tuples(st.sampled_from([8, 16, 24, 32]), st.booleans(), st.booleans()),
                       min_size=1, max_size=4).filter(lambda fs: sum(b for b, _, _ in fs) <= 64),
       tx=st.booleans(), data=st.data())
def test_any_pdos_message_is_its_codec(fields: list[tuple[int, bool, bool]], tx: bool,
                                       data: st.DataObject) -> None:
    """Any mapping, objects of 24 bits and signed quantities the EDS declares unsigned
    included: the message is laid out and signed as the codec packs."""
    from types import SimpleNamespace

    from omnican.plan.dbc import pdo_message
    from omnican.protocol.object_map import Entry

    entries = tuple(Entry(obj=None, index=0x2000 + i, subindex=0, bits=bits, signed=signed,
                          declared_signed=declared, shared=False, pdo_mappable=True,
                          writable=True, name=f"Field {i}")
                    for i, (bits, signed, declared) in enumerate(fields))
    pdo = PlannedPdo(number=1, cob_id=0x181 if tx else 0x201, trans_type=1, entries=entries)
    codec = PdoCodec(pdo)
    message = pdo_message(SimpleNamespace(node_id=1), pdo, tx, 100.0)  # type: ignore[arg-type]
    _check_message_is_the_codec(message, codec,
                                [data.draw(st.integers(lo, hi)) for lo, hi in codec.ranges])


def test_a_motor_temperature_reads_in_degrees(db: Any) -> None:
    """Issue 31 item 17: the DBC and monitor showed MotorTemperature=250 for 25.0 degC
    (0x2100 counts 0.1 degC, as the demo config says)."""
    message = db.get_message_by_frame_id(0x481)
    raw = (250).to_bytes(2, "little", signed=True) + bytes(message.length - 2)
    decoded = message.decode(raw, decode_choices=False)
    assert decoded["MotorTemperature"] == pytest.approx(25.0)
    assert message.get_signal_by_name("MotorTemperature").unit == "degC"
