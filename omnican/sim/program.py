"""A simulated drive's program download objects (CiA 302-3, :mod:`omnican.protocol.program`).

:class:`SimProgram` is the drive's bootloader as the bus sees it:

- 1F50h program data takes a block download (:mod:`omnican.sim.block_download`; an
  expedited or segmented one is refused: "unsupported access"); a
  download begins only while the program is stopped and the flash cleared, and puts the
  flash "in progress" (1F57h bit 0) until it ends: whole (CRC checked), the image is
  stored and valid, the program stopped; otherwise (an abort, a timeout, an NMT reset or
  power cycle midway) the flash holds no valid program;
- 1F51h program control: 0 stop (refused while a power stage is OPERATION ENABLED), 1
  start (refused without a valid program), 2 reset (stop and start), 3 clear (refused
  while the program runs); read back, the program's state;
- 1F56h program software identification: the CRC-32 of the stored image (0: none);
- 1F57h flash status identification.

A drive leaves the factory running a program of its own (:data:`FACTORY_IMAGE`). The
flash is non-volatile: a stored program survives a power cycle (the drive starts it at
power-up), an incomplete one does not. Whether the program runs changes nothing else of
the simulated drive (its CiA 402 side drives either way). The drive's EDS need not list
these objects (real EDS files understate): they are added to the simulated drive's
dictionary where it lacks them.

Threads: every method runs under the drive's lock (SDO handlers, the drive's methods).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import canopen
from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes
from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.cia301 import (
    SDO_ABORT_DEVICE_STATE,
    SDO_ABORT_TOO_LONG,
    SDO_ABORT_UNSUPPORTED_ACCESS,
    SDO_ABORT_VALUE_RANGE,
)
from omnican.protocol.program import (
    FLASH_NO_VALID_PROGRAM,
    FLASH_OK,
    FLASH_STATUS,
    PROGRAM_CONTROL,
    PROGRAM_DATA,
    PROGRAM_IDENTIFICATION,
    PROGRAM_NUMBER,
    Control,
    flash_status_value,
    image_crc,
)
from omnican.sim.block_download import DomainSink
from omnican.sim.objects import counted_array

logger = logging.getLogger(__name__)

#: The simulated drive's flash for programs (bytes): 1 MiB.
DEFAULT_FLASH_BYTES = 1 << 20
#: The program a simulated drive leaves the factory with (valid, started at power-up).
FACTORY_IMAGE = b"omnican simulated CiA 402 drive, factory program 1.0\n"

Key = tuple[int, int]
_PROGRAM_DATA = (PROGRAM_DATA, PROGRAM_NUMBER)
_CONTROL = (PROGRAM_CONTROL, PROGRAM_NUMBER)
_IDENTIFICATION = (PROGRAM_IDENTIFICATION, PROGRAM_NUMBER)
_FLASH_STATUS = (FLASH_STATUS, PROGRAM_NUMBER)
# State read back from 1F51h.
_STOPPED, _STARTED, _CLEARED = 0, 1, 3


class SimProgram:
    """The program download objects of one simulated drive (see the module docstring).

    Args:
        busy: whether the drive is driving now (a power stage OPERATION ENABLED): the
            program is not stopped then.
        flash_bytes: the largest image the flash takes.
        image: the program stored at the start (default: :data:`FACTORY_IMAGE`, running;
            None: an empty flash).
    """

    def __init__(self, busy: Callable[[], bool], flash_bytes: int = DEFAULT_FLASH_BYTES,
                 image: bytes | None = FACTORY_IMAGE) -> None:
        self.busy = busy
        self.flash_bytes = flash_bytes
        #: the stored image (None: none, or an incomplete one)
        self.image: bytes | None = image
        self.in_progress = False
        self.error = FLASH_OK if image is not None else FLASH_NO_VALID_PROGRAM
        self.running = image is not None
        self._control = _STARTED if self.running else _CLEARED
        #: downloads begun, ended whole, abandoned (for tests)
        self.begun = self.committed = self.abandoned = 0

    # ------------------------------------------------------------- reading

    @property
    def valid(self) -> bool:
        return self.image is not None and not self.in_progress and self.error == FLASH_OK

    def control_state(self) -> int:
        return self._control

    def identification(self) -> int:
        return image_crc(self.image) if self.valid and self.image is not None else 0

    def flash_status(self) -> int:
        return flash_status_value(self.in_progress, 0 if self.in_progress else self.error)

    def readers(self) -> dict[Key, Callable[[], int]]:
        return {_CONTROL: self.control_state, _IDENTIFICATION: self.identification,
                _FLASH_STATUS: self.flash_status}

    # ------------------------------------------------------------- 1F51h

    def control(self, value: int) -> None:
        """A write of 1F51h (raises :class:`SdoAbortedError` to refuse it)."""
        if value == Control.STOP:
            if self.busy():
                raise SdoAbortedError(SDO_ABORT_DEVICE_STATE)
            self.running = False
            if self._control == _STARTED:
                self._control = _STOPPED
        elif value in (Control.START, Control.RESET):
            if not self.valid or (value == Control.RESET and self.busy()):
                raise SdoAbortedError(SDO_ABORT_DEVICE_STATE)
            self.running, self._control = True, _STARTED
        elif value == Control.CLEAR:
            if self.running or self.in_progress:
                raise SdoAbortedError(SDO_ABORT_DEVICE_STATE)
            self.image, self.error, self._control = None, FLASH_NO_VALID_PROGRAM, _CLEARED
        else:
            raise SdoAbortedError(SDO_ABORT_VALUE_RANGE)

    # ------------------------------------------------------ 1F50h (DomainSink)

    def begin(self, size: int | None) -> None:
        if self.running or self.image is not None or self.in_progress:
            raise SdoAbortedError(SDO_ABORT_DEVICE_STATE)  # stop and clear it first
        if size is not None and size > self.flash_bytes:
            raise SdoAbortedError(SDO_ABORT_TOO_LONG)
        self.begun += 1
        self.in_progress, self.error, self._control = True, FLASH_NO_VALID_PROGRAM, _STOPPED

    def commit(self, data: bytes) -> None:
        if len(data) > self.flash_bytes:
            self.abandon()
            raise SdoAbortedError(SDO_ABORT_TOO_LONG)
        self.committed += 1
        self.image, self.in_progress, self.error = bytes(data), False, FLASH_OK
        logger.info("simulated drive: program of %d bytes stored (CRC-32 0x%08X)", len(data),
                    image_crc(self.image))

    def abandon(self) -> None:
        if self.in_progress:
            self.abandoned += 1
        self.image, self.in_progress, self.error = None, False, FLASH_NO_VALID_PROGRAM

    # ------------------------------------------------------------- power

    def power_cycle(self) -> None:
        """The drive lost power (a simulator rebuilding its drives keeps their flash): an
        incomplete download is gone, a valid program starts."""
        if self.in_progress:
            self.abandon()
        self.booted(reset_node=True)

    def booted(self, reset_node: bool) -> None:
        """A power-up or NMT reset node: a valid program starts, none runs otherwise (an
        incomplete download was abandoned already: the flash says so)."""
        if reset_node:
            self.running = self.valid
            self._control = _STARTED if self.running else (
                _STOPPED if self.image is not None else _CLEARED)


def _not_segmented(value: int) -> None:
    """1F50h written by an expedited or segmented download: the simulated drive takes
    program data by block download only."""
    raise SdoAbortedError(SDO_ABORT_UNSUPPORTED_ACCESS)


def add_objects(dictionary: od.ObjectDictionary) -> None:
    """1F50h, 1F51h, 1F56h and 1F57h (program 1), where ``dictionary`` lacks them."""
    for index, name, data_type, access in (
            (PROGRAM_DATA, "Program data", datatypes.DOMAIN, "wo"),
            (PROGRAM_CONTROL, "Program control", datatypes.UNSIGNED8, "rw"),
            (PROGRAM_IDENTIFICATION, "Program software identification",
             datatypes.UNSIGNED32, "ro"),
            (FLASH_STATUS, "Flash status identification", datatypes.UNSIGNED32, "ro")):
        if index in dictionary:
            continue
        array = counted_array(name, index, 1)
        var = od.ODVariable(f"Program number {PROGRAM_NUMBER}", index, PROGRAM_NUMBER)
        var.data_type, var.access_type = data_type, access
        array.add_member(var)
        dictionary.add_object(array)


def attach(local: canopen.LocalNode, readers: dict[Key, Callable[[], int]],
           writers: dict[Key, Callable[[int], None]], sinks: dict[Key, DomainSink],
           program: SimProgram) -> None:
    """Give a simulated drive ``program``: its objects in the dictionary, their readers
    and writer, and 1F50h's block downloads."""
    add_objects(local.object_dictionary)
    readers.update(program.readers())
    writers[_CONTROL] = program.control
    writers[_PROGRAM_DATA] = _not_segmented
    sinks[_PROGRAM_DATA] = program
