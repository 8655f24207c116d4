"""The ``omnican`` command: one module per subcommand, each with ``add_subparser()``
and ``run(args)`` (after cantools' layout). A subcommand whose optional dependency
is missing still appears and says what to install; the others keep working."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from omnican import __version__
from omnican.cli.common import (
    EXIT_FAILURE,
    EXIT_USAGE,
    Parser,
    UsageError,
    fail,
    setup_logging,
)
from omnican.errors import ConfigError, OmnicanError

SUBCOMMANDS = ("teleop", "drive", "sim", "scan", "monitor", "calibrate", "plot", "check_config",
               "ros2")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="omnican",
                    description="Drive a three-omni-wheel base of CANopen CiA 402 drives.")
    parser.add_argument("--version", action="version", version=f"omnican {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output (-v info, -vv debug)")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND", parser_class=Parser)
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"omnican.cli.{name}")
        except ImportError as exc:  # an optional dependency is missing
            missing = exc.name or str(exc)
            p = sub.add_parser(name.replace("_", "-"), help=f"(unavailable: needs {missing})")
            p.set_defaults(func=lambda args, m=missing, n=name: fail(
                f"'{n}' needs {m}: pip install 'omnican[plot]'", EXIT_USAGE))
            continue
        module.add_subparser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    setup_logging(args.verbose)
    try:
        code: int = args.func(args)
        return code
    except (ConfigError, UsageError) as exc:
        return fail(str(exc), EXIT_USAGE)
    except OmnicanError as exc:
        return fail(str(exc), EXIT_FAILURE)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # output piped into head & co.
        return 0

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
