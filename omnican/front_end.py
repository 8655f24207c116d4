"""What a front end is: a plug-in the command line runs beside a base (or beside a
simulator alone), found by name in the front ends' registry
(:data:`omnican.layers.FRONT_ENDS`, one line each).

A front end's plug-in is a subclass of :class:`FrontEnd` in its own folder. The class
says what the command line offers of it (:meth:`~FrontEnd.add_arguments`) and which
config table it reads (:attr:`~FrontEnd.table`); an instance is one run of it, made from
the flags and the config (:meth:`~FrontEnd.from_args`), attached to a base and its
simulator (:meth:`~FrontEnd.attach`) and closed once (:meth:`~FrontEnd.close`, or the end
of a ``with`` block). The base class owns that lifecycle, as python-can's ``BusABC``
does; a front end fills the narrow hooks (:meth:`~FrontEnd._attach` above all).

What a front end shows it takes from the base's telemetry
(:func:`omnican.telemetry.attach.feed_of`); it commands the base through a command source
of its own (:meth:`omnican.chassis.Chassis.command_source`), so that it shares the base
with the others by construction. The simulator's ground truth is in that telemetry
already when a base runs beside one: a front end wires nothing of it.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from omnican.config.front_ends import plugin as load_plugin
from omnican.layers import FRONT_ENDS, FrontEndEntry

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.config import ChassisConfig
    from omnican.config.front_ends import TableSpec
    from omnican.telemetry.attach import Simulator

#: Where a command runs its front ends: ``"base"`` beside a base it drives (teleop,
#: drive), ``"node"`` beside a base that is a ROS 2 node of its own (omnican ros2: its
#: graph flags serve the others too), ``"sim"`` beside a simulator alone (omnican sim).
Where = Literal["base", "node", "sim"]

Announce = Callable[[str], None]


class FrontEnd:
    """One front end (see the module docstring). ``settings``: what this run of it was
    told, its own type."""

    #: Its name in the registry, and its config table's (``[zenoh]``).
    name: ClassVar[str] = ""
    #: How a line names it ("Foxglove").
    title: ClassVar[str] = ""
    #: Its config table: keys, dataclass, checks (None: it reads none).
    table: ClassVar[TableSpec | None] = None
    #: The flag that lets it drive the base, for a line that lists the ways to (None: it
    #: never drives).
    drive_flag: ClassVar[str | None] = None
    #: It only watches unless told to drive: a command offers its flags before its own
    #: local inputs (teleop's --gamepad), the other front ends' after.
    watches: ClassVar[bool] = False

    def __init__(self, settings: Any) -> None:
        self.settings = settings
        self._stack = contextlib.ExitStack()
        self._attached = False
        self._closed = False

    # ------------------------------------------------------------ the command line

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser, where: Where) -> None:
        """Its flags on a command that runs front ends ``where``; nothing (the default):
        not offered there."""

    @classmethod
    def asked(cls, args: argparse.Namespace) -> bool:
        """Whether the flags alone ask for it (its config table may too)."""
        return False

    @classmethod
    def motion_refused(cls, args: argparse.Namespace) -> str | None:
        """Why a scripted motion (``omnican drive``) cannot run beside it, as its flags
        alone say (None: it can)."""
        return None

    @classmethod
    def from_args(cls, args: argparse.Namespace, cfg: ChassisConfig, where: Where,
                  graph: Mapping[str, Any] | None = None) -> FrontEnd | None:
        """A run of it as the flags and the config say (None: not asked for), checked
        now, before any drive comes up: a missing extra or a bad value is a ConfigError
        (one line, exit 2). ``graph``: where the command's own ROS 2 node sits
        (namespace, node name, domain, cmd_vel type), for a front end that joins that
        graph unless its table says otherwise."""
        return None

    @classmethod
    def check_table(cls, table: Any, cfg: ChassisConfig, origin: str) -> None:
        """Its config table, checked as a run of it would check it (every command that
        reads a config refuses what it would refuse)."""

    # ------------------------------------------------------------ one run

    @property
    def drives(self) -> bool:
        """It may command the base (its clients, its publishers)."""
        return False

    def motion_problem(self) -> str | None:
        """Why a scripted motion cannot run beside this run of it (None: it can)."""
        return None

    def lockstep_problem(self) -> str | None:
        """Why it cannot run in simulated time (``--fast``; None: it can)."""
        return None

    def prepare(self, cfg: ChassisConfig) -> None:
        """Its slow set-up, done before the base's control loop runs (optional)."""

    def attach(self, base: Chassis | None, sim: Simulator | None = None,
               announce: Announce | None = None) -> FrontEnd:
        """Runs it beside ``base`` (None: beside the simulator ``sim`` alone) until
        :meth:`close`; its startup lines go to ``announce``. Returns itself."""
        if self._attached or self._closed:
            raise RuntimeError(f"the {self.name} front end is attached already or closed")
        self._attached = True
        try:
            self._attach(self._stack, base, sim, announce or _quiet)
        except BaseException:
            self.close()
            raise
        return self

    def _attach(self, stack: contextlib.ExitStack, base: Chassis | None,
                sim: Simulator | None, announce: Announce) -> None:
        """The hook :meth:`attach` calls: start it, entering what it must close into
        ``stack`` (closed by :meth:`close`, last in first out)."""
        raise NotImplementedError

    @property
    def headline(self) -> str:
        """What a title line says of it once attached ("Zenoh /robot1/omnican")."""
        return self.title

    def close(self) -> None:
        """Stops it and frees what it holds; a second call does nothing."""
        if self._closed:
            return
        self._closed = True
        self._stack.close()

    def __enter__(self) -> FrontEnd:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _quiet(text: str) -> None:
    """An announce that says nothing."""


def plugin(name: str) -> type[FrontEnd]:
    """The plug-in class of the front end registered as ``name``, imported now."""
    found: type[FrontEnd] = load_plugin(name)
    return found


def plugins() -> list[type[FrontEnd]]:
    """Every registered front end's plug-in class, in the registry's order."""
    return [plugin(name) for name in FRONT_ENDS]


@contextlib.contextmanager
def registered(name: str, entry: FrontEndEntry) -> Any:
    """The front end ``entry`` registered as ``name`` while the block runs (a front end
    that is not part of the package: a test's, a program's own)."""
    if name in FRONT_ENDS:
        raise ValueError(f"a front end named {name!r} is registered already")
    FRONT_ENDS[name] = entry
    try:
        yield entry
    finally:
        del FRONT_ENDS[name]
