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
import time
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
from omnican.io.kernel_sync import KernelSync
from omnican.io.listeners import FRAME_BITS as _FRAME_BITS
from omnican.io.listeners import RX_ERROR_PAUSE_S, CountingNetwork, Taps, Traffic
from omnican.io.network import FRAME_ERRORS, frame_error
from omnican.io.owner import Recorder
from omnican.io.transport import (
    NOTIFIER_STOP_S,
    RECONNECT_EVERY_S,
    Transport,
    shutdown_quietly,
)
from omnican.protocol.can_state import CanController
from omnican.protocol.cia301 import SYNC_COB_ID
from omnican.protocol.sync_producer import (
    SyncMode,
    counter_payloads,
    expired,
    hold_count,
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


class CanBus:
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
        self.sync_counter = int(own.get("sync_counter", 0))
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
        #: SYNCs so far: sent by the loop, or (kernel) seen on the bus; a TPDO is filed
        #: under the value it has when the TPDO arrives
        self.sync_epoch = 0
        #: the SYNC whose answers the next cycle integrates (all of them have had a period
        #: to arrive): ``sync_epoch`` where the loop sends SYNC, the one before where the
        #: kernel does (the cycle starts as the SYNC comes, before its answers)
        self.settled_epoch = 0
        self.sync_time = 0.0
        self._sync_msgs = tuple(prepared_message(SYNC_COB_ID, p)
                                for p in counter_payloads(self.sync_counter))
        self._sync_next = 0  # the index of the next of them (the counter)
        self._sync_bits = _FRAME_BITS[len(self._sync_msgs[0].data)]
        #: the kernel's SYNC, while it runs (see start_kernel_sync)
        self.kernel_sync: KernelSync | None = None
        self.syncs_seen = 0  # SYNCs read from the bus while the kernel sends them
        self._held: list[can.Message] = []  # read after the newest SYNC: for the next wait
        self._seen_at_arm = 0
        self.seen_sync_time = 0.0  # when the last of them came (the clock's time)
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
        (In lock-step this is :meth:`_send_lockstep`.)"""
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

    def _send_lockstep(self, msg: can.Message, bits: int) -> bool:
        """:meth:`send_prepared` on a lock-step bus: one thread, so no lock; recorded
        before the send, since the answers arrive inside it."""
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

    def sync(self) -> bool:
        """The cycle's SYNC, after its RPDOs. From the loop: send one; samples the drives
        take for it carry the new epoch. From the kernel (while it runs): re-arm it for
        another :attr:`KernelSync.hold` SYNCs, on its own timer (started anew if it ran
        out while the loop was late)."""
        kernel = self.kernel_sync
        if kernel is not None:
            self.sync_time = self.seen_sync_time
            seen = self.syncs_seen
            if expired(seen - self._seen_at_arm, kernel.hold):
                ok = kernel.restart()
            else:
                ok = kernel.rearm()
            self._seen_at_arm = seen
            return ok
        self.sync_epoch += 1  # the loop thread is the only writer
        self.settled_epoch = self.sync_epoch
        self.sync_time = self.clock.now()
        msgs = self._sync_msgs
        i = self._sync_next
        self._sync_next = i + 1 if i + 1 < len(msgs) else 0
        return self.send_prepared(msgs[i], self._sync_bits)

    # ------------------------------------------------------------ the kernel's SYNC

    def start_kernel_sync(self, period_s: float) -> bool:
        """Where :attr:`sync_mode` is the kernel's: start its SYNC every ``period_s``
        (one at once) and watch for them on the bus; True if it runs. Elsewhere, or where
        the broadcast manager cannot be had (said once), False: the loop sends SYNC."""
        if self.sync_mode != "kernel" or self.kernel_sync is not None:
            return self.kernel_sync is not None
        bus = self.network.bus
        channel = getattr(bus, "channel", None) or self.bus_kwargs.get("channel")
        kernel = KernelSync(str(channel), period_s,
                            [bytes(m.data) for m in self._sync_msgs], hold_count(period_s))
        self.network.subscribe(SYNC_COB_ID, self._on_sync)
        self._seen_at_arm = self.syncs_seen
        self.seen_sync_time = self.clock.now()
        if not kernel.start():
            self.network.unsubscribe(SYNC_COB_ID, self._on_sync)
            kernel.stop()
            logger.warning("%s; the loop sends SYNC", kernel.error)
            self.sync_mode = "loop"
            return False
        self.kernel_sync = kernel
        logger.info("SYNC from the kernel's broadcast manager on %s every %g ms (at most %d "
                    "after the loop's last cycle)", channel, period_s * 1e3, kernel.hold)
        return True

    def stop_kernel_sync(self) -> None:
        """No more SYNC from the kernel (idempotent)."""
        kernel, self.kernel_sync = self.kernel_sync, None
        if kernel is not None:
            kernel.stop()
            held, self._held = self._held, []
            for msg in held:  # what the loop read past its last SYNC, as poll() would
                self._dispatch(msg)
            with contextlib.suppress(KeyError, ValueError):
                self.network.unsubscribe(SYNC_COB_ID, self._on_sync)

    def kernel_sync_ran_out(self, now: float) -> bool:
        """Whether the kernel's task has surely stopped: no SYNC came for longer than it
        was armed for (its hold, and a period more), as of ``now`` (the clock's time)."""
        kernel = self.kernel_sync
        if kernel is None:
            return False
        return now - self.seen_sync_time > (kernel.hold + 1) * kernel.period_s

    def restart_kernel_sync(self) -> bool:
        """Start the kernel's timer anew (none came back for a while: it ran out, or the
        interface went away and came back)."""
        kernel = self.kernel_sync
        if kernel is None:
            return False
        self._seen_at_arm = self.syncs_seen
        self.seen_sync_time = self.clock.now()  # one goes now; the next wait counts from it
        return kernel.restart()

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """A SYNC on the bus (the kernel's, read back): the answers that follow it are
        its. Its time is the kernel's receive stamp, on the loop's clock."""
        self.settled_epoch = self.sync_epoch
        self.sync_epoch += 1
        self.syncs_seen += 1
        now = self.clock.now()
        age = time.time() - timestamp if timestamp else 0.0
        self.seen_sync_time = now - age if 0.0 <= age < 1.0 else now

    def wait_sync(self, timeout_s: float) -> bool:
        """The kernel-timed loop's receive: wait up to ``timeout_s`` for a SYNC, then read
        everything that arrived and dispatch it up to and including the newest SYNC among
        it (True); what came after that SYNC (its first answers) is held for the next
        call. So when the cycle runs, every sample it has is of a SYNC before the one that
        woke it, and each wheel's newest is of the one just before (``settled_epoch``),
        also after the loop fell behind by several SYNCs: it catches up at once. No SYNC
        within ``timeout_s``: everything read is dispatched, False. A bus that fails to
        read waits out the time (the loop's checks then say it is down)."""
        deadline = time.monotonic() + timeout_s
        got = self._held
        self._held = []
        last = _last_sync(got)
        while last < 0:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            bus = self.network.bus
            if bus is None:  # being reopened
                time.sleep(left)
                break
            cached_bus, recv, internal = self._poll_bus
            if bus is not cached_bus:
                recv, internal = self._receivers(bus)
            try:
                msg = internal(left)[0] if internal is not None else recv(left)
                while msg is not None:  # and what else is there now
                    got.append(msg)
                    if len(got) > 4096:
                        break  # never more than a socket's worth at once
                    msg = internal(0)[0] if internal is not None else recv(0)
            except Exception as exc:  # an interface gone down: as poll() says
                self.rx_error = describe_receive_error(self.bus_kwargs, exc)
                time.sleep(max(0.0, deadline - time.monotonic()))
                break
            if got and self.rx_error is not None:
                self.rx_error = None
            last = _last_sync(got)
        if last >= 0:
            self._held = got[last + 1:]
            del got[last + 1:]
        dispatch = self._dispatch
        for msg in got:
            dispatch(msg)
        return last >= 0

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


def _last_sync(frames: list[can.Message]) -> int:
    """The index of the newest SYNC among ``frames`` (-1: none)."""
    for i in range(len(frames) - 1, -1, -1):
        msg = frames[i]
        if (msg.arbitration_id == SYNC_COB_ID and not msg.is_extended_id and
                not msg.is_error_frame and not msg.is_remote_frame):
            return i
    return -1


def prepared_message(can_id: int, data: bytes) -> can.Message:
    """A frame made once and sent every cycle with new ``data``.

    Its data is kept as ``bytes``: python-can's virtual bus deep-copies every frame it
    sends, and a ``bytes`` object (immutable) costs nothing to copy where a bytearray
    costs microseconds. Every interface only reads ``data`` while sending."""
    msg = can.Message(arbitration_id=can_id, is_extended_id=False, dlc=len(data))
    msg.data = data  # type: ignore[assignment]  # bytes where python-can says bytearray
    return msg
