"""Heartbeats of a simulated node (CiA 301 error control): the one it produces (1017h)
and the ones it consumes (1016h), the master's above all.

Bookkeeping only: the node sends the frames, and reacts when a producer falls silent
(EMCY 8130h, then the device's abort connection reaction). A consumer starts watching
at the first heartbeat it receives, and again after each boot.
"""

from __future__ import annotations

import math

from canopen import objectdictionary as od

from omnican.protocol.cia301 import CONSUMER_HEARTBEAT_TIME, MAX_NODE_ID, PRODUCER_HEARTBEAT_TIME
from omnican.sim.pdo import Getter, read_uint


class Heartbeat:
    """The heartbeat producer and consumer of one node."""

    def __init__(self) -> None:
        self.enabled = True  # the producer runs (a drive whose heartbeat stopped: False)
        self.period_s = 0.0  # 1017h; 0: no heartbeat
        self.last_sent = -1e9
        self._timeouts: dict[int, float] = {}  # 1016h: producer node id -> timeout s
        self._seen: dict[int, float] = {}  # producer -> when last heard
        self._lost: set[int] = set()
        # No watched producer times out before this (a little before, for rounding):
        # expired() does nothing until then (it runs at every housekeeping tick).
        self._quiet_until = -math.inf

    @property
    def timeouts(self) -> dict[int, float]:
        """1016h: producer node id -> timeout (s)."""
        return self._timeouts

    @timeouts.setter
    def timeouts(self, timeouts: dict[int, float]) -> None:
        self._timeouts = timeouts
        self._quiet_until = -math.inf

    def load(self, dictionary: od.ObjectDictionary, get_data: Getter) -> list[int]:
        """Take 1017h and 1016h from the dictionary; returns the producers consumed."""
        self.period_s = read_uint(get_data, PRODUCER_HEARTBEAT_TIME, 0, "<H") / 1000.0
        self.timeouts = {}
        obj = dictionary.get(CONSUMER_HEARTBEAT_TIME)
        if isinstance(obj, (od.ODArray, od.ODRecord)):
            for sub in obj.subindices:
                if sub == 0:
                    continue
                raw = read_uint(get_data, CONSUMER_HEARTBEAT_TIME, sub, "<I")
                producer, ms = (raw >> 16) & MAX_NODE_ID, raw & 0xFFFF
                if producer and ms:
                    self.timeouts[producer] = ms / 1000.0
        self._seen = {p: t for p, t in self._seen.items() if p in self.timeouts}
        self._lost &= set(self.timeouts)
        self._quiet_until = -math.inf
        return list(self.timeouts)

    def restart(self) -> None:
        """After a boot a consumer watches from the next heartbeat it receives, not from
        one it heard before (a host that ran earlier)."""
        self._seen, self._lost = {}, set()
        self._quiet_until = -math.inf

    def due(self, now: float) -> bool:
        """Time for the next heartbeat."""
        return self.period_s > 0 and now - self.last_sent >= self.period_s

    def pending(self, now: float) -> bool:
        """Anything to do at ``now``: a heartbeat :meth:`due`, or a producer that may have
        timed out (:meth:`expired` may find one). One call for both, at every tick."""
        return (now >= self._quiet_until
                or (self.period_s > 0 and now - self.last_sent >= self.period_s))

    def next_from(self, now: float) -> float:
        """When the heartbeat sent at ``now`` counts as sent, for the next one's timer: the
        time it was due, if it went out within a period of it (a timer keeps its cadence
        however late each tick finds it: ticks a control cycle apart would otherwise
        stretch every period by up to a cycle), else ``now``."""
        # The same test as due()'s (now - last_sent >= period): a sum compared instead
        # could disagree with it by a rounding and restart the period after all.
        late = now - self.last_sent
        return self.last_sent + self.period_s if late < 2 * self.period_s else now

    def heard(self, producer: int, now: float) -> bool:
        """A consumed producer's heartbeat arrived; True if it had been lost."""
        self._seen[producer] = now
        timeout = self._timeouts.get(producer)
        if timeout is not None:  # watched from now on, if it was not: its deadline counts
            self._quiet_until = min(self._quiet_until, _earliest(now, timeout))
        if producer in self._lost:
            self._lost.discard(producer)
            return True
        return False

    def expired(self, now: float) -> list[int]:
        """The producers whose heartbeat has just timed out (each reported once)."""
        lost: list[int] = []
        if now < self._quiet_until:
            return lost
        quiet = math.inf
        for producer, timeout in self._timeouts.items():
            seen = self._seen.get(producer)
            if seen is None or producer in self._lost:
                continue  # consumer starts at the first heartbeat received
            if now - seen > timeout:
                self._lost.add(producer)
                lost.append(producer)
            else:
                quiet = min(quiet, _earliest(seen, timeout))
        self._quiet_until = quiet
        return lost


def _earliest(seen: float, timeout: float) -> float:
    """A time before which ``now - seen > timeout`` cannot hold, however it rounds."""
    return seen + timeout - 1e-9 * (abs(seen) + timeout) - 1e-12
