"""Expedited SDO frames for objects a drive will not carry in a PDO.

When a drive refuses to map its target velocity (or its position) and its own
mapping lacks it, omnican writes (or reads) that object by expedited SDO every
control cycle instead. The requests go out as ordinary frames of the cycle, and
the answers are matched on the receive thread; nothing waits for them.

I/O-free: builds request frames and parses answer frames.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

SDO_REQUEST_BASE = 0x600  # client -> server, + node id
SDO_ANSWER_BASE = 0x580  # server -> client, + node id

# Command specifiers (first byte, top three bits).
_CCS_DOWNLOAD_INITIATE = 1 << 5
_CCS_UPLOAD_INITIATE = 2 << 5
_SCS_UPLOAD_INITIATE = 2 << 5
_SCS_DOWNLOAD_INITIATE = 3 << 5
_CS_ABORT = 4 << 5
_EXPEDITED = 0x02
_SIZE_GIVEN = 0x01


class AnswerKind(enum.Enum):
    DOWNLOADED = "downloaded"  # a write was confirmed
    UPLOADED = "uploaded"  # a read returned data
    ABORTED = "aborted"
    OTHER = "other"  # segmented or block transfer frames: not ours


@dataclass(frozen=True)
class Answer:
    """One SDO server answer."""

    kind: AnswerKind
    index: int
    subindex: int
    data: bytes = b""  # uploaded bytes (expedited: 1-4)
    abort_code: int = 0


def download_request(index: int, subindex: int, data: bytes) -> bytes:
    """Expedited download (write) request of 1-4 data bytes."""
    if not 1 <= len(data) <= 4:
        raise ValueError(f"an expedited SDO carries 1-4 bytes, got {len(data)}")
    cmd = _CCS_DOWNLOAD_INITIATE | ((4 - len(data)) << 2) | _EXPEDITED | _SIZE_GIVEN
    return (bytes([cmd]) + index.to_bytes(2, "little") + bytes([subindex]) +
            data.ljust(4, b"\x00"))


def upload_request(index: int, subindex: int) -> bytes:
    """Upload (read) initiate request; a server answers expedited for up to 4 bytes."""
    return bytes([_CCS_UPLOAD_INITIATE]) + index.to_bytes(2, "little") + bytes([subindex]) + \
        bytes(4)


def parse_answer(data: bytes | bytearray) -> Answer | None:
    """The answer in one 0x580+node frame, or None for a frame too short to be one."""
    if len(data) < 4:
        return None
    cmd = data[0]
    index = int.from_bytes(bytes(data[1:3]), "little")
    subindex = data[3]
    scs = cmd & 0xE0
    if scs == _CS_ABORT:
        code = int.from_bytes(bytes(data[4:8]).ljust(4, b"\x00"), "little")
        return Answer(AnswerKind.ABORTED, index, subindex, abort_code=code)
    if scs == _SCS_DOWNLOAD_INITIATE:
        return Answer(AnswerKind.DOWNLOADED, index, subindex)
    if scs == _SCS_UPLOAD_INITIATE and cmd & _EXPEDITED:
        size = 4 - ((cmd >> 2) & 0x3) if cmd & _SIZE_GIVEN else 4
        return Answer(AnswerKind.UPLOADED, index, subindex, data=bytes(data[4 : 4 + size]))
    return Answer(AnswerKind.OTHER, index, subindex)

