"""The bus as its parts see it: what the transport (:mod:`omnican.io.transport`), the
traffic count and the counting network (:mod:`omnican.io.listeners`) and the bus watch
(:mod:`omnican.io.bus_watch`) read and write of the :class:`~omnican.io.bus.CanBus`
that owns them (:class:`BusOwner`), and what records a bus (:class:`Recorder`).
Protocols, so that no part imports the bus that owns it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import can

from omnican.clock import Clock
from omnican.io.network import Network
from omnican.protocol.can_state import CanController


class Recorder(Protocol):
    """What records a bus: every received frame, every sent one (as plain values, on
    the sending thread: queue and return), then closed with the bus."""

    def on_message_received(self, msg: can.Message) -> None: ...

    def record_sent(self, timestamp: float, can_id: int, data: bytes, channel: Any) -> None: ...

    def close(self) -> None: ...


class BusOwner(Protocol):
    """What the parts of a bus share of it (:class:`omnican.io.bus.CanBus` is the one)."""

    clock: Clock
    lockstep: bool
    rx_error: str | None  # why receiving fails (None: it works)
    reconnect_error: str | None  # why the last reopening failed
    generation: int  # reopenings that succeeded
    controller: CanController  # the controller's state, from the error frames

    @property
    def bus_kwargs(self) -> Mapping[str, Any]: ...

    @property
    def network(self) -> Network: ...

    @property
    def recorder(self) -> Recorder | None: ...

    @property
    def failing(self) -> str | None: ...

    def request_reconnect(self, force: bool = False) -> None: ...

    def _dispatch(self, msg: can.Message) -> None: ...

    def _dispatch_frame(self, can_id: int, data: bytearray, timestamp: float) -> bool: ...

    def _sent(self, can_id: int, data: bytes) -> None: ...
