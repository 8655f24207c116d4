"""Find the CANopen nodes on a bus and check them against a config.

:func:`scan` listens for heartbeats, asks every node id for its device type (SDO
1000h), then reads each answering node's identity (1018h), supported modes (6502h)
and name (1008h). :func:`check` compares what was found with the config's nodes and
their EDS files. Nothing here prints; the ``omnican scan`` command does.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import canopen
from canopen import objectdictionary as od
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from omnican.config import ChassisConfig
from omnican.io.bus import CanBus
from omnican.plan.node import NodeLayout
from omnican.protocol.cia301 import (
    DEVICE_NAME,
    DEVICE_TYPE,
    HEARTBEAT_BASE,
    IDENTITY,
    MAX_NODE_ID,
    PRODUCER_HEARTBEAT_TIME,
    SDO_TX_BASE,
    nmt_state_name,
)
from omnican.protocol.cia402 import supported_modes
from omnican.protocol.object_map import Obj

logger = logging.getLogger(__name__)

CIA_402 = 402  # device profile number in the low 16 bits of 1000h
MAX_HEARTBEAT_WAIT_S = 5.0  # listen at most this long for a slow heartbeat
NODE_GUARDING_WAIT_S = 0.1  # answers to node guarding come within this


@dataclass(frozen=True)
class FoundNode:
    """One node that answered. ``None``: the node did not answer that read.
    ``identity``: vendor, product, revision, serial (1018h sub 1-4)."""

    node_id: int
    nmt: str | None = None  # NMT state from its heartbeat
    device_type: int | None = None
    identity: tuple[int | None, ...] = (None, None, None, None)
    modes: int | None = None  # 6502h bit field
    name: str | None = None
    heartbeat_ms: int | None = None  # producer heartbeat time (1017h); 0: sends none
    flags: tuple[str, ...] = field(default=())  # where it disagrees with the config
    answers: int = 1  # answers to the scan's one SDO request: 2 or more, two devices
    # What a configured node reports of its health (its config's objects, read by SDO).
    voltage_v: float | None = None
    temperature_c: float | None = None
    error_register: int | None = None

    @property
    def supported_modes(self) -> frozenset[int]:
        return frozenset() if self.modes is None else supported_modes(self.modes)


@dataclass(frozen=True)
class ScanReport:
    """The nodes found (with their flags) and the configured nodes that did not answer."""

    found: tuple[FoundNode, ...]
    missing: tuple[int, ...]
    configured: frozenset[int]

    @property
    def ok(self) -> bool:
        """No configured node missing, none disagreeing with the config."""
        return not self.missing and not any(f.flags and f.node_id in self.configured
                                            for f in self.found)


def _u32(node: canopen.RemoteNode, index: int, sub: int = 0) -> int | None:
    try:
        return int.from_bytes(node.sdo.upload(index, sub)[:4], "little")
    except (SdoAbortedError, SdoCommunicationError):
        return None


def _u16(node: canopen.RemoteNode, index: int, sub: int = 0) -> int | None:
    value = _u32(node, index, sub)
    return None if value is None else value & 0xFFFF


def probe(network: canopen.Network, node_id: int, sdo_timeout_s: float) -> FoundNode:
    """Read what a node says about itself over SDO (each read bounded, not retried)."""
    node = canopen.RemoteNode(node_id, od.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
    node.sdo.MAX_RETRIES = 1  # canopen counts attempts (0 would retry for ever)
    network.add_node(node)
    try:
        try:
            name: str | None = node.sdo.upload(DEVICE_NAME, 0).decode("latin-1").strip("\x00 ")
        except (SdoAbortedError, SdoCommunicationError):
            name = None
        return FoundNode(
            node_id,
            device_type=_u32(node, DEVICE_TYPE),
            identity=tuple(_u32(node, IDENTITY, sub) for sub in (1, 2, 3, 4)),
            modes=_u32(node, int(Obj.SUPPORTED_MODES)),
            name=name,
            heartbeat_ms=_u16(node, PRODUCER_HEARTBEAT_TIME),
        )
    finally:
        del network[node_id]


def read_health(network: canopen.Network, layout: NodeLayout,
                sdo_timeout_s: float) -> tuple[float | None, float | None, int | None]:
    """(DC link V, temperature degC of its first wheel, error register) of a configured
    node, read by SDO as its config names them (None: not given, or no answer)."""
    node = canopen.RemoteNode(layout.node_id, od.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
    node.sdo.MAX_RETRIES = 1
    network.add_node(node)
    out: dict[str, float | None] = {}
    try:
        for r in layout.health.reads:
            if r.quantity not in ("voltage", "temperature", "error_register") or \
                    r.quantity in out:
                continue
            try:
                raw = r.entry.decode(node.sdo.upload(r.entry.index, r.entry.subindex))
            except (SdoAbortedError, SdoCommunicationError):
                continue
            out[r.quantity] = raw * r.scale if r.scale is not None else None
    finally:
        del network[layout.node_id]
    register = out.get("error_register")
    return (out.get("voltage"), out.get("temperature"),
            None if register is None else int(register))


def scan(cfg: ChassisConfig, listen_s: float, sdo_timeout_s: float,
         layouts: Iterable[NodeLayout] = ()) -> list[FoundNode]:
    """The nodes on ``cfg``'s bus that send heartbeats or answer an SDO read of 1000h
    within ``listen_s``, by node id (this host's own id, ``host_node_id``, excluded).

    A node's NMT state comes from its heartbeat. For a node not heard within
    ``listen_s`` whose producer heartbeat time (1017h) is longer, the scan listens
    until one period and a half has passed (at most ``MAX_HEARTBEAT_WAIT_S``); a node
    that sends no heartbeat is asked by node guarding (a remote frame), which many
    drives answer. ``nmt`` stays None when neither tells."""
    heartbeats: dict[int, int] = {}
    answers: dict[int, int] = {}

    def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
        if data:
            heartbeats[can_id - HEARTBEAT_BASE] = data[0]

    def on_answer(can_id: int, data: bytearray, timestamp: float) -> None:
        node_id = can_id - SDO_TX_BASE
        answers[node_id] = answers.get(node_id, 0) + 1

    with CanBus(cfg.bus) as can_bus:
        network = can_bus.network
        for node_id in range(1, MAX_NODE_ID + 1):
            network.subscribe(HEARTBEAT_BASE + node_id, on_frame)
            network.subscribe(SDO_TX_BASE + node_id, on_answer)
        started = time.monotonic()
        network.scanner.search()  # SDO upload of 1000h to every node id
        time.sleep(listen_s)
        for node_id in range(1, MAX_NODE_ID + 1):  # one request each, counted: now the reads
            network.unsubscribe(SDO_TX_BASE + node_id, on_answer)
        ids = sorted((set(network.scanner.nodes) | set(heartbeats)) - {cfg.chassis.host_node_id})
        found = [replace(probe(network, node_id, sdo_timeout_s), answers=answers.get(node_id, 0))
                 for node_id in ids]
        _wait_for_heartbeats(found, heartbeats, started)
        silent = [f.node_id for f in found if f.node_id not in heartbeats]
        for node_id in silent:
            network.send_message(HEARTBEAT_BASE + node_id, b"", remote=True)
        if silent:
            time.sleep(NODE_GUARDING_WAIT_S)
        results = [replace(f, nmt=nmt_state_name(heartbeats[f.node_id]))
                   if f.node_id in heartbeats else f for f in found]
        by_id = {layout.node_id: layout for layout in layouts}
        for k, f in enumerate(results):
            layout = by_id.get(f.node_id)
            if layout is not None and f.answers <= 1:
                v, t, reg = read_health(network, layout, sdo_timeout_s)
                results[k] = replace(f, voltage_v=v, temperature_c=t, error_register=reg)
    logger.info("scan: %d node(s) found", len(results))
    return results


def _wait_for_heartbeats(found: list[FoundNode], heard: dict[int, int], started: float) -> None:
    """Until every node with a heartbeat period was heard, or had time to be."""
    due = {f.node_id: started + min(1.5 * f.heartbeat_ms / 1000.0 + 0.05, MAX_HEARTBEAT_WAIT_S)
           for f in found if f.heartbeat_ms}
    while True:
        waiting = [t for node_id, t in due.items() if node_id not in heard]
        now = time.monotonic()
        if not waiting or max(waiting) <= now:
            return
        time.sleep(min(0.02, max(waiting) - now))


def flags(found: FoundNode, layout: NodeLayout | None) -> tuple[str, ...]:
    """Where a found node disagrees with its config entry (``layout``; None: the config
    does not know the node)."""
    out = []
    if found.answers > 1:
        out.append(f"{found.answers} devices answer as node {found.node_id} (a cloned drive? "
                   "give each its own node id)")
    if layout is None:
        return (*out, "not in the config")
    if found.device_type is not None and found.device_type & 0xFFFF != CIA_402:
        out.append(f"device profile {found.device_type & 0xFFFF}, not CiA 402")
    info = layout.dictionary.device_information
    for label, want, got in (("vendor", info.vendor_number, found.identity[0]),
                             ("product", info.product_number, found.identity[1])):
        if want not in (None, 0) and got is not None and want != got:
            out.append(f"{label} 0x{got:08X}, EDS says 0x{want:08X}")
    if found.modes is not None and int(layout.mode) not in found.supported_modes:
        out.append(f"does not offer {layout.mode.short} mode")
    return tuple(out)


def check(found: Iterable[FoundNode], layouts: Iterable[NodeLayout]) -> ScanReport:
    """Compare the nodes found with the config's nodes (``omnican.plan.node.node_layouts``)."""
    by_id = {layout.node_id: layout for layout in layouts}
    checked = tuple(replace(f, flags=flags(f, by_id.get(f.node_id))) for f in found)
    seen = {f.node_id for f in checked}
    return ScanReport(checked, tuple(n for n in by_id if n not in seen), frozenset(by_id))
