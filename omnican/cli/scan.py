"""``omnican scan``: find the nodes on the bus and compare them with the config.

Listens for heartbeats, asks every node id for its device type (SDO 1000h), then
reads each answering node's identity (1018h) and supported modes (6502h). Prints a
table; flags configured nodes that are missing, nodes the config does not know,
and nodes whose profile, identity or modes disagree with their EDS. Exit 1 when a
configured node is missing or disagrees.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from typing import Any

import canopen
from canopen import objectdictionary as od
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from rich.console import Console
from rich.table import Table

from omnican.bus import CanBus
from omnican.cia301 import (
    DEVICE_NAME,
    DEVICE_TYPE,
    HEARTBEAT_BASE,
    IDENTITY,
    MAX_NODE_ID,
    nmt_state_name,
)
from omnican.cia402 import MODE_NAMES, supported_modes
from omnican.cli.common import EXIT_FAILURE, EXIT_OK, add_bus_arguments, positive_float, session
from omnican.config import ChassisConfig
from omnican.layout import NodeLayout, node_layouts


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("scan", help="find nodes on the bus and check them against the config",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--listen", type=positive_float, default=0.5, metavar="S",
                   help="seconds to listen for heartbeats and SDO answers (default 0.5)")
    p.add_argument("--sdo-timeout", type=positive_float, default=0.2, metavar="S",
                   help="timeout of each SDO read of a found node (default 0.2)")
    add_bus_arguments(p, sim_help="scan simulated drives in this process (the config's nodes)")
    p.set_defaults(func=run)


@dataclass
class Found:
    node_id: int
    nmt: str = "-"
    device_type: int | None = None
    identity: list[int | None] = field(default_factory=list)
    modes: int | None = None
    name: str | None = None
    flags: list[str] = field(default_factory=list)


def _u32(node: canopen.RemoteNode, index: int, sub: int = 0) -> int | None:
    try:
        return int.from_bytes(node.sdo.upload(index, sub)[:4], "little")
    except (SdoAbortedError, SdoCommunicationError):
        return None


def probe(network: canopen.Network, node_id: int, timeout: float) -> Found:
    node = canopen.RemoteNode(node_id, od.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = timeout
    node.sdo.MAX_RETRIES = 0
    network.add_node(node)
    try:
        found = Found(node_id)
        found.device_type = _u32(node, DEVICE_TYPE)
        found.identity = [_u32(node, IDENTITY, sub) for sub in (1, 2, 3, 4)]
        found.modes = _u32(node, 0x6502)
        try:
            found.name = node.sdo.upload(DEVICE_NAME, 0).decode("latin-1").strip("\x00 ")
        except (SdoAbortedError, SdoCommunicationError):
            found.name = None
        return found
    finally:
        del network[node_id]


def compare(found: Found, layout: NodeLayout | None) -> None:
    if layout is None:
        found.flags.append("not in the config")
        return
    if found.device_type is not None and found.device_type & 0xFFFF != 402:
        found.flags.append(f"device profile {found.device_type & 0xFFFF}, not CiA 402")
    info = layout.dictionary.device_information
    for label, want, got in (("vendor", info.vendor_number, found.identity[0]),
                             ("product", info.product_number, found.identity[1])):
        if want not in (None, 0) and got is not None and want != got:
            found.flags.append(f"{label} 0x{got:08X}, EDS says 0x{want:08X}")
    if found.modes is not None and int(layout.mode) not in supported_modes(found.modes):
        found.flags.append(f"does not offer {layout.mode.short} mode")


def scan(cfg: ChassisConfig, listen_s: float, sdo_timeout: float) -> list[Found]:
    heartbeats: dict[int, int] = {}

    def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
        if data:
            heartbeats[can_id - HEARTBEAT_BASE] = data[0]

    with CanBus(cfg.bus) as bus:
        network = bus.network
        for node_id in range(1, MAX_NODE_ID + 1):
            network.subscribe(HEARTBEAT_BASE + node_id, on_frame)
        network.scanner.search()  # SDO upload of 1000h to every node id
        time.sleep(listen_s)
        ids = sorted(set(network.scanner.nodes) | set(heartbeats))
        host = cfg.chassis.host_node_id
        results = []
        for node_id in ids:
            if node_id == host:
                continue
            found = probe(network, node_id, sdo_timeout)
            if node_id in heartbeats:
                found.nmt = nmt_state_name(heartbeats[node_id])
            results.append(found)
    return results


def run(args: argparse.Namespace) -> int:
    with session(args) as s:
        layouts = {layout.node_id: layout for layout in node_layouts(s.cfg)}
        results = scan(s.cfg, args.listen, args.sdo_timeout)
    by_id = {f.node_id: f for f in results}
    for f in results:
        compare(f, layouts.get(f.node_id))
    missing = [n for n in layouts if n not in by_id]
    table = Table(title="CANopen nodes", title_justify="left")
    for col in ("node", "NMT", "device type", "vendor", "product", "revision", "serial",
                "modes (6502h)", "check"):
        table.add_column(col)
    for f in results:
        dt = "-" if f.device_type is None else f"0x{f.device_type:08X}"
        ident = ["-" if v is None else f"0x{v:08X}" for v in f.identity]
        modes = "-" if f.modes is None else ", ".join(
            MODE_NAMES.get(m, str(m)) for m in sorted(supported_modes(f.modes)))
        check = "; ".join(f.flags) if f.flags else "ok"
        table.add_row(str(f.node_id), f.nmt, dt, *ident, modes, check,
                      style="red" if f.flags else None)
    for n in missing:
        table.add_row(str(n), "-", "-", "-", "-", "-", "-", "-",
                      "MISSING (configured, no answer)", style="bold red")
    Console(width=160).print(table)
    bad = missing or any(f.flags and f.node_id in layouts for f in results)
    print(f"{len(results)} node(s) found; {len(missing)} configured node(s) missing")
    return EXIT_FAILURE if bad else EXIT_OK
