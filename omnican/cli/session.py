"""What a subcommand runs with: the config (``--config``, else the demo base), the bus
(python-can's flags over the config's ``[bus]``), the simulated drives and the clock of
``--sim`` (``--fast``, ``--sim-speed``), and ``--record FILE``; the base opened on them,
with the simulator's ground truth in its telemetry (:meth:`Session.open_base`).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import logging
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from omnican.cli.common import UsageError, positive_float
from omnican.clock import REAL_TIME, Clock, SimClock

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.config import ChassisConfig
    from omnican.record.recording import FileRecording

_BUS_KEYS = ("channel", "interface", "bitrate", "fd", "data_bitrate", "timing")


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


def load(args: argparse.Namespace) -> ChassisConfig:
    """The config named by --config (or the demo base), with bus arguments applied."""
    from omnican.cli.front_ends import check_tables
    from omnican.config import default_config, load_config

    path = getattr(args, "config", None)
    cfg = check_tables(load_config(path)) if path else default_config()
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
    def open_base(self, cfg: ChassisConfig | None = None, record: str | None = None
                  ) -> Iterator[Chassis]:
        """The base, open on ``cfg`` (default the session's) in the session's clock while
        the block runs, recording to ``record`` (``--record FILE``) from its first frame;
        under --sim the simulator's ground truth in its telemetry, for every front end
        and recording (:func:`omnican.telemetry.attach.add_truth`)."""
        from omnican.chassis import Chassis
        from omnican.telemetry.attach import add_truth

        with Chassis.open(cfg or self.cfg, record=recording(record),
                          clock=self.clock) as base:
            add_truth(base, self.sim)
            yield base


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
