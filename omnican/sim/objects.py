"""The objects of a simulated node: what reading and writing them does, by SDO or RPDO.

:class:`NodeObjects` is :class:`canopen.LocalNode`'s read and write callback: a dynamic
object (statusword, counters, health values) is read from the device's reader instead of
the store; a write goes to the device's hook first (which may refuse the value with an
SDO abort: nothing is stored), then to the store, and on a new value to what depends on
it (the motion's parameters, the heartbeat times). Writes to the PDO mapping parameters
are checked as a drive does (:func:`omnican.sim.pdo.check_mapping_write`). RPDOs use the
same writes, decided once per mapped object (:meth:`NodeObjects.compile_write`).

It also gives every object without a default a value, as a drive does at boot.
Called under the drive's lock, by :class:`~omnican.sim.node.SimNode`'s frame handlers.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol

import canopen
from canopen import objectdictionary as od
from canopen.sdo.exceptions import SdoAbortedError

from omnican.protocol.cia301 import (
    COMMUNICATION_PROFILE,
    CONSUMER_HEARTBEAT_TIME,
    IDENTITY,
    MAX_PDOS,
    PRODUCER_HEARTBEAT_TIME,
    RESTORE_DEFAULTS,
    RPDO_MAP,
    SDO_ABORT_READ_ONLY,
    STORE_PARAMETERS,
    TPDO_MAP,
)
from omnican.sim.pdo import check_mapping_write

Key = tuple[int, int]
Reader = Callable[[], int]


class ObjectHooks(Protocol):
    """What the objects need from the device behind the node (a part of
    :class:`~omnican.sim.node.Application`)."""

    def write_hook(self, index: int, subindex: int,
                   var: od.ODVariable) -> Callable[[bytes, bool], None] | None:
        """What the device does before an object is written: a function of the new
        data and whether it changed, which raises :class:`SdoAbortedError` to refuse
        the value; None when the device does nothing then. Asked once per object and
        kept (PDOs write the same objects with every frame)."""

    def written(self, index: int, subindex: int) -> None:
        """An object was written with a new value (stored by now)."""


class NodeObjects:
    """The object dictionary side of one simulated node.

    Args:
        local: the LocalNode holding the object dictionary and its store.
        app: the device behind the node (its write hooks, told of new values).
        readers: dynamic objects, (index, subindex) -> raw value, read instead of the
            stored value (kept, not copied: the node's PDOs read the same mapping).
        defaults: values for objects the EDS gives none (besides the identity).
        heartbeat_changed: called when 1016h or 1017h takes a new value.
        max_mapping_entries, remappable, accept_unmappable: see
            :class:`~omnican.sim.SimulatedDrive`.
    """

    def __init__(self, local: canopen.LocalNode, app: ObjectHooks, readers: dict[Key, Reader],
                 defaults: Mapping[Key, int], heartbeat_changed: Callable[[], None], *,
                 max_mapping_entries: int | None = None, remappable: bool = True,
                 accept_unmappable: bool = False) -> None:
        self.local = local
        self.dictionary: od.ObjectDictionary = local.object_dictionary
        self.app = app
        self.readers = readers
        self._defaults = dict(defaults)
        self._heartbeat_changed = heartbeat_changed
        self.max_mapping_entries = max_mapping_entries
        self.remappable = remappable
        self.accept_unmappable = accept_unmappable
        #: what the device's non-volatile memory holds (1010h saved it): loaded over the
        #: defaults at every boot (the communication objects only at a reset communication)
        self.stored: Mapping[Key, bytes] = {}
        #: what a write to 1010h or 1011h does (:class:`omnican.sim.lss.ParameterStore`)
        self.store_command: Callable[[int, int, bytes], None] | None = None
        local.add_read_callback(self.on_read)
        local.add_write_callback(self.on_write)

    def prefill_defaults(self) -> None:
        """Give every numeric object without a default a value, as a drive would: its
        identity from the EDS's [DeviceInfo], the given defaults, else 0."""
        store = self.local.data_store
        info = self.dictionary.device_information
        known = {
            (IDENTITY, 1): info.vendor_number or 0,
            (IDENTITY, 2): info.product_number or 0,
            (IDENTITY, 3): info.revision_number or 0,
            **self._defaults,
        }
        for obj in self.dictionary.values():
            variables = [obj] if isinstance(obj, od.ODVariable) else list(obj.values())
            for var in variables:
                if var.value is None and var.default is None and var.data_type in od.NUMBER_TYPES:
                    value = known.get((var.index, var.subindex), 0)
                    if var.min is not None and var.min > value:
                        value = var.min
                    store.setdefault(var.index, {})[var.subindex] = var.encode_raw(value)

    def restore_defaults(self, reset_node: bool) -> None:
        """At a boot: ``reset_node``, every object back to its default, else the
        communication objects only."""
        store = self.local.data_store
        if reset_node:
            store.clear()
        else:
            for index in [i for i in store if i in COMMUNICATION_PROFILE]:
                del store[index]
        self.prefill_defaults()
        for (index, subindex), value in self.stored.items():
            if reset_node or index in COMMUNICATION_PROFILE:
                store.setdefault(index, {})[subindex] = value

    def on_read(self, index: int, subindex: int, od: od.ODVariable) -> int | None:
        reader = self.readers.get((index, subindex))
        return None if reader is None else reader()

    def on_write(self, index: int, subindex: int, od: od.ODVariable, data: bytes) -> None:
        if self.store_command is not None and index in (STORE_PARAMETERS, RESTORE_DEFAULTS):
            self.store_command(index, subindex, bytes(data))
            return
        if is_mapping(index):
            if not self.remappable:
                raise SdoAbortedError(SDO_ABORT_READ_ONLY)
            check_mapping_write(self.dictionary, self.local.get_data, index, subindex, data,
                                self.max_mapping_entries, self.accept_unmappable)
            return
        self._object_write(index, subindex, od)(bytes(data))

    def _object_write(self, index: int, subindex: int,
                      var: od.ODVariable) -> Callable[[bytes], None]:
        """Writing one (not a mapping) object: the device's hook (a refusal stores
        nothing), the store (LocalNode stores again after an SDO download: storing now
        lets what follows read the new value), and on a new value what depends on it."""
        hook = self.app.write_hook(index, subindex, var)
        store_of, written = self.local.data_store, self.app.written
        heartbeat = index in (CONSUMER_HEARTBEAT_TIME, PRODUCER_HEARTBEAT_TIME)

        def write(data: bytes) -> None:
            store = store_of.get(index)
            if store is None:  # (setdefault would make an empty dict with every write)
                store = store_of[index] = {}
            changed = store.get(subindex) != data
            if hook is not None:
                hook(data, changed)
            store[subindex] = data
            if changed:  # the same value again (a cyclic controlword): nothing to recompute
                written(index, subindex)
                if heartbeat:
                    self._heartbeat_changed()

        return write

    def compile_write(self, index: int, subindex: int,
                      var: od.ODVariable) -> Callable[[bytes], None] | None:
        """An RPDO's write of one object, decided once (see
        :class:`~omnican.sim.process_data.ProcessData`): what an SDO download of it does,
        while this is LocalNode's only write callback."""
        if self.local._write_callbacks != [self.on_write] or is_mapping(index):
            return None
        return self._object_write(index, subindex, var)


def is_mapping(index: int) -> bool:
    """A PDO mapping parameter (16xxh, 1Axxh): written as the PDO configuration."""
    return RPDO_MAP <= index < RPDO_MAP + MAX_PDOS or TPDO_MAP <= index < TPDO_MAP + MAX_PDOS


def counted_array(name: str, index: int, highest: int) -> od.ODArray:
    """An array object with only its sub-index 0, "Highest sub-index supported" (read
    only, ``highest``): its members are added by the caller."""
    array = od.ODArray(name, index)
    count = od.ODVariable("Highest sub-index supported", index, 0)
    count.data_type, count.access_type, count.default = od.UNSIGNED8, "ro", highest
    array.add_member(count)
    return array
