"""An in-process CAN channel for lock-step simulation.

python-can's ``virtual`` bus hands frames to the other buses of a channel through
queues that a receiving thread must poll. In lock-step there are no such threads:
a frame sent on a :class:`LockstepBus` reaches the receiver of every other bus on the
channel at once, on the sender's thread, stamped with the simulated clock. An SDO
request is therefore answered before ``send`` returns, and a SYNC's TPDOs are
delivered before the SYNC's ``send`` returns, in the order a real bus would carry
them.

A receiver may take standard data frames as values (COB-ID, data, timestamp: a
:data:`FrameReceiver`, beside the message receiver): the host's bus and the simulator's
network do while only canopen's subscribers and the traffic count hear them, and a
lock-step run then makes no message object per frame and peer.

Receivers only copy values and must not send from the receiving call while holding
a lock the sender holds (omnican's frame handlers never send).
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable
from typing import Any, ClassVar

import can

from omnican.clock import Clock

Receiver = Callable[[can.Message], None]
#: Takes a standard data frame as values (COB-ID, a copy of its data, its timestamp), or
#: returns False to be given it as a message (to the bus's :data:`Receiver`) instead.
FrameReceiver = Callable[[int, bytearray, float], bool]
_new = object.__new__


class LockstepBus(can.BusABC):
    """One node's connection to an in-process lock-step channel."""

    _channels: ClassVar[dict[str, list[LockstepBus]]] = {}
    _registry_lock: ClassVar[threading.Lock] = threading.Lock()
    #: Counts the changes of who hears what (a bus joins or leaves a channel, a receiver
    #: is set): a bus's list of the peers it sends to, and their frame receivers, is
    #: made again only after one.
    _changes: ClassVar[int] = 0

    def __init__(self, channel: str, clock: Clock, **kwargs: Any) -> None:
        self.channel_info = f"lock-step channel {channel!r}"
        self.channel = channel
        self._clock = clock
        self._receiver: Receiver | None = None
        self._frames: FrameReceiver | None = None
        self._queue: collections.deque[can.Message] = collections.deque()
        self._peers: tuple[tuple[LockstepBus, FrameReceiver | None], ...] = ()
        self._peers_as_of = -1  # the _changes they were listed at
        with self._registry_lock:
            self._channels.setdefault(channel, []).append(self)
            LockstepBus._changes += 1
        super().__init__(channel=channel, **kwargs)

    def set_receiver(self, receiver: Receiver | None, frames: FrameReceiver | None = None
                     ) -> None:
        """Frames for this bus go to ``receiver`` at once (None: queue them for recv());
        ``frames``: standard data frames go to it first, as values, no message made (it
        returns False for one it wants as a message: ``receiver`` has that one)."""
        with self._registry_lock:
            self._receiver = receiver
            self._frames = frames if receiver is not None else None
            LockstepBus._changes += 1

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or msg.is_fd
                or msg.bitrate_switch or msg.error_state_indicator
                or msg.dlc != len(msg.data)):
            self._send_message(msg)
        else:  # a standard data frame: its values are all it carries
            self.send_frame(msg.arbitration_id, msg.data)

    def send_frame(self, can_id: int, data: bytes | bytearray) -> None:
        """:meth:`send` of a standard data frame (an 11-bit ``can_id``, its dlc the length
        of ``data``), given as values: no message made where a peer takes it as values
        (its :data:`FrameReceiver`)."""
        if self._is_shutdown:
            raise can.CanOperationError("the lock-step bus is shut down")
        stamp = self._clock.wall()
        if self._peers_as_of != LockstepBus._changes:
            self._list_peers()
        for peer, frames in self._peers:
            if not peer._is_shutdown:
                if frames is not None and frames(can_id, bytearray(data), stamp):
                    continue
                out: can.Message = _new(can.Message)  # see _send_message
                out.timestamp = stamp
                out.arbitration_id = can_id
                out.is_extended_id = False
                out.is_remote_frame = False
                out.is_error_frame = False
                out.channel = self.channel
                out.is_fd = False
                out.is_rx = True
                out.bitrate_switch = False
                out.error_state_indicator = False
                out.data = bytearray(data)
                out.dlc = len(data)
                receiver = peer._receiver
                if receiver is not None:
                    receiver(out)
                else:
                    peer._queue.append(out)

    def _list_peers(self) -> None:
        """The other buses of the channel, each with its frame receiver, as of now."""
        with self._registry_lock:
            self._peers = tuple((peer, peer._frames) for peer in
                                self._channels.get(self.channel, ()) if peer is not self)
            self._peers_as_of = LockstepBus._changes

    def _send_message(self, msg: can.Message) -> None:
        """:meth:`send` of any other frame: each peer a message of its own."""
        if self._is_shutdown:
            raise can.CanOperationError("the lock-step bus is shut down")
        stamp = self._clock.wall()
        channel = self.channel
        for peer in self._channels.get(channel, ()):
            if peer is not self and not peer._is_shutdown:
                # What the peer receives: a message of its own with the same frame,
                # stamped, received. Made field by field, here: can.Message's
                # constructor (keywords, data conversion) and a call per peer are most
                # of what a frame costs the lock-step bus.
                out: can.Message = _new(can.Message)
                out.timestamp = stamp
                out.arbitration_id = msg.arbitration_id
                out.is_extended_id = msg.is_extended_id
                out.is_remote_frame = msg.is_remote_frame
                out.is_error_frame = msg.is_error_frame
                out.channel = channel
                out.is_fd = msg.is_fd
                out.is_rx = True
                out.bitrate_switch = msg.bitrate_switch
                out.error_state_indicator = msg.error_state_indicator
                out.data = bytearray(msg.data)
                out.dlc = msg.dlc
                receiver = peer._receiver
                if receiver is not None:
                    receiver(out)
                else:
                    peer._queue.append(out)

    def push(self, msg: can.Message) -> None:
        """Queue ``msg`` for :meth:`recv` (a receiver that reads through recv calls this
        first)."""
        self._queue.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        queue = self._queue
        # Tested, not caught: an empty queue is the usual case (the control loop polls
        # once a cycle, and its frames come through the receiver), and an IndexError
        # raised and caught is dearer than the test.
        return (queue.popleft() if queue else None), False

    def shutdown(self) -> None:
        with self._registry_lock:
            peers = self._channels.get(self.channel, [])
            if self in peers:
                peers.remove(self)
            if not peers:
                self._channels.pop(self.channel, None)
            LockstepBus._changes += 1
        super().shutdown()



def listeners_receiver(listeners: list[Any]) -> Receiver:
    """A receiver that hands each frame to python-can listeners, as a Notifier would."""

    def receive(msg: can.Message) -> None:
        for listener in listeners:
            listener.on_message_received(msg)

    return receive
