"""A CAN IMU on the base's own bus, read through its DBC (cantools).

:class:`CanImu` is a listener of the bus owner (:meth:`omnican.io.bus.CanBus.add_listener`:
the Notifier's thread, or the control loop's receive while it polls): a frame of the
IMU's yaw-rate message becomes an :class:`~omnican.core.imu.ImuSample` (SI units, the
base's frame, the host's monotonic time) in its :class:`~omnican.core.imu.ImuInbox`;
a frame of its acceleration message (another one, on J1939 IMUs) is kept and goes with
the next yaw rate. Extended (29-bit) ids are the usual case: a J1939 IMU shares the bus
with the CANopen drives, whose frames are all 11-bit.

A frame's time is the interface's receive time (SocketCAN stamps it in the kernel),
moved onto the monotonic clock; where that stamp is not believable (see
:func:`omnican.core.imu.host_time`), the time the listener saw it.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import can

from omnican.clock import REAL_TIME, Clock
from omnican.config import ImuSettings
from omnican.config.imu import dbc_imu
from omnican.core.imu import ImuInbox, ImuMount, host_time
from omnican.log_throttle import Throttle

if TYPE_CHECKING:
    from omnican.io.bus import CanBus

logger = logging.getLogger(__name__)


class CanImu(can.Listener):
    """Decodes the IMU ``settings`` names (``source = "can"``) into ``inbox`` (a new one
    by default). :meth:`attach` it to a bus; :meth:`close` detaches it (idempotent; a
    context manager). ``frames``: the IMU's frames seen; ``bad_frames``: those that did
    not decode (logged, throttled)."""

    def __init__(self, settings: ImuSettings, inbox: ImuInbox | None = None,
                 clock: Clock = REAL_TIME) -> None:
        if settings.source != "can":
            raise ValueError(f"a CAN IMU reads [imu] source = \"can\", not {settings.source!r}")
        self.settings = settings
        self.inbox = inbox if inbox is not None else ImuInbox()
        self.clock = clock
        dbc = dbc_imu(settings)
        self._rate = dbc.rate_message
        self._accel = dbc.accel_message
        self._rate_key = (self._rate.frame_id, bool(self._rate.is_extended_frame))
        self._accel_key = ((self._accel.frame_id, bool(self._accel.is_extended_frame))
                           if self._accel is not None else None)
        self._rate_factor = dbc.rate_factor
        self._yaw_signal = settings.yaw_rate or ""  # dbc_imu checked it is given
        self._accel_factor = dbc.accel_factor
        self._mount = ImuMount(settings.mount_yaw_deg, settings.upside_down)
        self._accel_now: tuple[float, float, float] | None = None  # (t, x, y) in SI
        self._bus: CanBus | None = None
        self._throttle = Throttle(logger)
        self.frames = 0
        self.bad_frames = 0

    @property
    def frame_id(self) -> int:
        """The yaw-rate message's CAN id (29-bit where the DBC says extended)."""
        return int(self._rate.frame_id)

    @property
    def is_extended_id(self) -> bool:
        return bool(self._rate.is_extended_frame)

    def attach(self, bus: CanBus) -> CanImu:
        """Hear ``bus`` from now on (across its reconnects)."""
        if self._bus is None:
            bus.add_listener(self)
            self._bus = bus
        return self

    def on_message_received(self, msg: can.Message) -> None:
        key = (msg.arbitration_id, msg.is_extended_id)
        if key == self._rate_key:
            self._on_rate(msg)
        if key == self._accel_key:
            self._on_accel(msg)

    def _time(self, msg: can.Message) -> float:
        clock = self.clock
        stamp = msg.timestamp
        now = clock.now()
        return host_time(stamp, now, clock.wall()) if stamp else now

    def _decode(self, message: Any, msg: can.Message) -> dict[str, Any] | None:
        try:
            values: dict[str, Any] = message.decode(bytes(msg.data), decode_choices=False)
        except Exception as exc:  # a short frame, a multiplexer it does not know
            self.bad_frames += 1
            self._throttle.warning("imu", "IMU frame 0x%X did not decode (%d so far): %s",
                                   msg.arbitration_id, self.bad_frames, exc)
            return None
        return values

    def _on_rate(self, msg: can.Message) -> None:
        self.frames += 1
        values = self._decode(self._rate, msg)
        if values is None:
            return
        s = self.settings
        rate = float(values[self._yaw_signal]) * self._rate_factor
        if not math.isfinite(rate):
            return
        t = self._time(msg)
        if self._accel is self._rate and s.accel_x is not None and s.accel_y is not None:
            ax = float(values[s.accel_x]) * self._accel_factor
            ay = float(values[s.accel_y]) * self._accel_factor
            self.inbox.put(self._mount.to_base(t, rate, ax, ay))
            return
        accel = self._accel_now
        if accel is not None and 0.0 <= t - accel[0] <= s.stale_s:
            self.inbox.put(self._mount.to_base(t, rate, accel[1], accel[2]))
        else:
            self.inbox.put(self._mount.to_base(t, rate))

    def _on_accel(self, msg: can.Message) -> None:
        if self._accel is self._rate:
            return  # read with the yaw rate
        values = self._decode(self._accel, msg)
        s = self.settings
        if values is None or s.accel_x is None or s.accel_y is None:
            return
        self._accel_now = (self._time(msg), float(values[s.accel_x]) * self._accel_factor,
                           float(values[s.accel_y]) * self._accel_factor)

    def stop(self) -> None:
        """python-can's listener hook: the bus keeps its listeners across reconnects."""

    def close(self, last: object = None) -> None:
        """Hear the bus no more (``last``: the base's last snapshot, as attachments are
        closed: unused)."""
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.remove_listener(self)
        self._throttle.flush()

    def __enter__(self) -> CanImu:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
