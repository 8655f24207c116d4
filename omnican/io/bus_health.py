"""Whether the bus works: :class:`BusWatch` (debounced down and back up, as the control
loop sees it; down asks for the bus to be reopened) and the words for a failed send.

The counts it reads (:attr:`omnican.io.bus.CanBus.send_errors`, ``rx_error``) are kept by
the bus itself, on its send and receive paths; the controller's state from the error
frames (error-passive, bus-off) by :mod:`omnican.protocol.can_state`.
"""

from __future__ import annotations

import errno
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from omnican.io.bus import CanBus

BUS_DOWN_AFTER_S = 0.05  # sends or receives failing for this long: the bus is down
BUS_UP_AFTER_S = 0.2  # and working again for this long: it is back up
WENT_DOWN, CAME_BACK = "went down", "came back"  # what BusWatch.check reports


class BusWatch:
    """Whether the bus works, as the control loop sees it, debounced: down once sends or
    receives have failed for ``BUS_DOWN_AFTER_S``, back once they have worked again for
    ``BUS_UP_AFTER_S`` (one frame through a filling queue is not a bus that works).
    While it is down the bus is being reopened, on a thread of its own."""

    __slots__ = ("_bus", "_fail_since", "_ok_since", "down", "failing")

    def __init__(self, bus: CanBus) -> None:
        self._bus = bus
        self.down = False
        self.failing: str | None = None  # the bus's trouble as of the last check
        self._fail_since: float | None = None
        self._ok_since: float | None = None

    def check(self, now: float) -> str | None:
        """Look at the bus (once a cycle): ``WENT_DOWN`` or ``CAME_BACK`` when that just
        happened, else None."""
        failing = self.failing = self._bus.failing
        if not self.down:
            if failing is None:
                self._fail_since = None
                return None
            if self._fail_since is None:
                self._fail_since = now
            if now - self._fail_since < BUS_DOWN_AFTER_S:
                return None
            self.down, self._ok_since = True, None
            self._bus.request_reconnect()
            return WENT_DOWN
        if failing is not None:
            self._ok_since = None
            self._bus.request_reconnect()  # a no-op while it is being reopened
            return None
        if self._ok_since is None:
            self._ok_since = now
        if now - self._ok_since < BUS_UP_AFTER_S:
            return None
        self.down = False
        self._fail_since = self._ok_since = None
        return CAME_BACK

    @property
    def error(self) -> str | None:
        """What the status shows: the failure, or while down why it went down."""
        return self.failing or (self._bus.reconnect_error if self.down else None)


def describe_send_error(can_id: int, exc: BaseException) -> str:
    """One line for a failed send, naming the usual causes."""
    code = getattr(exc, "error_code", None) or getattr(exc, "errno", None)
    if code == errno.ENOBUFS:
        return (f"send 0x{can_id:03X} failed: transmit queue full (no buffer space; nothing "
                "acknowledges the frames?)")
    if code == errno.ENETDOWN:
        return f"send 0x{can_id:03X} failed: the CAN interface is down"
    return f"send 0x{can_id:03X} failed: {exc}"
