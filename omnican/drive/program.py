"""Program download to a drive (CiA 302-3): stop its program, clear it, download an
image in SDO block mode, check what the drive says it stored, start it.

:func:`support` asks the drive itself whether it has the objects (an EDS may leave them
out); :func:`driving` says whether the base is driving (a drive OPERATION ENABLED, or
another master's SYNC and RPDOs on the bus) before anything is written;
:func:`download` does the rest and returns a :class:`ProgramResult`, whatever happened,
with the state the drive reports at the end (1F51h, 1F56h, 1F57h as read back, or
"no answer"). A download that did not end (an abort, a lost frame, a reset or power cut
midway) leaves a drive whose flash status says so; only a valid flash whose
identification (1F56h) is the image's CRC-32 is started: a wrong program is never
believed good.

The block transfer is canopen's (``SdoClient.open(..., "wb", block_transfer=True)``,
its CRC-16 when the drive offers one); the numbers are :mod:`omnican.protocol.program`'s.
Runs on the caller's thread; every SDO exchange is bounded by ``sdo_timeout_s``.
"""

from __future__ import annotations

import enum
import io
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import can
import canopen
from canopen import objectdictionary as od
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.protocol.cia301 import (
    SDO_ABORT_GENERAL,
    SDO_ABORT_NOT_IN_OD,
    SDO_ABORT_SUBINDEX,
    SYNC_COB_ID,
    abort_text,
)
from omnican.protocol.cia402 import State, decode_state
from omnican.protocol.program import (
    FLASH_STATUS,
    PROGRAM_CONTROL,
    PROGRAM_DATA,
    PROGRAM_IDENTIFICATION,
    PROGRAM_NUMBER,
    Control,
    FlashStatus,
    Verdict,
    control_name,
    flash_status,
    image_crc,
    verdict,
)

logger = logging.getLogger("omnican.drive")

#: progress(bytes sent, bytes in all)
Progress = Callable[[int, int], None]
#: Bytes handed to canopen's block stream at a time (a sub-block of 127 segments).
CHUNK_BYTES = 7 * 127
#: An SDO answer during a download may take this long (a drive erasing its flash).
DEFAULT_SDO_TIMEOUT_S = 5.0
#: How long :func:`driving` listens for another master's SYNC and RPDOs.
DEFAULT_LISTEN_S = 0.3
_RPDO_COB_BASES = (0x200, 0x300, 0x400, 0x500)


class Outcome(enum.Enum):
    """How a download to one drive ended."""

    STARTED = "started"  # verified and started
    NOT_SUPPORTED = "not supported"  # the drive lacks the 302-3 objects: nothing written
    REFUSED = "refused"  # the drive refused a step (stop, clear, the download's start)
    FAILED = "failed"  # the download did not end whole
    MISMATCH = "mismatch"  # stored, but not the image: not started
    LOST = "lost"  # the drive stopped answering


@dataclass(frozen=True)
class ProgramState:
    """What a drive says of its program (None: it did not answer that read)."""

    control: int | None = None  # 1F51h read back
    identification: int | None = None  # 1F56h
    flash: FlashStatus | None = None  # 1F57h

    @property
    def answered(self) -> bool:
        return (self.control, self.identification, self.flash) != (None, None, None)

    def describe(self) -> str:
        """``program started; flash: program valid; identification 0x1234ABCD``."""
        if not self.answered:
            return "no answer (its state is unknown: it may hold an incomplete program)"
        parts = [f"program {'?' if self.control is None else control_name(self.control)}",
                 f"flash: {'?' if self.flash is None else self.flash.describe()}"]
        if self.identification is not None and self.flash is not None and self.flash.valid:
            parts.append(f"identification 0x{self.identification:08X}")
        return "; ".join(parts)


@dataclass(frozen=True)
class ProgramResult:
    """One drive's download: how it ended, why, and the drive's state at the end."""

    node_id: int
    outcome: Outcome
    detail: str
    state: ProgramState
    image_crc: int
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.outcome is Outcome.STARTED

    def line(self) -> str:
        """One line for a user: what happened and what the drive says now."""
        if self.outcome is Outcome.NOT_SUPPORTED:
            return f"node {self.node_id}: {self.detail}"
        return f"node {self.node_id}: {self.detail}; the drive says: {self.state.describe()}"


def _client(network: canopen.Network, node_id: int, sdo_timeout_s: float) -> SdoClient:
    """An SDO client of ``node_id`` on ``network`` (until ``del network[node_id]``)."""
    node = canopen.RemoteNode(node_id, od.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
    node.sdo.MAX_RETRIES = 1  # canopen counts attempts
    network.add_node(node)
    sdo: SdoClient = node.sdo
    return sdo


def _read_u32(sdo: SdoClient, index: int, attempts: int = 1) -> int | None:
    for attempt in range(attempts):
        if attempt:
            settle(sdo)
        try:
            return int.from_bytes(sdo.upload(index, PROGRAM_NUMBER)[:4], "little")
        except (SdoAbortedError, SdoCommunicationError):
            continue
    return None


def settle(sdo: SdoClient, quiet_s: float = 0.2, limit_s: float = 3.0) -> None:
    """Wait until no SDO answer has come for ``quiet_s`` (at most ``limit_s``): after a
    transfer broke off, the drive may still answer the rest of it (aborts), which a read
    would take for its own."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        try:
            sdo.responses.get(timeout=quiet_s)
        except queue.Empty:
            return


def read_state(sdo: SdoClient, attempts: int = 1) -> ProgramState:
    """1F51h, 1F56h and 1F57h as the drive answers them (None where it does not, after
    ``attempts`` tries, the bus settled between them)."""
    control = _read_u32(sdo, PROGRAM_CONTROL, attempts)
    ident = _read_u32(sdo, PROGRAM_IDENTIFICATION, attempts)
    flash = _read_u32(sdo, FLASH_STATUS, attempts)
    return ProgramState(None if control is None else control & 0xFF, ident,
                        None if flash is None else flash_status(flash))


def support(sdo: SdoClient) -> str | None:
    """Why the drive cannot take a program over the bus (None: it can): each object is
    asked for (1F50h is write only: any answer but "object does not exist" shows it).
    Raises :class:`SdoCommunicationError` when the drive does not answer."""
    for index in (PROGRAM_DATA, PROGRAM_CONTROL, PROGRAM_IDENTIFICATION, FLASH_STATUS):
        try:
            sdo.upload(index, 0 if index == PROGRAM_DATA else PROGRAM_NUMBER)
        except SdoAbortedError as exc:
            if exc.code in (SDO_ABORT_NOT_IN_OD, SDO_ABORT_SUBINDEX):
                return (f"it has no {index:04X}h program {PROGRAM_NUMBER} (CiA 302-3 program "
                        "download): its firmware is loaded some other way")
    return None


def driving(network: canopen.Network, statuswords: Mapping[int, Sequence[tuple[int, int]]],
            listen_s: float = DEFAULT_LISTEN_S, sdo_timeout_s: float = 0.5) -> str | None:
    """Why the base counts as driving now (None: it does not): a drive's power stage in
    OPERATION ENABLED (``statuswords``: node id -> its statusword objects), or SYNC and
    RPDOs to these nodes on the bus within ``listen_s`` (another master's cycle)."""
    heard: dict[str, int] = {"sync": 0, "rpdo": 0}
    lock = threading.Lock()

    def on_sync(can_id: int, data: bytearray, timestamp: float) -> None:
        with lock:
            heard["sync"] += 1

    def on_rpdo(can_id: int, data: bytearray, timestamp: float) -> None:
        with lock:
            heard["rpdo"] += 1

    cobs = [base + n for n in statuswords for base in _RPDO_COB_BASES]
    network.subscribe(SYNC_COB_ID, on_sync)
    for cob in cobs:
        network.subscribe(cob, on_rpdo)
    try:
        time.sleep(listen_s)
    finally:
        network.unsubscribe(SYNC_COB_ID, on_sync)
        for cob in cobs:
            network.unsubscribe(cob, on_rpdo)
    if heard["sync"] >= 2 and heard["rpdo"]:
        return (f"another master drives the base: {heard['sync']} SYNC and {heard['rpdo']} "
                f"RPDO frames to the drives in {listen_s:.1f} s; stop it first")
    for node_id, objects in statuswords.items():
        sdo = _client(network, node_id, sdo_timeout_s)
        try:
            for index, subindex in objects:
                try:
                    word = int.from_bytes(sdo.upload(index, subindex)[:2], "little")
                except (SdoAbortedError, SdoCommunicationError):
                    continue
                if decode_state(word) is State.OPERATION_ENABLED:
                    return (f"node {node_id} is OPERATION ENABLED (statusword 0x{word:04X}): "
                            "the base is driving; stop it first")
        finally:
            del network[node_id]
    return None


def download(network: canopen.Network, node_id: int, image: bytes,
             progress: Progress | None = None,
             sdo_timeout_s: float = DEFAULT_SDO_TIMEOUT_S) -> ProgramResult:
    """Download ``image`` to node ``node_id`` as its program 1 and start it (see the
    module docstring). Check :func:`driving` first: this does not."""
    if not image:
        raise ValueError("an empty image")
    crc = image_crc(image)
    sdo = _client(network, node_id, sdo_timeout_s)
    started = time.monotonic()

    def result(outcome: Outcome, detail: str, state: ProgramState | None = None
               ) -> ProgramResult:
        if state is None:
            settle(sdo)
            state = read_state(sdo, attempts=3)
        if outcome not in (Outcome.STARTED, Outcome.LOST) and not state.answered:
            outcome, detail = Outcome.LOST, f"{detail} (no answer since)"
        return ProgramResult(node_id, outcome, detail, state, crc,
                             time.monotonic() - started)

    try:
        settle(sdo)  # answers still coming to an earlier client (a broken-off transfer)
        try:
            why = support(sdo)
        except SdoCommunicationError:
            return result(Outcome.LOST, "does not answer", ProgramState())
        if why is not None:
            return ProgramResult(node_id, Outcome.NOT_SUPPORTED, f"no program download: {why}",
                                 ProgramState(), crc)
        before = read_state(sdo, attempts=2)
        if not before.answered:
            return result(Outcome.LOST, "does not answer", before)
        step = _step(sdo, Control.STOP, "stopping its program")
        if step is not None:
            return result(Outcome.REFUSED, step)
        if before.flash is None or before.flash.holds_program:
            step = _step(sdo, Control.CLEAR, "clearing its program")
            if step is not None:
                return result(Outcome.REFUSED, step)
        failure = _block_download(sdo, image, progress)
        if failure is not None:
            return result(Outcome.FAILED, f"download failed: {failure}")
        after = read_state(sdo, attempts=3)
        if after.flash is None:
            return result(Outcome.LOST, "no flash status after the download", after)
        judged = verdict(after.flash, after.identification, image)
        if judged is Verdict.INCOMPLETE or judged is Verdict.INVALID:
            return result(Outcome.FAILED, "the download ended but the drive holds no valid "
                                          "program: not started", after)
        if judged is Verdict.MISMATCH:
            got = "none" if after.identification is None else f"0x{after.identification:08X}"
            return result(Outcome.MISMATCH, f"CRC mismatch: the drive identifies its program "
                                            f"as {got}, the image's CRC-32 is 0x{crc:08X}: "
                                            "not started", after)
        step = _step(sdo, Control.START, "starting the program")
        if step is not None:
            return result(Outcome.REFUSED, f"verified, but {step}")
        final = read_state(sdo, attempts=3)
        if final.control != Control.START or final.flash is None or \
                verdict(final.flash, final.identification, image) is not Verdict.VERIFIED:
            return result(Outcome.FAILED, "started, but the drive's answers since do not show "
                                          "the image running", final)
        return result(Outcome.STARTED, f"program of {len(image)} bytes downloaded in "
                                       f"{time.monotonic() - started:.1f} s, verified (CRC-32 "
                                       f"0x{crc:08X}) and started", final)
    finally:
        del network[node_id]


def _step(sdo: SdoClient, command: Control, what: str) -> str | None:
    """Write 1F51h; why it failed (None: done)."""
    try:
        sdo.download(PROGRAM_CONTROL, PROGRAM_NUMBER, bytes([int(command)]))
    except SdoAbortedError as exc:
        return f"it refused {what} (1F51h = {int(command)}: SDO abort {abort_text(exc.code)})"
    except SdoCommunicationError:
        return f"no answer to {what} (1F51h = {int(command)})"
    return None


def _block_download(sdo: SdoClient, image: bytes, progress: Progress | None) -> str | None:
    """canopen's block download of ``image`` to 1F50h; why it failed (None: done)."""
    total = len(image)
    try:
        stream = sdo.open(PROGRAM_DATA, PROGRAM_NUMBER, "wb", buffering=0, size=total,
                          block_transfer=True)
    except SdoAbortedError as exc:
        return f"the drive refused it (SDO abort {abort_text(exc.code)})"
    except SdoCommunicationError as exc:
        return f"no answer to its start ({exc})"
    sent = 0
    try:
        try:
            for chunk in _chunks(image):
                view = memoryview(chunk)
                while view:
                    n = stream.write(view[:7])  # canopen's raw stream: 7 bytes a segment
                    if not n:
                        raise RuntimeError("the block stream took no data")
                    view = view[n:]
                sent += len(chunk)
                if progress is not None:
                    progress(sent, total)
        except BaseException:
            io.RawIOBase.close(stream)  # closed without the end exchange: it failed
            raise
        stream.close()  # the end of the transfer: the drive checks the size and the CRC
    except SdoAbortedError as exc:
        return f"the drive aborted it after {sent} of {total} bytes " \
               f"(SDO abort {abort_text(exc.code)})"
    except SdoCommunicationError as exc:
        return f"no answer after {sent} of {total} bytes ({exc})"
    except RuntimeError as exc:  # canopen's stream after a retransmission it cannot make
        try:
            sdo.abort(SDO_ABORT_GENERAL)  # the drive hears the transfer is over
        except can.CanError:
            pass
        return f"the transfer broke after {sent} of {total} bytes ({exc})"
    return None


def _chunks(image: bytes) -> Iterable[bytes]:
    for start in range(0, len(image), CHUNK_BYTES):
        yield image[start:start + CHUNK_BYTES]
