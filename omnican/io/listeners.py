"""What the bus hands its frames to besides canopen's subscribers.

The traffic count (frames and worst-case bits, both directions, for the bus load), the
taps (listeners added while the bus runs: live views), and canopen's network with every
sent frame counted and recorded. :class:`omnican.io.bus.CanBus`
owns one of each.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

import can

from omnican.io.bus_watch import describe_receive_error
from omnican.io.network import Network
from omnican.plan.pdo import frame_bits
from omnican.protocol.cia301 import SDO_RX_BASE

if TYPE_CHECKING:
    from omnican.io.owner import BusOwner

RX_ERROR_PAUSE_S = 0.05
FRAME_BITS = tuple(frame_bits(n) for n in range(65))  # worst case, by data length


class Taps(can.Listener):
    """Listeners added while the bus runs (live views). It sits in every Notifier from the
    start, so adding one never touches a running Notifier (or races a reconnect). Tuples
    are replaced whole: the threads iterate them unlocked."""

    def __init__(self) -> None:
        self.received: tuple[can.Listener, ...] = ()
        self.sent: tuple[can.Listener, ...] = ()
        self._lock = threading.Lock()

    def add(self, listener: can.Listener, sent: bool) -> None:
        with self._lock:
            self.received += (listener,)
            if sent:
                self.sent += (listener,)

    def remove(self, listener: can.Listener) -> None:
        with self._lock:
            self.received = tuple(t for t in self.received if t is not listener)
            self.sent = tuple(t for t in self.sent if t is not listener)

    def on_message_received(self, msg: can.Message) -> None:
        for tap in self.received:
            tap.on_message_received(msg)

    def stop(self) -> None:
        """Called by the Notifier when it stops: the taps stay for the next one."""


class Traffic(can.Listener):
    """Counts frames and worst-case bits seen on the bus, both directions.

    Received frames are counted on the Notifier thread, sent ones on whichever thread
    sent them (the control loop, a configuration worker): one lock keeps the sums exact.
    Also notices receive errors, which python-can hands to ``on_error``."""

    def __init__(self, owner: BusOwner) -> None:
        self._owner = owner
        self._lock = threading.Lock()
        self._frames = 0
        self._bits = 0
        # The control loop's own sends: one writer, no lock needed.
        self.loop_frames = 0
        self.loop_bits = 0

    @property
    def frames(self) -> int:
        return self._frames + self.loop_frames

    @property
    def bits(self) -> int:
        return self._bits + self.loop_bits

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self._frames += 1
            self._bits += FRAME_BITS[len(msg.data)]
        if msg.is_error_frame:
            self._owner.controller.on_error_frame(msg.arbitration_id, msg.data)
        if self._owner.rx_error is not None:
            self._owner.rx_error = None  # frames arrive again

    def count_sent(self, data_len: int) -> None:
        with self._lock:
            self._frames += 1
            self._bits += FRAME_BITS[data_len]

    def on_error(self, exc: Exception) -> None:
        """python-can's Notifier calls this when a receive fails (an interface that went
        down, a hub that died). Handling it keeps the Notifier thread alive, without a
        traceback; the pause keeps a permanently failing receive from spinning."""
        self._owner.rx_error = describe_receive_error(self._owner.bus_kwargs, exc)
        time.sleep(RX_ERROR_PAUSE_S)

    def stop(self) -> None:
        pass


class CountingNetwork(Network):
    """The shared-bus network (:mod:`omnican.io.network`) with every sent frame counted and
    recorded, and the configuration SDO requests counted per node (a node whose answers
    outnumber them is two devices on one id)."""

    def __init__(self, owner: BusOwner) -> None:
        super().__init__()
        self._owner = owner
        self.sdo_requests: dict[int, int] = {}  # node id -> configuration requests sent

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if SDO_RX_BASE < can_id <= SDO_RX_BASE + 0x7F:
            node = can_id - SDO_RX_BASE
            self.sdo_requests[node] = self.sdo_requests.get(node, 0) + 1
        if self._owner.lockstep:  # the answers arrive inside the send: record it first
            self._owner._sent(can_id, data)
            super().send_message(can_id, data, remote)
            return
        super().send_message(can_id, data, remote)
        self._owner._sent(can_id, data)
