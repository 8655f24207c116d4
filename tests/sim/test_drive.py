"""Conformance of the simulated drive, checked with a master omnican did not write:
canopen's own RemoteNode / BaseNode402, SDO and PDO APIs, for the bundled EDS and
the three vendor EDS files."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import canopen
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from omnican import WHEEL_EDS
from omnican.sim import SimulatedDrive
from tests.support.helpers import VENDOR_EDS

NODE = 5
HOST = 0x7F


@dataclass
class Rig:
    """A simulated drive and a canopen master on one virtual channel."""

    sim_net: canopen.Network
    master: canopen.Network
    frames: list[tuple[int, bytes]] = field(default_factory=list)
    drives: list[SimulatedDrive] = field(default_factory=list)

    def drive(self, eds: Path = WHEEL_EDS, node_id: int = NODE, **kw: object) -> SimulatedDrive:
        d = SimulatedDrive(self.sim_net, node_id, eds, **kw)  # type: ignore[arg-type]
        self.drives.append(d)
        return d

    def node(self, eds: Path = WHEEL_EDS, node_id: int = NODE) -> canopen.BaseNode402:
        node = canopen.BaseNode402(node_id, str(eds))
        # canopen waits 0.3 s for an SDO answer: a real drive's figure, not that of a
        # simulator's thread beside busy processes. Silence tests set their own.
        node.sdo.RESPONSE_TIMEOUT = 2.0
        self.master.add_node(node)
        return node

    def seen(self, cob: int) -> list[bytes]:
        return [d for c, d in self.frames if c == cob]


def wait_for(pred: Callable[[], bool], timeout: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


@pytest.fixture
def rig(channel: str) -> Iterator[Rig]:
    sim_net = canopen.Network()
    sim_net.NOTIFIER_CYCLE = 0.05  # quick shutdown
    sim_net.connect(interface="virtual", channel=channel)
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    r = Rig(sim_net, master)

    class Spy(canopen.network.MessageListener):
        def on_message_received(self, msg):  # type: ignore[no-untyped-def]
            r.frames.append((msg.arbitration_id, bytes(msg.data)))

    master.listeners.append(Spy(master))
    master.connect(interface="virtual", channel=channel)
    try:
        yield r
    finally:
        for d in r.drives:
            d.close()
        master.disconnect()
        sim_net.disconnect()


def configure(node: canopen.BaseNode402, rx: list[list[tuple[int, int]]],
              tx: list[tuple[list[tuple[int, int]], int]]) -> None:
    """Map PDOs with canopen's PdoMap API: rx maps are async; tx = (objects, trans type)."""
    node.nmt.state = "PRE-OPERATIONAL"
    node.tpdo.read()
    node.rpdo.read()
    for n, objs in enumerate(rx, 1):
        m = node.rpdo[n]
        m.clear()
        for index, sub in objs:
            m.add_variable(index, sub)
        m.trans_type = 255
        m.enabled = True
        m.save()
    for n in range(len(rx) + 1, len(node.rpdo) + 1):
        node.rpdo[n].enabled = False
        node.rpdo[n].save()
    for n, (objs, trans) in enumerate(tx, 1):
        m = node.tpdo[n]
        m.clear()
        for index, sub in objs:
            m.add_variable(index, sub)
        m.trans_type = trans
        m.enabled = True
        m.save()
    for n in range(len(tx) + 1, len(node.tpdo) + 1):
        node.tpdo[n].enabled = False
        node.tpdo[n].save()


@dataclass(frozen=True)
class Layout:
    eds: Path
    axis_objects: Callable[[int], dict[str, tuple[int, int]]]
    axes: int


def single(eds: Path) -> Layout:
    return Layout(eds, lambda k: {"cw": (0x6040, 0), "sw": (0x6041, 0), "tv": (0x60FF, 0),
                                  "pos": (0x6064, 0), "mode": (0x6060, 0),
                                  "acc": (0x6083, 0)}, 1)


LAYOUTS = {
    "bundled": single(WHEEL_EDS),
    "epos4": single(VENDOR_EDS / "maxon_epos4.eds"),
    "roboteq": Layout(VENDOR_EDS / "roboteq_v80_21.eds",
                      lambda k: {"cw": (0x6040 + 0x800 * k, 0), "sw": (0x6041 + 0x800 * k, 0),
                                 "tv": (0x60FF + 0x800 * k, 0), "pos": (0x6064 + 0x800 * k, 0),
                                 "mode": (0x6060 + 0x800 * k, 0),
                                 "acc": (0x6083 + 0x800 * k, 0)}, 2),
    "zlac": Layout(VENDOR_EDS / "zlac8015d.eds",
                   lambda k: {"cw": (0x6040, 0), "sw": (0x6041, 0), "tv": (0x60FF, k + 1),
                              "pos": (0x6064, k + 1), "mode": (0x6060, 0),
                              "acc": (0x6083, k + 1)}, 2),
}


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_canopen_master_configures_enables_and_drives(rig: Rig, name: str) -> None:
    lay = LAYOUTS[name]
    axes = range(lay.axes)
    objs = [lay.axis_objects(k) for k in axes]
    drive = rig.drive(lay.eds, counts_per_unit=10.0)
    node = rig.node(lay.eds)
    assert wait_for(lambda: rig.seen(0x700 + NODE) == [b"\x00"])  # boot-up frame
    shared_cw = len({o["cw"] for o in objs}) == 1
    controlwords = [objs[0]["cw"]] if shared_cw else [o["cw"] for o in objs]
    # One object per PDO where a drive allows few entries; canopen's PdoMap.save() does the rest.
    rx = [[cw] for cw in controlwords] + [[o["tv"]] for o in objs]
    tx = [([o["sw"]], 255) for o in (objs[:1] if shared_cw else objs)] + \
         [([o["pos"]], 1) for o in objs]
    configure(node, rx, tx)
    for o in objs if not shared_cw else objs[:1]:
        node.sdo[o["mode"][0]].raw = 3  # profile velocity
    for o in objs:
        index, sub = o["acc"]
        var = node.sdo[index] if not sub else node.sdo[index][sub]
        var.raw = 100_000  # profile acceleration, units/s^2
    node.nmt.state = "OPERATIONAL"
    assert wait_for(lambda: drive.nmt_state == "OPERATIONAL")
    node.setup_402_state_machine(read_pdos=False)
    # Walk every axis to OPERATION ENABLED with explicit controlwords through RPDOs.
    for n in range(1, len(controlwords) + 1):
        for word, want in ((0x06, "READY TO SWITCH ON"), (0x07, "SWITCHED ON"),
                           (0x0F, "OPERATION ENABLED")):
            node.rpdo[n][0].raw = word
            node.rpdo[n].transmit()
            axis = n - 1 if not shared_cw else 0
            assert wait_for(lambda a=axis, w=want: str(drive.state(a)) == w), (name, word)
        # ...and the statusword TPDO says so too.
        sw_map = node.tpdo[n]
        assert wait_for(lambda m=sw_map: m.is_received and m[0].raw & 0x6F == 0x27)
    # Command a velocity on each axis and watch position advance through SYNC TPDOs.
    targets = [200 * (k + 1) * (-1) ** k for k in axes]  # drive units; 10 counts per unit
    first_tv = len(controlwords) + 1
    for k in axes:
        node.rpdo[first_tv + k][0].raw = targets[k]
        node.rpdo[first_tv + k].transmit()
    time.sleep(0.1)  # ramp up (profile acceleration)
    pos_maps = [node.tpdo[len(tx) - lay.axes + 1 + k] for k in axes]
    samples: list[tuple[float, list[int]]] = []
    for _ in range(6):
        for m in pos_maps:
            m.is_received = False
        t0 = time.monotonic()
        rig.master.sync.transmit()
        assert wait_for(lambda: all(m.is_received for m in pos_maps), 1.0)
        samples.append((t0, [m[0].raw for m in pos_maps]))
        time.sleep(0.05)
    (ta, pa), (tb, pb) = samples[0], samples[-1]
    for k in axes:
        rate = (pb[k] - pa[k]) / (tb - ta)
        assert rate == pytest.approx(targets[k] * 10.0, rel=0.1), (name, k)
    # And back to SWITCH ON DISABLED: the wheels coast to a stop.
    for n in range(1, len(controlwords) + 1):
        node.rpdo[n][0].raw = 0x00
        node.rpdo[n].transmit()
    for k in axes:
        assert wait_for(lambda a=k: str(drive.state(a)) == "SWITCH ON DISABLED")
    assert wait_for(lambda: all(abs(drive.velocity_counts(k)) < 1.0 for k in axes), 2.0)


def test_base_node_402_state_property_walks_the_machine(rig: Rig) -> None:
    drive = rig.drive()
    node = rig.node()
    configure(node, [[(0x6040, 0)]], [([(0x6041, 0)], 255)])
    node.sdo[0x6060].raw = 3
    node.nmt.state = "OPERATIONAL"
    node.setup_402_state_machine(read_pdos=False)
    node.state = "OPERATION ENABLED"
    assert str(drive.state()) == "OPERATION ENABLED"
    node.state = "SWITCH ON DISABLED"
    assert str(drive.state()) == "SWITCH ON DISABLED"


def enable(node: canopen.BaseNode402, drive: SimulatedDrive) -> None:
    for word in (0x06, 0x07, 0x0F):
        node.sdo[0x6040].raw = word
    assert str(drive.state()) == "OPERATION ENABLED"


def test_every_transition_by_sdo(rig: Rig) -> None:
    drive = rig.drive()
    node = rig.node()
    node.sdo[0x6060].raw = 3
    cw = node.sdo[0x6040]
    steps = [  # (controlword, expected state, transition number)
        (0x06, "READY TO SWITCH ON", 2), (0x07, "SWITCHED ON", 3), (0x0F, "OPERATION ENABLED", 4),
        (0x07, "SWITCHED ON", 5), (0x06, "READY TO SWITCH ON", 6),
        (0x00, "SWITCH ON DISABLED", 7), (0x06, "READY TO SWITCH ON", 2),
        (0x0F, "OPERATION ENABLED", 3),  # switch on + enable in one command
        (0x06, "READY TO SWITCH ON", 8), (0x0F, "OPERATION ENABLED", 3),
        (0x00, "SWITCH ON DISABLED", 9), (0x06, "READY TO SWITCH ON", 2),
        (0x07, "SWITCHED ON", 3), (0x02, "SWITCH ON DISABLED", 10),
        (0x06, "READY TO SWITCH ON", 2), (0x02, "SWITCH ON DISABLED", 7),
    ]
    for word, want, number in steps:
        cw.raw = word
        assert str(drive.state()) == want, f"transition {number}"
        assert node.sdo[0x6041].raw & 0x6F in ({"READY TO SWITCH ON": 0x21, "SWITCHED ON": 0x23,
                                                  "OPERATION ENABLED": 0x27}.get(want, 0x40),
                                                 0x40 if want == "SWITCH ON DISABLED" else -1)


def test_quick_stop_transitions(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=1.0)
    node = rig.node()
    node.sdo[0x6060].raw = 3
    node.sdo[0x6085].raw = 100_000  # quick stop deceleration, counts/s^2
    enable(node, drive)
    node.sdo[0x60FF].raw = 20_000
    assert wait_for(lambda: drive.velocity_counts() > 19_000)
    # 605Ah = 2 (default): quick stop (11), ramp down, then SWITCH ON DISABLED by itself.
    node.sdo[0x6040].raw = 0x0B
    assert str(drive.state()) == "QUICK STOP ACTIVE"
    assert node.sdo[0x6041].raw & 0x6F == 0x07
    time.sleep(0.05)
    assert 0 < drive.velocity_counts() < 19_000  # ramping on the quick-stop deceleration
    assert wait_for(lambda: str(drive.state()) == "SWITCH ON DISABLED", 1.0)
    # 605Ah = 6: stay in QUICK STOP ACTIVE; leave by enable (16) or disable voltage (12).
    node.sdo[0x605A].raw = 6
    enable(node, drive)
    node.sdo[0x6040].raw = 0x0B
    assert wait_for(lambda: abs(drive.velocity_counts()) < 1.0, 1.0)
    time.sleep(0.02)
    assert str(drive.state()) == "QUICK STOP ACTIVE"
    assert node.sdo[0x6041].raw & (1 << 10)  # target reached: stopped
    node.sdo[0x6040].raw = 0x0F
    assert str(drive.state()) == "OPERATION ENABLED"  # transition 16
    node.sdo[0x6040].raw = 0x0B
    node.sdo[0x6040].raw = 0x00
    assert str(drive.state()) == "SWITCH ON DISABLED"  # transition 12


def test_halt_bit_and_statusword_bits(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=1.0)
    node = rig.node()
    node.sdo[0x6060].raw = 3
    enable(node, drive)
    sw = node.sdo[0x6041]
    assert sw.raw & (1 << 9)  # remote
    assert sw.raw & (1 << 12)  # pv: speed is zero
    node.sdo[0x60FF].raw = 50_000
    assert not sw.raw & (1 << 10)  # target not reached while ramping
    assert wait_for(lambda: sw.raw & (1 << 10) != 0, 1.0)
    assert not sw.raw & (1 << 12)
    node.sdo[0x6040].raw = 0x10F  # halt: decelerate on the profile deceleration
    assert wait_for(lambda: abs(drive.velocity_counts()) < 1.0, 1.0)
    assert str(drive.state()) == "OPERATION ENABLED"
    assert sw.raw & (1 << 10)  # halted and stopped: target reached
    node.sdo[0x6040].raw = 0x0F
    node.sdo[0x607F].raw = 10_000  # max profile velocity below the target
    assert wait_for(lambda: sw.raw & (1 << 11) != 0, 1.0)  # internal limit active
    assert wait_for(lambda: abs(drive.velocity_counts() - 10_000) < 1, 1.0)


def test_modes_vl_and_csv(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=100.0)
    node = rig.node()
    node.sdo[0x6060].raw = 2  # vl
    assert node.sdo[0x6061].raw == 2
    node.sdo[0x6048][1].raw = 1000  # 1000 units per 1 s
    node.sdo[0x6048][2].raw = 1
    enable(node, drive)
    node.sdo[0x6042].raw = 300
    time.sleep(0.1)
    assert 0 < node.sdo[0x6043].raw < 300  # demand ramping at 1000 units/s
    assert wait_for(lambda: node.sdo[0x6044].raw == 300, 1.0)
    assert drive.velocity_counts() == pytest.approx(30_000, rel=0.01)
    node.sdo[0x6040].raw = 0x07
    node.sdo[0x6060].raw = 9  # csv: no ramp in the drive
    node.sdo[0x60FF].raw = -50
    node.sdo[0x6040].raw = 0x0F
    assert node.sdo[0x6041].raw & (1 << 12)  # csv: following the command value
    assert wait_for(lambda: node.sdo[0x606C].raw == -50, 1.0)
    with pytest.raises(SdoAbortedError) as info:
        node.sdo[0x6060].raw = 1  # profile position: not supported by the bundled drive
    assert info.value.code == 0x06090030
    # ZLAC8015D has no 6502h and allows modes 1-4 only.
    zlac = rig.drive(VENDOR_EDS / "zlac8015d.eds", node_id=6)
    zn = rig.node(VENDOR_EDS / "zlac8015d.eds", node_id=6)
    zn.sdo[0x6060].raw = 3
    with pytest.raises(SdoAbortedError):
        zn.sdo[0x6060].raw = 9
    assert zlac.state() is not None


def test_unmappable_object_is_refused(rig: Rig) -> None:
    rig.drive()
    node = rig.node()
    node.rpdo.read()
    m = node.rpdo[3]
    m.clear()
    m.add_variable(0x6041)  # the statusword is read-only: not an RPDO object
    m.enabled = True
    with pytest.raises(SdoAbortedError) as info:
        m.save()
    assert info.value.code == 0x06040041
    with pytest.raises(SdoAbortedError) as info:
        node.sdo[0x1A02][1].raw = 0x60070010  # 6007h is not PDO-mappable in the EDS
    assert info.value.code == 0x06040041
    with pytest.raises(SdoAbortedError) as info:
        node.sdo[0x1A02][1].raw = 0x60640010  # wrong length for an INTEGER32
    assert info.value.code == 0x06040043
    for sub in range(1, 4):  # 3 x 32 bits
        node.sdo[0x1A02][sub].raw = 0x60640020
    with pytest.raises(SdoAbortedError) as info:
        node.sdo[0x1A02][0].raw = 3
    assert info.value.code == 0x06040042


@pytest.mark.parametrize("accept", [True, False])
def test_understated_eds_mapping_accepted_or_refused(rig: Rig, accept: bool) -> None:
    """accept_unmappable: a drive that maps what its EDS marks PDOMapping=0 (6007h here),
    as drives behind understating vendor EDS files do; or one that holds to its EDS."""
    rig.drive(accept_unmappable=accept)
    node = rig.node()
    if accept:
        node.sdo[0x1A02][1].raw = 0x60070010
        assert node.sdo[0x1A02][1].raw == 0x60070010
    else:
        with pytest.raises(SdoAbortedError) as info:
            node.sdo[0x1A02][1].raw = 0x60070010
        assert info.value.code == 0x06040041
    with pytest.raises(SdoAbortedError) as info:  # a read-only object is never an RPDO's
        node.sdo[0x1602][1].raw = 0x60410010
    assert info.value.code == 0x06040041


def test_drive_that_refuses_remapping(rig: Rig) -> None:
    rig.drive(remappable=False)
    node = rig.node()
    node.tpdo.read()
    assert [v.index for v in node.tpdo[2]] == [0x6064]  # its fixed mapping can be read back
    node.tpdo[2].clear()
    node.tpdo[2].add_variable(0x606C)
    with pytest.raises(SdoAbortedError):
        node.tpdo[2].save()


def test_single_entry_pdos(rig: Rig) -> None:
    rig.drive(max_mapping_entries=1)
    node = rig.node()
    with pytest.raises(SdoAbortedError) as info:
        node.sdo[0x1A01][2].raw = 0x606C0020
    assert info.value.code == 0x06040042


def test_sync_tpdo_every_nth_sync_and_event_timer(rig: Rig) -> None:
    drive = rig.drive()
    node = rig.node()
    configure(node, [[(0x6040, 0)]], [([(0x6064, 0)], 3), ([(0x6041, 0)], 254)])
    node.sdo[0x1801][5].raw = 50  # event timer 50 ms on the statusword TPDO
    node.nmt.state = "OPERATIONAL"
    assert wait_for(lambda: drive.nmt_state == "OPERATIONAL")
    rig.frames.clear()
    for _ in range(9):
        rig.master.sync.transmit()
        time.sleep(0.01)
    time.sleep(0.02)
    assert len(rig.seen(0x180 + NODE)) == 3  # one TPDO every 3rd SYNC
    rig.frames.clear()
    time.sleep(0.5)
    n = len(rig.seen(0x280 + NODE))
    assert 7 <= n <= 11  # about every 50 ms, without any change


def test_event_tpdo_honours_inhibit_time(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=1.0)
    node = rig.node()
    configure(node, [[(0x6040, 0)]], [([(0x606C, 0)], 255)])
    node.sdo[0x1800][3].raw = 1000  # 100 ms inhibit time (units of 100 us)
    node.sdo[0x6060].raw = 3
    node.sdo[0x6083].raw = 100_000
    node.nmt.state = "OPERATIONAL"
    enable(node, drive)
    rig.frames.clear()
    node.sdo[0x60FF].raw = 20_000  # velocity changes continuously for 0.2 s
    time.sleep(0.45)
    times = len(rig.seen(0x180 + NODE))
    assert 2 <= times <= 6  # changes every tick, but at most one frame per 100 ms


def test_position_wraps_like_int32(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=1.0, initial_position=2**31 - 5_000)
    node = rig.node()
    node.sdo[0x6060].raw = 3
    enable(node, drive)
    assert node.sdo[0x6064].raw == 2**31 - 5_000
    node.sdo[0x60FF].raw = 100_000
    assert wait_for(lambda: node.sdo[0x6064].raw < 0, 1.0)  # wrapped to negative
    assert drive.physical_counts() > 5_000  # the wheel itself went on, from 0 at power-up


def test_fault_emcy_and_rising_edge_reset(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=1.0)
    node = rig.node()
    node.sdo[0x6060].raw = 3
    node.sdo[0x6085].raw = 200_000
    enable(node, drive)
    node.sdo[0x60FF].raw = 20_000
    assert wait_for(lambda: drive.velocity_counts() > 19_000)
    drive.inject_fault(0x2310)
    emcy = node.emcy.wait(0x2310, timeout=1.0)
    assert emcy is not None and emcy.register & 0x03 == 0x03  # generic + current
    assert str(drive.state()) == "FAULT REACTION ACTIVE"
    assert wait_for(lambda: str(drive.state()) == "FAULT", 1.0)
    assert node.sdo[0x6041].raw & 0x4F == 0x08
    assert node.sdo[0x603F].raw == 0x2310
    assert abs(drive.velocity_counts()) < 1.0
    # Holding bit 7 high does not reset; only its rising edge does.
    node.sdo[0x6040].raw = 0x80
    assert str(drive.state()) == "SWITCH ON DISABLED"
    assert node.sdo[0x603F].raw == 0
    drive.inject_fault(0x4210)
    assert str(drive.state()) == "FAULT"  # not enabled: no reaction phase
    node.sdo[0x6040].raw = 0x80  # bit 7 still high: no edge
    assert str(drive.state()) == "FAULT"
    node.sdo[0x6040].raw = 0x00
    node.sdo[0x6040].raw = 0x80
    assert str(drive.state()) == "SWITCH ON DISABLED"
    assert wait_for(lambda: any(d[:2] == b"\x00\x00" for d in rig.seen(0x80 + NODE)))  # reset


def test_heartbeat_producer_and_stop(rig: Rig) -> None:
    drive = rig.drive()
    node = rig.node()
    node.sdo[0x1017].raw = 20
    time.sleep(0.2)
    beats = rig.seen(0x700 + NODE)
    assert len(beats) >= 6 and beats[-1] == b"\x7f"
    node.nmt.state = "OPERATIONAL"
    assert node.nmt.wait_for_heartbeat(0.5) == "OPERATIONAL"
    drive.stop_heartbeat()
    time.sleep(0.05)
    rig.frames.clear()
    time.sleep(0.2)
    assert rig.seen(0x700 + NODE) == []


def test_host_heartbeat_lost_quick_stops_and_sends_emcy(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=1.0)
    node = rig.node()
    node.sdo[0x1016][1].raw = (HOST << 16) | 100  # watch node 0x7F, 100 ms
    node.sdo[0x6060].raw = 3
    enable(node, drive)
    node.sdo[0x60FF].raw = 20_000
    beat = rig.master.send_periodic(0x700 + HOST, b"\x05", 0.02)
    try:
        time.sleep(0.3)
        assert str(drive.state()) == "OPERATION ENABLED"  # host alive: keeps going
    finally:
        beat.stop()
    emcy = node.emcy.wait(0x8130, timeout=1.0)
    assert emcy is not None
    # 6007h = 3 (quick stop): QUICK STOP ACTIVE, ramp down, then SWITCH ON DISABLED.
    assert wait_for(lambda: str(drive.state()) == "SWITCH ON DISABLED", 1.0)
    assert abs(drive.velocity_counts()) < 1.0


def test_abort_option_fault(rig: Rig) -> None:
    drive = rig.drive(VENDOR_EDS / "maxon_epos4.eds")
    node = rig.node(VENDOR_EDS / "maxon_epos4.eds")
    node.sdo[0x6007].raw = 1  # fault signal
    node.sdo[0x1016][1].raw = (HOST << 16) | 50
    node.sdo[0x6060].raw = 3
    enable(node, drive)
    rig.master.send_message(0x700 + HOST, b"\x05")
    assert wait_for(lambda: str(drive.state()) == "FAULT", 1.0)
    assert drive.read(0x603F) == b"\x30\x81"


def test_reboot_bootup_defaults_and_counter(rig: Rig) -> None:
    drive = rig.drive(counts_per_unit=1.0)
    node = rig.node()
    node.sdo[0x1017].raw = 50
    node.sdo[0x6060].raw = 3
    enable(node, drive)
    node.sdo[0x60FF].raw = 50_000
    time.sleep(0.4)
    assert node.sdo[0x6064].raw > 15_000
    rig.frames.clear()
    drive.reboot()
    assert wait_for(lambda: rig.seen(0x700 + NODE)[:1] == [b"\x00"])  # boot-up
    assert node.sdo[0x1017].raw == 0  # defaults restored
    assert node.sdo[0x6060].raw == 0
    assert str(drive.state()) == "SWITCH ON DISABLED"
    # The counter restarted at 0; the wheel coasts on (< 50k counts/s * 0.1 s lag).
    assert abs(node.sdo[0x6064].raw) < 5_500
    assert drive.nmt_state == "PRE-OPERATIONAL"


def test_nmt_reset_commands(rig: Rig) -> None:
    drive = rig.drive()
    node = rig.node()
    node.sdo[0x6060].raw = 3
    node.sdo[0x1017].raw = 30
    rig.frames.clear()
    node.nmt.state = "RESET COMMUNICATION"
    assert wait_for(lambda: b"\x00" in rig.seen(0x700 + NODE))
    assert node.sdo[0x1017].raw == 0  # communication objects back to defaults
    assert node.sdo[0x6060].raw == 3  # application objects kept
    rig.frames.clear()
    node.nmt.state = "RESET"
    assert wait_for(lambda: b"\x00" in rig.seen(0x700 + NODE))
    assert node.sdo[0x6060].raw == 0
    node.nmt.state = "STOPPED"
    time.sleep(0.02)
    assert drive.nmt_state == "STOPPED"
    node.sdo.RESPONSE_TIMEOUT = 0.05
    with pytest.raises(SdoCommunicationError):
        _ = node.sdo[0x1000].raw  # no SDO in STOPPED


def test_freeze_goes_silent(rig: Rig) -> None:
    drive = rig.drive()
    node = rig.node()
    node.sdo[0x1017].raw = 20
    drive.freeze()
    time.sleep(0.05)
    rig.frames.clear()
    time.sleep(0.1)
    assert rig.frames == []
    node.sdo.RESPONSE_TIMEOUT = 0.05
    with pytest.raises(SdoCommunicationError):
        _ = node.sdo[0x1000].raw
    drive.thaw()
    assert node.sdo[0x1000].raw == 0x00020192


def test_frame_loss_and_noise(rig: Rig) -> None:
    lossy = rig.drive(frame_loss=1.0)
    node = rig.node()
    node.sdo[0x1017].raw = 10
    node.nmt.state = "OPERATIONAL"
    time.sleep(0.1)
    assert rig.seen(0x700 + NODE) == [b"\x00"]  # only the boot-up got through
    assert lossy.nmt_state == "OPERATIONAL"
    noisy = rig.drive(node_id=6, encoder_noise=50.0, seed=1)
    n6 = rig.node(node_id=6)
    values = {n6.sdo[0x6064].raw for _ in range(20)}
    assert len(values) > 10 and noisy.physical_counts() == 0.0


def test_close_detaches(rig: Rig) -> None:
    drive = rig.drive()
    drive.close()
    drive.close()  # idempotent
    assert NODE not in rig.sim_net.nodes


def test_the_rated_current_follows_6075h_as_written_and_as_booted(rig: Rig) -> None:
    """The health model reads 6075h once (each current's per mille divides by it), and
    again after an SDO download of it and after a reset node restores its default."""
    drive = rig.drive()
    node = rig.node()
    node.nmt.state = "PRE-OPERATIONAL"
    default = drive.health.rated_current_a()
    node.sdo[0x6075].raw = 4321  # mA
    assert drive.health.rated_current_a() == pytest.approx(4.321)
    node.sdo[0x6075].raw = 1234
    assert drive.health.rated_current_a() == pytest.approx(1.234)
    drive.reboot()
    assert wait_for(lambda: drive.nmt_state != "INITIALISING")
    assert wait_for(lambda: drive.health.rated_current_a() == pytest.approx(default))
