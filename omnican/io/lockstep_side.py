"""The bus owner's side of a lock-step bus (:mod:`omnican.io.lockstep`): how
:class:`omnican.io.bus.CanBus` sends there, and takes a frame handed over as values. A
part of the bus (a base class of it), in a module of its own so the bus's class stays
one screenful of concerns (as :mod:`omnican.io.sync_sending`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import can

from omnican.io.listeners import FRAME_BITS as _FRAME_BITS
from omnican.io.network import frame_error

if TYPE_CHECKING:
    from omnican.io.listeners import CountingNetwork, Taps, Traffic
    from omnican.io.owner import Recorder


class LockstepSide:
    """CanBus on a lock-step bus. Reads what the bus owns (declared here for the type
    checker)."""

    if TYPE_CHECKING:
        network: CountingNetwork
        traffic: Traffic
        recorder: Recorder | None
        send_errors: int
        _taps: Taps
        _extra_listeners: tuple[can.Listener, ...]

        def _record(self, can_id: int, data: bytes | bytearray) -> None: ...

        def _send_failed(self, msg: can.Message, bus: can.BusABC | None,
                         exc: Exception) -> bool: ...

        def _sends_work(self) -> None: ...

    def _send_lockstep(self, msg: can.Message, bits: int) -> bool:
        """:meth:`~omnican.io.bus.CanBus.send_prepared` on a lock-step bus: one thread, so
        no lock; recorded before the send, since the answers arrive inside it."""
        if self.recorder is not None or self._taps.sent:
            self._record(msg.arbitration_id, msg.data)
        bus = self.network.bus
        try:
            if bus is None:
                raise can.CanOperationError("bus is closed")
            bus.send(msg)
        except (can.CanError, OSError, RuntimeError, ValueError) as exc:
            return self._send_failed(msg, bus, exc)
        traffic = self.traffic
        traffic.loop_frames += 1
        traffic.loop_bits += bits
        if self.send_errors:
            self._sends_work()
        return True

    def _dispatch_frame(self, can_id: int, data: bytearray, timestamp: float) -> bool:
        """:meth:`~omnican.io.bus.CanBus._dispatch` of a standard data frame given as
        values (the lock-step bus's frame receiver); False (it wants a message) while
        listeners besides the traffic count hear the bus (a recorder, taps)."""
        if self._extra_listeners or self._taps.received:
            return False
        traffic = self.traffic
        traffic.loop_frames += 1
        traffic.loop_bits += _FRAME_BITS[len(data)]
        callbacks = self.network.subscribers.get(can_id)
        if callbacks:
            try:
                for callback in callbacks:
                    callback(can_id, data, timestamp)
            except Exception as exc:  # a callback's failure must not stop reception
                frame_error(can_id, exc)
        return True
