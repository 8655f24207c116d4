"""How a simulated drive gets a node id: the LSS slave (CiA 305), and the drives of a
simulated base that answer LSS, start without a node id when asked, and keep what they
stored across a power cycle.

- :class:`LssSlave` is the slave's protocol, pure (frames in, frames out): switch state
  global and selective, fast scan bit by bit, configure node id and bit timing, store,
  inquire identity and node id, identify remote and non-configured slaves.
- :class:`SimLss` puts them on a :class:`~omnican.sim.base.SimulatedBase`: one slave per
  drive on the LSS COB-IDs (7E5h in, 7E4h out), drives that start unconfigured (node id
  FFh: no NMT, SDO or heartbeat until they get one), a drive made anew when it takes an
  id (on leaving the LSS configuration state without one, else at its next NMT reset),
  and the power cycle (:meth:`SimLss.power_cycle`): what was stored in the drive's
  memory (:mod:`omnican.sim.memory`: the LSS node id and bit timing, what 1010h saved)
  comes back, the rest is lost.
"""

from __future__ import annotations

import enum
import logging
import struct
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.cia301 import IDENTITY, NMT_COB_ID, NmtCommand
from omnican.sim.memory import UNCONFIGURED, NonVolatile, ParameterStore

if TYPE_CHECKING:
    import canopen

    from omnican.sim.drive import SimulatedDrive
    from omnican.sim.truth import GroundTruth

logger = logging.getLogger(__name__)

LSS_MASTER_COB_ID = 0x7E5  # master -> slaves
LSS_SLAVE_COB_ID = 0x7E4  # slaves -> master

CS_SWITCH_GLOBAL = 0x04
CS_CONFIGURE_NODE_ID = 0x11
CS_CONFIGURE_BIT_TIMING = 0x13
CS_ACTIVATE_BIT_TIMING = 0x15
CS_STORE = 0x17
CS_SWITCH_SELECTIVE = range(0x40, 0x44)  # vendor, product, revision, serial
CS_SWITCH_SELECTIVE_ANSWER = 0x44
CS_IDENTIFY_REMOTE = range(0x46, 0x4C)  # vendor, product, revision low/high, serial low/high
CS_IDENTIFY_NON_CONFIGURED = 0x4C
CS_IDENTIFY_SLAVE = 0x4F
CS_IDENTIFY_NON_CONFIGURED_SLAVE = 0x50
CS_FAST_SCAN = 0x51
CS_INQUIRE_IDENTITY = range(0x5A, 0x5E)  # vendor, product, revision, serial
CS_INQUIRE_NODE_ID = 0x5E

#: CiA 305 table 0 of bit timings: index -> bit/s (5 is reserved, 9 automatic).
BIT_TIMINGS = {0: 1_000_000, 1: 800_000, 2: 500_000, 3: 250_000, 4: 125_000,
               6: 50_000, 7: 20_000, 8: 10_000}


class LssState(enum.Enum):
    WAITING = 0
    CONFIGURATION = 1


@dataclass(frozen=True)
class LssAnswer:
    """What the slave does with one request: ``frame`` (data of a 7E4h frame) to send,
    ``activate``: take the pending node id now (it had none: it boots with it)."""

    frame: bytes | None = None
    activate: bool = False


def _answer(cs: int, *values: int, fmt: str = "") -> LssAnswer:
    data = struct.pack("<B" + fmt, cs, *values)
    return LssAnswer(data + bytes(8 - len(data)))


class LssSlave:
    """The LSS slave of one device (CiA 305), pure: :meth:`handle` takes the data of a
    7E5h frame and says what to answer.

    Args:
        identity: vendor, product, revision, serial (its LSS address, 1018h sub 1-4).
        memory: the device's non-volatile memory (LSS store writes the pending node id
            and bit timing there).
        active_id: the node id it runs with now (FFh: none).
        refuse_store: answer "store configuration" with error 2 (storage media access
            error), as a drive whose memory failed.
    """

    def __init__(self, identity: tuple[int, int, int, int], memory: NonVolatile,
                 active_id: int = UNCONFIGURED, refuse_store: bool = False) -> None:
        self.identity = identity
        self.memory = memory
        self.active_id = active_id
        self.pending_id = active_id
        self.pending_bit_timing: int | None = memory.bit_timing
        self.refuse_store = refuse_store
        self.state = LssState.WAITING
        self._selective: list[int | None] = [None] * 4
        self._remote: list[int | None] = [None] * 6
        self._scan_position = 0

    def reset(self, active_id: int) -> None:
        """A power-on or NMT reset: waiting, running with ``active_id``."""
        self.active_id = self.pending_id = active_id
        self.state = LssState.WAITING
        self._selective = [None] * 4
        self._scan_position = 0

    def handle(self, data: bytes) -> LssAnswer:
        if len(data) < 8:
            return LssAnswer()
        cs = data[0]
        configuring = self.state is LssState.CONFIGURATION
        if cs == CS_SWITCH_GLOBAL:
            return self._switch_global(data[1])
        if cs in CS_SWITCH_SELECTIVE:
            return self._switch_selective(cs - CS_SWITCH_SELECTIVE.start, data)
        if cs in CS_IDENTIFY_REMOTE:
            return self._identify_remote(cs - CS_IDENTIFY_REMOTE.start, data)
        if cs == CS_IDENTIFY_NON_CONFIGURED:
            return (_answer(CS_IDENTIFY_NON_CONFIGURED_SLAVE)
                    if self.active_id == UNCONFIGURED else LssAnswer())
        if cs == CS_FAST_SCAN:
            return self._fast_scan(data)
        if not configuring:
            return LssAnswer()
        if cs == CS_CONFIGURE_NODE_ID:
            node_id = data[1]
            if 1 <= node_id <= 127 or node_id == UNCONFIGURED:
                self.pending_id = node_id
                return _answer(cs, 0, fmt="B")
            return _answer(cs, 1, fmt="B")  # node id out of range
        if cs == CS_CONFIGURE_BIT_TIMING:
            if data[1] != 0 or data[2] not in BIT_TIMINGS:
                return _answer(cs, 1, fmt="B")  # bit timing not supported
            self.pending_bit_timing = data[2]
            return _answer(cs, 0, fmt="B")
        if cs == CS_ACTIVATE_BIT_TIMING:
            return LssAnswer()  # one bus for all: the rate is what the bus has
        if cs == CS_STORE:
            if self.refuse_store:
                return _answer(cs, 2, fmt="B")  # storage media access error
            self.memory.node_id = self.pending_id
            self.memory.bit_timing = self.pending_bit_timing
            return _answer(cs, 0, fmt="B")
        if cs in CS_INQUIRE_IDENTITY:
            return _answer(cs, self.identity[cs - CS_INQUIRE_IDENTITY.start], fmt="I")
        if cs == CS_INQUIRE_NODE_ID:
            return _answer(cs, self.active_id, fmt="B")
        return LssAnswer()

    def _switch_global(self, mode: int) -> LssAnswer:
        if mode == 1:
            self.state = LssState.CONFIGURATION
        elif mode == 0:
            self.state = LssState.WAITING
            if self.active_id == UNCONFIGURED and self.pending_id != UNCONFIGURED:
                # CiA 305: a device without a node id takes the configured one on leaving
                # the configuration state (it boots with it); one with an id waits for
                # an NMT reset communication.
                self.active_id = self.pending_id
                return LssAnswer(activate=True)
        return LssAnswer()

    def _switch_selective(self, part: int, data: bytes) -> LssAnswer:
        if self.state is not LssState.WAITING:
            return LssAnswer()
        value = struct.unpack_from("<I", data, 1)[0]
        if part == 0:
            self._selective = [None] * 4
        self._selective[part] = value
        if part == 3:
            hit = tuple(self._selective) == self.identity
            self._selective = [None] * 4
            if hit:
                self.state = LssState.CONFIGURATION
                return _answer(CS_SWITCH_SELECTIVE_ANSWER)
        return LssAnswer()

    def _identify_remote(self, part: int, data: bytes) -> LssAnswer:
        if part == 0:
            self._remote = [None] * 6
        self._remote[part] = struct.unpack_from("<I", data, 1)[0]
        if part != 5 or None in self._remote:
            return LssAnswer()
        vendor, product, rev_lo, rev_hi, ser_lo, ser_hi = self._remote
        self._remote = [None] * 6
        v, p, r, s = self.identity
        assert rev_lo is not None and rev_hi is not None
        assert ser_lo is not None and ser_hi is not None
        if (vendor, product) == (v, p) and rev_lo <= r <= rev_hi and ser_lo <= s <= ser_hi:
            return _answer(CS_IDENTIFY_SLAVE)
        return LssAnswer()

    def _fast_scan(self, data: bytes) -> LssAnswer:
        """CiA 305 fast scan: only a slave without a node id, waiting, takes part. Bit
        ``checked`` 80h restarts the scan; else the slave answers when the bits of its
        address part ``sub`` from ``checked`` up equal the master's, and with every bit
        checked (0) moves on to part ``next``; back to an earlier part after the last
        (serial) one, the whole address matched: it is selected (configuration)."""
        if self.active_id != UNCONFIGURED or self.state is not LssState.WAITING:
            return LssAnswer()
        number, checked, sub, nxt = struct.unpack_from("<IBBB", data, 1)
        if checked == 0x80:
            self._scan_position = 0
            return _answer(CS_IDENTIFY_SLAVE)
        if checked > 31 or sub > 3 or sub != self._scan_position:
            return LssAnswer()
        mask = (0xFFFFFFFF << checked) & 0xFFFFFFFF
        if (self.identity[sub] ^ number) & mask:
            return LssAnswer()
        if checked == 0:
            self._scan_position = nxt & 3
            if nxt < sub:
                self.state = LssState.CONFIGURATION
        return _answer(CS_IDENTIFY_SLAVE)


@dataclass
class _Slot:
    """One simulated drive's place on the bus: its config node, memory and slave."""

    config_id: int  # the node the config names (the drive is made with it while it has none)
    memory: NonVolatile
    slave: LssSlave
    serial: int


class _Base(Protocol):
    """What :class:`SimLss` uses of a :class:`~omnican.sim.base.SimulatedBase`."""

    cfg: Any
    network: canopen.Network
    scheduler: Any
    drives: list[SimulatedDrive]
    wheel_axes: list[tuple[SimulatedDrive, int]]


class SimLss:
    """The LSS side and the power of a simulated base (see the module docstring).

    Args:
        base: the simulated base (its drives, one per config node, in node order).
        truth: its ground truth (kept where it was when a drive is made anew).
        make: (config node id, node id) -> that config node's drive made with that node
            id, not booted.
        serials: config node id -> the serial its drive reports (1018h sub 4) and
            answers LSS with; default the config's ``[[wheel]] serial``, else the
            drive's own (unconfigured: its config node id).
        unconfigured: every drive starts without a node id (FFh).
        refuse_store: config node ids whose drives refuse LSS "store configuration".
    """

    def __init__(self, base: _Base, truth: GroundTruth,
                 make: Callable[[int, int], SimulatedDrive],
                 serials: Mapping[int, int] | None = None, unconfigured: bool = False,
                 refuse_store: frozenset[int] = frozenset()) -> None:
        self.base = base
        self._truth = truth
        self._make = make
        self._lock = threading.RLock()  # the slaves (LSS requests)
        self._power = threading.RLock()  # making drives anew (slow: not under _lock)
        self._slots: list[_Slot] = []
        self._closed = False
        self._due: list[tuple[int, int]] = []  # (slot, node id): drives to boot with an id
        given = {w.node_id: w.serial for w in base.cfg.wheels if w.serial is not None}
        given.update(serials or {})
        for drive in base.drives:
            try:
                own = struct.unpack("<I", drive.read(IDENTITY, 4)[:4])[0]
            except (SdoAbortedError, struct.error):  # an EDS without the serial (ZLAC8015D)
                own = 0
            serial = given.get(drive.node_id, drive.node_id if unconfigured else own)
            memory = NonVolatile(node_id=UNCONFIGURED if unconfigured else drive.node_id)
            info = drive.dictionary.device_information
            identity = (info.vendor_number or 0, info.product_number or 0,
                        info.revision_number or 0, serial)
            slave = LssSlave(identity, memory, memory.node_id,
                             refuse_store=drive.node_id in refuse_store)
            self._slots.append(_Slot(drive.node_id, memory, slave, serial))
        for i, drive in enumerate(base.drives):
            self._fit(i, drive, online=not unconfigured, boot=False)  # booted if online
        base.network.subscribe(LSS_MASTER_COB_ID, self._on_request)
        base.network.subscribe(NMT_COB_ID, self._on_nmt)
        base.scheduler.add(self._boot_due)

    # ------------------------------------------------------------ what it tells

    def node_ids(self) -> list[tuple[int, int]]:
        """(serial, the node id its drive runs with now (FFh: none)) per drive, in the
        config's node order."""
        return [(s.serial, s.slave.active_id) for s in self._slots]

    def memory(self, serial: int) -> NonVolatile:
        """The non-volatile memory of the drive with ``serial``."""
        for slot in self._slots:
            if slot.serial == serial:
                return slot.memory
        raise KeyError(f"no simulated drive has serial {serial}")

    # ------------------------------------------------------------ the power

    def power_cycle(self) -> None:
        """Every drive off and on again: each comes back with what it stored (its LSS
        node id, else none; the parameters 1010h saved) and nothing else."""
        with self._power:
            with self._lock:
                self._due.clear()
                for slot in self._slots:
                    slot.slave.reset(slot.memory.node_id)
                    slot.slave.pending_bit_timing = slot.memory.bit_timing
            for i, slot in enumerate(self._slots):
                self._replace(i, slot.memory.node_id)

    # ------------------------------------------------------------ the bus

    def _on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if self._closed:
                return
            for i, slot in enumerate(self._slots):
                answer = slot.slave.handle(bytes(data))
                if answer.activate:
                    # Made on the housekeeping thread: this one answers LSS meanwhile (a
                    # master's next fast scan follows at once).
                    self._due.append((i, slot.slave.active_id))
                if answer.frame is not None:
                    self.base.network.send_message(LSS_SLAVE_COB_ID, answer.frame)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """A drive with a node id takes the one LSS configured at its next NMT reset
        (communication or node), CiA 305."""
        if len(data) < 2 or data[0] not in (NmtCommand.RESET_NODE,
                                            NmtCommand.RESET_COMMUNICATION):
            return
        with self._lock:
            if self._closed:
                return
            for i, slot in enumerate(self._slots):
                slave = slot.slave
                if data[1] in (0, slave.active_id) and slave.active_id != UNCONFIGURED \
                        and slave.pending_id not in (slave.active_id, UNCONFIGURED):
                    slave.active_id = slave.pending_id
                    self._due.append((i, slave.active_id))

    def _boot_due(self, now: float) -> None:
        """The drives that took a node id boot with it (on the housekeeping thread)."""
        if not self._due:
            return
        with self._power:
            with self._lock:
                due, self._due = self._due, []
            for i, node_id in due:
                if self._closed:
                    return
                logger.info("simulated drive serial %d takes node id %d",
                            self._slots[i].serial, node_id)
                self._replace(i, node_id)

    def _replace(self, i: int, node_id: int) -> None:
        """Drive ``i`` made anew (a power-on), running as ``node_id`` (FFh: none)."""
        slot, base = self._slots[i], self.base
        old = base.drives[i]
        old.close()
        new = self._make(slot.config_id, slot.config_id if node_id == UNCONFIGURED else node_id)
        pose = self._truth.pose  # the same true pose, the new drive's wheels
        base.drives[:] = [new if d is old else d for d in base.drives]
        base.wheel_axes[:] = [(new if d is old else d, axis) for d, axis in base.wheel_axes]
        self._truth.reset(pose)
        self._fit(i, new, online=node_id != UNCONFIGURED)

    def _fit(self, i: int, drive: SimulatedDrive, online: bool, boot: bool = True) -> None:
        """``drive`` as slot ``i``'s: its serial, its stored parameters (with 1010h and
        1011h), booted when it has a node id, else silent."""
        slot = self._slots[i]
        serial = slot.serial
        with drive.lock:
            drive.comm.readers[(IDENTITY, 4)] = lambda: serial
            ParameterStore(drive, slot.memory)
            if online:
                drive.comm.frozen = False
                if boot:
                    drive.comm.boot(reset_node=True)  # the stored parameters over the defaults
            else:
                drive.comm.frozen = True  # no node id: no NMT, SDO, heartbeat or PDO

    def close(self) -> None:
        with self._power, self._lock:  # after a drive being made anew is in its place
            self._closed = True
        self.base.scheduler.remove(self._boot_due)
        network = self.base.network
        for cob, handler in ((LSS_MASTER_COB_ID, self._on_request),
                             (NMT_COB_ID, self._on_nmt)):
            if handler in network.subscribers.get(cob, []):
                network.unsubscribe(cob, handler)
