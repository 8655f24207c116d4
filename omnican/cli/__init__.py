"""The ``omnican`` command: one module per subcommand (see ``omnican --help``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from omnican import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="omnican",
        description="Drive a three-omni-wheel base of CANopen CiA 402 drives.",
    )
    parser.add_argument("--version", action="version", version=f"omnican {__version__}")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    parser.parse_args(argv)
    parser.print_help()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
