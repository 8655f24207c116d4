"""The server side of an SDO block download (CiA 301 7.2.4.3.9), which canopen's
:class:`~canopen.sdo.SdoServer` lacks: it answers a block download's initiate with the
abort "command specifier not valid" (canopen 2.4). A simulated drive takes program data
(1F50h, :mod:`omnican.sim.program`) this way, as real drives do.

:class:`BlockDownloadServer` sees every SDO request of its node first
(:meth:`BlockDownloadServer.on_request`): it takes a block download's initiate and,
while one runs, every frame (the segments' first byte is a sequence number, which
overlaps the other command specifiers); anything else goes on to canopen's server.
Segments are acknowledged per sub-block (up to ``blksize``, 127); one lost in a
sub-block is acknowledged as missing (the last in sequence) so the client sends the rest
again; the end's CRC (CRC-16/XMODEM, canopen's ``CrcXmodem``) is checked when both
sides offered it. An object with a :class:`DomainSink` hears the download begin, end
whole, or be abandoned (an abort, a timeout, an NMT reset): the data reach it only when
complete; other objects are written through the LocalNode at the end.

Threads: called under the drive's lock by the node side's SDO handler and tick.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable, Mapping
from typing import Protocol

import canopen
from canopen.sdo.base import CrcXmodem
from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.cia301 import (
    SDO_ABORT_BLOCK_SIZE,
    SDO_ABORT_COMMAND,
    SDO_ABORT_CRC,
    SDO_ABORT_GENERAL,
    SDO_ABORT_LENGTH,
    SDO_ABORT_TIMEOUT,
    SDO_ABORT_TOO_LONG,
)

logger = logging.getLogger(__name__)

Key = tuple[int, int]

_CCS_MASK = 0xE0
_REQUEST_BLOCK_DOWNLOAD = 0xC0  # client command specifier 6
_RESPONSE_BLOCK_DOWNLOAD = 0xA0  # server command specifier 5
_ABORT = 0x80
_CRC_SUPPORTED = 0x04
_SIZE_INDICATED = 0x02
_SUB_END = 0x01  # client subcommand: 0 initiate, 1 end
_SUB_BLOCK_ACK = 0x02  # server subcommand of a sub-block's acknowledgement
_LAST_SEGMENT = 0x80
MAX_BLKSIZE = 127
#: seconds without a frame after which a block download in progress is abandoned
DEFAULT_TIMEOUT_S = 5.0
#: after a download broke off on the server's side (its abort, a reset), the client's
#: segments still coming are its rest, not requests, until a gap this long (s)
QUIET_S = 0.1


class DomainSink(Protocol):
    """An object that takes a block download itself (1F50h program data)."""

    def begin(self, size: int | None) -> None:
        """A download of ``size`` bytes (None: not indicated) begins; raise
        :class:`SdoAbortedError` to refuse it."""

    def commit(self, data: bytes) -> None:
        """The download ended whole (CRC checked); raise :class:`SdoAbortedError` to
        refuse it (the client sees the abort)."""

    def abandon(self) -> None:
        """The download did not end (aborted, timed out, the node reset)."""


class BlockDownloadServer:
    """Block downloads to one node (see the module docstring).

    Args:
        local: the node's LocalNode (its objects; written at the end for objects without a
            sink).
        send: puts an SDO answer on the bus.
        now: the drive's clock.
        sinks: objects that take a download themselves, (index, subindex) -> sink.
        blksize: segments per sub-block the server asks for (1-127).
        timeout_s: a download with no frame for this long is abandoned.
    """

    def __init__(self, local: canopen.LocalNode, send: Callable[[bytes], None],
                 now: Callable[[], float], sinks: Mapping[Key, DomainSink] | None = None,
                 blksize: int = MAX_BLKSIZE, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
        if not 1 <= blksize <= MAX_BLKSIZE:
            raise ValueError(f"a block size is 1-{MAX_BLKSIZE}, got {blksize}")
        self.local = local
        self.send = send
        self.now = now
        self.sinks: dict[Key, DomainSink] = dict(sinks or {})
        self.blksize = blksize
        self.timeout_s = timeout_s
        #: frames the server loses as they arrive (a test's noise on the line): True drops
        self.lose: Callable[[bytes], bool] | None = None
        self.active = False  # a download in progress (segments or its end awaited)
        self._key: Key = (0, 0)
        self._size: int | None = None
        self._crc = False
        self._data = bytearray()
        self._ackseq = 0
        self._ending = False  # the last segment came: the end request is next
        self._last_frame = 0.0
        self._draining = False  # the rest of a broken-off download still coming

    # ------------------------------------------------------------ frames

    def on_request(self, data: bytes | bytearray) -> bool:
        """Handle an SDO request if it is a block download's; False: not ours."""
        if self.lose is not None and self.lose(bytes(data)):
            return True
        if not (self.active or self._draining):  # the usual case: one test, no clock
            return self._idle(data)
        now = self.now()
        if self.active and now - self._last_frame > self.timeout_s:
            self._fail(SDO_ABORT_TIMEOUT, answer=False)
        if self._draining:
            quiet = now - self._last_frame > QUIET_S
            self._last_frame = now
            if not quiet:
                return True  # the rest of the broken-off download: no request
            self._draining = False
        if not self.active:
            return self._idle(data)  # a request after the download
        self._last_frame = now
        if not data:
            return True
        command = data[0]
        if command == _ABORT:  # the client gave up
            logger.info("block download to 0x%04X:%02X aborted by the client", *self._key)
            self._finish(whole=False)
            return True
        if self._ending:
            self._end(bytes(data))
        else:
            self._segment(bytes(data))
        return True

    def _idle(self, data: bytes | bytearray) -> bool:
        """No download runs: a block download's initiate starts one."""
        if data and data[0] & (_CCS_MASK | _SUB_END) == _REQUEST_BLOCK_DOWNLOAD:
            self._last_frame = self.now()
            self._initiate(bytes(data))
            return True
        return False

    def _initiate(self, frame: bytes) -> None:
        command, index, subindex = struct.unpack_from("<BHB", frame)
        self._key = (index, subindex)
        size = struct.unpack_from("<L", frame, 4)[0] if command & _SIZE_INDICATED else None
        sink = self.sinks.get(self._key)
        try:
            if sink is not None:
                sink.begin(size)
            else:
                var = self.local._find_object(index, subindex)  # raises the right abort
                if not var.writable:
                    raise SdoAbortedError(0x06010002)
        except SdoAbortedError as exc:
            self._answer_abort(exc.code)
            return
        self.active, self._size, self._data = True, size, bytearray()
        self._crc = bool(command & _CRC_SUPPORTED)
        self._ackseq, self._ending = 0, False
        answer = bytearray(8)
        struct.pack_into("<BHBB", answer, 0,
                         _RESPONSE_BLOCK_DOWNLOAD | (_CRC_SUPPORTED if self._crc else 0),
                         index, subindex, self.blksize)
        self.send(bytes(answer))

    def _segment(self, frame: bytes) -> None:
        seqno, last = frame[0] & 0x7F, bool(frame[0] & _LAST_SEGMENT)
        if seqno == 0:
            self._fail(SDO_ABORT_BLOCK_SIZE, drain=True)
            return
        in_sequence = seqno == self._ackseq + 1
        if in_sequence:
            self._ackseq = seqno
            self._data += frame[1:8].ljust(7, b"\x00")
            if self._size is not None and len(self._data) > self._size + 7:
                self._fail(SDO_ABORT_TOO_LONG, drain=True)
                return
        # A sub-block ends at its last sequence number, or at the download's last segment
        # (a lost one before it: the acknowledgement says which came in sequence).
        if seqno >= self.blksize or last:
            if last and in_sequence:
                self._ending = True
            answer = bytes([_RESPONSE_BLOCK_DOWNLOAD | _SUB_BLOCK_ACK, self._ackseq,
                            self.blksize, 0, 0, 0, 0, 0])
            self._ackseq = 0
            self.send(answer)

    def _end(self, frame: bytes) -> None:
        command = frame[0]
        if command & _CCS_MASK != _REQUEST_BLOCK_DOWNLOAD or not command & _SUB_END:
            self._fail(SDO_ABORT_COMMAND)
            return
        unused = (command >> 2) & 0x7
        data = bytes(self._data[:len(self._data) - unused])
        if self._size is not None and len(data) != self._size:
            self._fail(SDO_ABORT_LENGTH)
            return
        if self._crc:
            crc = CrcXmodem()
            crc.process(data)
            if crc.final() != struct.unpack_from("<H", frame, 1)[0]:
                logger.info("block download to 0x%04X:%02X: CRC error", *self._key)
                self._fail(SDO_ABORT_CRC)
                return
        try:
            sink = self.sinks.get(self._key)
            if sink is not None:
                sink.commit(data)
            else:
                self.local.set_data(*self._key, data, check_writable=True)
        except SdoAbortedError as exc:
            self._fail(exc.code)
            return
        except Exception:  # a bug in a sink: the client hears a general error
            logger.exception("block download to 0x%04X:%02X", *self._key)
            self._fail(SDO_ABORT_GENERAL)
            return
        self._finish(whole=True)
        self.send(bytes([_RESPONSE_BLOCK_DOWNLOAD | _SUB_END, 0, 0, 0, 0, 0, 0, 0]))

    # ------------------------------------------------------------ endings

    def expire(self, now: float) -> None:
        """Abandon a download that has had no frame for ``timeout_s`` (housekeeping)."""
        if self.active and now - self._last_frame > self.timeout_s:
            self._fail(SDO_ABORT_TIMEOUT)

    def reset(self) -> None:
        """The node reset: a download in progress is abandoned, unanswered (the rest of
        it, still coming, is taken for nothing)."""
        if self.active:
            self._finish(whole=False)
            self._draining = True
            self._last_frame = self.now()

    def _fail(self, code: int, answer: bool = True, drain: bool = False) -> None:
        self._finish(whole=False)
        self._draining = drain
        if answer:
            self._answer_abort(code)

    def _finish(self, whole: bool) -> None:
        self.active, self._ending, self._data = False, False, bytearray()
        sink = self.sinks.get(self._key)
        if not whole and sink is not None:
            sink.abandon()

    def _answer_abort(self, code: int) -> None:
        self.send(struct.pack("<BHBL", _ABORT, self._key[0], self._key[1], code))
