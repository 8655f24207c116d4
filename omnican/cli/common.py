"""What every subcommand and the command line itself share: the exit codes (0 success,
2 bad usage/config/EDS, 1 run-time failure; 130 and 143 interrupted), one-line errors,
the argument parser and the number types of its flags, how a pose and a number are
printed, and the logging of one command. The rest a subcommand takes from the module of
its concern: :mod:`omnican.cli.session` (config, bus, ``--sim``, ``--record``),
:mod:`omnican.cli.progress`, :mod:`omnican.cli.console` (stdin lines), and
:mod:`omnican.cli.front_ends` (the front ends it runs beside what it does).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import signal
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, NoReturn

from omnican.errors import ConfigError

if TYPE_CHECKING:
    from omnican.core.odometry import Pose2D

EXIT_OK, EXIT_FAILURE, EXIT_USAGE = 0, 1, 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports Ctrl-C
EXIT_TERMINATED = 128 + signal.SIGTERM  # 143


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread (see omnican.cli.main): a command unwinds as on
    Ctrl-C (the drives stop and are disabled, the pose is printed), then exits 143."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signum)
        self.signum = signum


def interrupted_exit(exc: BaseException) -> int:
    """The exit status for a Ctrl-C (130) or a SIGTERM (143)."""
    return 128 + exc.signum if isinstance(exc, Terminated) else EXIT_INTERRUPTED


def interrupted_word(exc: BaseException) -> str:
    return "terminated" if isinstance(exc, Terminated) else "interrupted"

class UsageError(Exception):
    """Bad command-line usage: one line on stderr, exit 2."""


class Parser(argparse.ArgumentParser):
    """argparse with errors on one line (usage is one ``--help`` away) and exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def finite_float(text: str) -> float:
    """argparse type: a finite number (argparse's float accepts 'nan' and 'inf')."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse type: a whole number above zero."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive whole number, got {text!r}")
    return value


def fixed(value: float, places: int, sign: bool = False) -> str:
    """``value`` with ``places`` decimals (and its sign with ``sign``); a value that
    rounds to zero is 0, never -0."""
    text = f"{value:+.{places}f}" if sign else f"{value:.{places}f}"
    if float(text) == 0.0:
        text = f"{0.0:+.{places}f}" if sign else f"{0.0:.{places}f}"
    return text


def rounded(value: float, places: int = 6) -> float:
    """``value`` rounded for JSON, with -0.0 as 0.0."""
    return round(value, places) + 0.0


def pose_line(p: Pose2D) -> str:
    """``pose x=<m> y=<m> theta=<rad>``: how every command prints a final pose."""
    return f"pose x={fixed(p.x, 4)} y={fixed(p.y, 4)} theta={fixed(p.theta, 4)}"


def pose_dict(p: Pose2D) -> dict[str, float]:
    return {"x": rounded(p.x), "y": rounded(p.y), "theta": rounded(p.theta)}


_QUIETED = ("canopen", "can", "canopen.objectdictionary", "canopen.sdo.client")


@contextlib.contextmanager
def logging_for_command(verbosity: int, stream: Any = None) -> Iterator[None]:
    """:func:`setup_logging` for one command, and the logging as it was afterwards: a
    program calling :func:`omnican.cli.main` keeps its own handlers and levels, and no
    handler is left writing to a stream that has gone (a test's captured stderr)."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    levels = {name: logging.getLogger(name).level for name in _QUIETED}
    setup_logging(verbosity, stream)
    try:
        yield
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)
        for name, old in levels.items():
            logging.getLogger(name).setLevel(old)


def setup_logging(verbosity: int, stream: Any = None) -> None:
    """Warnings by default; -v info; -vv debug (canopen's chatty INFO only at -vv)."""
    level = logging.WARNING if verbosity <= 0 else logging.INFO if verbosity == 1 else logging.DEBUG
    root = logging.getLogger()
    root.handlers.clear()
    handler = logging.StreamHandler(stream or sys.stderr)
    handler.setFormatter(logging.Formatter("omnican: %(levelname)s: %(message)s"))
    root.addHandler(handler)
    root.setLevel(level)
    for noisy in ("canopen", "can"):
        logging.getLogger(noisy).setLevel(logging.DEBUG if verbosity >= 2 else logging.WARNING)
    # Vendor EDS files often declare defaults outside their own limits (ZLAC8015D: mode 0
    # with a minimum of 1); canopen warns on every such read. Keep that for -v.
    logging.getLogger("canopen.objectdictionary").setLevel(
        logging.WARNING if verbosity >= 1 else logging.ERROR)
    # canopen warns of each SDO request it sends again and logs the abort of one that
    # failed: omnican retries on purpose (a lost frame is normal) and says itself, in
    # one line naming the node and the step, when a request failed for good.
    logging.getLogger("canopen.sdo.client").setLevel(
        logging.DEBUG if verbosity >= 2 else logging.INFO if verbosity == 1 else
        logging.CRITICAL)


def fail(message: str, code: int = EXIT_FAILURE) -> int:
    """Print one line on stderr and return the exit code."""
    print(f"omnican: error: {message}", file=sys.stderr)
    return code


def is_config_error(exc: BaseException) -> bool:
    return isinstance(exc, (ConfigError, UsageError))
