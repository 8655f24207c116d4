"""The ``omnican`` command: one module per subcommand, each with ``add_subparser()``
and ``run(args)`` (after cantools' layout). A subcommand whose optional dependency
is missing still appears and says what to install; the others keep working."""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import re
import sys
from collections.abc import Sequence

from omnican import __version__
from omnican.cli.common import (
    EXIT_FAILURE,
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    Parser,
    UsageError,
    fail,
    setup_logging,
)
from omnican.errors import ConfigError, OmnicanError

SUBCOMMANDS = ("teleop", "drive", "sim", "scan", "monitor", "calibrate", "plot", "check_config",
               "ros2")


def install_hint(module: str) -> str:
    """How to install a missing optional dependency: the omnican extra that carries it
    (read from the installed package's metadata), else the module itself."""
    try:
        requires = importlib.metadata.requires("omnican") or []
    except importlib.metadata.PackageNotFoundError:
        requires = []
    wanted = _normalise(module.split(".", maxsplit=1)[0])
    for requirement in requires:
        m = _EXTRA_REQUIREMENT.match(requirement)
        if m and _normalise(m["name"]) == wanted and m["extra"] not in ("test", "dev"):
            return f"pip install 'omnican[{m['extra']}]'"
    return f"pip install {module.split('.', maxsplit=1)[0]}"


_EXTRA_REQUIREMENT = re.compile(
    r"^\s*(?P<name>[A-Za-z0-9][A-Za-z0-9._-]*).*;.*\bextra\s*==\s*['\"](?P<extra>[^'\"]+)['\"]")


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="omnican",
                    description="Drive a three-omni-wheel base of CANopen CiA 402 drives.")
    parser.add_argument("--version", action="version", version=f"omnican {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output (-v info, -vv debug)")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND", parser_class=Parser)
    unavailable: dict[str, str] = {}
    for name in SUBCOMMANDS:
        command = name.replace("_", "-")
        try:
            module = importlib.import_module(f"omnican.cli.{name}")
        except ImportError as exc:  # an optional dependency is missing
            missing = exc.name or str(exc)
            reason = f"'{command}' needs {missing}: {install_hint(missing)}"
            unavailable[command] = reason
            sub.add_parser(command, help=f"(unavailable: needs {missing}: "
                                         f"{install_hint(missing)})")
            continue
        module.add_subparser(sub)
    parser.set_defaults(unavailable=unavailable)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    unavailable: dict[str, str] = parser.get_default("unavailable")
    words = list(sys.argv[1:] if argv is None else argv)
    command = next((w for w in words if not w.startswith("-")), None)
    if command in unavailable:  # whatever its arguments: they are the missing module's
        return fail(unavailable[command], EXIT_USAGE)
    args = parser.parse_args(words)
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
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # output piped into head & co.
        return 0

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
