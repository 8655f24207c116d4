"""Generate ``dbc/omnican.dbc``: the CAN frames of the demo base (nodes 1-3 on the
bundled EDS) for cantools, ``omnican monitor`` and ``cantools decode``.

The frames come from ``omnican.plan.dbc`` (the plan omnican configures), so the file stays
derivable from the bundled EDS; ``tests/plan/test_dbc.py`` fails when the two drift apart.

Usage::

    python tools/gen_dbc.py            # rewrite omnican/dbc/omnican.dbc
    python tools/gen_dbc.py --check    # exit 1 if the file is out of date
    python tools/gen_dbc.py -o FILE    # write elsewhere ("-" = stdout)
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from omnican.plan.dbc import build_database, dbc_text

DBC_PATH = Path(__file__).resolve().parent.parent / "omnican" / "dbc" / "omnican.dbc"

__all__ = ["DBC_PATH", "build_database", "dbc_text", "main"]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default=str(DBC_PATH),
                        help=f"where to write (default {DBC_PATH}; '-' = stdout)")
    parser.add_argument("--check", action="store_true",
                        help="do not write; exit 1 if the output file differs")
    args = parser.parse_args(argv)
    text = dbc_text()
    if args.output == "-":
        sys.stdout.write(text)
        return 0
    out = Path(args.output)
    if args.check:
        current = out.read_bytes().decode("utf-8") if out.exists() else ""
        if current != text:
            sys.stderr.write(f"{out} is out of date: run python tools/gen_dbc.py\n")
            return 1
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(text.encode("utf-8"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
