"""The live view in Foxglove as a front end's plug-in (:class:`omnican.front_end.FrontEnd`):
its flags (``--foxglove [HOST:]PORT`` and, where it may drive, ``--foxglove-control``,
``--foxglove-allow-remote``, ``--foxglove-token``, ``--foxglove-origin``), its settings from
them and the ``[foxglove]`` table (:mod:`omnican.live.table`), and the view beside a base
or a simulator alone (:func:`omnican.live.view.watch`).

Importing it imports neither the SDK nor the view: what it needs of them it imports
when it runs.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from omnican.front_end import Announce, FrontEnd, Where
from omnican.live.settings import FOXGLOVE_HELP, FoxgloveSettings, foxglove_address
from omnican.live.table import TABLE

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.config import ChassisConfig
    from omnican.telemetry.attach import Simulator

CONTROL_HELP = (
    "let Foxglove clients drive the base (implies --foxglove): Twists from the Teleop "
    "panel on /cmd_vel, services /omnican/recover, /omnican/stop, /omnican/reset_odometry, "
    "the limits as parameters; one client at a time; --no-foxglove-control keeps a "
    "config's [foxglove] control = true off (default: off)")
#: ``--foxglove`` beside a simulator alone (omnican sim).
TRUTH_HELP = ("serve the ground truth and the bus to Foxglove on [HOST:]PORT (default "
              "127.0.0.1:8765; loopback unless a host is given)")
#: Why a scripted motion cannot run beside Foxglove's control.
BOTH_DRIVE = ("--foxglove-control takes the motion from Foxglove: give no motion, only "
              "--duration (or --no-foxglove-control to drive the motion given)")


def add_foxglove_arguments(parser: argparse.ArgumentParser, control: bool = True) -> None:
    """--foxglove [HOST:]PORT and, for front ends that drive, --foxglove-control and
    --foxglove-allow-remote."""
    parser.add_argument("--foxglove", nargs="?", const="", type=foxglove_address,
                        metavar="[HOST:]PORT", help=FOXGLOVE_HELP)
    if control:
        parser.add_argument("--foxglove-control", action=argparse.BooleanOptionalAction,
                            default=None, help=CONTROL_HELP)
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


def foxglove_settings(args: argparse.Namespace, cfg: ChassisConfig) -> FoxgloveSettings | None:
    """The live view's :class:`~omnican.live.FoxgloveSettings` from the config's
    [foxglove] table and the flags, or None when no view was asked for."""
    address = getattr(args, "foxglove", None)
    control = getattr(args, "foxglove_control", None)
    if address is None and not control:
        return None
    from omnican.live.settings import resolve

    return resolve(cfg.front_ends.get("foxglove"), address, control=control,
                   allow_remote=getattr(args, "foxglove_allow_remote", None),
                   token=getattr(args, "foxglove_token", None),
                   origins=getattr(args, "foxglove_origin", None) or (),
                   origin=str(cfg.source) if cfg.source else "config")


class FoxgloveFrontEnd(FrontEnd):
    """A Foxglove live view: watches, and with control on its clients may drive."""

    name = "foxglove"
    title = "Foxglove"
    table = TABLE
    drive_flag = "--foxglove-control"
    watches = True

    def __init__(self, settings: FoxgloveSettings) -> None:
        super().__init__(settings)
        self.view: Any = None  # the LiveView once attached

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser, where: Where) -> None:
        if where == "sim":  # the simulator's truth and bus; no base to drive
            parser.add_argument("--foxglove", nargs="?", const="", type=foxglove_address,
                                metavar="[HOST:]PORT", help=TRUTH_HELP)
        else:
            add_foxglove_arguments(parser)

    @classmethod
    def asked(cls, args: argparse.Namespace) -> bool:
        return (getattr(args, "foxglove", None) is not None
                or bool(getattr(args, "foxglove_control", None)))

    @classmethod
    def motion_refused(cls, args: argparse.Namespace) -> str | None:
        return BOTH_DRIVE if getattr(args, "foxglove_control", None) else None

    @classmethod
    def from_args(cls, args: argparse.Namespace, cfg: ChassisConfig, where: Where,
                  graph: Mapping[str, Any] | None = None) -> FoxgloveFrontEnd | None:
        if where != "sim":
            settings = foxglove_settings(args, cfg)
            return None if settings is None else cls(settings)
        address = getattr(args, "foxglove", None)
        if address is None:
            return None
        from omnican.errors import ConfigError
        from omnican.live.settings import parse_address

        try:
            host, port = parse_address(address)
        except ValueError as exc:
            raise ConfigError(f"--foxglove: {exc}") from None
        return cls(FoxgloveSettings(host=host, port=port))

    @classmethod
    def check_table(cls, table: Any, cfg: ChassisConfig, origin: str) -> None:
        from omnican.live.settings import resolve

        resolve(table, None, origin=origin, check_sdk=False)

    @property
    def drives(self) -> bool:
        return bool(self.settings.control)

    def motion_problem(self) -> str | None:
        return BOTH_DRIVE if self.settings.control else None

    def lockstep_problem(self) -> str | None:
        return ("--foxglove-control drives in real time: drop --fast and --sim-speed"
                if self.settings.control else None)

    def prepare(self, cfg: ChassisConfig) -> None:
        from omnican.live.view import prepare

        prepare(cfg)

    def _attach(self, stack: contextlib.ExitStack, base: Chassis | None,
                sim: Simulator | None, announce: Announce) -> None:
        from omnican.live.view import watch

        self.view = stack.enter_context(watch(base, sim, self.settings, announce=announce))

    @property
    def headline(self) -> str:
        control = " (control on)" if self.settings.control else ""
        return f"Foxglove {self.view.url}{control}" if self.view is not None else self.title
