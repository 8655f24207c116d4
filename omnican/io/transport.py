"""Who holds the CAN bus and who reads it: opening it (a configured interface, or the
lock-step bus), handing reception between python-can's Notifier and the control loop,
shutting it down, and reopening it when it fails: paced, on a thread of its own, so the
control loop never waits for it.

:class:`omnican.io.bus.CanBus` owns one :class:`Transport`; the per-frame paths (send,
poll, SYNC) stay in the bus and never go through it.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from typing import TYPE_CHECKING

import can

from omnican.errors import BusError, ConfigError
from omnican.io.bus_watch import describe_open_error, open_error_reason
from omnican.io.lockstep import LockstepBus

if TYPE_CHECKING:
    from omnican.io.owner import BusOwner

logger = logging.getLogger("omnican.io.bus")  # one name for the bus's story in the log

RECONNECT_EVERY_S = 1.0  # between attempts to reopen a bus that went down
NOTIFIER_STOP_S = 0.5


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


class Transport:
    """The ``can.Bus`` and the Notifier of one :class:`~omnican.io.bus.CanBus` (its
    ``network``): opened, handed over, released, reopened. Each reopening that succeeds
    increments the bus's ``generation``."""

    def __init__(self, owner: BusOwner) -> None:
        self._owner = owner
        self.network = owner.network
        self.closed = False
        self.polling = False
        self._lock = threading.Lock()
        self._reconnect_wanted = threading.Event()
        self._force_reopen = False
        self._reconnect_thread: threading.Thread | None = None

    @property
    def reconnecting(self) -> bool:
        return self._reconnect_wanted.is_set()

    # ------------------------------------------------------------ opening

    def connect(self) -> None:
        owner = self._owner
        if owner.lockstep:
            self._connect_lockstep()
            return
        try:
            self.network.connect(**owner.bus_kwargs)
        except Exception as exc:  # python-can raises many kinds for a bad interface/channel
            if owner.recorder is not None:
                owner.recorder.close()
            if not owner.bus_kwargs and "interface" in str(exc).lower():
                raise ConfigError("no CAN interface configured: pass -i/-c (e.g. -i socketcan "
                               "-c can0), add a [bus] table to the config, or set up python-can's "
                               "config file; --sim runs without hardware") from None
            raise BusError(describe_open_error(owner.bus_kwargs, exc)) from None
        logger.info("bus open: %s", self.network.bus.channel_info if self.network.bus else "?")

    def _connect_lockstep(self) -> None:
        owner = self._owner
        interface = owner.bus_kwargs.get("interface", "virtual")
        channel = owner.bus_kwargs.get("channel")
        if interface != "virtual" or not channel:
            raise ConfigError("lock-step simulation runs on an in-process channel: the bus "
                              f"must be interface 'virtual' with a channel, not {interface!r}")
        lockstep = LockstepBus(str(channel), owner.clock)

        # The real-time loop's own dispatch, for each frame as it arrives: lock-step runs
        # exercise the same path (traffic, listeners, subscribers) as a robot. A frame only
        # the traffic count and canopen's subscribers hear goes to them as values
        # (_dispatch_frame, held to _dispatch by tests/io/test_lockstep_frames.py).
        lockstep.set_receiver(owner._dispatch, owner._dispatch_frame)
        self.network.bus = lockstep

    # ------------------------------------------------------------ who reads the bus

    def start_polling(self) -> None:
        """See :meth:`omnican.io.bus.CanBus.start_polling`: stop the Notifier thread."""
        if self._owner.lockstep or self.polling:
            return
        with self.network.send_lock:
            notifier, self.network.notifier = self.network.notifier, None
            self.polling = True
        if notifier is not None:
            notifier.stop(NOTIFIER_STOP_S)

    def stop_polling(self) -> None:
        """Give reception back to a Notifier thread (before the loop stops)."""
        network = self.network
        with network.send_lock:
            if not self.polling:
                return
            self.polling = False
            bus = network.bus
        if bus is not None and not self.closed:
            listeners: list[can.Listener] = network.listeners  # type: ignore[assignment]
            try:
                network.notifier = can.Notifier(bus, listeners, network.NOTIFIER_CYCLE)
            except Exception as exc:  # a dead bus: the reconnect path opens a new one
                logger.debug("restarting the Notifier: %s", exc)

    # ------------------------------------------------------------ reconnecting

    def request_reconnect(self, force: bool = False) -> None:
        """Reopen the bus in the background, retrying every ``RECONNECT_EVERY_S`` until
        it opens (or the bus is closed). Returns at once. A bus that works again by the
        time of an attempt is left as it is, unless ``force``."""
        with self._lock:
            if self.closed or self._reconnect_wanted.is_set() or self._owner.lockstep:
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
        owner = self._owner
        while not self.closed:
            if owner.failing is None and not self._force_reopen:
                break  # it works again (reopened, or the link came back up as it was)
            self._force_reopen = False
            self._reopen()
            deadline = time.monotonic() + RECONNECT_EVERY_S
            while not self.closed and time.monotonic() < deadline:
                time.sleep(0.05)
        self._reconnect_wanted.clear()

    def release(self) -> None:
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
        owner, network = self._owner, self.network
        self.release()
        if self.closed:
            return False
        try:
            new_bus = can.Bus(**owner.bus_kwargs)
        except Exception as exc:  # the interface is still gone, the hub not back yet
            owner.reconnect_error = ("reopening the bus failed: "
                                     f"{open_error_reason(owner.bus_kwargs, exc)}")
            logger.debug("%s", owner.reconnect_error)
            return False
        listeners: list[can.Listener] = network.listeners  # type: ignore[assignment]
        notifier = None
        if not self.polling:  # the control loop reads the new bus itself otherwise
            try:
                notifier = can.Notifier(new_bus, listeners, network.NOTIFIER_CYCLE)
            except Exception as exc:
                shutdown_quietly(new_bus)
                owner.reconnect_error = f"reopening the bus failed: {exc}"
                return False
        with network.send_lock:
            if self.closed:
                if notifier is not None:
                    notifier.stop(NOTIFIER_STOP_S)
                shutdown_quietly(new_bus)
                return False
            network.bus, network.notifier = new_bus, notifier
        owner.rx_error = None
        owner.reconnect_error = None
        owner.controller.reset()
        owner.generation += 1
        logger.warning("CAN bus reopened")
        return True

    # ------------------------------------------------------------ closing

    def close(self) -> bool:
        """No more reopening: wait for an attempt under way. False when already closed."""
        with self._lock:
            if self.closed:
                return False
            self.closed = True
        thread = self._reconnect_thread
        if thread is not None:
            thread.join(timeout=RECONNECT_EVERY_S + 2 * NOTIFIER_STOP_S + 1.0)
        return True
