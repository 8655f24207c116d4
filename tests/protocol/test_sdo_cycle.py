"""Expedited SDO frames, checked against an SDO server omnican did not write:
canopen's own (LocalNode), fed frame by frame without a bus."""

from __future__ import annotations

import functools

import canopen
import pytest
from hypothesis import given
from hypothesis import strategies as st

from omnican import WHEEL_EDS
from omnican.protocol.sdo_cycle import (
    SDO_ANSWER_BASE,
    SDO_REQUEST_BASE,
    AnswerKind,
    download_request,
    parse_answer,
    upload_request,
)

NODE = 3
# (index, subindex, bytes) of objects of the bundled EDS: I32, I16, U16, I8.
OBJECTS = [(0x60FF, 0, 4), (0x6042, 0, 2), (0x6040, 0, 2), (0x6060, 0, 1)]


class _Wire:
    """Stands in for the network: keeps what the server sends."""

    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes]] = []

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.sent.append((can_id, bytes(data)))


@functools.cache
def _od() -> canopen.ObjectDictionary:
    return canopen.import_od(str(WHEEL_EDS), NODE)


def server() -> tuple[canopen.LocalNode, _Wire]:
    node = canopen.LocalNode(NODE, _od())
    wire = _Wire()
    node.sdo.network = wire  # the SDO server only calls send_message
    return node, wire


def exchange(node: canopen.LocalNode, wire: _Wire, request: bytes) -> bytes:
    assert len(request) == 8  # SDO frames always carry 8 bytes
    node.sdo.on_request(SDO_REQUEST_BASE + NODE, bytearray(request), 0.0)
    cob, answer = wire.sent.pop()
    assert cob == SDO_ANSWER_BASE + NODE
    return answer


@given(obj=st.sampled_from(OBJECTS), raw=st.integers(0, 2**32 - 1))
def test_write_then_read_back_through_canopens_server(obj: tuple[int, int, int],
                                                      raw: int) -> None:
    index, sub, size = obj
    value = raw % (1 << (8 * size))
    data = value.to_bytes(size, "little")
    node, wire = server()
    answer = parse_answer(exchange(node, wire, download_request(index, sub, data)))
    assert answer is not None
    assert (answer.kind, answer.index, answer.subindex) == (AnswerKind.DOWNLOADED, index, sub)
    assert node.get_data(index, sub) == data  # the server stored exactly our bytes
    answer = parse_answer(exchange(node, wire, upload_request(index, sub)))
    assert answer is not None
    assert (answer.kind, answer.index, answer.subindex, answer.data) == (
        AnswerKind.UPLOADED, index, sub, data)


def test_aborts_carry_their_code() -> None:
    node, wire = server()
    answer = parse_answer(exchange(node, wire, upload_request(0x2345, 0)))
    assert answer is not None
    assert (answer.kind, answer.index, answer.abort_code) == (AnswerKind.ABORTED, 0x2345,
                                                              0x06020000)


def test_non_expedited_and_short_frames() -> None:
    segment = bytes([0x00]) + bytes(7)  # an upload segment answer: not ours
    answer = parse_answer(segment)
    assert answer is not None and answer.kind is AnswerKind.OTHER
    assert parse_answer(b"\x60\xff") is None
    with pytest.raises(ValueError):
        download_request(0x60FF, 0, b"12345")
