"""The one owner of the CAN bus: one ``can.Bus``, one ``canopen.Network``, one Notifier.

Also counts traffic (frames and worst-case bits, for the bus load) and records every
frame, received and sent, to a python-can log file when asked (format by extension:
``.log`` candump text, ``.asc``, ``.blf``, ``.csv``...).
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import can
import canopen

from omnican.errors import BusError, ConfigError
from omnican.pdoplan import frame_bits

logger = logging.getLogger(__name__)

SYNC_COB_ID = 0x80


class _Recorder(can.Listener):
    """Writes frames to a python-can log file; survives Notifier restarts (reconnects)."""

    def __init__(self, path: Path) -> None:
        self._lock = threading.Lock()
        try:
            self._writer: can.Listener | None = can.Logger(str(path))
        except (ValueError, OSError) as exc:  # unknown suffix, unwritable place
            raise ConfigError(f"cannot record to {path}: {exc}") from None
        self.path = path

    def on_message_received(self, msg: can.Message) -> None:
        # Runs on the Notifier thread: an exception here would stop all reception.
        with self._lock:
            if self._writer is None:
                return
            try:
                self._writer.on_message_received(msg)
            except (struct.error, ValueError, OverflowError):
                # BLF stores the channel as a 16-bit number taken from the trailing digits
                # of its name ("omnican-sim-95857398" overflows): write it without one.
                try:
                    self._writer.on_message_received(can.Message(
                        timestamp=msg.timestamp, arbitration_id=msg.arbitration_id,
                        is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                        is_error_frame=msg.is_error_frame, dlc=msg.dlc, data=msg.data,
                        is_rx=msg.is_rx, channel=None))
                except Exception as exc:  # a broken log must not take the bus down with it
                    logger.error("recording to %s stopped: %s", self.path, exc)
                    self._writer = None
            except Exception as exc:
                logger.error("recording to %s stopped: %s", self.path, exc)
                self._writer = None

    def stop(self) -> None:
        """Called by the Notifier when it stops: keep writing after a reconnect."""

    def close(self) -> None:
        with self._lock:
            if self._writer is not None:
                self._writer.stop()
                self._writer = None


def _recorder_for(path: Path) -> _Recorder | Any:
    """The recorder for ``path``'s format: MCAP (raw frames plus the robot's state, see
    :mod:`omnican.mcap_record`) or any python-can log format."""
    if path.suffix.lower() == ".mcap":
        from omnican.mcap_record import McapRecorder

        return McapRecorder(path)
    return _Recorder(path)


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
    """Counts frames and worst-case bits seen on the bus (both directions)."""

    def __init__(self) -> None:
        self.frames = 0
        self.bits = 0

    def on_message_received(self, msg: can.Message) -> None:
        self.frames += 1
        self.bits += frame_bits(len(msg.data))

    def stop(self) -> None:
        pass


class _Network(canopen.Network):
    """canopen's network with every sent frame counted and recorded."""

    def __init__(self, owner: CanBus) -> None:
        super().__init__()
        self._owner = owner

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        super().send_message(can_id, data, remote)
        self._owner._sent(can_id, data)


class CanBus:
    """Opens the bus from a ``[bus]`` config table (None: python-can's own config).

    A context manager; :meth:`close` is idempotent."""

    def __init__(self, bus: Mapping[str, Any] | None = None, record: str | Path | None = None,
                 notifier_cycle_s: float = 0.1) -> None:
        self.bus_kwargs: dict[str, Any] = dict(bus or {})
        self.traffic = _Traffic()
        self.recorder = _recorder_for(Path(record)) if record is not None else None
        self._taps = _Taps()
        self.network = _Network(self)
        self.network.NOTIFIER_CYCLE = notifier_cycle_s
        # canopen types this list as MessageListener only; any can.Listener works.
        listeners: list[can.Listener] = self.network.listeners  # type: ignore[assignment]
        listeners.append(self.traffic)
        listeners.append(self._taps)
        if self.recorder is not None:
            listeners.append(self.recorder)
        self.sync_epoch = 0
        self.sync_time = 0.0
        self.last_error: str | None = None
        self.send_errors = 0
        self._closed = False
        self._lock = threading.Lock()
        self._connect()

    @property
    def bitrate(self) -> int | None:
        rate = self.bus_kwargs.get("bitrate")
        return int(rate) if rate else None

    def _connect(self) -> None:
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

    def _sent(self, can_id: int, data: bytes) -> None:
        self.traffic.bits += frame_bits(len(data))
        self.traffic.frames += 1
        if self.recorder is not None or self._taps.sent:
            msg = can.Message(arbitration_id=can_id, data=data, is_extended_id=can_id > 0x7FF,
                              timestamp=time.time(), is_rx=False,
                              channel=self.bus_kwargs.get("channel"))
            if self.recorder is not None:
                self.recorder.on_message_received(msg)
            for tap in self._taps.sent:
                tap.on_message_received(msg)

    def add_listener(self, listener: can.Listener, sent: bool = False) -> None:
        """Hand every received frame to ``listener`` from now on, across reconnects (on the
        Notifier thread, so it must not block); ``sent``: also the frames this host sends
        (on the sending thread, the control loop's: append to a queue and return)."""
        self._taps.add(listener, sent)

    def remove_listener(self, listener: can.Listener) -> None:
        self._taps.remove(listener)

    def send(self, can_id: int, data: bytes) -> bool:
        """Send one frame; a failure is counted and reported, not raised.

        The control loop's path: straight to the bus (canopen's ``send_message`` adds a
        second message object and a Notifier check per frame)."""
        msg = can.Message(arbitration_id=can_id, data=data, is_extended_id=False)
        network = self.network
        try:
            bus = network.bus
            if bus is None:
                raise can.CanOperationError("bus is closed")
            with network.send_lock:
                bus.send(msg)
        except (can.CanError, OSError, RuntimeError) as exc:
            self.send_errors += 1
            self.last_error = f"send 0x{can_id:03X} failed: {exc}"
            return False
        self._sent(can_id, data)
        if self.send_errors:
            logger.info("bus sends work again after %d errors", self.send_errors)
            self.send_errors = 0
            self.last_error = None
        return True

    def sync(self) -> bool:
        """Send a SYNC; samples the drives take for it carry the new epoch."""
        with self._lock:
            self.sync_epoch += 1
            self.sync_time = time.monotonic()
        return self.send(SYNC_COB_ID, b"")

    def reconnect(self) -> bool:
        """Close and reopen the bus (after bus-off or an interface going down)."""
        with self._lock:
            if self._closed:
                return False
            try:
                if self.network.notifier is not None:
                    self.network.notifier.stop(1.0)
                if self.network.bus is not None:
                    self.network.bus.shutdown()
            except Exception as exc:  # a dead interface may fail to shut down cleanly
                logger.debug("closing the broken bus: %s", exc)
            self.network.bus = None
            try:
                self.network.connect(**self.bus_kwargs)
            except Exception as exc:
                self.last_error = f"reconnect failed: {exc}"
                return False
        logger.warning("CAN bus reopened")
        return True

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        try:
            self.network.disconnect()
        except Exception as exc:  # best effort on the way out
            logger.debug("disconnect: %s", exc)
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> CanBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
