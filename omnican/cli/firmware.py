"""omnican firmware: download a program image to the drives (CiA 302-3).

For each drive (every configured node, or the one --wheel or --node names): asks the
drive whether it takes programs over the bus (1F50h, 1F51h, 1F56h, 1F57h), stops its
program, clears it, downloads the image in SDO block mode with a progress bar, checks
that the drive identifies what it stored by the image's CRC-32 (1F56h) and calls its
flash valid (1F57h), starts it, and prints the state the drive reports. Refused, with
nothing written, while the base is driving (a drive OPERATION ENABLED, or another
master's SYNC and RPDOs on the bus). A download that breaks off (a lost drive, a reset or
power cut midway) leaves a drive that says so: its line names the state it reports.
Exit 1 when a drive did not end with the image verified and started.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from omnican.cli.common import EXIT_FAILURE, EXIT_OK, UsageError, fail, positive_float
from omnican.cli.progress import ProgressBar
from omnican.cli.session import add_bus_arguments, session
from omnican.config import ChassisConfig
from omnican.protocol.cia301 import MAX_NODE_ID

#: The wait for each SDO answer (s): omnican.drive.program's (not imported here: the
#: command's help loads neither python-can nor canopen).
DEFAULT_SDO_TIMEOUT_S = 5.0

#: The largest image the command reads: far beyond a drive's flash (a larger file is
#: the wrong file).
MAX_IMAGE_BYTES = 16 << 20
STATUSWORD = (0x6041, 0)  # a node the config does not describe: axis 0's statusword


def add_subparser(sub: Any) -> None:
    p = sub.add_parser("firmware", help="download a program image to the drives (CiA 302-3)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    add_bus_arguments(p, sim_help="download to simulated drives in this process")
    p.set_defaults(func=run)


def add_arguments(parser: argparse.ArgumentParser, image_flag: str = "--image",
                  required: bool = True) -> None:
    """The download's own arguments (not the bus's): the image (``image_flag``, stored
    as ``args.image``), which drives, how long to listen for another master, the SDO
    timeout. Another command offers the download with these and calls
    :func:`download_all`."""
    parser.add_argument(image_flag, dest="image", metavar="FILE", required=required,
                        help="the program image to download (a binary file)")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--wheel", type=int, metavar="N",
                       help="only the drive of wheel N (0-based, in config order)")
    which.add_argument("--node", type=int, metavar="ID",
                       help="only node ID (1-127)")
    parser.add_argument("--listen", type=positive_float, default=0.3, metavar="S",
                        help="seconds to listen for another master's SYNC and RPDOs before "
                             "writing anything (default 0.3)")
    parser.add_argument("--sdo-timeout", type=positive_float, default=DEFAULT_SDO_TIMEOUT_S,
                        metavar="S", help="the wait for each SDO answer during the download "
                        f"(default {DEFAULT_SDO_TIMEOUT_S:g}; a drive erasing its flash may "
                        "take seconds)")


def read_image(path: str) -> bytes:
    """The image file's bytes; a missing, empty or oversized file is a usage error."""
    file = Path(path)
    try:
        size = file.stat().st_size
        if not file.is_file():
            raise UsageError(f"firmware image {path}: not a file")
        if size == 0:
            raise UsageError(f"firmware image {path}: the file is empty")
        if size > MAX_IMAGE_BYTES:
            raise UsageError(f"firmware image {path}: {size} bytes, more than the "
                             f"{MAX_IMAGE_BYTES >> 20} MiB any drive's flash holds: "
                             "the wrong file?")
        return file.read_bytes()
    except FileNotFoundError:
        raise UsageError(f"firmware image {path}: no such file") from None
    except OSError as exc:
        raise UsageError(f"firmware image {path}: {exc.strerror or exc}") from None


def chosen_nodes(args: argparse.Namespace, cfg: ChassisConfig) -> list[int]:
    """The node ids --wheel or --node name (default: every configured node)."""
    wheel, node = getattr(args, "wheel", None), getattr(args, "node", None)
    if wheel is not None:
        if not 0 <= wheel < len(cfg.wheels):
            raise UsageError(f"--wheel {wheel}: the config has wheels 0-{len(cfg.wheels) - 1}")
        return [cfg.wheels[wheel].node_id]
    if node is not None:
        if not 1 <= node <= MAX_NODE_ID:
            raise UsageError(f"--node {node}: a node id is 1-{MAX_NODE_ID}")
        return [node]
    return sorted(cfg.nodes())


def statuswords(cfg: ChassisConfig, nodes: list[int]) -> dict[int, list[tuple[int, int]]]:
    """Each node's statusword objects, as its EDS places them."""
    from omnican.plan.node import node_layouts

    known = {layout.node_id: [(s.statusword.index, s.statusword.subindex)
                              for s in layout.stages] for layout in node_layouts(cfg)}
    return {n: known.get(n, [STATUSWORD]) for n in nodes}


def download_all(args: argparse.Namespace, cfg: ChassisConfig, network: Any,
                 image: bytes, out: Any = None) -> int:
    """The download on an open ``network`` (canopen's): refused while the base drives,
    then each chosen drive in turn, its state line on ``out``; the exit status."""
    from omnican.drive.program import download, driving

    out = out or sys.stdout
    nodes = chosen_nodes(args, cfg)
    why = driving(network, statuswords(cfg, nodes), args.listen)
    if why is not None:
        return fail(f"firmware refused: {why}; nothing was written")
    failed = 0
    for node_id in nodes:
        bar = ProgressBar(len(image))

        def progress(sent: int, total: int, node_id: int = node_id, bar: ProgressBar = bar
                     ) -> None:
            bar(sent, total, f"node {node_id}")

        try:
            result = download(network, node_id, image, progress, args.sdo_timeout)
        finally:
            bar.close()
        print(result.line(), file=out, flush=True)
        failed += not result.ok
    if len(nodes) > 1:
        print(f"{len(nodes) - failed} of {len(nodes)} drives run the image", file=out)
    return EXIT_FAILURE if failed else EXIT_OK


def run(args: argparse.Namespace) -> int:
    from omnican.io.bus import CanBus

    image = read_image(args.image)
    with session(args) as s:
        chosen_nodes(args, s.cfg)  # a bad --wheel or --node before the bus opens
        with CanBus(s.cfg.bus) as can_bus:
            return download_all(args, s.cfg, can_bus.network, image)
