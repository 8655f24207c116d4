"""omnican scan: find the nodes on the bus and compare them with the config.

Listens for heartbeats, asks every node id for its device type (SDO 1000h), then
reads each answering node's identity (1018h) and supported modes (6502h), and what a
configured node reports of its health (DC link voltage, temperature, error register).
Prints a table; flags configured nodes that are missing, nodes the config does not know,
and nodes whose profile, identity or modes disagree with their EDS. Exit 1 when a
configured node is missing or disagrees.
"""

from __future__ import annotations

import argparse
from typing import Any

from rich.console import Console
from rich.table import Table

from omnican.analysis.scan import FoundNode, check, scan
from omnican.cli.common import EXIT_FAILURE, EXIT_OK, positive_float
from omnican.cli.session import add_bus_arguments, session
from omnican.plan.node import node_layouts
from omnican.protocol.cia402 import MODE_NAMES


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("scan", help="find nodes on the bus and check them against the config",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--listen", type=positive_float, default=0.5, metavar="S",
                   help="seconds to listen for heartbeats and SDO answers (default 0.5)")
    p.add_argument("--sdo-timeout", type=positive_float, default=0.2, metavar="S",
                   help="timeout of each SDO read of a found node (default 0.2)")
    add_bus_arguments(p, sim_help="scan simulated drives in this process (the config's nodes)")
    p.set_defaults(func=run)


def _nmt_notes(found: tuple[FoundNode, ...]) -> list[str]:
    """Why the NMT column is empty where it is."""
    notes = []
    for label, nodes, why in (
        ("no heartbeat", [f for f in found if f.nmt is None and f.heartbeat_ms == 0],
         "producer heartbeat time 1017h = 0"),
        ("not heard", [f for f in found if f.nmt is None and f.heartbeat_ms != 0],
         "no heartbeat within the listening time"),
    ):
        if not nodes:
            continue
        ids = ", ".join(str(f.node_id) for f in nodes)
        who = f"nodes {ids} send" if len(nodes) > 1 else f"node {ids} sends"
        if label == "no heartbeat":
            notes.append(f"NMT: {who} no heartbeat ({why}) and did not answer node guarding; "
                         "'omnican drive' and 'omnican teleop' turn heartbeats on")
        else:
            notes.append(f"NMT: {'nodes' if len(nodes) > 1 else 'node'} {ids}: {why} and no "
                         "answer to node guarding")
    return notes


_LEFT = ("node", "NMT", "device type")
_IDENTITY = ("vendor", "product", "revision", "serial")
_RIGHT = ("modes (6502h)", "check")


def _table(title: str, columns: tuple[str, ...], check_width: int = 0) -> Table:
    table = Table(title=title, title_justify="left")
    for col in columns:
        # Short values never wrap; the modes and the check text wrap within their cells,
        # the modes first (a check text is read at once, a list of modes can wait).
        short_check = col == "check" and 0 < check_width <= 30
        table.add_column(col, no_wrap=col not in _RIGHT or short_check)
    return table


def _tables(rows: list[tuple[list[str], list[str], list[str], str | None]],
            width: int) -> list[Table]:
    """One table when it fits ``width`` columns; else the identity (1018h) apart."""
    whole = _table("CANopen nodes", _LEFT + _IDENTITY + _RIGHT)
    for left, ident, right, style in rows:
        whole.add_row(*left, *ident, *right, style=style)
    cells = [[*left, *ident] for left, ident, _, _ in rows]
    fixed = 1 + sum(3 + max([len(title)] + [len(row[i]) for row in cells])
                    for i, title in enumerate(_LEFT + _IDENTITY))  # text, padding, rule
    if fixed + 2 * 18 <= width:  # room for the modes and the check beside them
        return [whole]
    check_width = max((len(right[1]) for _, _, right, _ in rows), default=0)
    main = _table("CANopen nodes", _LEFT + _RIGHT, check_width)
    identity = _table("identity (1018h)", ("node", *_IDENTITY))
    for left, ident, right, style in rows:
        main.add_row(*left, *right, style=style)
        identity.add_row(left[0], *ident, style=style)
    return [main, identity]


def _health_table(found: tuple[FoundNode, ...]) -> Table | None:
    """What the configured nodes report of their health; None when none reports any."""
    rows = [f for f in found
            if (f.voltage_v, f.temperature_c, f.error_register) != (None, None, None)]
    if not rows:
        return None
    table = _table("health (as the config reads it)", ("node", "DC link", "temperature",
                                                      "error register (1001h)"))
    for f in rows:
        reg = f.error_register
        table.add_row(str(f.node_id),
                      "-" if f.voltage_v is None else f"{f.voltage_v:.1f} V",
                      "-" if f.temperature_c is None else f"{f.temperature_c:.1f} °C",
                      "-" if reg is None else f"0x{reg:02X}" + (" (no error)" if reg == 0
                                                               else f" ({_register(reg)})"),
                      style="red" if reg else None)
    return table


_REGISTER_BITS = ((0x01, "generic"), (0x02, "current"), (0x04, "voltage"),
                  (0x08, "temperature"), (0x10, "communication"), (0x20, "device profile"),
                  (0x80, "manufacturer"))


def _register(value: int) -> str:
    return ", ".join(name for bit, name in _REGISTER_BITS if value & bit) or "?"


def run(args: argparse.Namespace) -> int:
    with session(args) as s:
        layouts = node_layouts(s.cfg)
        found = scan(s.cfg, args.listen, args.sdo_timeout, layouts)
    report = check(found, layouts)
    console = Console()  # the terminal's width (80 when it is no terminal)
    rows = []
    for f in report.found:
        dt = "-" if f.device_type is None else f"0x{f.device_type:08X}"
        ident = ["-" if v is None else f"0x{v:08X}" for v in f.identity]
        modes = "-" if f.modes is None else ", ".join(
            MODE_NAMES.get(m, str(m)) for m in sorted(f.supported_modes))
        check_text = "; ".join(f.flags) if f.flags else "ok"
        nmt = f.nmt or ("no heartbeat" if f.heartbeat_ms == 0 else "not heard")
        rows.append(([str(f.node_id), nmt, dt], ident, [modes, check_text],
                     "red" if f.flags else None))
    for n in report.missing:
        rows.append(([str(n), "no answer", "-"], ["-"] * 4, ["-", "MISSING (configured)"],
                     "bold red"))
    for table in _tables(rows, console.width):
        console.print(table)
    health = _health_table(report.found)
    if health is not None:
        console.print(health)
    for line in _nmt_notes(report.found):
        console.print(line, markup=False, highlight=False)  # wrapped at the terminal's width
    print(f"{len(report.found)} node(s) found; {len(report.missing)} configured node(s) missing")
    return EXIT_OK if report.ok else EXIT_FAILURE
