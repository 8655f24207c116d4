"""omnican's SDO client against a server answering late, without threads: a simulated
clock carries the answers (as canopen's own tests replace ``send_message``)."""

from __future__ import annotations

import struct

import canopen
import pytest

from omnican import WHEEL_EDS
from omnican.clock import SimClock
from omnican.drive.sdo_client import CheckedSdoClient, SdoTooSlowError


class LateServer:
    """Answers each initiate request ``delay_s`` after it, with 4 bytes of its index."""

    def __init__(self, clock: SimClock, client: CheckedSdoClient, delay_s: float) -> None:
        self.clock, self.client, self.delay_s = clock, client, delay_s
        self.due: list[tuple[float, bytes]] = []
        clock.every(0.001, self.tick)

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        data = bytes(data)
        if data[0] & 0xE0 == 0x80:  # the client's abort
            return
        index, sub = struct.unpack_from("<HB", data, 1)
        if data[0] & 0xE0 == 0x40:  # upload: expedited, 4 bytes
            answer = struct.pack("<BHBI", 0x43, index, sub, index)
        else:
            answer = struct.pack("<BHBI", 0x60, index, sub, 0)
        self.due.append((self.clock.now() + self.delay_s, answer))

    def tick(self, now: float) -> None:
        while self.due and self.due[0][0] <= now + 1e-9:
            self.client.on_response(0x581, bytearray(self.due.pop(0)[1]), now)


def rig(delay_s: float) -> tuple[SimClock, CheckedSdoClient]:
    clock = SimClock()
    od = canopen.import_od(str(WHEEL_EDS), 1)
    client = CheckedSdoClient(0x601, 0x581, od, clock, timeout_s=0.5)
    client.MAX_RETRIES = 4
    client.network = LateServer(clock, client, delay_s)  # type: ignore[assignment]
    return clock, client


def test_answers_within_the_timeout_are_each_their_own_request_s() -> None:
    clock, client = rig(0.45)
    assert client.upload(0x1000, 0) == struct.pack("<I", 0x1000)
    assert client.upload(0x1018, 1) == struct.pack("<I", 0x1018)
    client.download(0x1017, 0, b"\x64\x00")
    assert clock.now() == pytest.approx(3 * 0.45, abs=0.005)


def test_a_late_answer_is_never_taken_for_another_request_s_and_is_named() -> None:
    clock, client = rig(0.55)
    # The first request gets its own (late) answer: the same object, the same value.
    assert client.upload(0x1000, 0) == struct.pack("<I", 0x1000)
    # The second would have got the first's second answer (0x1000's value for 0x1018's):
    # it is told apart, and how late the server answers is said.
    with pytest.raises(SdoTooSlowError) as raised:
        client.upload(0x1018, 1)
    assert raised.value.late_s == pytest.approx(0.55, abs=0.005)
    assert clock.now() <= 3 * 0.5
