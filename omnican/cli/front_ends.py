"""The front ends a command runs, each a plug-in of the registry
(:data:`omnican.layers.FRONT_ENDS`, :class:`omnican.front_end.FrontEnd`): a command that
runs them beside what it does loops over them here, for their flags, their settings from
the flags and the config, their slow set-up, and running them beside its base (or its
simulator) until it ends. It names none of them.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from omnican.front_end import Announce, FrontEnd, Where, plugin, plugins

if TYPE_CHECKING:
    from omnican.config import ChassisConfig


def add_arguments(parser: argparse.ArgumentParser, where: Where,
                  inputs: Callable[[argparse.ArgumentParser], None] | None = None) -> None:
    """Every front end's flags for a command that runs them ``where``: first those of the
    front ends that only watch unless told to drive, then the command's own local
    ``inputs`` (teleop's gamepad), then the others'."""
    front_ends = plugins()
    for front_end in front_ends:
        if front_end.watches:
            front_end.add_arguments(parser, where)
    if inputs is not None:
        inputs(parser)
    for front_end in front_ends:
        if not front_end.watches:
            front_end.add_arguments(parser, where)


def asked(args: argparse.Namespace) -> bool:
    """Whether the flags alone ask for a front end."""
    return any(front_end.asked(args) for front_end in plugins())


def motion_refused(args: argparse.Namespace) -> str | None:
    """Why the flags alone refuse a scripted motion beside a front end (None: they do
    not)."""
    return next((why for front_end in plugins()
                 if (why := front_end.motion_refused(args)) is not None), None)


def drive_flags() -> tuple[list[str], list[str]]:
    """(the flags that let a front end drive, their front ends' titles), in the
    registry's order, for a line that lists the ways to drive."""
    flags = [(f.drive_flag, f.title) for f in plugins() if f.drive_flag is not None]
    return [flag for flag, _ in flags], [title for _, title in flags]


def from_args(args: argparse.Namespace, cfg: ChassisConfig, where: Where,
              graph: Mapping[str, Any] | None = None) -> list[FrontEnd]:
    """The front ends the flags and the config ask for, each checked (ConfigError, one
    line) before any drive comes up; in the registry's order."""
    running = []
    for front_end in plugins():
        run = front_end.from_args(args, cfg, where, graph)
        if run is not None:
            running.append(run)
    return running


def check_tables(cfg: ChassisConfig) -> ChassisConfig:
    """The front ends' tables of ``cfg``, checked as the front ends check them (so every
    command refuses what ``omnican ros2`` would: ``[ros2] domain_id = 999``). The
    library checks only their keys and types."""
    origin = str(cfg.source) if cfg.source else "config"
    for name, table in cfg.front_ends.items():
        plugin(name).check_table(table, cfg, origin)
    return cfg


def prepare(front_ends: Sequence[FrontEnd], cfg: ChassisConfig) -> None:
    """Each one's slow set-up, before the base's control loop runs."""
    for front_end in front_ends:
        front_end.prepare(cfg)


@contextlib.contextmanager
def attached(front_ends: Sequence[FrontEnd], base: Any, sim: Any = None,
             announce: Announce | None = None) -> Iterator[Sequence[FrontEnd]]:
    """Each of ``front_ends`` running beside ``base`` (None: beside the simulator ``sim``
    alone) while the block runs, in their order; closed in the other order when it
    ends (whatever ends it)."""
    with contextlib.ExitStack() as stack:
        for front_end in front_ends:
            stack.callback(front_end.close)
            front_end.attach(base, sim, announce)
        yield front_ends


def headlines(front_ends: Sequence[FrontEnd]) -> str:
    """What a title line adds of each front end that runs: `` - Foxglove ws://... -
    Zenoh /omnican``."""
    return "".join(f" - {front_end.headline}" for front_end in front_ends)
