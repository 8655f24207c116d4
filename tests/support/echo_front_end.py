"""A whole front end, as a newcomer writes one (docs/front-ends.md): copied into a folder
of its own (``omnican/echo/front_end.py``) it needs one line in the registry
(``omnican/layers.py``'s ``FRONT_ENDS``); the tests register it at run time instead.

It counts the odometry of the base's telemetry and, when told (``--echo-stop-after N``
or its table's ``stop_after``), stops the base after that many messages: it takes what
it shows from the telemetry and commands the base through a command source of its own.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omnican.config import ChassisConfig, FrontEndTable, Key, TableSpec
from omnican.config.reader import Reader
from omnican.front_end import Announce, FrontEnd, Where
from omnican.telemetry.attach import feed_of

#: Its table, ``[echo]``: its keys (README's reference would list them).
KEYS = {"stop_after": Key((int,), None, "stop the base after this many /odom messages",
                          range=(1, 1_000_000))}


@dataclass(frozen=True)
class EchoTable(FrontEndTable):
    stop_after: int | None = None


def read(r: Reader, t: dict[str, Any], given: frozenset[str],
         base_dir: Path | None) -> EchoTable:
    return EchoTable(**t)


class EchoFrontEnd(FrontEnd):
    """Counts ``/odom``; stops the base after ``settings`` of them (None: never)."""

    name = "echo"
    title = "Echo"
    table = TableSpec(KEYS, read)
    drive_flag = "--echo-stop-after"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser, where: Where) -> None:
        if where == "base":
            parser.add_argument("--echo", action="store_true", help="count the odometry")
            parser.add_argument("--echo-stop-after", type=int, metavar="N",
                                help="stop the base after N odometry messages")

    @classmethod
    def asked(cls, args: argparse.Namespace) -> bool:
        return bool(getattr(args, "echo", False) or getattr(args, "echo_stop_after", None))

    @classmethod
    def from_args(cls, args: argparse.Namespace, cfg: ChassisConfig, where: Where,
                  graph: Mapping[str, Any] | None = None) -> EchoFrontEnd | None:
        table = cfg.front_ends.get("echo")
        stop_after = getattr(args, "echo_stop_after", None) or (
            table.stop_after if isinstance(table, EchoTable) else None)
        if not (cls.asked(args) or table is not None):
            return None
        return cls(stop_after)

    def __init__(self, settings: int | None) -> None:
        super().__init__(settings)
        self.count = 0
        self.stopped = False

    @property
    def drives(self) -> bool:
        return self.settings is not None

    def _attach(self, stack: contextlib.ExitStack, base: Any, sim: Any,
                announce: Announce) -> None:
        self.source = base.command_source("echo")
        feed = feed_of(base)
        feed.add(self)
        stack.callback(feed.remove, self)
        announce(f"Echo: counting /odom; stop after {self.settings}")

    @property
    def headline(self) -> str:
        return f"Echo {self.count} /odom"

    # ------------------------------------------------------------ a telemetry sink

    def wants(self, topic: str) -> bool:
        return topic == "/odom"

    def publish(self, messages: list[Any]) -> None:
        self.count += sum(1 for m in messages if m.topic == "/odom")
        if self.settings is not None and self.count >= self.settings and not self.stopped:
            self.stopped = True
            self.source.stop()
