"""A drive's settings kept across a power cycle: the ``[[wheel.sdo]]`` settings written
and stored (1010h sub 1, "save"), then read back after a reset and compared; or
forgotten (1011h sub 1, "load": the defaults from the next reset on). CiA 301. Nothing
here prints; ``omnican commission --store`` and ``--restore-defaults`` do."""

from __future__ import annotations

import struct
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.analysis.commission import Progress
from omnican.analysis.master import MasterWatch, sdo_client, wait_boot
from omnican.config import ChassisConfig
from omnican.io.bus import CanBus
from omnican.plan.node import NodeLayout
from omnican.protocol.cia301 import (
    LOAD_SIGNATURE,
    NMT_COB_ID,
    RESTORE_DEFAULTS,
    SAVE_SIGNATURE,
    STORE_PARAMETERS,
    NmtCommand,
)


def differences(written: Mapping[tuple[int, int], bytes],
                read: Mapping[tuple[int, int], bytes | None]) -> list[tuple[int, int]]:
    """The objects whose value read back is not the value written (None: not read)."""
    return [key for key, data in written.items()
            if read.get(key) is None or bytes(read[key] or b"")[:len(data)] != data]



@dataclass(frozen=True)
class StoredCheck:
    """One node's ``[[wheel.sdo]]`` settings: stored (1010h), then read back after a
    reset; ``differ``: what came back otherwise (address, written, read)."""

    node_id: int
    written: int
    differ: tuple[tuple[str, str, str], ...] = field(default=())
    problem: str | None = None


def store_settings(cfg: ChassisConfig, layouts: Iterable[NodeLayout], *,
                   sdo_timeout_s: float = 0.3, progress: Progress | None = None
                   ) -> list[StoredCheck]:
    """Write each node's ``[[wheel.sdo]]`` settings, store them (1010h sub 1, "save"),
    reset the node and read them back."""
    say = progress or (lambda text: None)
    out = []
    with CanBus(cfg.bus) as can_bus:
        network = can_bus.network
        watch = MasterWatch(network)
        try:
            for layout in layouts:
                writes = layout.sdo_writes
                node_id = layout.node_id
                if not writes:
                    continue
                say(f"node {node_id}: writing and storing {len(writes)} setting(s)")
                client = sdo_client(network, node_id, sdo_timeout_s)
                try:
                    written = {}
                    for w in writes:
                        client.download(w.entry.index, w.entry.subindex, w.data)
                        written[(w.entry.index, w.entry.subindex)] = w.data
                    client.download(STORE_PARAMETERS, 1, struct.pack("<I", SAVE_SIGNATURE))
                    watch.watch_boot(node_id)
                    sent = time.monotonic()
                    network.send_message(NMT_COB_ID, bytes([NmtCommand.RESET_NODE, node_id]))
                    wait_boot(watch, node_id, sent)
                    read: dict[tuple[int, int], bytes | None] = {}
                    for key in written:
                        try:
                            read[key] = bytes(client.upload(*key))
                        except (SdoAbortedError, SdoCommunicationError):
                            read[key] = None
                    differ = tuple(
                        (f"{k[0]:04X}h:{k[1]:02X}", written[k].hex(),
                         "no answer" if read[k] is None else (read[k] or b"").hex())
                        for k in differences(written, read))
                    out.append(StoredCheck(node_id, len(written), differ))
                except (SdoAbortedError, SdoCommunicationError) as exc:
                    out.append(StoredCheck(node_id, 0, problem=f"node {node_id}: {exc}"))
                finally:
                    network.unsubscribe(client.tx_cobid, client.on_response)
        finally:
            watch.close()
    return out


def restore_defaults(cfg: ChassisConfig, node_ids: Iterable[int], *, sdo_timeout_s: float = 0.3
                     ) -> dict[int, str | None]:
    """1011h sub 1 ("load") on each node, then an NMT reset node: the drives' parameters
    at their defaults. Node id -> None (done) or why not."""
    out: dict[int, str | None] = {}
    with CanBus(cfg.bus) as can_bus:
        network = can_bus.network
        watch = MasterWatch(network)
        try:
            for node_id in node_ids:
                client = sdo_client(network, node_id, sdo_timeout_s)
                try:
                    client.download(RESTORE_DEFAULTS, 1, struct.pack("<I", LOAD_SIGNATURE))
                    watch.watch_boot(node_id)
                    sent = time.monotonic()
                    network.send_message(NMT_COB_ID, bytes([NmtCommand.RESET_NODE, node_id]))
                    out[node_id] = None if wait_boot(watch, node_id, sent) else \
                        "restored, but no boot-up after the reset"
                except (SdoAbortedError, SdoCommunicationError) as exc:
                    out[node_id] = str(exc)
                finally:
                    network.unsubscribe(client.tx_cobid, client.on_response)
        finally:
            watch.close()
    return out
