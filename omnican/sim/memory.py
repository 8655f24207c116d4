"""What a simulated drive keeps when the power goes (its non-volatile memory), and the
objects that store into it and forget it: 1010h (store parameters, "save") and 1011h
(restore default parameters, "load"), CiA 301. The LSS slave (:mod:`omnican.sim.lss`)
stores its node id and bit timing here too; :class:`~omnican.sim.lss.SimLss` keeps one
memory per drive across its power cycles."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from canopen import objectdictionary as od
from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.cia301 import (
    COMMUNICATION_PROFILE,
    IDENTITY,
    LOAD_SIGNATURE,
    RESTORE_DEFAULTS,
    SAVE_SIGNATURE,
    STORE_PARAMETERS,
)
from omnican.sim.objects import counted_array

if TYPE_CHECKING:
    from omnican.sim.drive import SimulatedDrive

UNCONFIGURED = 0xFF  # the node id of a drive that has none
Key = tuple[int, int]

#: 1010h/1011h sub-index -> the objects it stores or restores (CiA 301): 1 all,
#: 2 communication, 3 application (the profile's), 4 manufacturer-specific.
PARAMETER_GROUPS: dict[int, tuple[range, ...]] = {
    1: (range(0x1000, 0xA000),),
    2: (COMMUNICATION_PROFILE,),
    3: (range(0x6000, 0xA000),),
    4: (range(0x2000, 0x6000),),
}
SDO_ABORT_NOT_STORED = 0x08000020  # data cannot be transferred or stored
#: Objects never stored: the store commands themselves, the identity (the device's own).
_NEVER_STORED = (STORE_PARAMETERS, RESTORE_DEFAULTS, IDENTITY)

@dataclass
class NonVolatile:
    """One drive's non-volatile memory: what survives a power cycle."""

    node_id: int = UNCONFIGURED  # what LSS stored (FFh: none)
    bit_timing: int | None = None  # CiA 305 table 0 index LSS stored (None: as shipped)
    params: dict[Key, bytes] = field(default_factory=dict)  # what 1010h saved


class ParameterStore:
    """1010h (store parameters) and 1011h (restore default parameters) of one simulated
    node (CiA 301): a write of "save" to 1010h sub n copies the objects of group n
    (:data:`PARAMETER_GROUPS`) into the non-volatile memory, "load" to 1011h sub n
    forgets them there (the defaults come back at the next reset or power-on); any
    other value is refused (SDO abort 0800 0020h). Both read 1: the device stores on
    command."""

    def __init__(self, drive: SimulatedDrive, memory: NonVolatile) -> None:
        self.drive = drive
        self.memory = memory
        objects = drive.comm.objects
        _add_store_objects(drive.dictionary)
        for index in (STORE_PARAMETERS, RESTORE_DEFAULTS):
            objects.readers[(index, 0)] = lambda: 4
            for sub in PARAMETER_GROUPS:
                objects.readers[(index, sub)] = lambda: 1
        objects.stored = memory.params
        objects.store_command = self.command

    def command(self, index: int, subindex: int, data: bytes) -> None:
        """A write to 1010h or 1011h (the caller holds the drive's lock)."""
        groups = PARAMETER_GROUPS.get(subindex)
        signature = SAVE_SIGNATURE if index == STORE_PARAMETERS else LOAD_SIGNATURE
        if groups is None or len(data) != 4 or struct.unpack("<I", data)[0] != signature:
            raise SdoAbortedError(SDO_ABORT_NOT_STORED)
        params = self.memory.params
        if index == RESTORE_DEFAULTS:
            for key in [k for k in params if any(k[0] in g for g in groups)]:
                del params[key]
            return
        dictionary = self.drive.dictionary
        for obj_index, subs in self.drive.node.data_store.items():
            if obj_index in _NEVER_STORED or not any(obj_index in g for g in groups):
                continue
            for sub, value in subs.items():
                try:
                    var = dictionary.get_variable(obj_index, sub)
                except KeyError:
                    var = None
                if var is not None and var.pdo_mappable:
                    continue  # process data (a controlword, a target), no parameter
                params[(obj_index, sub)] = bytes(value)


def _add_store_objects(dictionary: od.ObjectDictionary) -> None:
    """1010h and 1011h in the dictionary, as CiA 301 defines them, where the EDS has none."""
    for index, name in ((STORE_PARAMETERS, "Store parameters"),
                        (RESTORE_DEFAULTS, "Restore default parameters")):
        if index in dictionary:
            continue
        array = counted_array(name, index, 4)
        for sub, what in ((1, "all"), (2, "communication"), (3, "application"),
                          (4, "manufacturer")):
            var = od.ODVariable(f"{name}: {what}", index, sub)
            var.data_type, var.access_type, var.default = od.UNSIGNED32, "rw", 1
            array.add_member(var)
        dictionary.add_object(array)
