"""Whether the bus works: :class:`BusWatch` (debounced down and back up, as the control
loop sees it; down asks for the bus to be reopened) and the words for a bus that does not
open, a failed send and a failed receive: what a user can act on (the kernel module to
load, the interface to create, the hub that went away) rather than the interface's own
words (``file descriptor cannot be a negative integer (-1)``).

The counts it reads (:attr:`omnican.io.bus.CanBus.send_errors`, ``rx_error``) are kept by
the bus itself, on its send and receive paths; the controller's state from the error
frames (error-passive, bus-off) by :mod:`omnican.protocol.can_state`.
"""

from __future__ import annotations

import errno
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from omnican.io.owner import BusOwner

BUS_DOWN_AFTER_S = 0.05  # sends or receives failing for this long: the bus is down
BUS_UP_AFTER_S = 0.2  # and working again for this long: it is back up
WENT_DOWN, CAME_BACK = "went down", "came back"  # what BusWatch.check reports


class BusWatch:
    """Whether the bus works, as the control loop sees it, debounced: down once sends or
    receives have failed for ``BUS_DOWN_AFTER_S``, back once they have worked again for
    ``BUS_UP_AFTER_S`` (one frame through a filling queue is not a bus that works).
    While it is down the bus is being reopened, on a thread of its own."""

    __slots__ = ("_bus", "_fail_since", "_ok_since", "down", "failing")

    def __init__(self, bus: BusOwner) -> None:
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


def _code(exc: BaseException) -> int | None:
    """The OS error number behind ``exc`` (python-can keeps it as ``error_code``; some
    interfaces raise a CanError from the OSError)."""
    while exc is not None:
        code = getattr(exc, "error_code", None) or getattr(exc, "errno", None)
        if isinstance(code, int):
            return code
        exc = exc.__cause__  # type: ignore[assignment]
    return None


def _hub(bus: Mapping[str, Any] | None) -> str | None:
    """The hub's address, for a bus on python-can-remote (``omnican sim``'s hub)."""
    bus = bus or {}
    return str(bus.get("channel") or "?") if bus.get("interface") == "remote" else None


#: What the hub's going away looks like from its client's side: the socket is closed (a
#: -1 file descriptor), reset, or broken.
_GONE = (errno.EPIPE, errno.ECONNRESET, errno.ECONNABORTED, errno.ENOTCONN, errno.EBADF)


def bus_where(bus: Mapping[str, Any] | None) -> str:
    """``channel=can0, interface=socketcan``, or python-can's own configuration."""
    return ", ".join(f"{k}={v}" for k, v in (bus or {}).items()) or \
        "python-can's configuration"


def describe_open_error(bus: Mapping[str, Any] | None, exc: BaseException) -> str:
    """One line for a bus that did not open: ``cannot open CAN bus (channel=vcan0,
    interface=socketcan): ...``, naming what to do for the usual causes."""
    return f"cannot open CAN bus ({bus_where(bus)}): {open_error_reason(bus, exc)}"


def open_error_reason(bus: Mapping[str, Any] | None, exc: BaseException) -> str:
    """Why a bus did not open (:func:`describe_open_error` without the bus's name)."""
    bus = bus or {}
    code = _code(exc)
    hub = _hub(bus)
    if hub is not None and code in (errno.ECONNREFUSED, *_GONE):
        return f"nothing answers at {hub} (is omnican sim serving there?)"
    if bus.get("interface") == "socketcan":
        channel = str(bus.get("channel") or "")
        vcan = (f", and vcan for a virtual interface like {channel} (sudo modprobe vcan)"
                if channel.startswith("vcan") else "")
        if code == errno.EAFNOSUPPORT:
            return ("this kernel has no SocketCAN (no CAN address family): load the kernel "
                    f"modules can and can_raw (sudo modprobe can_raw){vcan}")
        if code == errno.EPROTONOSUPPORT:
            return ("this kernel has SocketCAN but no raw CAN sockets: load the kernel "
                    f"module can_raw (sudo modprobe can_raw){vcan}")
        if code == errno.ENODEV:
            make = (f"create it: sudo modprobe vcan && sudo ip link add dev {channel} type "
                    f"vcan && sudo ip link set {channel} up" if channel.startswith("vcan")
                    else "see 'ip link show' for the CAN interfaces there are")
            return f"there is no network interface {channel or '(none given)'}: {make}"
    return _words(exc)


def _words(exc: BaseException) -> str:
    """An exception's own words, on one line."""
    return " ".join(str(exc).split()) or type(exc).__name__


def describe_receive_error(bus: Mapping[str, Any] | None, exc: BaseException) -> str:
    """One line for a failed receive: the interface down, the hub gone, or the
    interface's own words."""
    hub = _hub(bus)
    if hub is not None:  # its socket closed under the reader: the hub went away
        return f"the hub at {hub} went away: did omnican sim stop?"
    if _code(exc) == errno.ENETDOWN:
        return "receive failed: the CAN interface is down"
    return f"receive failed: {_words(exc)}"


def describe_send_error(can_id: int, exc: BaseException,
                        bus: Mapping[str, Any] | None = None) -> str:
    """One line for a failed send, naming the usual causes."""
    code = _code(exc)
    hub = _hub(bus)
    if hub is not None and (code in _GONE or isinstance(exc, ValueError)):
        return f"send 0x{can_id:03X} failed: the hub at {hub} went away: did omnican sim stop?"
    if code == errno.ENOBUFS:
        return (f"send 0x{can_id:03X} failed: transmit queue full (no buffer space; nothing "
                "acknowledges the frames?)")
    if code == errno.ENETDOWN:
        return f"send 0x{can_id:03X} failed: the CAN interface is down"
    return f"send 0x{can_id:03X} failed: {_words(exc)}"
