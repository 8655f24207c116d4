"""The simulated drives' LSS slave (CiA 305) and what they keep across a power cycle
(1010h/1011h, the LSS store), issue 38 item 4.

The slave's protocol is pure (:class:`omnican.sim.lss.LssSlave`): property tests drive it
with a fast scan done bit by bit as CiA 305 has a master do it. The drives are checked on
the wire with python canopen's own LSS master and SDO client."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import replace

import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican.sim import SimulatedBase
from omnican.sim.lss import CS_FAST_SCAN, CS_IDENTIFY_SLAVE, LssSlave, LssState
from omnican.sim.memory import UNCONFIGURED, NonVolatile
from tests.support.helpers import sim_config, wait_for

u32 = st.integers(0, 0xFFFFFFFF)
identities = st.tuples(u32, u32, u32, u32)


def _scan_frame(number: int, checked: int, sub: int, nxt: int) -> bytes:
    return struct.pack("<BIBBBx", CS_FAST_SCAN, number, checked, sub, nxt)


def fast_scan(slaves: list[LssSlave]) -> tuple[int, int, int, int] | None:
    """CiA 305's fast scan, as python canopen's LssMaster.fast_scan sends it: the address
    found (every slave that answers a step is one that matched), None when none answers."""

    def ask(frame: bytes) -> bool:
        answers = [s.handle(frame).frame for s in slaves]
        return any(a is not None and a[0] == CS_IDENTIFY_SLAVE for a in answers)

    if not ask(_scan_frame(0, 0x80, 0, 0)):
        return None
    found = [0, 0, 0, 0]
    nxt = 0
    for sub in range(4):
        for bit in range(31, -1, -1):
            if not ask(_scan_frame(found[sub], bit, sub, nxt)):
                found[sub] |= 1 << bit
        nxt = (sub + 1) & 3
        if not ask(_scan_frame(found[sub], 0, sub, nxt)):
            return None
    return found[0], found[1], found[2], found[3]


@settings(max_examples=60, deadline=None)
@given(st.lists(identities, min_size=1, max_size=4, unique=True))
def test_fast_scan_finds_the_lowest_address_and_selects_only_that_slave(
        addresses: list[tuple[int, int, int, int]]) -> None:
    slaves = [LssSlave(a, NonVolatile()) for a in addresses]
    assert fast_scan(slaves) == min(addresses)
    selected = [s.identity for s in slaves if s.state is LssState.CONFIGURATION]
    assert selected == [min(addresses)]


@settings(max_examples=40, deadline=None)
@given(st.lists(identities, min_size=1, max_size=4, unique=True), st.data())
def test_each_slave_given_an_id_leaves_the_scan_until_none_is_left(
        addresses: list[tuple[int, int, int, int]], data: st.DataObject) -> None:
    slaves = [LssSlave(a, NonVolatile()) for a in addresses]
    order = []
    for node_id in range(1, len(addresses) + 1):
        found = fast_scan(slaves)
        assert found is not None
        order.append(found)
        chosen = [s for s in slaves if s.state is LssState.CONFIGURATION]
        assert [s.identity for s in chosen] == [found]
        assert chosen[0].handle(bytes([0x11, node_id]) + bytes(6)).frame == \
            bytes([0x11, 0]) + bytes(6)
        assert chosen[0].handle(bytes([0x17]) + bytes(7)).frame == bytes([0x17, 0]) + bytes(6)
        answers = [s.handle(bytes([0x04, 0]) + bytes(6)) for s in slaves]
        assert [a.activate for a in answers] == [s is chosen[0] for s in slaves]
        assert chosen[0].active_id == chosen[0].memory.node_id == node_id
    assert fast_scan(slaves) is None
    assert order == sorted(addresses)


@given(identities, st.integers(0, 255))
def test_a_node_id_out_of_range_is_refused_and_nothing_is_stored(
        address: tuple[int, int, int, int], node_id: int) -> None:
    slave = LssSlave(address, NonVolatile())
    slave.handle(bytes([0x04, 1]) + bytes(6))  # all into configuration
    answer = slave.handle(bytes([0x11, node_id]) + bytes(6)).frame
    ok = 1 <= node_id <= 127 or node_id == UNCONFIGURED
    assert answer == bytes([0x11, 0 if ok else 1]) + bytes(6)
    slave.handle(bytes([0x17]) + bytes(7))
    assert slave.memory.node_id == (node_id if ok else UNCONFIGURED)


def test_selective_switch_and_inquiries_answer_with_the_drives_identity() -> None:
    address = (0x1234, 0x402, 0x10000, 77)
    slave, other = LssSlave(address, NonVolatile()), LssSlave((0x1234, 0x402, 0x10000, 78),
                                                            NonVolatile())
    for part, value in enumerate(address):
        frame = struct.pack("<BI", 0x40 + part, value) + bytes(3)
        answers = [slave.handle(frame).frame, other.handle(frame).frame]
    assert answers == [bytes([0x44]) + bytes(7), None]
    assert slave.state is LssState.CONFIGURATION and other.state is LssState.WAITING
    for part, value in enumerate(address):
        assert slave.handle(bytes([0x5A + part]) + bytes(7)).frame == \
            struct.pack("<BI", 0x5A + part, value) + bytes(3)
        assert other.handle(bytes([0x5A + part]) + bytes(7)).frame is None
    assert slave.handle(bytes([0x5E]) + bytes(7)).frame == bytes([0x5E, 0xFF]) + bytes(6)


def test_a_drive_that_refuses_to_store_keeps_nothing() -> None:
    slave = LssSlave((1, 2, 3, 4), NonVolatile(), refuse_store=True)
    slave.handle(bytes([0x04, 1]) + bytes(6))
    slave.handle(bytes([0x11, 5]) + bytes(6))
    assert slave.handle(bytes([0x17]) + bytes(7)).frame == bytes([0x17, 2]) + bytes(6)
    assert slave.memory.node_id == UNCONFIGURED


# ---------------------------------------------------------------- on the wire


@pytest.fixture
def unconfigured(channel: str) -> Iterator[tuple[SimulatedBase, canopen.Network]]:
    cfg = sim_config(channel)
    cfg = replace(cfg, wheels=tuple(replace(w, serial=100 + w.node_id) for w in cfg.wheels))
    network = canopen.Network()
    with SimulatedBase.from_config(cfg, unconfigured=True) as sim:
        network.connect(interface="virtual", channel=channel)
        network.lss.RESPONSE_TIMEOUT = 0.3
        try:
            yield sim, network
        finally:
            network.disconnect()


def scan(lss: canopen.lss.LssMaster) -> tuple[bool, list[int] | None]:
    """canopen's fast scan, again when it found nothing (an answer late on a loaded
    machine reads as a bit of 1, and the scan's last step fails)."""
    for _ in range(3):
        found = lss.fast_scan()
        if found[0]:
            break
    return found


def _heard(network: canopen.Network, cob_ids: set[int]) -> list[int]:
    heard: list[int] = []
    for cob in cob_ids:
        network.subscribe(cob, lambda can_id, data, ts: heard.append(can_id))
    return heard


def test_unconfigured_drives_are_silent_until_lss_gives_them_their_ids(
        unconfigured: tuple[SimulatedBase, canopen.Network]) -> None:
    sim, network = unconfigured
    heard = _heard(network, {0x700 + n for n in (1, 2, 3, 11, 12, 13)} |
                   {0x580 + n for n in (1, 2, 3)})
    network.send_message(0x000, bytes([0x81, 0]))  # NMT reset all: nobody boots
    network.send_message(0x601, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    lss = network.lss
    lss.send_switch_state_global(lss.WAITING_STATE)
    found: list[int] = []
    for node_id in (11, 12, 13):
        assert set(heard) <= {0x700 + n for n in range(11, node_id)}  # only those given ids
        ok, ident = scan(lss)
        assert ok
        found.append(ident[3])
        lss.configure_node_id(node_id)
        lss.store_configuration()
        lss.send_switch_state_global(lss.WAITING_STATE)
        assert wait_for(lambda n=node_id: 0x700 + n in heard, 5.0)
    assert lss.fast_scan() == (False, None)
    assert found == [101, 102, 103]
    assert sim.lss is not None and sim.lss.node_ids() == [(101, 11), (102, 12), (103, 13)]
    node = network.add_node(12, canopen.ObjectDictionary())
    assert struct.unpack("<I", node.sdo.upload(0x1018, 4))[0] == 102


def test_power_cycle_keeps_what_was_stored_and_loses_the_rest(
        unconfigured: tuple[SimulatedBase, canopen.Network]) -> None:
    sim, network = unconfigured
    lss = network.lss
    lss.send_switch_state_global(lss.WAITING_STATE)
    for node_id in (21, 22, 23):
        assert scan(lss)[0]
        lss.configure_node_id(node_id)
        if node_id != 23:  # the third is given its id but not told to store it
            lss.store_configuration()
        lss.send_switch_state_global(lss.WAITING_STATE)
    assert sim.lss is not None
    assert wait_for(lambda: [n for _, n in sim.lss.node_ids()] == [21, 22, 23], 5.0)
    a, b = network.add_node(21, canopen.ObjectDictionary()), \
        network.add_node(22, canopen.ObjectDictionary())
    for node in (a, b):
        node.sdo.download(0x1017, 0, struct.pack("<H", 123))
    a.sdo.download(0x1010, 1, b"save")  # only node 21 saves its heartbeat time
    with pytest.raises(SdoAbortedError) as refused:
        b.sdo.download(0x1010, 1, b"evas")
    assert refused.value.code == 0x08000020
    assert a.sdo.upload(0x1010, 1) == struct.pack("<I", 1)
    sim.power_cycle()
    assert [n for _, n in sim.lss.node_ids()] == [21, 22, UNCONFIGURED]
    assert a.sdo.upload(0x1017, 0) == struct.pack("<H", 123)
    assert b.sdo.upload(0x1017, 0) != struct.pack("<H", 123)
    # 1011h "load": the defaults at the next power-on; a wrong signature is refused.
    with pytest.raises(SdoAbortedError):
        a.sdo.download(0x1011, 1, b"daol")
    a.sdo.download(0x1011, 1, b"load")
    assert a.sdo.upload(0x1017, 0) == struct.pack("<H", 123)  # until the power goes
    sim.power_cycle()
    assert a.sdo.upload(0x1017, 0) != struct.pack("<H", 123)
    assert [n for _, n in sim.lss.node_ids()] == [21, 22, UNCONFIGURED]
