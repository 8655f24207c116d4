"""Heartbeats of a simulated node (CiA 301 error control): the one it produces (1017h)
and the ones it consumes (1016h), the master's above all.

Bookkeeping only: the node sends the frames, and reacts when a producer falls silent
(EMCY 8130h, then the device's abort connection reaction). A consumer starts watching
at the first heartbeat it receives, and again after each boot.
"""

from __future__ import annotations

from canopen import objectdictionary as od

from omnican.protocol.cia301 import CONSUMER_HEARTBEAT_TIME, MAX_NODE_ID, PRODUCER_HEARTBEAT_TIME
from omnican.sim.pdo import Getter, read_uint


class Heartbeat:
    """The heartbeat producer and consumer of one node."""

    def __init__(self) -> None:
        self.enabled = True  # the producer runs (a drive whose heartbeat stopped: False)
        self.period_s = 0.0  # 1017h; 0: no heartbeat
        self.last_sent = -1e9
        self.timeouts: dict[int, float] = {}  # 1016h: producer node id -> timeout s
        self._seen: dict[int, float] = {}  # producer -> when last heard
        self._lost: set[int] = set()

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
        return list(self.timeouts)

    def restart(self) -> None:
        """After a boot a consumer watches from the next heartbeat it receives, not from
        one it heard before (a host that ran earlier)."""
        self._seen, self._lost = {}, set()

    def due(self, now: float) -> bool:
        """Time for the next heartbeat."""
        return self.period_s > 0 and now - self.last_sent >= self.period_s

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
        if producer in self._lost:
            self._lost.discard(producer)
            return True
        return False

    def expired(self, now: float) -> list[int]:
        """The producers whose heartbeat has just timed out (each reported once)."""
        lost: list[int] = []
        for producer, timeout in self.timeouts.items():
            seen = self._seen.get(producer)
            if seen is None or producer in self._lost:
                continue  # consumer starts at the first heartbeat received
            if now - seen > timeout:
                self._lost.add(producer)
                lost.append(producer)
        return lost
