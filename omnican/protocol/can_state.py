"""The CAN controller's state, from the error frames SocketCAN delivers
(``linux/can/error.h``): error-active, error-warning (96 or more errors counted),
error-passive (128 or more) and bus-off (the controller left the bus), the transmit
and receive error counters, and the other errors it reports (no acknowledgement,
protocol errors, lost arbitration, overflows).

A bus-off controller sends nothing until it is restarted: the kernel does that after
the interface's ``restart-ms`` (``ip link set can0 type can restart-ms 100``) and says so
with a "restarted" error frame, which brings the state back to error-active.

python-can hands an error frame with ``is_error_frame`` set and the error class in
``arbitration_id``. Pure: frames in, a :class:`ControllerState` out; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

# Error classes (can_id bits of an error frame).
ERR_TX_TIMEOUT = 0x001
ERR_LOSTARB = 0x002
ERR_CRTL = 0x004  # data[1]: controller problems
ERR_PROT = 0x008  # data[2]: type, data[3]: location
ERR_TRX = 0x010
ERR_ACK = 0x020
ERR_BUSOFF = 0x040
ERR_BUSERROR = 0x080
ERR_RESTARTED = 0x100
ERR_CNT = 0x200  # data[6]: transmit error counter, data[7]: receive error counter
# data[1] of ERR_CRTL
CRTL_RX_OVERFLOW = 0x01
CRTL_TX_OVERFLOW = 0x02
CRTL_RX_WARNING = 0x04
CRTL_TX_WARNING = 0x08
CRTL_RX_PASSIVE = 0x10
CRTL_TX_PASSIVE = 0x20
CRTL_ACTIVE = 0x40
# data[2] of ERR_PROT
_PROT_TYPES = ((0x01, "single bit error"), (0x02, "frame format error"),
               (0x04, "bit stuffing error"), (0x08, "unable to send a dominant bit"),
               (0x10, "unable to send a recessive bit"), (0x20, "bus overload"),
               (0x40, "active error announcement"), (0x80, "error while transmitting"))

ERROR_ACTIVE, ERROR_WARNING, ERROR_PASSIVE, BUS_OFF = ("error-active", "error-warning",
                                                       "error-passive", "bus-off")
STATES = (ERROR_ACTIVE, ERROR_WARNING, ERROR_PASSIVE, BUS_OFF)


@dataclass(frozen=True)
class ControllerState:
    """What the error frames said so far. Counters are None until a frame carried them."""

    state: str = ERROR_ACTIVE  # one of STATES
    tx_errors: int | None = None
    rx_errors: int | None = None
    error_frames: int = 0
    last_error: str | None = None  # the newest error frame, in words
    bus_offs: int = 0
    restarts: int = 0

    @property
    def bus_off(self) -> bool:
        return self.state == BUS_OFF

    def describe(self) -> str:
        """e.g. ``error-passive (tx 130, rx 0)``."""
        counters = (f" (tx {self.tx_errors}, rx {self.rx_errors})"
                    if self.tx_errors is not None and self.rx_errors is not None else "")
        return f"{self.state}{counters}"


def describe_error(can_id: int, data: bytes | bytearray) -> str:
    """One error frame in words, e.g. ``controller error-passive (tx)``."""
    parts = []
    if can_id & ERR_BUSOFF:
        parts.append("bus-off")
    if can_id & ERR_RESTARTED:
        parts.append("controller restarted")
    if can_id & ERR_CRTL and len(data) > 1:
        ctrl = data[1]
        for bit, text in ((CRTL_TX_PASSIVE, "error-passive (tx)"),
                          (CRTL_RX_PASSIVE, "error-passive (rx)"),
                          (CRTL_TX_WARNING, "error-warning (tx)"),
                          (CRTL_RX_WARNING, "error-warning (rx)"),
                          (CRTL_ACTIVE, "back to error-active"),
                          (CRTL_RX_OVERFLOW, "receive overflow"),
                          (CRTL_TX_OVERFLOW, "transmit overflow")):
            if ctrl & bit:
                parts.append(f"controller {text}")
    if can_id & ERR_PROT:
        kind = data[2] if len(data) > 2 else 0
        named = [text for bit, text in _PROT_TYPES if kind & bit]
        parts.append("protocol error" + (f": {', '.join(named)}" if named else ""))
    for bit, text in ((ERR_ACK, "no acknowledgement (no other node on the bus?)"),
                      (ERR_LOSTARB, "arbitration lost"), (ERR_TX_TIMEOUT, "transmit timeout"),
                      (ERR_TRX, "transceiver error"), (ERR_BUSERROR, "bus error")):
        if can_id & bit:
            parts.append(text)
    return "; ".join(parts) or f"error frame 0x{can_id:03X}"


def next_state(state: ControllerState, can_id: int, data: bytes | bytearray) -> ControllerState:
    """The controller's state after one error frame."""
    level = state.state
    bus_offs, restarts = state.bus_offs, state.restarts
    if can_id & ERR_RESTARTED:
        level, restarts = ERROR_ACTIVE, restarts + 1
    if level == BUS_OFF:  # only a restart (or the controller saying so) ends a bus-off
        if can_id & ERR_CRTL and len(data) > 1 and data[1] & CRTL_ACTIVE:
            level = ERROR_ACTIVE
    elif can_id & ERR_CRTL and len(data) > 1:
        ctrl = data[1]
        if ctrl & (CRTL_TX_PASSIVE | CRTL_RX_PASSIVE):
            level = ERROR_PASSIVE
        elif ctrl & (CRTL_TX_WARNING | CRTL_RX_WARNING):
            level = ERROR_WARNING
        elif ctrl & CRTL_ACTIVE:
            level = ERROR_ACTIVE
    if can_id & ERR_BUSOFF:
        level, bus_offs = BUS_OFF, bus_offs + (state.state != BUS_OFF)
    tx, rx = state.tx_errors, state.rx_errors
    if len(data) >= 8 and (can_id & ERR_CNT or can_id & ERR_CRTL):
        tx, rx = data[6], data[7]
    return replace(state, state=level, tx_errors=tx, rx_errors=rx,
                   error_frames=state.error_frames + 1,
                   last_error=describe_error(can_id, data), bus_offs=bus_offs,
                   restarts=restarts)


class CanController:
    """The state of one bus's controller, updated by each error frame (on the receiving
    thread); :attr:`state` is replaced whole, so any thread may read it."""

    def __init__(self) -> None:
        self.state = ControllerState()

    def on_error_frame(self, can_id: int, data: bytes | bytearray) -> None:
        self.state = next_state(self.state, can_id, data)

    def reset(self) -> None:
        """A new bus (reopened): nothing it said before holds."""
        self.state = ControllerState()
