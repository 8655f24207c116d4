"""Program download (CiA 302-3) in the standard's words: the objects, the program
control commands and what the flash status (1F57h) says.

A drive that takes programs over CANopen holds, per program number (sub-index; omnican
uses program 1):

- 1F50h program data (DOMAIN, write only): the image, downloaded in one SDO transfer;
- 1F51h program control (UNSIGNED8): written 0 stop, 1 start, 2 reset, 3 clear; read
  back, the program's state (:data:`CONTROL_NAMES`);
- 1F56h program software identification (UNSIGNED32): what the drive says its program
  is; omnican's simulator (and many drives) give the CRC-32 of the stored image;
- 1F57h flash status identification (UNSIGNED32): bit 0 set while a download is in
  progress (the other bits and 1F56h are then not valid); bits 1-7 an error code, 0 when
  the stored program is valid (:data:`FLASH_ERRORS`).

Pure: no I/O. :func:`flash_status` decodes 1F57h, :func:`verdict` says whether a drive's
answers after a download show the image it was given, stored whole.
"""

from __future__ import annotations

import enum
import zlib
from dataclasses import dataclass

PROGRAM_DATA = 0x1F50
PROGRAM_CONTROL = 0x1F51
PROGRAM_IDENTIFICATION = 0x1F56
FLASH_STATUS = 0x1F57
#: The program number omnican downloads (the sub-index of each object above).
PROGRAM_NUMBER = 1
#: Every object a drive must have for a program download.
PROGRAM_OBJECTS = (PROGRAM_DATA, PROGRAM_CONTROL, PROGRAM_IDENTIFICATION, FLASH_STATUS)


class Control(enum.IntEnum):
    """1F51h, written: what the drive is asked to do with its program."""

    STOP = 0
    START = 1
    RESET = 2
    CLEAR = 3


#: 1F51h, read back: the program's state.
CONTROL_NAMES: dict[int, str] = {0: "stopped", 1: "started", 2: "stopped (reset)",
                                 3: "cleared (no program)"}

#: 1F57h bit 0: a download is in progress (the rest of 1F57h and 1F56h are not valid).
FLASH_IN_PROGRESS = 0x1
FLASH_OK = 0
FLASH_NO_VALID_PROGRAM = 1
FLASH_FORMAT_UNKNOWN = 2
FLASH_FORMAT_OR_CRC_ERROR = 3
FLASH_NOT_CLEARED = 4
FLASH_WRITE_ERROR = 5
FLASH_ADDRESS_ERROR = 6
FLASH_SECURED = 7
FLASH_UNSPECIFIED = 63

#: 1F57h bits 1-7: what the drive says of its flash.
FLASH_ERRORS: dict[int, str] = {
    FLASH_OK: "program valid",
    FLASH_NO_VALID_PROGRAM: "no valid program",
    FLASH_FORMAT_UNKNOWN: "data format unknown",
    FLASH_FORMAT_OR_CRC_ERROR: "data format or CRC error",
    FLASH_NOT_CLEARED: "flash not cleared before writing",
    FLASH_WRITE_ERROR: "flash write error",
    FLASH_ADDRESS_ERROR: "general address error",
    FLASH_SECURED: "flash secured (write access refused)",
    FLASH_UNSPECIFIED: "unspecified error",
}


@dataclass(frozen=True)
class FlashStatus:
    """1F57h decoded: ``in_progress`` (bit 0) and ``error`` (bits 1-7, 0: valid)."""

    raw: int
    in_progress: bool
    error: int

    @property
    def valid(self) -> bool:
        """The drive holds a valid program (no download under way, no error)."""
        return not self.in_progress and self.error == FLASH_OK

    @property
    def holds_program(self) -> bool:
        """The flash holds something that is not nothing: a program to clear before
        another goes in (anything but "no valid program"; while in progress: an unknown
        state, so yes)."""
        return self.in_progress or self.error != FLASH_NO_VALID_PROGRAM

    def describe(self) -> str:
        """``program valid``, ``download in progress (incomplete)``, ``no valid program``..."""
        if self.in_progress:
            return "download in progress (incomplete, not valid)"
        return FLASH_ERRORS.get(self.error, f"error code {self.error}")


def flash_status(raw: int) -> FlashStatus:
    """Decode a 1F57h value (UNSIGNED32)."""
    raw &= 0xFFFFFFFF
    return FlashStatus(raw, bool(raw & FLASH_IN_PROGRESS), (raw >> 1) & 0x7F)


def flash_status_value(in_progress: bool, error: int) -> int:
    """The 1F57h value of a state (the simulator's side of :func:`flash_status`)."""
    if not 0 <= error <= 0x7F:
        raise ValueError(f"a flash error code is 0-127, got {error}")
    return (error << 1) | (FLASH_IN_PROGRESS if in_progress else 0)


def control_name(value: int) -> str:
    """1F51h read back, in words."""
    return CONTROL_NAMES.get(value, f"state {value}")


def image_crc(image: bytes) -> int:
    """The CRC-32 (ISO-HDLC, as zlib) of an image: what 1F56h holds after a download to
    a drive that identifies its program by its CRC."""
    return zlib.crc32(image) & 0xFFFFFFFF


class Verdict(enum.Enum):
    """What a drive's answers after a download show."""

    VERIFIED = "verified"  # valid, and its identification is the image's CRC-32
    MISMATCH = "mismatch"  # valid, but the identification is another program's
    INCOMPLETE = "incomplete"  # in progress: the download did not end
    INVALID = "invalid"  # no valid program, or a flash error


def verdict(status: FlashStatus, identification: int | None, image: bytes) -> Verdict:
    """Whether a drive that answered ``status`` (1F57h) and ``identification`` (1F56h;
    None: not read) after a download holds ``image``. Only a valid flash whose
    identification is the image's CRC-32 is :attr:`Verdict.VERIFIED`: nothing else is
    started."""
    if status.in_progress:
        return Verdict.INCOMPLETE
    if not status.valid:
        return Verdict.INVALID
    if identification is None or identification & 0xFFFFFFFF != image_crc(image):
        return Verdict.MISMATCH
    return Verdict.VERIFIED
