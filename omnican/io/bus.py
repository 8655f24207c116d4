"""The one owner of the CAN bus: one ``can.Bus``, one ``canopen.Network``, one Notifier.

:class:`CanBus` sends (each cycle's frames, SYNC), polls and dispatches what arrived, and
counts both. Around it, one concern a module:

- :mod:`omnican.io.listeners`: what it hands every frame to (the traffic count for the
  bus load, a recorder (:mod:`omnican.record.can_log`), the taps added while it runs);
- :mod:`omnican.io.transport`: opening the bus, handing reception between the Notifier
  and the loop, reopening it when it does not work, paced, on a thread of its own;
- :mod:`omnican.io.bus_watch`: whether it works (:class:`BusWatch`); the controller's
  state, from the error frames SocketCAN delivers, is :mod:`omnican.protocol.can_state`;
- :mod:`omnican.io.owner`: what those parts see of the bus (a protocol: none of them
  imports this module), and what records it.

The names those modules hold are importable from here too, as before.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Mapping
from typing import Any

import can
import canopen

from omnican.clock import REAL_TIME, Clock
from omnican.io.bus_watch import (
    BUS_DOWN_AFTER_S,
    BUS_UP_AFTER_S,
    CAME_BACK,
    WENT_DOWN,
    BusWatch,
    describe_receive_error,
    describe_send_error,
)
from omnican.io.listeners import FRAME_BITS as _FRAME_BITS
from omnican.io.listeners import RX_ERROR_PAUSE_S, CountingNetwork, Taps, Traffic
from omnican.io.lockstep_side import LockstepSide
from omnican.io.network import FRAME_ERRORS, frame_error
from omnican.io.owner import Recorder
from omnican.io.sync_sending import SyncSending, prepared_message
from omnican.io.transport import (
    NOTIFIER_STOP_S,
    RECONNECT_EVERY_S,
    Transport,
    shutdown_quietly,
)
from omnican.protocol.can_state import CanController
from omnican.protocol.sync_producer import (
    SyncMode,
    sync_mode,
)

__all__ = [
    "BUS_DOWN_AFTER_S", "BUS_UP_AFTER_S", "CAME_BACK", "NOTIFIER_CYCLE_S", "NOTIFIER_STOP_S",
    "RECONNECT_EVERY_S", "RX_ERROR_PAUSE_S", "WENT_DOWN", "BusWatch", "CanBus", "Recorder",
    "describe_receive_error", "describe_send_error", "prepared_message", "shutdown_quietly",
]

logger = logging.getLogger(__name__)

# How long the Notifier thread blocks in one receive: also how long handing reception to
# the loop waits for it to end on a quiet bus (startup: 0.1 s here cost 0.1 s half the time).
NOTIFIER_CYCLE_S = 0.02

#: The keys of the [bus] table that are omnican's, not python-can's: taken out before
#: the rest goes to ``can.Bus`` (see :data:`omnican.config.schema.BUS_KEYS`).
SYNC_KEYS = ("sync", "sync_counter")


class CanBus(SyncSending, LockstepSide):
    """Opens the bus from a ``[bus]`` config table (None: python-can's own config).

    Sends never raise: a failed send is counted (:attr:`send_errors`, :attr:`last_error`)
    and the caller decides when the bus counts as down. :meth:`request_reconnect` reopens
    the bus on a thread of its own (the control loop never waits for it); each reopening
    that succeeds increments :attr:`generation`.

    SYNC (``[bus] sync``): on SocketCAN the kernel's broadcast manager sends it on its own
    timer (:mod:`omnican.io.kernel_sync`) once :meth:`start_kernel_sync` ran, and the
    control loop waits for each one (:meth:`wait_sync`); elsewhere, or with ``sync =
    "loop"``, :meth:`sync` sends it from the loop, after the cycle's RPDOs.

    With a lock-step ``clock`` (:class:`omnican.clock.SimClock`) the bus is an in-process
    :class:`omnican.io.lockstep.LockstepBus` on the configured channel name: no Notifier
    thread, frames delivered on the sender's thread.

    A context manager; :meth:`close` is idempotent."""

    def __init__(self, bus: Mapping[str, Any] | None = None, recorder: Recorder | None = None,
                 notifier_cycle_s: float = NOTIFIER_CYCLE_S, clock: Clock = REAL_TIME) -> None:
        self.bus_kwargs: dict[str, Any] = dict(bus or {})
        own = {k: self.bus_kwargs.pop(k) for k in SYNC_KEYS if k in self.bus_kwargs}
        self.sync_setting = str(own.get("sync", "auto"))
        self.clock = clock
        self.lockstep = clock.lockstep
        self.traffic = Traffic(self)
        #: gets every frame, received and sent, until the bus closes; closed with it
        self.recorder = recorder
        self._taps = Taps()
        self.network = CountingNetwork(self)
        self.network.NOTIFIER_CYCLE = notifier_cycle_s
        # canopen types this list as MessageListener only; any can.Listener works.
        listeners: list[can.Listener] = self.network.listeners  # type: ignore[assignment]
        listeners.append(self.traffic)
        listeners.append(self._taps)
        if recorder is not None:
            listeners.append(recorder)  # type: ignore[arg-type]  # a listener by protocol
        # What poll() hands each frame to besides canopen's subscribers (the list is made
        # here, once: later listeners go through the taps).
        # The taps are read in place (most of the time there are none: no call).
        self._extra_listeners: tuple[can.Listener, ...] = tuple(
            x for x in listeners if x is not self.traffic and x is not self._taps and
            not isinstance(x, canopen.network.MessageListener))
        self._init_sync(int(own.get("sync_counter", 0)))
        self.last_error: str | None = None
        self.send_errors = 0
        self.dropped_frames = 0  # frames the bus refused (never queued for later)
        self.rx_error: str | None = None
        #: the controller's state, from the error frames (SocketCAN delivers them)
        self.controller = CanController()
        self.generation = 0  # reopenings that succeeded (by the transport)
        self.reconnect_error: str | None = None
        self._poll_bus: tuple[Any, Any, Any] = (None, None, None)  # bus, its recv, fast recv
        if self.lockstep:
            self.send_prepared = self._send_lockstep  # type: ignore[method-assign]
        #: opens the bus, hands reception over, reopens it (never on a per-frame path)
        self._transport = Transport(self)
        self._transport.connect()
        bus_obj = self.network.bus
        #: who sends SYNC: the kernel (SocketCAN) or the loop
        self.sync_mode: SyncMode = sync_mode(
            self.sync_setting, not self.lockstep and
            type(bus_obj).__name__ == "SocketcanBus")
        if self.sync_setting == "kernel" and self.sync_mode == "loop":
            logger.info("[bus] sync = 'kernel' needs a SocketCAN bus; the loop sends SYNC "
                        "on %s", getattr(bus_obj, "channel_info", "this bus"))

    @property
    def bitrate(self) -> int | None:
        rate = self.bus_kwargs.get("bitrate")
        return int(rate) if rate else None

    @property
    def failing(self) -> str | None:
        """Why the bus does not work right now (a send or a receive failed), or None."""
        if self.send_errors:
            return self.last_error or "sends fail"
        return self.rx_error

    @property
    def reconnecting(self) -> bool:
        return self._transport.reconnecting

    # ------------------------------------------------------------ polling

    @property
    def polling(self) -> bool:
        return self._transport.polling

    def start_polling(self) -> None:
        """Hand reception to the control loop: stop the Notifier thread; from now on
        :meth:`poll` reads what arrived, once a cycle, and hands each frame to the
        listeners and to canopen as the Notifier would (TPDOs, SDO answers, EMCY,
        heartbeats).

        One thread waking per cycle instead of one per frame is most of what a cycle
        costs at 1 kHz; SDO answers to configuration workers then wait up to a period."""
        self._transport.start_polling()

    def stop_polling(self) -> None:
        """Give reception back to a Notifier thread (before the loop stops)."""
        self._transport.stop_polling()

    def poll(self, limit: int = 256) -> int:
        """Read and dispatch the frames that arrived (at most ``limit``); the control
        loop's receive. Returns how many were read."""
        if self.kernel_sync is not None:
            return 0  # wait_sync read up to the SYNC that woke the loop: the rest waits
        bus = self.network.bus
        if bus is None:
            return 0
        cached_bus, recv, internal = self._poll_bus
        if bus is not cached_bus:
            recv, internal = self._receivers(bus)
        dispatch = self._dispatch
        n = 0
        while n < limit:
            try:
                msg = internal(0)[0] if internal is not None else recv(0)
            except Exception as exc:  # an interface gone down: as the Notifier says
                self.rx_error = describe_receive_error(self.bus_kwargs, exc)
                break
            if msg is None:
                break
            n += 1
            dispatch(msg)
        if n and self.rx_error is not None:
            self.rx_error = None
        return n

    def _receivers(self, bus: Any) -> tuple[Any, Any]:
        """A new bus (opened, reopened): looked at once, for :meth:`poll` and
        :meth:`wait_sync`: its ``recv`` and, where no filters apply, the interface's own
        receive (BusABC.recv would only add its timeout and filter bookkeeping around it,
        for every frame), else None."""
        recv, internal = bus.recv, None
        if bus.filters is None and type(bus)._recv_internal is not can.BusABC._recv_internal:
            internal = bus._recv_internal
        self._poll_bus = (bus, recv, internal)
        return recv, internal

    def _dispatch(self, msg: can.Message) -> None:
        """One received frame, as the Notifier would hand it on: counted, to the
        listeners, and (a standard data frame) to canopen's subscribers by COB-ID, a
        copy-on-write dict of lists. canopen's Network.notify less its node scanner
        (omnican scan runs a network of its own). The loop's poll calls this for each
        frame, and the lock-step bus as each frame arrives."""
        traffic = self.traffic
        data = msg.data
        traffic.loop_frames += 1
        traffic.loop_bits += _FRAME_BITS[len(data)]
        for listener in self._extra_listeners:
            listener.on_message_received(msg)
        taps = self._taps.received
        if taps:
            for tap in taps:
                tap.on_message_received(msg)
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            if msg.is_error_frame:  # the controller's state (SocketCAN)
                self.controller.on_error_frame(msg.arbitration_id, data)
            return  # 29-bit frames are other devices', never CANopen
        callbacks = self.network.subscribers.get(msg.arbitration_id)
        if callbacks:
            try:
                for callback in callbacks:
                    callback(msg.arbitration_id, data, msg.timestamp)
            except Exception as exc:  # a callback's failure must not stop reception
                frame_error(msg.arbitration_id, exc)

    def _sent(self, can_id: int, data: bytes) -> None:
        self.traffic.count_sent(len(data))
        self._record(can_id, data)

    def _record(self, can_id: int, data: bytes | bytearray) -> None:
        """A frame this host sent, to the recorder and the listeners that want sent frames."""
        recorder, taps = self.recorder, self._taps.sent
        if recorder is None and not taps:
            return
        frame = (self.clock.wall(), can_id, bytes(data), self.bus_kwargs.get("channel"))
        if recorder is not None:
            recorder.record_sent(*frame)  # made into a message on its writer thread
        for tap in taps:
            tap.record_sent(*frame)  # type: ignore[attr-defined]  # see add_listener

    def add_listener(self, listener: can.Listener, sent: bool = False) -> None:
        """Hand every received frame to ``listener`` from now on, across reconnects (on the
        Notifier thread, so it must not block); ``sent``: also the frames this host sends,
        as plain values to its ``record_sent(timestamp, can_id, data, channel)`` (on the
        sending thread, the control loop's: append to a queue and return)."""
        self._taps.add(listener, sent)

    def remove_listener(self, listener: can.Listener) -> None:
        self._taps.remove(listener)

    def send(self, can_id: int, data: bytes) -> bool:
        """Send one frame from the control loop (a heartbeat, an NMT start); a failure is
        counted and reported, not raised. See :meth:`send_prepared`."""
        return self.send_prepared(prepared_message(can_id, bytes(data)), _FRAME_BITS[len(data)])

    def send_prepared(self, msg: can.Message, bits: int) -> bool:
        """The control loop's send: ``msg`` is made once and reused (its ``data`` a
        ``bytes`` object, which python-can's virtual bus copies for free), ``bits`` its
        worst-case size. Only the loop thread calls this (its traffic counters take no
        lock). A failure is counted and reported, not raised; a frame the bus refuses
        (interface down, transmit queue full) is dropped, never queued: what the drives
        need is this cycle's targets, not a backlog. Straight to the bus: canopen's
        ``send_message`` adds a second message object and a Notifier check per frame.
        (In lock-step this is :meth:`~omnican.io.lockstep_side.LockstepSide._send_lockstep`.)"""
        network = self.network
        bus = None
        try:
            with network.send_lock:
                bus = network.bus
                if bus is None:
                    raise can.CanOperationError("bus is closed (reopening)")
                bus.send(msg)
        except (can.CanError, OSError, RuntimeError, ValueError) as exc:
            return self._send_failed(msg, bus, exc)
        traffic = self.traffic
        traffic.loop_frames += 1
        traffic.loop_bits += bits
        if self.recorder is not None or self._taps.sent:
            self._record(msg.arbitration_id, msg.data)
        if self.send_errors:
            self._sends_work()
        return True

    def _send_failed(self, msg: can.Message, bus: can.BusABC | None, exc: Exception) -> bool:
        self.send_errors += 1
        self.dropped_frames += 1
        if bus is not None or self.last_error is None:
            # While the bus is closed to be reopened, the error shown stays the one it
            # went down for (the interface is down, say), not "closed".
            self.last_error = describe_send_error(msg.arbitration_id, exc, self.bus_kwargs)
        return False

    def _sends_work(self) -> None:
        logger.info("bus sends work again after %d errors", self.send_errors)
        self.send_errors = 0
        self.last_error = None

    # ------------------------------------------------------------ reconnecting, closing

    def request_reconnect(self, force: bool = False) -> None:
        """Reopen the bus in the background, retrying every ``RECONNECT_EVERY_S`` until
        it opens (or the bus is closed). Returns at once. A bus that works again by the
        time of an attempt is left as it is, unless ``force``."""
        self._transport.request_reconnect(force)

    def close(self) -> None:
        self.stop_kernel_sync()
        if not self._transport.close():
            return
        for node in self.network.nodes.values():
            pdo = getattr(node, "pdo", None)
            if pdo is not None:
                with contextlib.suppress(Exception):
                    pdo.stop()
        self._transport.release()
        FRAME_ERRORS.flush()
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> CanBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
