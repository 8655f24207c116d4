"""What a simulated node puts on the bus: one frame per COB-ID, refilled for each send,
and a send the link refuses said once, then now and then (never a line per frame).

Random frame loss, a frozen node's silence and what each frame holds are the node's
(:class:`~omnican.sim.node.SimNode`): this only sends.
"""

from __future__ import annotations

import logging
import math

import can
import canopen

from omnican.clock import Clock
from omnican.io.bus import prepared_message
from omnican.io.lockstep import LockstepBus

logger = logging.getLogger(__name__)

SEND_WARNING_EVERY_S = 5.0  # a refused send is logged at most this often


class Transmitter:
    """Sends node ``node_id``'s frames on ``network``'s bus (none while it has no bus),
    under the network's send lock; ``clock`` paces the warnings."""

    def __init__(self, network: canopen.Network, node_id: int, clock: Clock) -> None:
        self.network = network
        self.node_id = node_id
        self.clock = clock
        self.failures = 0  # frames the link refused
        # One frame per COB-ID, refilled for each send (under the send lock): every
        # interface only reads a frame while sending it, and can.Message's constructor
        # is most of what a simulated frame costs.
        self._frames: dict[int, can.Message] = {}
        self._warned_at = -math.inf

    def send(self, cob_id: int, data: bytes) -> None:
        bus = self.network.bus
        if bus is None:
            return
        try:
            with self.network.send_lock:
                if type(bus) is LockstepBus:  # no message to fill: the frame as values
                    bus.send_frame(cob_id, data)
                    return
                msg = self._frames.get(cob_id)
                if msg is None:
                    msg = self._frames[cob_id] = prepared_message(cob_id, bytes(data))
                else:
                    msg.data = data  # type: ignore[assignment]  # bytes (see prepared_message)
                    msg.dlc = len(data)
                bus.send(msg)
        except (can.CanError, OSError, RuntimeError) as exc:
            # A link that is down refuses every frame: say so once, then now and then.
            self.failures += 1
            now = self.clock.now()
            if now - self._warned_at >= SEND_WARNING_EVERY_S:
                self._warned_at = now
                logger.warning("simulated node %d could not send 0x%03X (%d frames refused "
                               "so far): %s", self.node_id, cob_id, self.failures, exc)
