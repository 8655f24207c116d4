"""Program download (CiA 302-3) from omnican's library to simulated drives on a virtual
bus: verified and started, or, whatever broke (a reset or power cut midway, a lost
frame, a lost drive, another program stored), a result naming the state the drive
reports, and never a wrong program started."""

from __future__ import annotations

import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field

import can
import canopen
import pytest

from omnican.drive.program import Outcome, download, driving
from omnican.sim import SimulatedDrive

NODE = 3
IMAGE = bytes((i * 7 + 3) & 0xFF for i in range(40_000))


@dataclass
class Rig:
    sim_net: canopen.Network
    master: canopen.Network
    drives: list[SimulatedDrive] = field(default_factory=list)
    requests: list[bytes] = field(default_factory=list)  # SDO requests the master sent

    def drive(self, node_id: int = NODE, **kw: object) -> SimulatedDrive:
        d = SimulatedDrive(self.sim_net, node_id, **kw)  # type: ignore[arg-type]
        self.drives.append(d)
        return d


@pytest.fixture
def rig(channel: str) -> Iterator[Rig]:
    sim_net, master = canopen.Network(), canopen.Network()
    sim_net.NOTIFIER_CYCLE = master.NOTIFIER_CYCLE = 0.05
    r = Rig(sim_net, master)

    class Spy(canopen.network.MessageListener):
        def on_message_received(self, msg: can.Message) -> None:
            if 0x600 < msg.arbitration_id <= 0x67F:
                r.requests.append(bytes(msg.data))

    sim_net.listeners.append(Spy(sim_net))  # the simulator's side sees what the master sent
    sim_net.connect(interface="virtual", channel=channel)
    master.connect(interface="virtual", channel=channel)
    try:
        yield r
    finally:
        for d in r.drives:
            d.close()
        master.disconnect()
        sim_net.disconnect()


def test_an_image_is_downloaded_verified_and_started(rig: Rig) -> None:
    drive = rig.drive()
    seen: list[tuple[int, int]] = []
    result = download(rig.master, NODE, IMAGE, lambda sent, total: seen.append((sent, total)))
    assert result.outcome is Outcome.STARTED and result.ok, result.line()
    assert result.state.control == 1 and result.state.identification == zlib.crc32(IMAGE)
    assert result.state.flash is not None and result.state.flash.valid
    assert seen[-1] == (len(IMAGE), len(IMAGE))
    assert [s for s, _ in seen] == sorted(s for s, _ in seen)
    assert drive.program is not None and drive.program.image == IMAGE and drive.program.running
    assert any(r[0] & 0xE1 == 0xC0 for r in rig.requests)  # a block download's initiate
    assert result.line().startswith(f"node {NODE}: program of 40000 bytes downloaded in ")
    assert "the drive says: program started; flash: program valid; identification 0x" \
        in result.line()


def test_a_new_image_replaces_a_running_one(rig: Rig) -> None:
    drive = rig.drive()
    assert download(rig.master, NODE, IMAGE[:1000]).ok
    result = download(rig.master, NODE, IMAGE)
    assert result.ok, result.line()
    assert drive.program is not None and drive.program.image == IMAGE


def test_a_drive_without_the_objects_is_left_untouched(rig: Rig) -> None:
    rig.drive(program=False)
    result = download(rig.master, NODE, IMAGE)
    assert result.outcome is Outcome.NOT_SUPPORTED
    assert result.line() == (f"node {NODE}: no program download: it has no 1F50h program 1 "
                             "(CiA 302-3 program download): its firmware is loaded some other "
                             "way")
    writes = [r for r in rig.requests if r[0] & 0xE0 in (0x20, 0xC0)]  # downloads of any kind
    assert writes == []


def test_a_reset_midway_leaves_a_drive_that_says_it_has_no_valid_program(rig: Rig) -> None:
    drive = rig.drive()
    assert download(rig.master, NODE, IMAGE[:500]).ok  # an old program, to be replaced

    def power_cut(sent: int, total: int) -> None:
        if sent > total // 3 and drive.program is not None and drive.program.in_progress:
            drive.reboot()  # the power cut: boot-up, the download gone

    result = download(rig.master, NODE, IMAGE, power_cut, sdo_timeout_s=1.0)
    assert result.outcome is Outcome.FAILED, result.line()
    assert result.state.flash is not None and not result.state.flash.valid
    assert result.state.control != 1
    assert "download failed" in result.line()
    assert "the drive says: program cleared (no program); flash: no valid program" \
        in result.line()
    assert drive.program is not None and not drive.program.running
    assert drive.program.image is None


def test_a_lost_segment_is_sent_again_and_the_image_verified(rig: Rig) -> None:
    drive = rig.drive()
    count = [0]

    def lose(frame: bytes) -> bool:
        count[0] += 1
        return count[0] in (700, 3000)  # two segments, in different sub-blocks

    drive.comm.block.lose = lose
    result = download(rig.master, NODE, IMAGE)
    assert result.ok, result.line()
    assert result.state.identification == zlib.crc32(IMAGE)


def test_a_lost_last_segment_fails_and_the_drive_says_so(rig: Rig) -> None:
    drive = rig.drive()
    block = drive.comm.block
    # While the download runs: the segment with the "last" bit (not the client's abort).
    block.lose = lambda frame: block.active and bool(frame[0] & 0x80) and frame[0] != 0x80
    result = download(rig.master, NODE, IMAGE, sdo_timeout_s=0.5)
    block.lose = None
    assert result.outcome is Outcome.FAILED, result.line()
    assert "no answer after" in result.detail
    assert result.state.flash is not None and not result.state.flash.valid
    assert drive.program is not None and not drive.program.running


def test_a_drive_lost_midway_is_named_and_says_so_when_it_is_back(rig: Rig) -> None:
    drive = rig.drive()

    def lost(sent: int, total: int) -> None:
        if sent > total // 2:
            drive.freeze()

    result = download(rig.master, NODE, IMAGE, lost, sdo_timeout_s=0.3)
    assert result.outcome is Outcome.LOST, result.line()
    assert result.line().endswith("the drive says: no answer (its state is unknown: it may "
                                  "hold an incomplete program)")
    drive.thaw()
    drive.reboot()  # its power cycled: the incomplete download is gone, nothing starts
    again = download(rig.master, NODE, IMAGE[:10])
    assert again.ok, again.line()


def test_a_drive_naming_another_program_is_not_started(rig: Rig) -> None:
    drive = rig.drive()
    drive.comm.readers[(0x1F56, 1)] = lambda: 0xDEADBEEF  # stores something else
    result = download(rig.master, NODE, IMAGE)
    assert result.outcome is Outcome.MISMATCH
    assert f"CRC mismatch: the drive identifies its program as 0xDEADBEEF, the image's " \
           f"CRC-32 is 0x{zlib.crc32(IMAGE):08X}: not started" in result.line()
    assert drive.program is not None and not drive.program.running
    assert result.state.control == 0


def test_nothing_drives_an_idle_bus(rig: Rig) -> None:
    rig.drive()
    assert driving(rig.master, {NODE: [(0x6041, 0)]}, listen_s=0.2) is None


def test_a_drive_in_operation_enabled_counts_as_driving(rig: Rig) -> None:
    rig.drive()
    node = canopen.RemoteNode(NODE, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = 2.0
    rig.master.add_node(node)
    for word in (0x06, 0x07, 0x0F):
        node.sdo.download(0x6040, 0, word.to_bytes(2, "little"))
    del rig.master[NODE]
    why = driving(rig.master, {NODE: [(0x6041, 0)]}, listen_s=0.1)
    assert why is not None and why.startswith(f"node {NODE} is OPERATION ENABLED")


def test_another_masters_cycle_counts_as_driving(rig: Rig, channel: str) -> None:
    rig.drive()
    other = can.Bus(interface="virtual", channel=channel)
    tasks = [other.send_periodic(can.Message(arbitration_id=cob, data=data,
                                             is_extended_id=False), 0.01)
             for cob, data in ((0x80, b""), (0x300 + NODE, b"\0\0\0\0"))]
    try:
        deadline = time.monotonic() + 5
        why = None
        while why is None and time.monotonic() < deadline:
            why = driving(rig.master, {NODE: [(0x6041, 0)]}, listen_s=0.2)
    finally:
        for task in tasks:
            task.stop()
        other.shutdown()
    assert why is not None and why.startswith("another master drives the base: ")


def test_a_segment_lost_in_the_last_sub_block_fails_and_the_drive_says_so(rig: Rig) -> None:
    """canopen 2.4's block transfer cannot send a lost segment of the last sub-block again
    (its stream counts itself done): the download fails, the drive is told (an abort), and
    it says it holds no valid program; nothing is started."""
    drive = rig.drive()
    block, count = drive.comm.block, [0]

    def lose(frame: bytes) -> bool:
        if block.active:
            count[0] += 1
            return count[0] == 5650  # of 5,715 segments: the last sub-block's
        return False

    block.lose = lose
    result = download(rig.master, NODE, IMAGE)
    assert result.outcome is Outcome.FAILED, result.line()
    assert result.state.flash is not None and not result.state.flash.valid
    assert not block.active  # told at once, not left waiting for its timeout
    assert drive.program is not None and not drive.program.running
