"""canopen's ``Network`` for a bus that is shared, the host's and the simulator's.

* Only standard (11-bit) frames reach canopen's subscribers. A robot's bus carries
  29-bit frames too (a battery management system, a charger, J1939 devices), and one
  whose extended id equals a TPDO's COB-ID is not that TPDO. canopen itself dispatches
  by the bare number.
* A subscriber that fails, or a broken frame (an EMCY of two bytes), is logged at most
  once every few seconds per COB-ID, with a count: never a line per frame.
* Subscriptions never change a list the receiving thread may be iterating: canopen's
  ``notify`` iterates ``subscribers[cob]`` while a configuration worker subscribes and
  unsubscribes PDO handlers, and an in-place ``list.remove`` under a running iteration
  skips the next callback. Each change builds a new list and swaps it in.
* No after-send ``check``: canopen raises the Notifier's stored receive error after
  every send; omnican handles those errors itself (the bus counts as down, then it is
  reopened), so a handled one must not fail the sends that follow.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import can
import canopen

from omnican.log_throttle import Throttle

logger = logging.getLogger(__name__)

#: Failing subscribers and broken frames: a line per COB-ID every this many seconds.
FRAME_ERRORS = Throttle(logger)


def frame_error(can_id: int, exc: BaseException) -> None:
    """A frame a subscriber could not handle (broken, or a bug): logged, throttled."""
    FRAME_ERRORS.error(can_id, "handling frame 0x%03X: %s", can_id, exc)


class StandardFrames(canopen.network.MessageListener):
    """canopen's listener, for standard data frames only."""

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return
        try:
            self.network.notify(msg.arbitration_id, msg.data, msg.timestamp)
        except Exception as exc:  # one bad frame must not stop reception
            frame_error(msg.arbitration_id, exc)


class Network(canopen.Network):
    """See the module docstring."""

    def __init__(self, bus: can.BusABC | None = None) -> None:
        self._subscribe_lock = threading.Lock()  # before canopen's __init__ subscribes
        super().__init__(bus)
        self.listeners[0] = StandardFrames(self)

    def check(self) -> None:
        """Receive errors are handled where they happen (see the module docstring)."""

    def lockstep_receiver(self) -> Callable[[can.Message], None]:
        """What a :class:`~omnican.io.lockstep.LockstepBus` hands each frame to: every
        listener, as a Notifier would, with canopen's own (:class:`StandardFrames`,
        then :meth:`notify`) done in this one call, not three: a lock-step simulation
        runs every frame of every node through here."""
        listeners, subscribers, scanner = self.listeners, self.subscribers, self.scanner

        def receive(msg: can.Message) -> None:
            for listener in listeners:
                if type(listener) is not StandardFrames:
                    listener.on_message_received(msg)
                    continue
                if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
                    continue
                can_id = msg.arbitration_id
                try:
                    callbacks = subscribers.get(can_id)
                    if callbacks:
                        data, stamp = msg.data, msg.timestamp
                        for callback in callbacks:
                            callback(can_id, data, stamp)
                    scanner.on_message_received(can_id)
                except Exception as exc:  # one bad frame must not stop reception
                    frame_error(can_id, exc)

        return receive

    def lockstep_frame_receiver(self) -> Callable[[int, bytearray, float], bool]:
        """:meth:`lockstep_receiver` of a standard data frame given as values (the
        lock-step bus's frame receiver): canopen's subscribers and its node scanner, as
        that would call them; False (it wants a message) while another listener hears
        the network."""
        listeners, subscribers, scanner = self.listeners, self.subscribers, self.scanner
        services = scanner.SERVICES

        def receive_frame(can_id: int, data: bytearray, stamp: float) -> bool:
            if len(listeners) != 1 or type(listeners[0]) is not StandardFrames:
                return False
            try:
                callbacks = subscribers.get(can_id)
                if callbacks:
                    for callback in callbacks:
                        callback(can_id, data, stamp)
                # The scanner notes a node's first frame of one of its services: no call
                # for the others (its own test, first; it makes the call for the rest).
                node_id = can_id & 0x7F
                if node_id and (can_id & 0x780) in services and node_id not in scanner.nodes:
                    scanner.on_message_received(can_id)
            except Exception as exc:  # one bad frame must not stop reception
                frame_error(can_id, exc)
            return True

        return receive_frame

    def subscribe(self, can_id: int, callback: Any) -> None:
        with self._subscribe_lock:
            current = self.subscribers.get(can_id, [])
            if callback not in current:
                self.subscribers[can_id] = [*current, callback]

    def unsubscribe(self, can_id: int, callback: Any = None) -> None:
        with self._subscribe_lock:
            current = self.subscribers.get(can_id)
            if current is None:
                return
            kept = [] if callback is None else [c for c in current if c != callback]
            if kept:
                self.subscribers[can_id] = kept
            else:
                del self.subscribers[can_id]
