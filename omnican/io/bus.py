"""The one owner of the CAN bus: one ``can.Bus``, one ``canopen.Network``, one Notifier.

Also counts traffic (frames and worst-case bits, for the bus load), hands every frame,
received and sent, to a recorder when given one (:mod:`omnican.record.can_log`) and to the
listeners added while it runs (a telemetry tap), watches whether the bus works
(:class:`BusWatch`) and reopens it when it does not, on a thread of its own, and keeps
the controller's state from the error frames SocketCAN delivers
(:mod:`omnican.protocol.can_state`).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import threading
import time
from collections.abc import Mapping
from typing import Any, Protocol

import can
import canopen

from omnican.clock import REAL_TIME, Clock
from omnican.errors import BusError, ConfigError
from omnican.io.lockstep import LockstepBus
from omnican.io.network import FRAME_ERRORS, Network, frame_error
from omnican.plan.pdo import frame_bits
from omnican.protocol.can_state import CanController
from omnican.protocol.cia301 import SDO_RX_BASE, SYNC_COB_ID

logger = logging.getLogger(__name__)

RECONNECT_EVERY_S = 1.0  # between attempts to reopen a bus that went down
BUS_DOWN_AFTER_S = 0.05  # sends or receives failing for this long: the bus is down
BUS_UP_AFTER_S = 0.2  # and working again for this long: it is back up
WENT_DOWN, CAME_BACK = "went down", "came back"  # what BusWatch.check reports
NOTIFIER_STOP_S = 0.5
# How long the Notifier thread blocks in one receive: also how long handing reception to
# the loop waits for it to end on a quiet bus (startup: 0.1 s here cost 0.1 s half the time).
NOTIFIER_CYCLE_S = 0.02
RX_ERROR_PAUSE_S = 0.05
_FRAME_BITS = tuple(frame_bits(n) for n in range(65))  # worst case, by data length


class Recorder(Protocol):
    """What records a bus: every received frame, every sent one (as plain values, on
    the sending thread: queue and return), then closed with the bus."""

    def on_message_received(self, msg: can.Message) -> None: ...

    def record_sent(self, timestamp: float, can_id: int, data: bytes, channel: Any) -> None: ...

    def close(self) -> None: ...


class _Taps(can.Listener):
    """Listeners added while the bus runs (live views). It sits in every Notifier from the
    start, so adding one never touches a running Notifier (or races a reconnect). Tuples
    are replaced whole: the threads iterate them unlocked."""

    def __init__(self) -> None:
        self.received: tuple[can.Listener, ...] = ()
        self.sent: tuple[can.Listener, ...] = ()
        self._lock = threading.Lock()

    def add(self, listener: can.Listener, sent: bool) -> None:
        with self._lock:
            self.received += (listener,)
            if sent:
                self.sent += (listener,)

    def remove(self, listener: can.Listener) -> None:
        with self._lock:
            self.received = tuple(t for t in self.received if t is not listener)
            self.sent = tuple(t for t in self.sent if t is not listener)

    def on_message_received(self, msg: can.Message) -> None:
        for tap in self.received:
            tap.on_message_received(msg)

    def stop(self) -> None:
        """Called by the Notifier when it stops: the taps stay for the next one."""


class _Traffic(can.Listener):
    """Counts frames and worst-case bits seen on the bus, both directions.

    Received frames are counted on the Notifier thread, sent ones on whichever thread
    sent them (the control loop, a configuration worker): one lock keeps the sums exact.
    Also notices receive errors, which python-can hands to ``on_error``."""

    def __init__(self, owner: CanBus) -> None:
        self._owner = owner
        self._lock = threading.Lock()
        self._frames = 0
        self._bits = 0
        # The control loop's own sends: one writer, no lock needed.
        self.loop_frames = 0
        self.loop_bits = 0

    @property
    def frames(self) -> int:
        return self._frames + self.loop_frames

    @property
    def bits(self) -> int:
        return self._bits + self.loop_bits

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self._frames += 1
            self._bits += _FRAME_BITS[len(msg.data)]
        if msg.is_error_frame:
            self._owner.controller.on_error_frame(msg.arbitration_id, msg.data)
        if self._owner.rx_error is not None:
            self._owner.rx_error = None  # frames arrive again

    def count_sent(self, data_len: int) -> None:
        with self._lock:
            self._frames += 1
            self._bits += _FRAME_BITS[data_len]

    def on_error(self, exc: Exception) -> None:
        """python-can's Notifier calls this when a receive fails (an interface that went
        down, a hub that died). Handling it keeps the Notifier thread alive, without a
        traceback; the pause keeps a permanently failing receive from spinning."""
        self._owner.rx_error = f"receive failed: {exc}"
        time.sleep(RX_ERROR_PAUSE_S)

    def stop(self) -> None:
        pass


class _Network(Network):
    """The shared-bus network (:mod:`omnican.io.network`) with every sent frame counted and
    recorded, and the configuration SDO requests counted per node (a node whose answers
    outnumber them is two devices on one id)."""

    def __init__(self, owner: CanBus) -> None:
        super().__init__()
        self._owner = owner
        self.sdo_requests: dict[int, int] = {}  # node id -> configuration requests sent

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if SDO_RX_BASE < can_id <= SDO_RX_BASE + 0x7F:
            node = can_id - SDO_RX_BASE
            self.sdo_requests[node] = self.sdo_requests.get(node, 0) + 1
        if self._owner.lockstep:  # the answers arrive inside the send: record it first
            self._owner._sent(can_id, data)
            super().send_message(can_id, data, remote)
            return
        super().send_message(can_id, data, remote)
        self._owner._sent(can_id, data)


def shutdown_quietly(bus: can.BusABC) -> None:
    """Shut a bus down whatever state its transport is in.

    A bus whose peer vanished can fail in ``shutdown`` (python-can-remote: ENOTCONN
    from the dead socket); python-can then retries from ``BusABC.__del__`` and prints an
    "Exception ignored" traceback at exit. Mark it shut down either way."""
    try:
        bus.shutdown()
    except Exception as exc:  # a dead transport fails in many ways
        logger.debug("shutting down %s: %s", type(bus).__name__, exc)
        sock = getattr(bus, "socket", None)
        close = getattr(sock, "close", None)
        if callable(close):
            with contextlib.suppress(OSError):
                close()
    finally:
        bus._is_shutdown = True  # python-can's own flag: no retry from __del__


class CanBus:
    """Opens the bus from a ``[bus]`` config table (None: python-can's own config).

    Sends never raise: a failed send is counted (:attr:`send_errors`, :attr:`last_error`)
    and the caller decides when the bus counts as down. :meth:`request_reconnect` reopens
    the bus on a thread of its own (the control loop never waits for it); each reopening
    that succeeds increments :attr:`generation`.

    With a lock-step ``clock`` (:class:`omnican.clock.SimClock`) the bus is an in-process
    :class:`omnican.io.lockstep.LockstepBus` on the configured channel name: no Notifier
    thread, frames delivered on the sender's thread.

    A context manager; :meth:`close` is idempotent."""

    def __init__(self, bus: Mapping[str, Any] | None = None, recorder: Recorder | None = None,
                 notifier_cycle_s: float = NOTIFIER_CYCLE_S, clock: Clock = REAL_TIME) -> None:
        self.bus_kwargs: dict[str, Any] = dict(bus or {})
        self.clock = clock
        self.lockstep = clock.lockstep
        self.traffic = _Traffic(self)
        #: gets every frame, received and sent, until the bus closes; closed with it
        self.recorder = recorder
        self._taps = _Taps()
        self.network = _Network(self)
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
        self.sync_epoch = 0
        self.sync_time = 0.0
        self._sync_msg = prepared_message(SYNC_COB_ID, b"")
        self.last_error: str | None = None
        self.send_errors = 0
        self.dropped_frames = 0  # frames the bus refused (never queued for later)
        self.rx_error: str | None = None
        #: the controller's state, from the error frames (SocketCAN delivers them)
        self.controller = CanController()
        self.generation = 0
        self.reconnect_error: str | None = None
        self._closed = False
        self._lock = threading.Lock()
        self._reconnect_wanted = threading.Event()
        self._polling = False
        self._force_reopen = False
        self._poll_bus: tuple[Any, Any, Any] = (None, None, None)  # bus, its recv, fast recv
        self._reconnect_thread: threading.Thread | None = None
        if self.lockstep:
            self.send_prepared = self._send_lockstep  # type: ignore[method-assign]
        self._connect()

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
        return self._reconnect_wanted.is_set()

    # ------------------------------------------------------------ polling

    @property
    def polling(self) -> bool:
        return self._polling

    def start_polling(self) -> None:
        """Hand reception to the control loop: stop the Notifier thread; from now on
        :meth:`poll` reads what arrived, once a cycle, and hands each frame to the
        listeners and to canopen as the Notifier would (TPDOs, SDO answers, EMCY,
        heartbeats).

        One thread waking per cycle instead of one per frame is most of what a cycle
        costs at 1 kHz; SDO answers to configuration workers then wait up to a period."""
        if self.lockstep or self._polling:
            return
        with self.network.send_lock:
            notifier, self.network.notifier = self.network.notifier, None
            self._polling = True
        if notifier is not None:
            notifier.stop(NOTIFIER_STOP_S)

    def stop_polling(self) -> None:
        """Give reception back to a Notifier thread (before the loop stops)."""
        with self.network.send_lock:
            if not self._polling:
                return
            self._polling = False
            bus = self.network.bus
        if bus is not None and not self._closed:
            listeners: list[can.Listener] = self.network.listeners  # type: ignore[assignment]
            try:
                self.network.notifier = can.Notifier(bus, listeners, self.network.NOTIFIER_CYCLE)
            except Exception as exc:  # a dead bus: the reconnect path opens a new one
                logger.debug("restarting the Notifier: %s", exc)

    def poll(self, limit: int = 256) -> int:
        """Read and dispatch the frames that arrived (at most ``limit``); the control
        loop's receive. Returns how many were read."""
        bus = self.network.bus
        if bus is None:
            return 0
        cached_bus, recv, internal = self._poll_bus
        if bus is not cached_bus:  # a new bus (opened, reopened): look at it once
            recv, internal = bus.recv, None
            if bus.filters is None and type(bus)._recv_internal is not can.BusABC._recv_internal:
                # No filters to apply: BusABC.recv would only add its timeout and filter
                # bookkeeping around the interface's own receive, for every frame.
                internal = bus._recv_internal
            self._poll_bus = (bus, recv, internal)
        dispatch = self._dispatch
        n = 0
        while n < limit:
            try:
                msg = internal(0)[0] if internal is not None else recv(0)
            except Exception as exc:  # an interface gone down: as the Notifier says
                self.rx_error = f"receive failed: {exc}"
                break
            if msg is None:
                break
            n += 1
            dispatch(msg)
        if n and self.rx_error is not None:
            self.rx_error = None
        return n

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

    def _connect(self) -> None:
        if self.lockstep:
            self._connect_lockstep()
            return
        try:
            self.network.connect(**self.bus_kwargs)
        except Exception as exc:  # python-can raises many kinds for a bad interface/channel
            if self.recorder is not None:
                self.recorder.close()
            if not self.bus_kwargs and "interface" in str(exc).lower():
                raise ConfigError("no CAN interface configured: pass -i/-c (e.g. -i socketcan "
                               "-c can0), add a [bus] table to the config, or set up python-can's "
                               "config file; --sim runs without hardware") from None
            where = ", ".join(f"{k}={v}" for k, v in self.bus_kwargs.items()) or \
                "python-can's configuration"
            raise BusError(f"cannot open CAN bus ({where}): {exc}") from None
        logger.info("bus open: %s", self.network.bus.channel_info if self.network.bus else "?")

    def _connect_lockstep(self) -> None:
        interface = self.bus_kwargs.get("interface", "virtual")
        channel = self.bus_kwargs.get("channel")
        if interface != "virtual" or not channel:
            raise ConfigError("lock-step simulation runs on an in-process channel: the bus "
                              f"must be interface 'virtual' with a channel, not {interface!r}")
        lockstep = LockstepBus(str(channel), self.clock)

        # The real-time loop's own dispatch, for each frame as it arrives: lock-step runs
        # exercise the same path (traffic, listeners, subscribers) as a robot.
        lockstep.set_receiver(self._dispatch)
        self.network.bus = lockstep

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
            self.last_error = describe_send_error(msg.arbitration_id, exc)
        return False

    def _sends_work(self) -> None:
        logger.info("bus sends work again after %d errors", self.send_errors)
        self.send_errors = 0
        self.last_error = None

    def sync(self) -> bool:
        """Send a SYNC; samples the drives take for it carry the new epoch."""
        self.sync_epoch += 1  # the loop thread is the only writer
        self.sync_time = self.clock.now()
        return self.send_prepared(self._sync_msg, _FRAME_BITS[0])

    # ------------------------------------------------------------ reconnecting

    def request_reconnect(self, force: bool = False) -> None:
        """Reopen the bus in the background, retrying every ``RECONNECT_EVERY_S`` until
        it opens (or the bus is closed). Returns at once. A bus that works again by the
        time of an attempt is left as it is, unless ``force``."""
        with self._lock:
            if self._closed or self._reconnect_wanted.is_set() or self.lockstep:
                return
            self._force_reopen = force
            self._reconnect_wanted.set()
            if self._reconnect_thread is None or not self._reconnect_thread.is_alive():
                self._reconnect_thread = threading.Thread(
                    target=self._reconnect_loop, name="omnican-bus-reconnect", daemon=True)
                self._reconnect_thread.start()

    def _reconnect_loop(self) -> None:
        """The one place reopening is paced: an attempt, then ``RECONNECT_EVERY_S`` to
        see whether the bus works (sends and receives through it), and again while not."""
        while not self._closed:
            if self.failing is None and not self._force_reopen:
                break  # it works again (reopened, or the link came back up as it was)
            self._force_reopen = False
            self._reopen()
            deadline = time.monotonic() + RECONNECT_EVERY_S
            while not self._closed and time.monotonic() < deadline:
                time.sleep(0.05)
        self._reconnect_wanted.clear()

    def _release(self) -> None:
        """Stop the Notifier and shut the bus down; sends fail fast meanwhile."""
        network = self.network
        with network.send_lock:
            bus, network.bus = network.bus, None
        notifier, network.notifier = network.notifier, None
        if notifier is not None:
            try:
                notifier.stop(NOTIFIER_STOP_S)
            except Exception as exc:  # a listener's stop() failing must not block reopening
                logger.debug("stopping the Notifier: %s", exc)
        if bus is not None:
            shutdown_quietly(bus)

    def _reopen(self) -> bool:
        self._release()
        if self._closed:
            return False
        try:
            new_bus = can.Bus(**self.bus_kwargs)
        except Exception as exc:  # the interface is still gone, the hub not back yet
            self.reconnect_error = f"reopening the bus failed: {exc}"
            logger.debug("%s", self.reconnect_error)
            return False
        listeners: list[can.Listener] = self.network.listeners  # type: ignore[assignment]
        notifier = None
        if not self._polling:  # the control loop reads the new bus itself otherwise
            try:
                notifier = can.Notifier(new_bus, listeners, self.network.NOTIFIER_CYCLE)
            except Exception as exc:
                shutdown_quietly(new_bus)
                self.reconnect_error = f"reopening the bus failed: {exc}"
                return False
        with self.network.send_lock:
            if self._closed:
                if notifier is not None:
                    notifier.stop(NOTIFIER_STOP_S)
                shutdown_quietly(new_bus)
                return False
            self.network.bus, self.network.notifier = new_bus, notifier
        self.rx_error = None
        self.reconnect_error = None
        self.controller.reset()
        self.generation += 1
        logger.warning("CAN bus reopened")
        return True

    # ------------------------------------------------------------ closing

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        thread = self._reconnect_thread
        if thread is not None:
            thread.join(timeout=RECONNECT_EVERY_S + 2 * NOTIFIER_STOP_S + 1.0)
        for node in self.network.nodes.values():
            pdo = getattr(node, "pdo", None)
            if pdo is not None:
                with contextlib.suppress(Exception):
                    pdo.stop()
        self._release()
        FRAME_ERRORS.flush()
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> CanBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


def prepared_message(can_id: int, data: bytes) -> can.Message:
    """A frame made once and sent every cycle with new ``data``.

    Its data is kept as ``bytes``: python-can's virtual bus deep-copies every frame it
    sends, and a ``bytes`` object (immutable) costs nothing to copy where a bytearray
    costs microseconds. Every interface only reads ``data`` while sending."""
    msg = can.Message(arbitration_id=can_id, is_extended_id=False, dlc=len(data))
    msg.data = data  # type: ignore[assignment]  # bytes where python-can says bytearray
    return msg


def describe_send_error(can_id: int, exc: BaseException) -> str:
    """One line for a failed send, naming the usual causes."""
    code = getattr(exc, "error_code", None) or getattr(exc, "errno", None)
    if code == errno.ENOBUFS:
        return (f"send 0x{can_id:03X} failed: transmit queue full (no buffer space; nothing "
                "acknowledges the frames?)")
    if code == errno.ENETDOWN:
        return f"send 0x{can_id:03X} failed: the CAN interface is down"
    return f"send 0x{can_id:03X} failed: {exc}"
