"""The ``omnican`` command: one module per subcommand, each with ``add_subparser()`` and
``run(args)`` (after cantools' layout).

Only the subcommand named on the command line is imported (with what it needs); the
others are listed from :data:`COMMANDS`, so ``omnican --help`` and ``--version`` load
neither numpy nor python-can, canopen or any optional extra. A subcommand whose extra
is missing still shows its help; running it says what to install (exit 2)."""

from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import importlib
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from typing import Any

from omnican import __version__
from omnican.cli.common import (
    EXIT_FAILURE,
    EXIT_USAGE,
    Parser,
    Terminated,
    UsageError,
    fail,
    interrupted_exit,
    logging_for_command,
)
from omnican.extras import needs
from omnican.layers import FRONT_ENDS

# Command -> (module under omnican.cli, one-line help, the extra it needs): the library's,
# then each front end's own (the registry's: omnican.layers.FRONT_ENDS).
COMMANDS: dict[str, tuple[str, str, str | None]] = {
    "teleop": ("teleop", "drive the base from the keyboard (live dashboard)", None),
    "drive": ("drive", "drive a scripted motion and print the pose", None),
    "sim": ("sim", "serve simulated drives to another process", None),
    "scan": ("scan", "find nodes on the bus and check them against the config", None),
    "monitor": ("monitor", "live decode of the bus: per-id rates, signals, bus load", None),
    "calibrate": ("calibrate", "calibrate the wheel scales and the base radius", None),
    "commission": ("commission", "give the drives their node ids (LSS) and store their "
                   "settings", None),
    "plot": ("plot", "plot a recording: trajectory, wheel speeds, drive states", "plot"),
    "check-config": ("check_config", "validate config files and their EDS files offline", None),
    "firmware": ("firmware", "download a program image to the drives (CiA 302-3)", None),
    **{command: (command.replace("-", "_"), help_text, entry.extra)
       for entry in FRONT_ENDS.values() for command, help_text in entry.commands},
}
#: The modules of the subcommands, in the order ``--help`` lists them.
SUBCOMMANDS = tuple(module for module, _, _ in COMMANDS.values())


def unavailable(command: str) -> str | None:
    """Why ``command`` cannot run here (its extra is missing, with how to install it)."""
    extra = COMMANDS[command][2]
    return None if extra is None else needs(extra, f"'{command}'")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; ``command``'s subparser in full (importing its module), the others
    as names with their help (all in full when ``command`` is None)."""
    parser = Parser(prog="omnican",
                    description="Drive a three-omni-wheel base of CANopen CiA 402 drives.")
    parser.add_argument("--version", action="version", version=f"omnican {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output (-v info, -vv debug); also after the command")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND", parser_class=Parser)
    for name, (module, help_text, _) in COMMANDS.items():
        if command is None or name == command:
            importlib.import_module(f"omnican.cli.{module}").add_subparser(sub)
            continue
        why = unavailable(name)
        sub.add_parser(name, help=help_text if why is None else f"{help_text} "
                       f"(unavailable: {why.split(' ', 1)[1]})")
    for choice in sub.choices.values():  # -v after the command too (its own count)
        if not any("-v" in a.option_strings for a in choice._actions):
            choice.add_argument("-v", "--verbose", action="count", default=0,
                                dest="command_verbose", help=argparse.SUPPRESS)
    return parser


def _command_word(words: Sequence[str]) -> str | None:
    for word in words:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word
    return None


@contextlib.contextmanager
def _sigterm_unwinds() -> Iterator[None]:
    """SIGTERM (``timeout``, ``kill``, systemd) raises :class:`Terminated` in the main
    thread, so a command ends as on Ctrl-C: the drives stop and are disabled, and it
    says where the base stopped (exit 143)."""
    def handle(signum: int, frame: Any) -> None:
        raise Terminated(signum)

    try:
        old = signal.signal(signal.SIGTERM, handle)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def main(argv: Sequence[str] | None = None) -> int:
    """The command line (``argv``: the words after ``omnican``; None: the process's own
    command, which sets the process up as :func:`_own_process` says and ends it)."""
    if argv is None:
        _own_process()
    try:
        with _sigterm_unwinds():
            code = _main(list(sys.argv[1:] if argv is None else argv), own=argv is None)
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM before a command could say more
        print(f"omnican: {'terminated' if isinstance(exc, Terminated) else 'interrupted'}",
              file=sys.stderr)
        code = interrupted_exit(exc)
    if argv is None:  # the process's own command: it ends here
        _exit_past_foreign_threads(code)
        _exit_unfinalized(code)
    return code


def _own_process() -> None:
    """What the ``omnican`` process does before it imports anything else: numpy does
    3x3 maths here, and OpenBLAS's worker threads (one per core, started when numpy is
    imported, spinning a while) cost a command 30-40 ms of CPU and would take cores from
    the control loop for nothing. A user's own OPENBLAS_NUM_THREADS stands."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _exit_past_foreign_threads(code: int) -> None:
    """End a process that imported a front end whose library calls into Python from
    threads of its own (its registry line says ``foreign_threads``) now, its output
    flushed, without the interpreter's finalization: such a thread calling into Python
    meanwhile is ended by it with a forced unwind through Rust frames, which aborts the
    process ("FATAL: exception not rethrown", exit -6 instead of the command's code; 2
    runs in 120 of ``fleet --once --json``). Every command has closed what it opened by
    now."""
    from omnican.layers import FRONT_ENDS

    if not any(module in sys.modules for entry in FRONT_ENDS.values()
               for module in entry.foreign_threads):
        return
    import logging

    logging.shutdown()
    _end_now(code)


def _exit_unfinalized(code: int) -> None:
    """End the process now that its command returned ``code``, as the interpreter's own
    exit would (the exit handlers run: logging's shutdown, the finalizers a library left;
    the output flushed) but without its finalization, which tears the modules and what
    they hold down (numpy, python-can, canopen, omnican): ~12 ms of CPU at the end of
    ``drive --sim --fast``, for nothing once the command has closed what it opened, as
    every command has. A thread besides the main one that is not a daemon (none of
    omnican's) keeps the interpreter's exit, which waits for it; so does a profiler or a
    tracer (``python -m cProfile -m omnican ...``, coverage), which writes its findings
    once the command has returned."""
    if sys.getprofile() is not None or sys.gettrace() is not None or any(
            not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        return
    atexit._run_exitfuncs()
    _end_now(code)


def _end_now(code: int) -> None:
    """The process's output flushed, then its end with ``code``, past the interpreter's
    finalization (what the two exits above have made safe to skip)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


@contextlib.contextmanager
def _imports_uncollected() -> Iterator[None]:
    """The command's modules imported with the garbage collector off, then frozen out of
    its reach (``gc.freeze``): what an import makes (modules, classes, functions) lives
    as long as the process, and the collections it set off (a fifth of a second of
    imports: about 17 ms of CPU, a full one among them) walked it again and again. The
    collector runs as before from here on. The process's own command only: a program
    (a test) that calls :func:`main` keeps its heap as it was."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def _main(words: list[str], own: bool = False) -> int:
    """``own``: the process's own command (its imports frozen out of the collector)."""
    command = _command_word(words)
    with _imports_uncollected() if own else contextlib.nullcontext():
        parser = build_parser(command if command in COMMANDS else "")
    args = parser.parse_args(words)
    if not hasattr(args, "func"):
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    with logging_for_command(args.verbose + getattr(args, "command_verbose", 0)):
        why = unavailable(command) if command in COMMANDS else None
        if why is not None:  # its help shows; running it needs the extra
            return fail(why, EXIT_USAGE)
        from omnican.errors import ConfigError, OmnicanError

        try:
            code: int = args.func(args)
            return code
        except (ConfigError, UsageError) as exc:
            return fail(str(exc), EXIT_USAGE)
        except OmnicanError as exc:
            return fail(str(exc), EXIT_FAILURE)
        except BrokenPipeError:  # output piped into head & co.
            return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
