"""SYNC, as the bus owner (:class:`omnican.io.bus.CanBus`) sends it and waits for it.

From the loop: :meth:`SyncSending.sync` sends one after the cycle's RPDOs, with CiA 301's
counter where ``[bus] sync_counter`` asks. From the kernel (SocketCAN, ``[bus] sync``):
the broadcast manager sends it on its own timer (:mod:`omnican.io.kernel_sync`), armed
for a bounded count that each cycle renews, and the loop waits for each one
(:meth:`SyncSending.wait_sync`). A part of :class:`~omnican.io.bus.CanBus` (a base class
of it), in a module of its own so the bus's class stays one screenful of concerns.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import can

from omnican.clock import Clock
from omnican.io.bus_watch import describe_receive_error
from omnican.io.kernel_sync import KernelSync
from omnican.io.listeners import FRAME_BITS as _FRAME_BITS
from omnican.io.listeners import CountingNetwork
from omnican.protocol.cia301 import SYNC_COB_ID
from omnican.protocol.sync_producer import SyncMode, counter_payloads, expired, hold_count

logger = logging.getLogger(__name__)


class SyncSending:
    """CanBus's SYNC: sent by the loop or the kernel, and the kernel-timed loop's wait.
    Reads what :class:`~omnican.io.bus.CanBus` owns (declared here for the type checker)."""

    if TYPE_CHECKING:
        network: CountingNetwork
        bus_kwargs: dict[str, Any]
        clock: Clock
        sync_mode: SyncMode
        rx_error: str | None
        _poll_bus: tuple[Any, Any, Any]
        send_prepared: Callable[[can.Message, int], bool]

        def _dispatch(self, msg: can.Message) -> None: ...

        def _receivers(self, bus: Any) -> tuple[Any, Any]: ...

    def _init_sync(self, counter: int) -> None:
        self.sync_counter = counter
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
