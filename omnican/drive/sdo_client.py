"""canopen's SDO client, telling a late answer from none.

canopen resends an unanswered request and takes whatever answer comes next for its
own: a drive answering just after ``sdo_timeout_s`` has its late answer to one attempt
taken for the next attempt's, and the answer to that attempt for the next request's.
Here an initiate request (every expedited transfer omnican makes) takes only an answer
naming its own object; an answer naming the previous request's object, coming after
that request was answered, shows how late the drive answers: :class:`SdoTooSlowError`.

In lock-step an answer not in the queue when its request was sent is waited for on the
simulated clock where it can advance (opening; not inside the control cycle).
"""

from __future__ import annotations

import queue
import struct

from canopen import ObjectDictionary, RemoteNode
from canopen.sdo.client import SdoClient
from canopen.sdo.constants import ABORT_TIMED_OUT
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.clock import Clock

_ABORT = 0x80
_INITIATE_REQUESTS = (0x20, 0x40)  # download / upload initiate (command specifier << 5)
_INITIATE_ANSWERS = (0x60, 0x40, _ABORT)  # download / upload initiate answers, abort


class SdoTooSlowError(SdoCommunicationError):
    """The node answers, but later than the timeout: ``late_s`` after a request."""

    def __init__(self, late_s: float) -> None:
        super().__init__(f"SDO answers come {late_s:.2f} s after the request")
        self.late_s = late_s


def object_of(frame: bytes) -> tuple[int, int]:
    """Index and sub-index an SDO initiate frame names."""
    index, subindex = struct.unpack_from("<HB", frame, 1)
    return index, subindex


class CheckedSdoClient(SdoClient):
    """An :class:`SdoClient` that matches initiate answers to their request's object
    and says when a node answers later than the timeout.

    Args:
        clock: the node's clock (the time of sends and answers; lock-step waiting).
        timeout_s: the wait for an answer in lock-step, on the simulated clock.
    """

    def __init__(self, rx_cobid: int, tx_cobid: int, od: object, clock: Clock,
                 timeout_s: float) -> None:
        super().__init__(rx_cobid, tx_cobid, od)
        self.clock = clock
        self.timeout_s = timeout_s
        self._arrivals: queue.Queue[float] = queue.Queue()  # when each answer came
        # The last answered request: the object it named, when its last attempt went out.
        self._answered: tuple[tuple[int, int], float] | None = None

    def on_response(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._arrivals.put(self.clock.now())
        super().on_response(can_id, data, timestamp)

    def request_response(self, sdo_request: bytes | bytearray) -> bytes:
        request = bytes(sdo_request)
        wanted = object_of(request) if request[0] & 0xE0 in _INITIATE_REQUESTS else None
        self._drain()
        retries_left = self.MAX_RETRIES
        while True:
            sent = self.clock.now()  # before the send: an answer is never early
            self.send_request(request)
            try:
                answer = self._answer(wanted)
            except SdoTooSlowError:
                raise
            except SdoCommunicationError:
                retries_left -= 1
                if not retries_left:
                    self.abort(ABORT_TIMED_OUT)
                    raise
                continue
            if wanted is not None:
                self._answered = (wanted, sent)
            return answer

    def _waits(self) -> bool:
        """Lock-step, where the clock can advance: wait on simulated time."""
        return self.clock.lockstep and self.clock.can_wait

    def _timeout(self) -> float:
        return self.timeout_s if self._waits() else self.RESPONSE_TIMEOUT

    def _answer(self, wanted: tuple[int, int] | None) -> bytes:
        """The next answer to ``wanted`` within one timeout; answers naming another
        object are stale (the previous request's, late)."""
        clock = self.clock
        end = clock.now() + self._timeout()
        while True:
            frame, at = self._next(max(end - clock.now(), 0.0))
            if frame is None:
                raise SdoCommunicationError("No SDO response received")
            if wanted is None or frame[0] & 0xE0 not in _INITIATE_ANSWERS or \
                    object_of(frame) == wanted:
                if frame[0] == _ABORT:
                    raise SdoAbortedError(struct.unpack_from("<L", frame, 4)[0])
                return frame
            self._stale(frame, at)

    def _next(self, wait_s: float) -> tuple[bytes | None, float]:
        """The next answer within ``wait_s`` (of the clock's time) and when it came."""
        clock = self.clock
        if self._waits():
            run_until = getattr(clock, "run_until", None)
            if run_until is not None and wait_s > 0 and self.responses.empty():
                run_until(lambda: not self.responses.empty(), wait_s, 0.001)
            wait_s = 0.0
        try:
            frame = self.responses.get(block=wait_s > 0, timeout=wait_s or None)
        except queue.Empty:
            return None, clock.now()
        try:
            at = self._arrivals.get_nowait()
        except queue.Empty:
            at = clock.now()
        return frame, at

    def _drain(self) -> None:
        """Answers that came between two requests: the previous request's, late."""
        while not self.responses.empty():
            frame, at = self._next(0.0)
            if frame is None:
                break
            self._stale(frame, at)
        while not self._arrivals.empty():
            self._arrivals.get_nowait()

    def _stale(self, frame: bytes, at: float) -> None:
        """An answer to the request answered before: came this long after its last
        attempt. Later than the timeout: the node is slower than omnican waits."""
        answered = self._answered
        if answered is None or len(frame) < 4 or frame[0] & 0xE0 not in _INITIATE_ANSWERS:
            return
        obj, sent = answered
        late = at - sent
        if object_of(frame) == obj and late > self._timeout():
            # What follows (the way out: disabling the drive) waits long enough.
            self.timeout_s = max(self.timeout_s, 1.25 * late)
            self.RESPONSE_TIMEOUT = max(self.RESPONSE_TIMEOUT, 1.25 * late)
            raise SdoTooSlowError(late)


class CheckedRemoteNode(RemoteNode):
    """canopen's RemoteNode with :class:`CheckedSdoClient` as its SDO client."""

    def __init__(self, node_id: int, dictionary: ObjectDictionary, clock: Clock,
                 timeout_s: float) -> None:
        self._sdo_clock, self._sdo_timeout_s = clock, timeout_s  # before add_sdo runs
        super().__init__(node_id, dictionary)

    def add_sdo(self, rx_cobid: int, tx_cobid: int) -> CheckedSdoClient:
        client = CheckedSdoClient(rx_cobid, tx_cobid, self.object_dictionary, self._sdo_clock,
                                  self._sdo_timeout_s)
        self.sdo_channels.append(client)
        if self.has_network():
            self.network.subscribe(client.tx_cobid, client.on_response)
        return client
