"""omnican commission: give new drives their node ids, and store their settings.

Drives without a node id (FFh) are found by LSS fast scan (CiA 305: vendor, product,
revision, serial), drives with another node id than theirs by their identity (1018h);
each gets the node id of the [[wheel]] whose `serial = ...` is its serial, stores it
(LSS store), is reset and read back. --new-bitrate stores a bit rate as well (the drives
take it at their next power-on: give the bus that rate then). The command ends with a
table of which drive (serial) has which node id, whatever happened; two drives with one
serial, a drive that refuses to store, another master on the bus (LSS or NMT frames this
command did not send) and no drive found are one line each (exit 1).

--store writes each node's [[wheel.sdo]] settings, stores them (1010h sub 1, "save"),
resets the node and reads them back, naming any that differ. --restore-defaults instead
asks the drives to forget what they stored (1011h sub 1, "load") and resets them: it
asks first (y/N) unless --yes.

    omnican sim --config robot.toml --unconfigured       # drives at FFh, in a terminal
    omnican commission robot.toml -i remote -c ws://127.0.0.1:54701/
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from rich.console import Console
from rich.table import Table

from omnican.cli.common import EXIT_FAILURE, EXIT_OK, UsageError, fail, positive_float
from omnican.cli.session import add_bus_arguments, session


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("commission", help="give the drives their node ids (LSS) and store "
                       "their settings", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config_file", nargs="?", metavar="CONFIG",
                   help="robot config whose [[wheel]] tables give each node's serial "
                        "(or --config)")
    p.add_argument("--new-bitrate", type=int, metavar="BPS",
                   help="store this bit rate in the drives too (1000000, 800000, 500000, "
                        "250000, 125000, 50000, 20000 or 10000), taken at their next power-on")
    p.add_argument("--store", action="store_true",
                   help="write each node's [[wheel.sdo]] settings, store them (1010h) and "
                        "read them back after a reset")
    p.add_argument("--restore-defaults", action="store_true",
                   help="only this: the configured drives forget what they stored (1011h) "
                        "and are reset; asks first unless --yes")
    p.add_argument("--yes", action="store_true", help="do not ask before --restore-defaults")
    p.add_argument("--lss-timeout", type=positive_float, default=0.05, metavar="S",
                   help="wait for each LSS answer (default 0.05; a fast scan waits once per "
                        "1 bit of each identity)")
    p.add_argument("--sdo-timeout", type=positive_float, default=0.3, metavar="S",
                   help="wait for each SDO answer (default 0.3)")
    add_bus_arguments(p, sim_help="commission simulated drives in this process: they start "
                      "without node ids, with the config's serials")
    p.set_defaults(func=run)


class _Progress:
    """The steps, one line on stderr: redrawn in place on a terminal."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self.width = 0

    def __call__(self, text: str) -> None:
        if self.tty:
            sys.stderr.write("\r" + text.ljust(self.width)[:200])
            self.width = len(text)
        else:
            sys.stderr.write(f"omnican: {text}\n")
        sys.stderr.flush()

    def close(self) -> None:
        if self.tty and self.width:
            sys.stderr.write("\r" + " " * self.width + "\r")
            sys.stderr.flush()


def run(args: argparse.Namespace) -> int:
    from omnican.analysis.commission import bit_timing_index, wanted_ids

    if args.config_file is not None:
        if args.config is not None:
            raise UsageError("give the config once: CONFIG or --config")
        args.config = args.config_file
    if args.new_bitrate is not None:
        bit_timing_index(args.new_bitrate)  # a rate LSS cannot set: one line, exit 2
    if args.restore_defaults and (args.store or args.new_bitrate is not None):
        raise UsageError("--restore-defaults is an action of its own: give it without "
                         "--store and --new-bitrate")
    with session(args, unconfigured=not args.restore_defaults) as s:
        if args.restore_defaults:
            return _restore(args, s.cfg)
        if not wanted_ids(s.cfg):
            raise UsageError("the config gives no drive's serial: add `serial = N` (the "
                             "drive's 1018h sub 4, on its label) to each [[wheel]]")
        return _commission(args, s.cfg)


def _commission(args: argparse.Namespace, cfg: Any) -> int:
    from omnican.analysis.commission import CommissionError, commission
    from omnican.analysis.parameters import store_settings
    from omnican.plan.node import node_layouts

    layouts = node_layouts(cfg) if args.store else []  # a bad [[wheel.sdo]]: exit 2 first
    progress = _Progress()
    try:
        result = commission(cfg, bitrate=args.new_bitrate, lss_timeout_s=args.lss_timeout,
                            sdo_timeout_s=args.sdo_timeout, progress=progress)
    except CommissionError as exc:
        progress.close()
        return fail(str(exc))
    checks = []
    if args.store and not result.problems:
        checks = store_settings(cfg, layouts, sdo_timeout_s=args.sdo_timeout,
                                progress=progress)
    progress.close()
    _table(result, cfg)
    code = EXIT_OK
    for problem in result.problems:
        code = fail(problem)
    if result.bit_timing is not None:
        print(f"bit rate {result.bit_timing} bit/s stored: the drives take it at their next "
              "power-on (give the bus that rate then: [bus] bitrate or -b)")
    for check in checks:
        if check.problem is not None:
            code = fail(f"storing the settings: {check.problem}")
        elif check.differ:
            for address, written, read in check.differ:
                code = fail(f"node {check.node_id}: {address} was stored as {written} but "
                            f"reads {read} after a reset")
        else:
            print(f"node {check.node_id}: {check.written} setting(s) stored (1010h) and read "
                  "back the same after a reset")
    if args.store and not checks and not result.problems:
        print("no [[wheel.sdo]] settings to store")
    return code if code == EXIT_OK else EXIT_FAILURE


def _table(result: Any, cfg: Any) -> None:
    """Which drive (serial) has which node id now, the config's serials not found too."""
    table = Table(title="drives (LSS)", title_justify="left")
    for col in ("serial", "product", "node id before", "now", "config", "what was done"):
        table.add_column(col, no_wrap=col != "what was done")
    for row in sorted(result.drives, key=lambda r: r.serial):
        ok = row.after is not None and row.after == row.wanted
        table.add_row(f"0x{row.serial:08X}", f"0x{row.identity[1]:X}", _node(row.before),
                      _node(row.after), "-" if row.wanted is None else str(row.wanted),
                      row.note, style=None if ok else "red")
    seen = {row.serial for row in result.drives}
    for w in cfg.wheels:
        if w.serial is not None and w.serial not in seen:
            seen.add(w.serial)
            table.add_row(f"0x{w.serial:08X}", "-", "-", "-", str(w.node_id), "not found",
                          style="bold red")
    Console().print(table)


def _node(node_id: int | None) -> str:
    if node_id is None:
        return "?"
    return "none (FFh)" if node_id == 0xFF else str(node_id)


def _restore(args: argparse.Namespace, cfg: Any) -> int:
    from omnican.analysis.parameters import restore_defaults

    nodes = sorted(cfg.nodes())
    listed = ", ".join(str(n) for n in nodes)
    if not args.yes:
        if not sys.stdin.isatty():
            raise UsageError("--restore-defaults asks before it acts: add --yes to run it "
                             "without a terminal")
        answer = input(f"nodes {listed} forget every stored setting (1011h) and reset: "
                       "go on? [y/N] ")
        if answer.strip().lower() not in ("y", "yes"):
            print("nothing restored")
            return EXIT_OK
    results = restore_defaults(cfg, nodes, sdo_timeout_s=args.sdo_timeout)
    code = EXIT_OK
    for node_id, problem in results.items():
        if problem is None:
            print(f"node {node_id}: defaults restored (1011h) and reset")
        else:
            code = fail(f"node {node_id}: restoring the defaults failed: {problem}")
    return code
