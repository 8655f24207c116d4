"""SYNC sent by the kernel: the SocketCAN broadcast manager (BCM) on a timer of its own.

A Python loop's SYNC leaves when the loop gets the CPU; the drives sample their encoders
on it, so its jitter is odometry noise. The BCM sends it from a kernel high-resolution
timer instead (as ros_canopen's ``canopen_bcm_sync`` does, and python-can's
``send_periodic`` on SocketCAN). Unlike ``send_periodic``, the task here is armed for a
bounded count of SYNCs (:func:`omnican.protocol.sync_producer.hold_count`) and re-armed by
the control loop every cycle without restarting its timer (``SETTIMER`` without
``STARTTIMER``: the period's phase stays the kernel's), so that:

- a loop that hangs (stopped, deadlocked) stops SYNC after that count;
- a process that dies closes the BCM socket, and the kernel deletes its tasks with it;
- :meth:`KernelSync.stop` deletes the task (``TX_DELETE``).

The SYNC counter (1019h) is the task's list of frames: the BCM sends them in turn, one a
period, and a re-arm that hands the same list back keeps its place in it.

The frame and header layouts are python-can's (``can.interfaces.socketcan.socketcan``);
the socket is this module's own, not the bus's, so that closing it ends exactly this task.
"""

from __future__ import annotations

import contextlib
import logging
import socket
from collections.abc import Sequence

import can

from omnican.protocol.cia301 import SYNC_COB_ID

logger = logging.getLogger(__name__)

_TASK_ID = SYNC_COB_ID  # the BCM's name for the task (its frames carry their own id)


def _bcm() -> tuple[object, object]:
    """python-can's SocketCAN module and its constants (imported only where used: Linux)."""
    from can.interfaces.socketcan import constants
    from can.interfaces.socketcan import socketcan as sc
    return sc, constants


class KernelSync:
    """A BCM task sending SYNC on ``channel`` every ``period_s``, the frames' data
    ``payloads`` in turn, at most ``hold`` of them after each :meth:`start` or
    :meth:`rearm`. Nothing raises after construction: a failed call returns False and
    keeps its reason in :attr:`error` (the loop then falls back on its own timeout).

    A context manager; :meth:`stop` is idempotent."""

    def __init__(self, channel: str, period_s: float, payloads: Sequence[bytes],
                 hold: int) -> None:
        if not payloads:
            raise ValueError("payloads: at least one SYNC")
        sc, constants = _bcm()
        self.channel = channel
        self.period_s = period_s
        self.hold = hold
        self.error: str | None = None
        self.restarts = 0  # times the timer was started anew after it had run out
        frames = b"".join(sc.build_can_frame(  # type: ignore[attr-defined]
            can.Message(arbitration_id=SYNC_COB_ID, is_extended_id=False, data=p))
            for p in payloads)
        seconds = int(period_s)
        usec = round((period_s - seconds) * 1e6)
        if seconds == 0 and usec == 0:
            raise ValueError(f"period: at least 1 us, not {period_s}")
        header = sc.build_bcm_header  # type: ignore[attr-defined]
        setup = constants.CAN_BCM_TX_SETUP  # type: ignore[attr-defined]
        settimer = constants.SETTIMER  # type: ignore[attr-defined]
        starttimer = constants.STARTTIMER  # type: ignore[attr-defined]
        n = len(payloads)
        # ival1 for `hold` frames, then ival2 = 0: the timer stops after the count.
        # STARTTIMER also sends one at once (the spec's "announce") and restarts the
        # timer; TX_RESET_MULTI_IDX is never set, so the counter goes on where it was.
        self._start_msg = header(setup, settimer | starttimer, hold, seconds, usec, 0, 0,
                                 _TASK_ID, n) + frames
        self._rearm_msg = header(setup, settimer, hold, seconds, usec, 0, 0, _TASK_ID,
                                 n) + frames
        self._delete_msg = header(constants.CAN_BCM_TX_DELETE,  # type: ignore[attr-defined]
                                  0, 0, 0, 0, 0, 0, _TASK_ID, 1)
        self._create = sc.create_bcm_socket  # type: ignore[attr-defined]
        self._sock: socket.socket | None = None

    @property
    def running(self) -> bool:
        return self._sock is not None

    def start(self) -> bool:
        """Open the BCM socket if needed and start the timer: a SYNC now, then every
        period, ``hold`` in all unless re-armed."""
        if self._sock is None:
            try:
                self._sock = self._create(self.channel)
            except OSError as exc:
                self.error = f"cannot open the broadcast manager on {self.channel}: " \
                             f"{exc.strerror or exc}"
                return False
        return self._send(self._start_msg)

    def restart(self) -> bool:
        """Start the timer anew after it ran out (the loop was stalled, or the interface
        went away: then the socket is opened again)."""
        self.restarts += 1
        if not self._send(self._start_msg):
            self._close_socket()
            return self.start()
        return True

    def rearm(self) -> bool:
        """``hold`` more SYNCs from now, on the running timer (its phase untouched). The
        control loop's once-a-cycle call: a timer that already ran out stays stopped
        (see :func:`omnican.protocol.sync_producer.expired`; :meth:`restart` starts it)."""
        return self._send(self._rearm_msg)

    def _send(self, msg: bytes) -> bool:
        sock = self._sock
        if sock is None:
            self.error = "the broadcast manager's socket is closed"
            return False
        try:
            sock.send(msg)
        except OSError as exc:
            self.error = f"the broadcast manager refused SYNC on {self.channel}: " \
                         f"{exc.strerror or exc}"
            return False
        if self.error is not None:
            self.error = None
        return True

    def stop(self) -> None:
        """Delete the task and close the socket (closing alone would end it too)."""
        sock = self._sock
        if sock is None:
            return
        with contextlib.suppress(OSError):
            sock.send(self._delete_msg)
        self._close_socket()

    def _close_socket(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()

    def __enter__(self) -> KernelSync:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
