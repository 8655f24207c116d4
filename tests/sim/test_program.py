"""The simulated drive's program download objects (CiA 302-3) and its SDO block
download server, checked with canopen's own SDO client (its block transfer, its CRC) and
with frames built here by hand."""

from __future__ import annotations

import io
import struct
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass

import can
import canopen
import pytest
from canopen import objectdictionary as od
from canopen.sdo.base import CrcXmodem
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.program import flash_status
from omnican.sim import SimulatedDrive
from omnican.sim.program import FACTORY_IMAGE, SimProgram

NODE = 4


@dataclass
class Rig:
    drive: SimulatedDrive
    sdo: SdoClient

    def u32(self, index: int, sub: int = 1) -> int:
        return int.from_bytes(self.sdo.upload(index, sub)[:4], "little")

    def control(self, value: int) -> None:
        self.sdo.download(0x1F51, 1, bytes([value]))

    def block_download(self, image: bytes) -> bool:
        """canopen's block download of ``image`` to 1F50h; whether CRC was used."""
        with self.sdo.open(0x1F50, 1, "wb", buffering=0, size=len(image),
                           block_transfer=True) as stream:
            for at in range(0, len(image), 7):
                stream.write(image[at:at + 7])
            return bool(stream.crc_supported)


@pytest.fixture
def nets(channel: str) -> Iterator[tuple[canopen.Network, canopen.Network]]:
    sim_net, master = canopen.Network(), canopen.Network()
    sim_net.NOTIFIER_CYCLE = master.NOTIFIER_CYCLE = 0.05
    sim_net.connect(interface="virtual", channel=channel)
    master.connect(interface="virtual", channel=channel)
    try:
        yield sim_net, master
    finally:
        master.disconnect()
        sim_net.disconnect()


@pytest.fixture
def rig(nets: tuple[canopen.Network, canopen.Network]) -> Iterator[Rig]:
    sim_net, master = nets
    drive = SimulatedDrive(sim_net, NODE, program=SimProgram(lambda: False, image=None))
    node = canopen.RemoteNode(NODE, od.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = 2.0  # the simulator's thread beside busy processes
    master.add_node(node)
    try:
        yield Rig(drive, node.sdo)
    finally:
        drive.close()


IMAGE = bytes(range(256)) * 40 + b"tail"  # 10,244 bytes: not a multiple of 7


def test_a_drive_leaves_the_factory_running_a_valid_program(
        nets: tuple[canopen.Network, canopen.Network]) -> None:
    sim_net, master = nets
    with SimulatedDrive(sim_net, NODE):
        node = canopen.RemoteNode(NODE, od.ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = 2.0
        master.add_node(node)


        def u32(index: int) -> int:
            return int.from_bytes(node.sdo.upload(index, 1)[:4], "little")

        assert u32(0x1F57) == 0  # valid
        assert u32(0x1F56) == zlib.crc32(FACTORY_IMAGE)
        assert u32(0x1F51) == 1  # started
        for command in (0, 3):  # stop, clear
            node.sdo.download(0x1F51, 1, bytes([command]))
        assert u32(0x1F57) == 1 << 1 and u32(0x1F51) == 3  # cleared


def test_a_block_download_is_stored_identified_and_started(rig: Rig) -> None:
    assert rig.u32(0x1F57) == 1 << 1  # no valid program
    assert rig.u32(0x1F51) == 3  # cleared
    assert rig.u32(0x1F56) == 0
    assert rig.block_download(IMAGE)  # with canopen's CRC-16: both sides offer it
    assert flash_status(rig.u32(0x1F57)).valid
    assert rig.u32(0x1F56) == zlib.crc32(IMAGE)
    assert rig.u32(0x1F51) == 0  # stored, stopped
    rig.control(1)
    assert rig.u32(0x1F51) == 1
    assert rig.drive.program is not None and rig.drive.program.image == IMAGE


def test_a_reset_midway_leaves_no_valid_program_and_none_started(
        rig: Rig, nets: tuple[canopen.Network, canopen.Network]) -> None:
    _, master = nets
    program = rig.drive.program
    assert program is not None
    stream = rig.sdo.open(0x1F50, 1, "wb", buffering=0, size=len(IMAGE), block_transfer=True)
    for at in range(0, 7 * 300, 7):
        stream.write(IMAGE[at:at + 7])
    assert flash_status(program.flash_status()).in_progress  # 1F57h bit 0 while it runs
    master.send_message(0x000, bytes([0x81, NODE]))  # NMT reset node midway
    assert _wait(lambda: not program.in_progress)
    time.sleep(0.2)  # the sim takes the rest of the broken-off download for nothing
    status = flash_status(rig.u32(0x1F57))
    assert not status.valid and not status.in_progress and status.describe() == "no valid program"
    assert rig.u32(0x1F56) == 0
    assert rig.u32(0x1F51) != 1
    with pytest.raises(SdoAbortedError) as refused:
        rig.control(1)  # nothing to start
    assert refused.value.code == 0x08000022
    assert program.abandoned == 1 and program.committed == 0
    io.RawIOBase.close(stream)  # the client's side of it, without its end exchange


def test_the_flash_keeps_a_program_across_a_power_cycle_and_starts_it(rig: Rig) -> None:
    rig.block_download(IMAGE)
    rig.drive.reboot()
    assert flash_status(rig.u32(0x1F57)).valid
    assert rig.u32(0x1F56) == zlib.crc32(IMAGE)
    assert rig.u32(0x1F51) == 1  # a valid program starts at power-up


def test_a_drive_made_again_keeps_its_flash_but_not_an_incomplete_download(
        nets: tuple[canopen.Network, canopen.Network]) -> None:
    """A simulator that rebuilds its drives for a power cycle hands each its flash."""
    sim_net, _ = nets
    with SimulatedDrive(sim_net, NODE + 2) as first:
        flash = first.program
        assert flash is not None
    flash.control(0)
    with SimulatedDrive(sim_net, NODE + 2, program=flash) as again:
        assert again.program is flash and flash.running and flash.image == FACTORY_IMAGE
        flash.control(0)
        flash.control(3)
        flash.begin(100)  # a download under way when the power goes
    with SimulatedDrive(sim_net, NODE + 2, program=flash):
        assert not flash.in_progress and flash.image is None and not flash.running
        assert flash_status(flash.flash_status()).describe() == "no valid program"


def test_a_segment_lost_midway_is_sent_again(rig: Rig) -> None:
    seen = [0]

    def lose_one(frame: bytes) -> bool:
        seen[0] += 1
        return seen[0] == 200  # a segment in the second sub-block

    rig.drive.comm.block.lose = lose_one
    rig.block_download(IMAGE)
    assert rig.u32(0x1F56) == zlib.crc32(IMAGE)
    assert flash_status(rig.u32(0x1F57)).valid


def test_the_program_is_not_stopped_while_the_drive_drives(rig: Rig) -> None:
    rig.block_download(IMAGE)
    rig.control(1)
    for word in (0x06, 0x07, 0x0F):  # shutdown, switch on, enable operation
        rig.sdo.download(0x6040, 0, struct.pack("<H", word))
    assert _wait(lambda: int.from_bytes(rig.sdo.upload(0x6041, 0), "little") & 0x6F == 0x27)
    with pytest.raises(SdoAbortedError) as refused:
        rig.control(0)
    assert refused.value.code == 0x08000022
    assert rig.u32(0x1F51) == 1


def test_a_download_waits_for_a_stopped_and_cleared_program(rig: Rig) -> None:
    rig.block_download(IMAGE)
    rig.control(1)
    for refused_while in ("started", "stopped, not cleared"):
        with pytest.raises(SdoAbortedError) as refused:
            rig.block_download(IMAGE[:100])
        assert refused.value.code == 0x08000022, refused_while
        rig.control(0)
    with pytest.raises(SdoAbortedError):
        rig.control(9)  # no such command
    rig.control(3)
    assert rig.u32(0x1F57) == 1 << 1
    rig.block_download(IMAGE[:100])
    assert rig.u32(0x1F56) == zlib.crc32(IMAGE[:100])


def test_program_data_goes_by_block_download_only(rig: Rig) -> None:
    with pytest.raises(SdoAbortedError) as refused:
        rig.sdo.download(0x1F50, 1, IMAGE[:100])  # segmented
    assert refused.value.code == 0x06010000
    assert rig.u32(0x1F57) == 1 << 1 and rig.drive.program is not None
    assert rig.drive.program.begun == 0


def test_a_drive_without_program_download_has_no_1f50h(
        nets: tuple[canopen.Network, canopen.Network]) -> None:
    sim_net, master = nets
    with SimulatedDrive(sim_net, NODE + 1, program=False):
        node = canopen.RemoteNode(NODE + 1, od.ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = 2.0
        master.add_node(node)
        for index in (0x1F50, 0x1F51, 0x1F56, 0x1F57):
            with pytest.raises(SdoAbortedError) as absent:
                node.sdo.upload(index, 0)
            assert absent.value.code == 0x06020000


# ------------------------------------------------------- frames built by hand


class Wire:
    """Raw SDO frames to node ``NODE`` and its answers."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)

    def send(self, data: bytes) -> None:
        while self.bus.recv(0) is not None:  # answers to others' requests (the rig's)
            pass
        self.bus.send(can.Message(arbitration_id=0x600 + NODE, data=data.ljust(8, b"\0"),
                                  is_extended_id=False))

    def answer(self, timeout: float = 2.0) -> bytes:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.bus.recv(0.1)
            if msg is not None and msg.arbitration_id == 0x580 + NODE:
                return bytes(msg.data)
        raise AssertionError("no SDO answer")

    def close(self) -> None:
        self.bus.shutdown()


@pytest.fixture
def wire(channel: str, rig: Rig) -> Iterator[Wire]:
    w = Wire(channel)
    try:
        yield w
    finally:
        w.close()


def _download(wire: Wire, data: bytes, crc: int | None, size: int | None = None) -> bytes:
    """A block download of ``data`` in one sub-block; the answer to its end."""
    flags = (0x04 if crc is not None else 0) | 0x02
    wire.send(struct.pack("<BHBL", 0xC0 | flags, 0x1F50, 1,
                          len(data) if size is None else size))
    init = wire.answer()
    assert init[0] & 0xE3 == 0xA0 and init[4] >= 1  # initiate answered, a block size
    chunks = [data[i:i + 7] for i in range(0, len(data), 7)]
    for seq, chunk in enumerate(chunks, 1):
        wire.send(bytes([seq | (0x80 if seq == len(chunks) else 0)]) + chunk)
    ack = wire.answer()
    assert ack[:2] == bytes([0xA2, len(chunks)])
    unused = 7 - len(chunks[-1])
    wire.send(struct.pack("<BH", 0xC1 | (unused << 2), crc or 0))
    return wire.answer()


def test_a_wrong_crc_is_refused_and_leaves_no_valid_program(rig: Rig, wire: Wire) -> None:
    data = b"firmware" * 5
    good = CrcXmodem()
    good.process(data)
    answer = _download(wire, data, good.final() ^ 0x5A5A)
    assert answer[0] == 0x80 and struct.unpack_from("<L", answer, 4)[0] == 0x05040004
    assert _value(rig, 0x1F57) == 1 << 1 and _value(rig, 0x1F56) == 0
    assert _download(wire, data, good.final())[0] == 0xA1  # the right CRC: stored
    assert _value(rig, 0x1F56) == zlib.crc32(data)


def test_a_download_shorter_than_announced_is_refused(rig: Rig, wire: Wire) -> None:
    answer = _download(wire, b"0123456789", None, size=20)
    assert answer[0] == 0x80 and struct.unpack_from("<L", answer, 4)[0] == 0x06070010
    assert not flash_status(_value(rig, 0x1F57)).valid


def test_an_image_larger_than_the_flash_is_refused_at_once(rig: Rig, wire: Wire) -> None:
    wire.send(struct.pack("<BHBL", 0xC6, 0x1F50, 1, (1 << 20) + 1))
    answer = wire.answer()
    assert answer[0] == 0x80 and struct.unpack_from("<L", answer, 4)[0] == 0x06070012
    assert _value(rig, 0x1F57) == 1 << 1


def _wait(pred: object, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():  # type: ignore[operator]
            return True
        time.sleep(0.005)
    return bool(pred())  # type: ignore[operator]


def _value(rig: Rig, index: int) -> int:
    """An object's value as the drive holds it (not over the bus: the hand-built frames'
    answers reach the rig's SDO client too)."""
    return int.from_bytes(rig.drive.read(index, 1), "little")
