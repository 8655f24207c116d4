"""A node's health values at run time: the health TPDOs decoded as they arrive (on the
receiving thread: values copied, nothing else) and the round-robin expedited SDO reads
of the rest, one request at a time, sent on the loop thread as often as
``chassis.health_rate_hz`` says.

The plan is :mod:`omnican.plan.health`'s; :class:`NodeHealth` keeps the newest raw value
of each object and when it came, and says what each wheel's values are in SI units.
A value older than :data:`STALE_PERIODS` health periods is unknown (None): a drive that
went silent shows nothing rather than its last current.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import canopen

from omnican.clock import Clock
from omnican.plan.codec import PdoCodec
from omnican.plan.health import HealthPlan, HealthRead
from omnican.protocol.sdo_cycle import SDO_REQUEST_BASE, Answer, AnswerKind, upload_request

logger = logging.getLogger("omnican.drive")

STALE_PERIODS = 5.0  # health periods without a value: unknown
Key = tuple[int, int]
Send = Callable[[int, bytes], Any]


class NodeHealth:
    """The health values of one node (see the module docstring)."""

    def __init__(self, network: canopen.Network, node_id: int, plan: HealthPlan,
                 clock: Clock, sdo_timeout_s: float) -> None:
        self.network = network
        self.node_id = node_id
        self.clock = clock
        self.plan = plan
        self._sdo_timeout_s = sdo_timeout_s
        #: raw value and arrival time of each object (receiving thread writes whole)
        self.values: dict[Key, tuple[int, float]] = {}
        #: SI per unit of reads whose scale is found at startup (6078h: the rated current)
        self.scales: dict[Key, float] = {}
        self._subscribed: list[tuple[int, Callable[[int, bytearray, float], None]]] = []
        self._next = 0  # the next SDO read, round robin
        self._due = 0.0
        self._pending: tuple[Key, float] | None = None
        self.stale_after_s = STALE_PERIODS / plan.rate_hz
        self.use(plan)

    @property
    def next_poll_at(self) -> float:
        """When :meth:`poll` next has something to do (s)."""
        pending = self._pending
        if pending is not None:
            return max(self._due, pending[1] + self._sdo_timeout_s)
        return self._due

    def use(self, plan: HealthPlan) -> None:
        """Read as ``plan`` says from now on (configured, or fallen back to SDO)."""
        self._unsubscribe()
        self.plan = plan
        self._next, self._pending = 0, None
        for pdo in plan.pdos:
            handler = self._make_handler(PdoCodec(pdo))
            self.network.subscribe(pdo.cob_id, handler)
            self._subscribed.append((pdo.cob_id, handler))

    def _make_handler(self, codec: PdoCodec) -> Callable[[int, bytearray, float], None]:
        unpack = codec.unpacker()
        length = codec.length
        keys = tuple((f.entry.index, f.entry.subindex) for f in codec.fields)
        values, now = self.values, self.clock.now

        def on_tpdo(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) < length:
                return
            decoded = unpack(data)
            if decoded is None:
                return
            t = now()
            for key, value in zip(keys, decoded, strict=True):
                values[key] = (value, t)

        return on_tpdo

    # ------------------------------------------------------------ SDO, round robin

    def poll(self, now: float, send: Send) -> None:
        """Send the next SDO read when one is due (loop thread, at the health-check
        rate). One request at a time: the next waits for the answer or its timeout."""
        sdo = self.plan.sdo
        if not sdo or now < self._due:
            return
        pending = self._pending
        if pending is not None and now - pending[1] < self._sdo_timeout_s:
            return
        read = sdo[self._next % len(sdo)]
        self._next += 1
        self._due = now + self.plan.sdo_period_s
        self._pending = (read.key, now)
        send(SDO_REQUEST_BASE + self.node_id, upload_request(*read.key))

    def on_answer(self, answer: Answer) -> bool:
        """An SDO answer of this node (receiving thread): True when it answered a health
        read (then it is taken here)."""
        pending = self._pending
        if pending is None or (answer.index, answer.subindex) != pending[0]:
            return False
        if answer.kind is AnswerKind.UPLOADED:
            read = next(r for r in self.plan.sdo if r.key == pending[0])
            entry = read.entry
            self.values[pending[0]] = (entry.decode(answer.data.ljust(entry.bits // 8, b"\x00")),
                                       self.clock.now())
        elif answer.kind is AnswerKind.ABORTED:
            logger.debug("node %d: health read of %s refused (0x%08X)", self.node_id,
                         read_name(self.plan, pending[0]), answer.abort_code)
        else:
            return False
        self._pending = None
        return True

    # ------------------------------------------------------------ values

    def raw(self, key: Key, now: float) -> int | None:
        """The newest raw value of an object, None when unknown or stale."""
        got = self.values.get(key)
        if got is None or now - got[1] > self.stale_after_s:
            return None
        return got[0]

    def si(self, read: HealthRead, now: float) -> float | None:
        """A read's value in SI units now (None: unknown, stale, or no scale)."""
        raw = self.raw(read.key, now)
        if raw is None:
            return None
        scale = read.scale if read.scale is not None else self.scales.get(read.key)
        return None if scale is None else raw * scale

    def forget(self) -> None:
        """The drive rebooted or is configured again: nothing it said still holds."""
        self.values.clear()
        self._pending = None

    def _unsubscribe(self) -> None:
        for cob, handler in self._subscribed:
            if handler in self.network.subscribers.get(cob, []):
                self.network.unsubscribe(cob, handler)
        self._subscribed = []

    def detach(self) -> None:
        self._unsubscribe()


def read_name(plan: HealthPlan, key: Key) -> str:
    for r in plan.reads:
        if r.key == key:
            return f"{r.entry.name} ({r.entry.address})"
    return f"0x{key[0]:04X}:{key[1]:02X}"
