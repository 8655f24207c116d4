"""What every subcommand shares: argument builders, the bus/config/--sim resolution,
one-line errors and exit codes (0 success, 2 bad usage/config/EDS, 1 run-time failure).

Size: about 500 lines, above the 450 the package keeps to, on purpose: every piece here
is small and used by several subcommands (argument types, the session, progress, output
formats, logging), and one place for what they share is what keeps the subcommands
thin.
"""

from __future__ import annotations

import argparse
import codecs
import contextlib
import importlib
import importlib.util
import logging
import math
import os
import select
import signal
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from omnican.clock import REAL_TIME, Clock, SimClock
from omnican.errors import ConfigError

if TYPE_CHECKING:
    from omnican.config import ChassisConfig
    from omnican.core.odometry import Pose2D
    from omnican.record.recording import FileRecording

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

_BUS_KEYS = ("channel", "interface", "bitrate", "fd", "data_bitrate", "timing")


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


def recording_suffixes() -> dict[str, str]:
    """Suffix -> what it is, for every format omnican both records and reads back
    (plot, calibrate --fit, replay): python-can's log formats that have a reader as
    well as a writer, and MCAP."""
    from can.io.logger import MESSAGE_WRITERS
    from can.io.player import MESSAGE_READERS

    names = {".log": "candump", ".asc": "Vector ASC", ".blf": "Vector BLF", ".csv": "CSV",
             ".db": "SQLite", ".trc": "PEAK trace", ".mf4": "ASAM MDF4"}
    out = {s: names.get(s, s[1:]) for s in sorted(set(MESSAGE_WRITERS) & set(MESSAGE_READERS))}
    if ".mf4" in out and importlib.util.find_spec("asammdf") is None:
        del out[".mf4"]  # python-can's MF4 support needs asammdf
    out.pop(".db", None)  # its writer loses the last frames of a run: not read back whole
    out[".mcap"] = "MCAP"
    return out


def record_path(text: str) -> str:
    """argparse type for ``--record FILE``: a format omnican can read back (python-can
    also writes .txt, as text that no reader reads); ``.gz`` compresses a text log."""
    path = Path(text)
    suffixes = recording_suffixes()
    suffix = path.suffix.lower()
    inner = Path(path.stem).suffix.lower() if suffix == ".gz" else suffix
    if suffix == ".gz" and inner in (".mcap", ".blf", ".db", ".mf4"):
        inner = ""  # binary formats compress themselves, or not at all
    if inner not in suffixes:
        known = ", ".join(f"{s} ({what})" for s, what in suffixes.items())
        why = (" (python-can writes .txt as printed text, which nothing reads back)"
               if inner == ".txt" else "")
        raise argparse.ArgumentTypeError(
            f"cannot record to {text}{why}: give a file ending in one of {known}")
    if not (path.parent if str(path.parent) else Path(".")).is_dir():
        raise argparse.ArgumentTypeError(f"cannot record to {text}: no such directory "
                                         f"{path.parent}")
    return text


def add_record_argument(parser: Any, what: str = "record the bus to FILE") -> None:
    """--record FILE, refusing at parse time a format omnican cannot read back."""
    from omnican.extras import install_hint

    parser.add_argument("--record", metavar="FILE", type=record_path,
                        help=f"{what}; format by extension: .log (candump), .asc, .blf, .csv, "
                             ".trc; .mcap: frames plus the robot's state as ROS 2 messages "
                             f"({install_hint('mcap')})")


def recording(path: str | Path | None) -> FileRecording | None:
    """``--record FILE`` as a recording of the base (``Chassis.open(..., record=)``: from
    the bus's first frame on, closed with the base); None without one."""
    if path is None:
        return None
    from omnican.record.recording import FileRecording

    return FileRecording(path)


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="TOML",
                        help="robot config (default: the demo base of three bundled drives, "
                             "nodes 1-3)")


def add_bus_arguments(parser: argparse.ArgumentParser, sim_help: str | None = None) -> None:
    """--config, --sim and python-can's bus arguments (-i/-c/-b ...)."""
    add_config_argument(parser)
    parser.add_argument("--sim", action="store_true",
                        help=sim_help or "run against simulated drives in this process "
                        "(a virtual bus; no hardware)")
    add_python_can_arguments(parser, "bus arguments (override [bus] of the config)")


def add_python_can_arguments(parser: argparse.ArgumentParser, title: str) -> None:
    """python-can's bus arguments (``can.cli.add_bus_arguments``), with the interface
    named once: python-can's own ``-i`` lists every interface it knows twice in its
    usage and help line (about 400 characters a line)."""
    import can.cli

    can.cli.add_bus_arguments(parser, group_title=title)
    for action in parser._actions:
        if action.dest == "interface" and action.choices:
            action.metavar = "INTERFACE"
            action.help = ("python-can's interface: socketcan (Linux), virtual (within one "
                           "process), remote (omnican sim's hub) or another of "
                           f"{', '.join(sorted(action.choices))} (default: [bus] of the "
                           "config, else python-can's configuration)")


def add_sim_time_arguments(parser: argparse.ArgumentParser) -> None:
    """--fast and --sim-speed: run --sim in simulated time (lock-step)."""
    group = parser.add_argument_group("simulated time (with --sim)")
    group.add_argument("--fast", action="store_true",
                       help="run the simulation as fast as the CPU allows (lock-step, "
                            "deterministic); the results are those of real time")
    group.add_argument("--sim-speed", type=positive_float, metavar="FACTOR",
                       help="run the simulation at FACTOR times real time (lock-step)")


def bus_overrides(args: argparse.Namespace) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in _BUS_KEYS:
        if key in args:
            out[key] = getattr(args, key)
    if "bus_kwargs" in args:
        out.update(args.bus_kwargs)
    return out


def check_bus(bus: Any) -> None:
    """What python-can needs to build the bus (``bus``: the ``can.Bus`` arguments, None for
    python-can's own configuration) is there: an interface, and every argument that
    interface's bus requires (kvaser, pcan & co. want a channel). A missing one is a
    usage error saying what to give, before anything opens (python-can would fail with a
    TypeError in its own words)."""
    import inspect

    import can
    import can.util

    try:
        resolved = can.util.load_config(config=dict(bus or {}))
    except can.CanInterfaceNotImplementedError:
        raise UsageError("no CAN interface: give -i INTERFACE (e.g. -i socketcan -c can0), "
                         "interface in the config's [bus] table, or python-can's config "
                         "file; --sim runs without hardware") from None
    interface = resolved.get("interface")
    backend = can.interfaces.BACKENDS.get(str(interface))
    if backend is None:
        raise UsageError(f"unknown CAN interface {interface!r} (known: "
                         f"{', '.join(sorted(can.interfaces.VALID_INTERFACES))})")
    logger = logging.getLogger("can")
    level = logger.level
    logger.setLevel(logging.ERROR)  # importing a driver whose library is absent warns
    try:
        bus_class = getattr(importlib.import_module(backend[0]), backend[1])
        params = inspect.signature(bus_class.__init__).parameters
    except Exception:  # the driver does not even import: opening it will say why
        return
    finally:
        logger.setLevel(level)
    for name, param in list(params.items())[1:]:
        if param.default is not inspect.Parameter.empty or param.kind in (
                inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD):
            continue
        if resolved.get(name) is None:
            flag = {"channel": "-c CHANNEL", "bitrate": "-b BITRATE"}.get(name)
            how = f"{flag}, or {name}" if flag else name
            raise UsageError(f"the {interface} interface needs a {name}: give {how} in the "
                             "config's [bus] table")


def check_front_ends(cfg: ChassisConfig) -> ChassisConfig:
    """The tables front ends read, checked as they check them (so every command refuses
    what ``omnican ros2`` would: ``[ros2] domain_id = 999``). The library checks only
    their keys and types; ``[gamepad]``'s values it checks itself."""
    origin = str(cfg.source) if cfg.source else "config"
    if cfg.ros2 is not None:
        from omnican.ros2.settings import from_table

        from_table(cfg.ros2, origin)
        check_joint_names(cfg, origin)
    if cfg.foxglove is not None:
        from omnican.live.settings import resolve

        resolve(cfg.foxglove, None, origin=origin, check_sdk=False)
    if cfg.zenoh is not None:
        from omnican.zenoh.settings import from_table as zenoh_table

        zenoh_table(cfg.zenoh, origin)
    return cfg


def check_joint_names(cfg: ChassisConfig, origin: str) -> None:
    """[ros2] joint_names: one per wheel (the telemetry every command builds refuses
    others; check-config passed them)."""
    names = (cfg.ros2 or {}).get("joint_names")
    if names is not None and len(names) != len(cfg.wheels):
        raise ConfigError(f"{origin}: ros2.joint_names: {len(names)} names for "
                          f"{len(cfg.wheels)} wheels (one per [[wheel]], in order)")


FOXGLOVE_CONTROL_HELP = (
    "let Foxglove clients drive the base (implies --foxglove): Twists from the Teleop "
    "panel on /cmd_vel, services /omnican/recover, /omnican/stop, /omnican/reset_odometry, "
    "the limits as parameters; one client at a time; --no-foxglove-control keeps a "
    "config's [foxglove] control = true off (default: off)")


def add_foxglove_arguments(parser: argparse.ArgumentParser, control: bool = True) -> None:
    """--foxglove [HOST:]PORT and, for front ends that drive, --foxglove-control and
    --foxglove-allow-remote."""
    from omnican.live import FOXGLOVE_HELP, foxglove_address

    parser.add_argument("--foxglove", nargs="?", const="", type=foxglove_address,
                        metavar="[HOST:]PORT", help=FOXGLOVE_HELP)
    if control:
        parser.add_argument("--foxglove-control", action=argparse.BooleanOptionalAction,
                            default=None, help=FOXGLOVE_CONTROL_HELP)
        parser.add_argument("--foxglove-allow-remote", action="store_true", default=None,
                            help="allow --foxglove-control on a host other than loopback "
                                 "(anyone who reaches it can drive the robot)")
        parser.add_argument("--foxglove-token", metavar="TOKEN", default=None,
                            help="only a client that gives TOKEN (ws://HOST:PORT/?token=TOKEN) "
                                 "may drive; the others watch ([foxglove] token keeps it out "
                                 "of the process list)")
    parser.add_argument("--foxglove-origin", metavar="ORIGIN", action="append", default=[],
                        help="also let browsers on this web page connect (the Origin header, "
                             "e.g. http://localhost:8080; * any); default Foxglove's app and "
                             "desktop, and programs that send no Origin")


def foxglove_settings(args: argparse.Namespace, cfg: ChassisConfig) -> Any:
    """The live view's :class:`~omnican.live.FoxgloveSettings` from the config's
    [foxglove] table and the flags, or None when no view was asked for."""
    address = getattr(args, "foxglove", None)
    control = getattr(args, "foxglove_control", None)
    if address is None and not control:
        return None
    from omnican.live import resolve

    return resolve(cfg.foxglove, address, control=control,
                   allow_remote=getattr(args, "foxglove_allow_remote", None),
                   token=getattr(args, "foxglove_token", None),
                   origins=getattr(args, "foxglove_origin", None) or (),
                   origin=str(cfg.source) if cfg.source else "config")


def load(args: argparse.Namespace) -> ChassisConfig:
    """The config named by --config (or the demo base), with bus arguments applied."""
    from omnican.config import default_config, load_config

    path = getattr(args, "config", None)
    cfg = check_front_ends(load_config(path)) if path else default_config()
    overrides = bus_overrides(args)
    if overrides:
        cfg = cfg.with_bus(**{**(cfg.bus or {}), **overrides})
    return cfg


@dataclass
class Session:
    """The config a subcommand runs with, the simulated base under --sim, and the clock
    to open the base with (simulated time under --fast / --sim-speed)."""

    cfg: ChassisConfig
    sim: Any = None  # omnican.sim.SimulatedBase under --sim
    clock: Clock = REAL_TIME


@contextlib.contextmanager
def session(args: argparse.Namespace, **sim_options: Any) -> Iterator[Session]:
    """Resolve config and bus; under --sim, start simulated drives on a fresh virtual channel."""
    cfg = load(args)
    fast, speed = getattr(args, "fast", False), getattr(args, "sim_speed", None)
    if fast and speed is not None:
        raise UsageError("give --fast or --sim-speed, not both")
    if not getattr(args, "sim", False):
        if fast or speed is not None:
            raise UsageError("--fast and --sim-speed run simulated drives in simulated time: "
                             "add --sim")
        check_bus(cfg.bus)
        yield Session(cfg)
        return
    if bus_overrides(args):
        raise UsageError("--sim runs on its own virtual bus: drop the bus arguments, or use "
                         "'omnican sim' to serve simulated drives on a real interface")
    from omnican.sim import SimulatedBase

    clock = SimClock(speed=speed) if fast or speed is not None else REAL_TIME
    # The simulated bus stands for the configured one: its nominal bitrate, so that the
    # bus load (the dashboard's, /status.bus_load, diagnostics) is a share of it.
    cfg = cfg.with_bus(interface="virtual", channel=f"omnican-sim-{uuid.uuid4().hex[:8]}",
                       bitrate=sim_bitrate(cfg))
    # In real time the base's control loop runs the drives (omnican.io.stepped): they are
    # as steady as the loop beside a busy desktop, not threads that may fall behind it.
    with SimulatedBase.from_config(cfg, clock=clock, stepped=not clock.lockstep,
                                   **sim_options) as sim:
        yield Session(cfg, sim, clock)


#: The simulated bus's nominal bitrate when the config's [bus] gives none (the demo base):
#: the examples' 500 kbit/s.
SIM_BITRATE = 500_000


def sim_bitrate(cfg: ChassisConfig) -> int:
    """The nominal bitrate of ``--sim``'s bus: the config's ``[bus] bitrate``, else
    :data:`SIM_BITRATE`."""
    rate = (cfg.bus or {}).get("bitrate")
    return int(rate) if isinstance(rate, int) and not isinstance(rate, bool) and rate > 0 \
        else SIM_BITRATE


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


class ProgressBar:
    """A one-line progress display on stderr when it is a terminal and the work is long
    enough to want one; a ``progress(done_s, total_s, label)`` callback. It says how
    long is left on the wall clock (under --fast simulated time runs faster than it),
    once it has seen a second of progress, and redraws at most ten times a second."""

    def __init__(self, total_s: float, stream: Any = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() and total_s > 2.0
        self._clock = clock
        self._start: tuple[float, float] | None = None  # (wall clock, done_s) at first
        self._drawn = -math.inf
        self._width = 0

    def __call__(self, done_s: float, total_s: float, label: str) -> None:
        if not self.enabled:
            return
        now = self._clock()
        if self._start is None:
            self._start = (now, done_s)
        if now - self._drawn < 0.1 and done_s < total_s:
            return
        self._drawn = now
        frac = min(1.0, done_s / total_s) if total_s > 0 else 1.0
        bar = "=" * int(frac * 30)
        line = f"[{bar:<30}] {frac:4.0%} {label:<10}"
        wall, done = now - self._start[0], done_s - self._start[1]
        if wall >= 1.0 and done > 0 and done_s < total_s:
            line += f" {clock_time((total_s - done_s) * wall / done)} left"
        self.stream.write("\r" + line.ljust(self._width))
        self.stream.flush()
        self._width = len(line)

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\r" + " " * max(50, self._width) + "\r")
            self.stream.flush()


def clock_time(seconds: float) -> str:
    """``seconds`` as a clock shows a duration: ``0:42``, ``12:05``, ``3:10:00``."""
    whole = int(min(seconds, 359_999))  # 99:59:59
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


@contextlib.contextmanager
def progress_bar(total_s: float) -> Iterator[ProgressBar]:
    """A :class:`ProgressBar` that is cleared from the line when the block ends."""
    bar = ProgressBar(total_s)
    try:
        yield bar
    finally:
        bar.close()


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


def serve_lines(handle: Callable[[str], str | None], duration: float | None) -> None:
    """Feed stdin lines to ``handle`` (its reply is printed; None quits) until the duration
    ends or Ctrl-C; stdin closing (e.g. < /dev/null) keeps it running. Lines that arrive
    together (a script piping several commands) are each handled at once: stdin is read
    as bytes into a buffer of our own, never through Python's, which ``select`` cannot
    see into."""
    end = time.monotonic() + duration if duration else None
    stdin_open = not sys.stdin.closed
    fd = sys.stdin.fileno() if stdin_open else -1
    decoder = codecs.getincrementaldecoder(sys.stdin.encoding or "utf-8")("replace")
    pending = ""
    # A prompt for a person at a terminal (a script piping commands reads replies only).
    prompt = "> " if stdin_open and sys.stdin.isatty() else ""
    if prompt:
        print(prompt, end="", flush=True)
    try:
        while end is None or time.monotonic() < end:
            timeout = 0.2 if end is None else max(0.0, min(0.2, end - time.monotonic()))
            if not stdin_open:
                time.sleep(timeout)
                continue
            ready, _, _ = select.select([fd], [], [], timeout)
            if not ready:
                continue
            chunk = os.read(fd, 4096)
            if not chunk:  # closed: the last line may have had no end
                stdin_open = False
                pending += decoder.decode(b"", final=True)
                lines, pending = ([pending], "") if pending else ([], "")
            else:
                *lines, pending = (pending + decoder.decode(chunk)).split("\n")
            for line in lines:
                reply = handle(line + "\n")
                if reply is None:
                    return
                if reply:
                    print(reply, flush=True)
                if prompt:
                    print(prompt, end="", flush=True)
    except KeyboardInterrupt:
        pass
