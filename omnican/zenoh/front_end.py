"""The Zenoh front end as a plug-in (:class:`omnican.front_end.FrontEnd`): ``--zenoh``
beside a base puts it on Zenoh in rmw_zenoh's format (the bridge: telemetry out, cmd_vel
in, the services: :mod:`omnican.zenoh.bridge`), beside a simulator alone it publishes
the simulator's true pose (:mod:`omnican.zenoh.simulator`). Its table is ``[zenoh]``
(:mod:`omnican.zenoh.table`), its flags :mod:`omnican.zenoh.arguments`'.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from omnican.front_end import Announce, FrontEnd, Where
from omnican.zenoh.arguments import TRUTH_HELP, add_zenoh_arguments, front_end_settings
from omnican.zenoh.table import TABLE

if TYPE_CHECKING:
    from omnican.chassis import Chassis
    from omnican.config import ChassisConfig
    from omnican.telemetry.attach import Simulator
    from omnican.zenoh.settings import ZenohSettings


class ZenohFrontEnd(FrontEnd):
    """The base on Zenoh (beside a base), or the simulator's truth (beside a simulator
    alone: ``truth_only``)."""

    name = "zenoh"
    title = "Zenoh"
    table = TABLE
    drive_flag = "--zenoh"

    def __init__(self, settings: ZenohSettings, truth_only: bool = False) -> None:
        super().__init__(settings)
        self.truth_only = truth_only
        #: the bridge (or the truth's publisher) once attached
        self.bridge: Any = None

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser, where: Where) -> None:
        if where == "sim":
            add_zenoh_arguments(parser, commands=False, what=TRUTH_HELP)
        else:  # beside a ROS 2 node, its graph flags serve both
            add_zenoh_arguments(parser, graph=where != "node")

    @classmethod
    def asked(cls, args: argparse.Namespace) -> bool:
        return bool(getattr(args, "zenoh", None))

    @classmethod
    def from_args(cls, args: argparse.Namespace, cfg: ChassisConfig, where: Where,
                  graph: Mapping[str, Any] | None = None) -> ZenohFrontEnd | None:
        settings = front_end_settings(args, cfg, graph)
        return None if settings is None else cls(settings, truth_only=where == "sim")

    @classmethod
    def check_table(cls, table: Any, cfg: ChassisConfig, origin: str) -> None:
        from omnican.zenoh.settings import from_table

        from_table(table, origin)

    @property
    def drives(self) -> bool:
        return not self.truth_only

    def lockstep_problem(self) -> str | None:
        return "--zenoh runs in real time: drop --fast and --sim-speed"

    def _attach(self, stack: contextlib.ExitStack, base: Chassis | None,
                sim: Simulator | None, announce: Announce) -> None:
        if base is None:
            self.bridge = stack.enter_context(zenoh_truth(self.settings, sim, announce))
        else:
            self.bridge = stack.enter_context(zenoh_front_end(self.settings, base, sim,
                                                              announce))

    @property
    def headline(self) -> str:
        return f"Zenoh {self.settings.node_fq_name}"


@contextlib.contextmanager
def zenoh_front_end(settings: ZenohSettings | None, base: Chassis, sim: Any = None,
                    announce: Callable[[str], None] | None = None) -> Iterator[Any]:
    """The base on Zenoh while the block runs (yields the
    :class:`~omnican.zenoh.bridge.ZenohBridge`; None and nothing done without
    ``settings``): a session opened as the settings say, the bridge on it (``sim``: the
    simulator the base runs against), its one startup line to ``announce``; the bridge,
    then the session closed at the end."""
    if settings is None:
        yield None
        return
    from omnican.zenoh.bridge import ZenohBridge, open_session

    with contextlib.closing(open_session(settings)) as session, \
            ZenohBridge(base, settings, session, sim=sim) as bridge:
        if announce is not None:
            out = ", ".join(pub.name for pub in bridge.publishers.values())
            announce(f"{node_line(bridge)}: in {bridge.cmd_topic}; out {out}")
        yield bridge


@contextlib.contextmanager
def zenoh_truth(settings: ZenohSettings | None, sim: Any,
                announce: Callable[[str], None] | None = None) -> Iterator[Any]:
    """``omnican sim --zenoh``: the simulator's true pose on Zenoh, from the node
    ``<node name>_sim``, while the block runs (None and nothing done without
    ``settings``); its one startup line to ``announce``."""
    if settings is None:
        yield None
        return
    from omnican.zenoh.bridge import open_session
    from omnican.zenoh.simulator import publish_truth

    settings = replace(settings, node_name=f"{settings.node_name}_sim")
    with contextlib.closing(open_session(settings)) as session, \
            publish_truth(sim, settings, session) as truth:
        if announce is not None:
            announce(f"{node_line(truth)}: out {truth.publisher.name} "
                     f"{truth.rate_hz:g} Hz")
        yield truth


def node_line(front: Any) -> str:
    """``Zenoh node /robot1/omnican on domain 0 (session ..., peer; connect: ...;
    multicast off)``: the first line a Zenoh front end says."""
    s = front.settings
    node = s.node_fq_name
    where = ", ".join(s.connect) or "no router given"
    who = s.who
    secured = f"mTLS as {who}" if who is not None else "no credentials"
    return (f"Zenoh node {node} on domain {s.domain_id} (session {front.node.session_id}, "
            f"{s.mode}; connect: {where}; multicast {'on' if s.multicast else 'off'}; "
            f"{secured})")
