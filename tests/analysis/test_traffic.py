"""Bus traffic counting and DBC decoding (omnican.analysis.traffic), without the monitor command."""

from __future__ import annotations

import time

import can
import cantools
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican.analysis.traffic import (
    DEFAULT_DBC,
    TrafficCounter,
    decode,
    listening,
    load_dbc,
)
from omnican.plan.pdo import frame_bits


def test_decode_names_choices_and_words() -> None:
    db = load_dbc(DEFAULT_DBC)
    assert decode(db, 0x182, False, bytes([0x37, 0x06, 0x03, 0x00, 0x00])) == (
        "TPDO1_node2",
        "Statusword=0x0637 OPERATION ENABLED  ModeDisplay=profile velocity  "
        "ErrorCode=no error")
    assert decode(db, 0x203, False, (-1234).to_bytes(4, "little", signed=True) +
                  bytes([0x0F, 0x00])) == (
        "RPDO1_node3", "TargetVelocity=-1234 inc/s  Controlword=0x000F enable operation")
    assert decode(db, 0x080, False, b"") == ("SYNC", "")
    assert decode(db, 0x601, False, b"\x40\x41\x60\x00") == ("", "40 41 60 00")
    assert decode(db, 0x080, True, b"") == ("", "(no data)")  # extended: not the SYNC


def test_the_bundled_dbc_loads() -> None:
    db = load_dbc(DEFAULT_DBC)
    assert isinstance(db, cantools.database.can.Database)
    assert db.get_message_by_name("RPDO1_node2").frame_id == 0x202


frames = st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=60)


@given(frames)
def test_counts_and_bits_add_up(sent: list[tuple[int, bytes]]) -> None:
    counter = TrafficCounter(db=None, bitrate=500_000, window_s=60.0)
    for can_id, data in sent:
        counter.on_message_received(can.Message(arbitration_id=can_id, data=data,
                                                is_extended_id=False))
    snap = counter.snapshot()
    assert snap.frames == len(sent)
    assert sum(r.count for r in snap.rows) == len(sent)
    assert [r.can_id for r in snap.rows] == sorted({c for c, _ in sent})
    bits = sum(frame_bits(len(d)) for _, d in sent)
    assert snap.window_bits_per_s == pytest.approx(bits / snap.window_s, rel=1e-6)
    assert snap.load == pytest.approx(snap.window_bits_per_s / 500_000)
    for row in snap.rows:  # the last frame of each id, named after CANopen when no DBC
        last = [d for c, d in sent if c == row.can_id][-1]
        assert row.signals == (last.hex(" ").upper() if last else "(no data)")
        assert not row.known


def test_the_load_is_unknown_without_a_bitrate() -> None:
    counter = TrafficCounter()
    counter.on_message_received(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
    snap = counter.snapshot()
    assert snap.load is None and snap.rows[0].name == "SYNC"


def test_listening_hears_a_bus(channel: str) -> None:
    counter = TrafficCounter(load_dbc(DEFAULT_DBC))
    with can.Bus(interface="virtual", channel=channel) as sender, \
            listening({"interface": "virtual", "channel": channel}, counter):
        for _ in range(5):
            sender.send(can.Message(arbitration_id=0x201, data=b"\x0f\x00", is_extended_id=False))
        deadline = time.monotonic() + 2.0
        while counter.snapshot().frames < 5 and time.monotonic() < deadline:
            time.sleep(0.01)
    [row] = counter.snapshot().rows
    assert (row.id_text, row.name, row.count, row.known) == ("0x201", "RPDO1_node1", 5, True)
