"""The CiA 301 side of a simulated drive: NMT, the SDO server, PDOs, SYNC, heartbeats
and EMCY.

Built on :class:`canopen.LocalNode` (object dictionary from an EDS, SDO server) and
adding what it lacks (canopen #555, #558): NMT states with boot-up frames and both
resets, TPDOs answering SYNC and RPDOs applied to the dictionary, as the master
configured them (taken from 14xxh-1Axxh on entering OPERATIONAL); event-driven TPDOs
with inhibit and event times; a heartbeat producer (1017h) and consumer (1016h);
silence when frozen, and random frame loss. :class:`SimNode` handles the frames; what
reading and writing an object does is :mod:`omnican.sim.objects`', the PDOs at run time
:mod:`omnican.sim.process_data`'s, the heartbeats' bookkeeping :mod:`omnican.sim.heartbeat`'s,
putting the frames on the bus :mod:`omnican.sim.transmit`'s.

What the device does with its objects is the :class:`Application`'s (the CiA 402
drive, :mod:`omnican.sim.drive`): it provides the dynamic objects' readers and hears
about writes, NMT resets and a lost master. Frame handlers run on the network's
Notifier thread (or the sender's, in lock-step) under the drive's lock.
"""

from __future__ import annotations

import logging
import random
import struct
import threading
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import canopen
from canopen import objectdictionary as od

from omnican.clock import Clock
from omnican.protocol.cia301 import (
    COB_ID_MASK,
    EMCY_BASE,
    EMCY_HEARTBEAT,
    EMCY_PDO_LENGTH,
    ERROR_REGISTER_COMMUNICATION,
    ERROR_REGISTER_GENERIC,
    HEARTBEAT_BASE,
    NMT_COB_ID,
    NMT_STATE_NAMES,
    SYNC_COB_ID,
    SYNC_COB_ID_OBJECT,
    NmtCommand,
    NmtState,
)
from omnican.sim.block_download import BlockDownloadServer
from omnican.sim.heartbeat import Heartbeat
from omnican.sim.objects import NodeObjects, ObjectHooks
from omnican.sim.pdo import read_uint
from omnican.sim.process_data import ProcessData
from omnican.sim.transmit import SEND_WARNING_EVERY_S, Transmitter  # noqa: F401 (here too)

logger = logging.getLogger(__name__)

_OPERATIONAL = int(NmtState.OPERATIONAL)  # a plain name: NmtState.X is a descriptor call

Key = tuple[int, int]
Reader = Callable[[], int]


class Application(ObjectHooks, Protocol):
    """What the node side needs from the device behind it (besides its objects' hooks)."""

    @property
    def last_advance(self) -> float:
        """The time the device's state was last brought up to (s)."""
        ...

    def advance(self, now: float) -> None:
        """Bring the device up to ``now`` (before a frame acts on it)."""

    def booted(self, reset_node: bool) -> None:
        """The node booted: ``reset_node`` a power-on or NMT reset node (application
        objects at their defaults), else a reset communication."""

    def abort_connection(self) -> None:
        """The master is gone (its heartbeat timed out, an NMT stop or reset)."""

    def connection_restored(self) -> None:
        """A lost master's heartbeat is back."""


class SimNode:
    """The communication side of one simulated drive on a connected network.

    Args:
        network: the connected network the node answers on.
        local: the LocalNode holding the object dictionary and the SDO server.
        app: the device behind it.
        readers: dynamic objects, (index, subindex) -> raw value, read instead of the
            stored value (by SDO uploads and TPDOs alike).
        defaults: values for objects the EDS gives none (besides the identity).
        lock: the drive's lock, taken by every frame handler.
        clock: the drive's clock.
        rng: random source of frame loss.
        frame_loss: probability that a PDO or heartbeat frame is lost (either way).
        max_mapping_entries, remappable, accept_unmappable: see
            :class:`~omnican.sim.SimulatedDrive`.
    """

    def __init__(self, network: canopen.Network, local: canopen.LocalNode, app: Application,
                 *, readers: Mapping[Key, Reader], defaults: Mapping[Key, int],
                 lock: threading.RLock, clock: Clock, rng: random.Random,
                 frame_loss: float = 0.0, max_mapping_entries: int | None = None,
                 remappable: bool = True, accept_unmappable: bool = False) -> None:
        self.network = network
        self.local = local
        if local.id is None:
            raise ValueError("the LocalNode has no node id")
        self.node_id: int = local.id
        self.dictionary: od.ObjectDictionary = local.object_dictionary
        self.app = app
        self.readers = dict(readers)
        self.lock = lock
        self.clock = clock
        self._rng = rng
        self.frame_loss = frame_loss

        self.nmt = NmtState.BOOT_UP
        self.frozen = False
        self.closed = False
        #: seconds from an NMT reset to the boot-up frame: the drive answers SDOs
        #: meanwhile (its communication is up, its application still starting) but sends
        #: no heartbeat; another reset starts the wait again
        self.boot_delay_s = 0.0
        self._boot_due: tuple[float, bool] | None = None  # (when, reset node) of a slow boot
        #: seconds from an SDO request to its answer (a slow SDO server)
        self.sdo_delay_s = 0.0
        self._sdo_answers: list[tuple[float, bytes]] = []  # (due, frame) held back
        self.heartbeat = Heartbeat()
        #: heartbeats on the producer's period only, as lely's producer sends them: the
        #: first one period after 1017h is written, none at an NMT state change (False:
        #: also at once on both, as the simulator always did)
        self.heartbeat_periodic = False
        self._subscribed_hb: set[int] = set()
        self._tx = Transmitter(network, self.node_id, clock)

        # LocalNode produces its heartbeat from a 1017h write callback; we do it ourselves.
        local._write_callbacks.remove(local.nmt.on_write)
        #: what reading and writing the objects does (LocalNode's callbacks)
        self.objects = NodeObjects(
            local, app, self.readers, defaults, self._load_heartbeat_config,
            max_mapping_entries=max_mapping_entries, remappable=remappable,
            accept_unmappable=accept_unmappable)
        self.pdos = ProcessData(local, self.readers, self._send, self.objects.compile_write,
                                stamp=getattr(app, "event_stamp", None),
                                stamped=getattr(app, "stamped", None))
        network.add_node(local)
        # Replace LocalNode's NMT and SDO handlers with ones that honour freeze/NMT state.
        network.unsubscribe(NMT_COB_ID, local.nmt.on_command)
        network.unsubscribe(local.sdo.rx_cobid, local.sdo.on_request)
        network.subscribe(NMT_COB_ID, self._on_nmt)
        network.subscribe(local.sdo.rx_cobid, self._on_sdo)
        local.sdo.send_response = self._send_sdo_answer  # type: ignore[method-assign]
        #: block downloads, which canopen's SDO server lacks (its sinks: 1F50h's taker)
        self.block = BlockDownloadServer(local, self._send_sdo_answer, clock.now)
        #: called at every boot with ``reset_node`` (after the objects' defaults)
        self.on_boot: list[Callable[[bool], None]] = []
        self._sync_cob = read_uint(local.get_data, SYNC_COB_ID_OBJECT, 0, "<I",
                                   SYNC_COB_ID) & COB_ID_MASK
        network.subscribe(self._sync_cob, self._on_sync)

    @property
    def nmt_state(self) -> str:
        return NMT_STATE_NAMES.get(self.nmt, hex(self.nmt))

    def prefill_defaults(self) -> None:
        """Give every numeric object without a default a value, as a drive would (see
        :meth:`NodeObjects.prefill_defaults`)."""
        self.objects.prefill_defaults()

    # ---------------------------------------------------------------- NMT

    def boot(self, reset_node: bool) -> None:
        """Boot-up frame and PRE-OPERATIONAL; ``reset_node``: every object back to its
        default, else the communication objects only."""
        self._boot_due = None
        self.nmt = NmtState.BOOT_UP
        self.pdos.stop()
        self.objects.restore_defaults(reset_node)
        self.block.reset()
        self.app.booted(reset_node)
        for hook in self.on_boot:
            hook(reset_node)
        self.heartbeat.enabled = True
        self._send(HEARTBEAT_BASE + self.node_id, bytes([NmtState.BOOT_UP]), droppable=False)
        self.nmt = NmtState.PRE_OPERATIONAL
        self.heartbeat.restart()
        self._load_heartbeat_config()
        self.heartbeat.last_sent = self.clock.now()

    def _load_heartbeat_config(self) -> None:
        period = self.heartbeat.period_s
        for producer in self.heartbeat.load(self.dictionary, self.local.get_data):
            if producer not in self._subscribed_hb:
                self.network.subscribe(HEARTBEAT_BASE + producer, self._on_heartbeat)
                self._subscribed_hb.add(producer)
        if self.heartbeat_periodic and self.heartbeat.period_s != period:
            self.heartbeat.last_sent = self.clock.now()  # the producer's timer starts now

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        with self.lock:
            if self.frozen:
                return
            cmd = data[0]
            now = self.clock.now()
            self.app.advance(now)
            if cmd == NmtCommand.START:
                self._enter_operational()
            elif cmd == NmtCommand.STOP:
                self.app.abort_connection()
                self.nmt = NmtState.STOPPED
                self.pdos.stop()
            elif cmd == NmtCommand.ENTER_PRE_OPERATIONAL:
                self.nmt = NmtState.PRE_OPERATIONAL
                self.pdos.stop()
            elif cmd == NmtCommand.RESET_NODE:
                self._reset(reset_node=True, now=now)
            elif cmd == NmtCommand.RESET_COMMUNICATION:
                self.app.abort_connection()
                self._reset(reset_node=False, now=now)
            if not self.heartbeat_periodic:
                self._send_heartbeat(now)  # heartbeats show a new state at once

    def _reset(self, reset_node: bool, now: float) -> None:
        """An NMT reset: the boot at once, or (``boot_delay_s``) after a while, quiet
        but answering SDOs meanwhile; a reset during that wait starts it again."""
        if self.boot_delay_s <= 0:
            self.boot(reset_node)
            return
        self.nmt = NmtState.BOOT_UP
        self.pdos.stop()
        self.heartbeat.enabled = False
        due = self._boot_due
        self._boot_due = (now + self.boot_delay_s, reset_node or (due is not None and due[1]))

    def _enter_operational(self) -> None:
        for cob in self.pdos.start():
            self.network.subscribe(cob, self._on_rpdo)
        self.nmt = NmtState.OPERATIONAL

    # ---------------------------------------------------------------- SDO

    def _on_sdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            if self.frozen or self.nmt == NmtState.STOPPED or (
                    self.nmt == NmtState.BOOT_UP and self._boot_due is None):
                return
            self.app.advance(self.clock.now())
            if not self.block.on_request(data):
                self.local.sdo.on_request(can_id, data, timestamp)

    def _send_sdo_answer(self, response: bytes | bytearray) -> None:
        """The SDO server's answer: on the bus now, or ``sdo_delay_s`` later."""
        if self.sdo_delay_s > 0:
            self._sdo_answers.append((self.clock.now() + self.sdo_delay_s, bytes(response)))
        else:
            self._send(self.local.sdo.tx_cobid, bytes(response), droppable=False)

    # ------------------------------------------------------------- PDOs

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            if (self.frozen or self.nmt != _OPERATIONAL
                    or (self.frame_loss and self._lost())):
                return
            clock = self.clock  # _frame_time, its lock-step case written out (each SYNC)
            now = clock.now() if clock.lockstep else self._frame_time(timestamp)
            self.app.advance(now)
            self.pdos.sync(now)

    def _frame_time(self, timestamp: float) -> float:
        """When a frame reached the bus, on the monotonic clock: every drive acts on a
        SYNC at the instant it was sent, not when its handler got to run."""
        clock = self.clock
        if clock.lockstep:
            return clock.now()  # delivered the instant it was sent
        age = clock.wall() - timestamp if timestamp else 0.0
        return max(self.app.last_advance, clock.now() - min(max(age, 0.0), 0.05))

    def _on_rpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            rpdo = self.pdos.rpdos.get(can_id)
            if (rpdo is None or self.frozen or self.nmt != _OPERATIONAL
                    or (self.frame_loss and self._lost())):
                return
            if len(data) < rpdo.length:
                self.emcy(EMCY_PDO_LENGTH, ERROR_REGISTER_COMMUNICATION)
                return
            if rpdo.synchronous:
                self.pdos.hold(can_id, bytes(data))
            else:
                now = self._frame_time(timestamp)
                self.app.advance(now)
                self.pdos.apply(rpdo, bytes(data))
                self.event_tpdos(now)

    def event_tpdos(self, now: float) -> None:
        """Send the event-driven TPDOs that are due (in OPERATIONAL)."""
        if self.nmt == _OPERATIONAL:
            self.pdos.events(now)

    # ------------------------------------------------------ heartbeat, EMCY

    def tick(self, now: float) -> None:
        """Time-driven work: the heartbeat, the consumer timeouts, event TPDOs (under
        the lock, the device brought up to ``now``)."""
        if self.frozen:
            return
        if self._boot_due is not None and now >= self._boot_due[0]:
            reset_node = self._boot_due[1]
            self._boot_due = None
            self.boot(reset_node)
        if self.block.active:
            self.block.expire(now)
        while self._sdo_answers and now >= self._sdo_answers[0][0]:
            self._send(self.local.sdo.tx_cobid, self._sdo_answers.pop(0)[1], droppable=False)
        heartbeat = self.heartbeat
        if heartbeat.pending(now):  # (nothing, nearly every tick)
            if heartbeat.due(now):
                sent_at = heartbeat.next_from(now)  # the timer's cadence, kept
                self._send_heartbeat(now)
                heartbeat.last_sent = sent_at
            for producer in heartbeat.expired(now):
                logger.info("simulated node %d lost the heartbeat of node %d", self.node_id,
                            producer)
                self.emcy(EMCY_HEARTBEAT,
                          ERROR_REGISTER_GENERIC | ERROR_REGISTER_COMMUNICATION)
                self.app.abort_connection()
        if self.nmt == _OPERATIONAL:
            self.pdos.events(now)

    def _on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        producer = can_id - HEARTBEAT_BASE
        with self.lock:
            if self.frozen or producer not in self.heartbeat.timeouts:
                return
            if self.heartbeat.heard(producer, self.clock.now()):
                self.app.connection_restored()

    def _send_heartbeat(self, now: float) -> None:
        heartbeat = self.heartbeat
        if heartbeat.enabled and heartbeat.period_s > 0:
            heartbeat.last_sent = now
            self._send(HEARTBEAT_BASE + self.node_id, bytes([self.nmt]))

    def emcy(self, code: int, register: int) -> None:
        """Send an EMCY frame (never lost to frame loss)."""
        self._send(EMCY_BASE + self.node_id, struct.pack("<HB5s", code, register, b""),
                   droppable=False)

    def _lost(self) -> bool:
        return self.frame_loss > 0 and self._rng.random() < self.frame_loss

    def _send(self, cob_id: int, data: bytes, droppable: bool = True) -> None:
        """``data`` on ``cob_id``, unless the node is frozen or closed, or (``droppable``)
        the frame is lost (:attr:`frame_loss`)."""
        if self.frozen or self.closed or (droppable and self.frame_loss and self._lost()):
            return
        self._tx.send(cob_id, data)

    # ------------------------------------------------------------ lifecycle

    def detach(self) -> None:
        """Leave the network: every handler subscribed, the node registered."""
        net = self.network
        for cob, handler in [(NMT_COB_ID, self._on_nmt), (self.local.sdo.rx_cobid, self._on_sdo),
                             (self._sync_cob, self._on_sync)]:
            _unsubscribe(net, cob, handler)
        for cob in list(self.pdos.rpdos):
            _unsubscribe(net, cob, self._on_rpdo)
        for producer in self._subscribed_hb:
            _unsubscribe(net, HEARTBEAT_BASE + producer, self._on_heartbeat)
        if self.node_id in net.nodes and net.nodes[self.node_id] is self.local:
            # LocalNode.remove_network would unsubscribe handlers we already replaced.
            del net.nodes[self.node_id]


def _unsubscribe(net: canopen.Network, cob: int, handler: Any) -> None:
    if handler in net.subscribers.get(cob, []):
        net.unsubscribe(cob, handler)
