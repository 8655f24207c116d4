"""The layers of the package, lowest first: the one order its imports follow.

A module may import from the layers below its own and from its own folder, never from a
layer above, and never from a sibling of its own layer (the command sources, recordings
and analyses know nothing of each other; neither do the front ends, below the command
line that starts them). The order is written once, here; ``tests/test_layers.py`` holds
every module of the package to it and the docs build draws it (docs/architecture.md).

The front ends are plug-ins: :data:`FRONT_ENDS` is their registry, one line each (as
python-can's ``BACKENDS``), and their folders are the front ends' layer. Nothing of a
front end is imported until it is asked for (:mod:`omnican.front_end`).

Pure: it reads no file. A caller hands it a module's source text.
"""

from __future__ import annotations

import ast
from collections.abc import Mapping
from typing import Literal, NamedTuple


class FrontEndEntry(NamedTuple):
    """A front end's line in the registry: its plug-in (``"omnican.<folder>.<module>:
    <class>"``, a subclass of :class:`omnican.front_end.FrontEnd`), the extra it needs
    (:mod:`omnican.extras`), and its own subcommands (command, one-line help; the
    command's module is ``omnican.cli.<command>``), which ``omnican --help`` lists
    without importing anything of it. ``foreign_threads``: the modules of its libraries
    that call into Python from threads of their own; a process that imported one ends
    past the interpreter's finalization (:func:`omnican.cli.main`). ``imu_topic``: it
    reads an IMU's ``sensor_msgs/Imu`` topic into the base when the config's ``[imu]``
    names it as the ``source``."""

    plugin: str
    extra: str | None = None
    commands: tuple[tuple[str, str], ...] = ()
    foreign_threads: tuple[str, ...] = ()
    imu_topic: bool = False

    @property
    def folder(self) -> str:
        """Its folder under ``omnican/`` (a member of the front ends' layer)."""
        return self.plugin.split(":", 1)[0].split(".")[1]


#: The front ends, by name (its config table's name too: ``[zenoh]``), in the order a
#: command offers them. A new front end is its folder and one line here.
FRONT_ENDS: dict[str, FrontEndEntry] = {
    "ros2": FrontEndEntry("omnican.ros2.front_end:Ros2FrontEnd", "ros2", (
        ("ros2", "run the base as a ROS 2 node (DDS; no ROS install)"),), imu_topic=True),
    "foxglove": FrontEndEntry("omnican.live.front_end:FoxgloveFrontEnd", "foxglove"),
    "zenoh": FrontEndEntry("omnican.zenoh.front_end:ZenohFrontEnd", "zenoh", (
        ("zenoh", "run the base on Zenoh (rmw_zenoh's format)"),
        ("fleet", "every base on the Zenoh network: view, stop, recover")),
        foreign_threads=("zenoh",), imu_topic=True),
}

#: Lowest first. A set is one layer of siblings.
LAYERS: tuple[frozenset[str], ...] = tuple(frozenset(s) for s in (
    {"errors", "clock", "extras", "log_throttle", "layers", "lazy"},  # what every layer may use
    {"core"},            # pure robot maths
    {"protocol"},        # pure CANopen/CAN
    {"config"},          # schema, model, parsing
    {"plan"},            # this robot on the wire, worked out offline
    {"io"},              # the only owners of sockets and the Notifier
    {"drive"},           # one CiA 402 node
    {"chassis"},         # the base and its control cycle
    {"telemetry"},       # what front ends publish, built once
    {"command", "record", "analysis"},
    {"sim"},             # simulated drives and base
    {"front_end"},       # what a front end is (the plug-ins' base class)
    {"gamepad", *(entry.folder for entry in FRONT_ENDS.values())},  # front ends
    {"cli"},             # the command line, which starts the others
))

#: What every layer may use (the lowest layer).
SHARED: frozenset[str] = LAYERS[0]

#: The package's public face: it may name any layer (lazily), and old names kept for a
#: release point at their new homes.
FACE: frozenset[str] = frozenset({"__init__", "__main__", "motion", "teleop_model",
                                  "slamware"})

Crossing = Literal["below", "above", "sibling"]


class UnlayeredModuleError(ValueError):
    """A module of the package that no layer holds."""


def layer_of(module: str) -> tuple[int, str] | None:
    """(rank, top folder or module) of ``omnican.<module>`` (given without ``omnican.``);
    None for the public face.

    Raises :class:`UnlayeredModuleError` for a top folder or module no layer holds.
    """
    top = module.split(".", maxsplit=1)[0]
    if top in FACE:
        return None
    for rank, layer in enumerate(LAYERS):
        if top in layer:
            return rank, top
    raise UnlayeredModuleError(f"omnican.{top} is in no layer: add it to omnican/layers.py "
                               "(and to docs/architecture.md's table)")


def crossing(module: str, target: str) -> Crossing | None:
    """How an import of ``omnican.<target>`` from ``omnican.<module>`` crosses the layers:
    None where either is the face or both are in one folder."""
    own, theirs = layer_of(module), layer_of(target)
    if own is None or theirs is None or own[1] == theirs[1]:
        return None
    if theirs[0] > own[0]:
        return "above"
    return "sibling" if theirs[0] == own[0] else "below"


def _known(name: str) -> bool:
    return name in FACE or any(name in layer for layer in LAYERS)


def imports_in(source: str, homes: Mapping[str, str], filename: str = "<source>") -> set[str]:
    """The omnican modules ``source`` imports (below ``omnican.``), wherever the import is
    (under TYPE_CHECKING too: a type is a dependency a reader follows).

    ``homes``: the package's public names and the module each lives in
    (``omnican._HOMES``), for ``from omnican import Name``. Relative imports are not read
    (the package has none).
    """
    found: set[str] = set()
    for node in ast.walk(ast.parse(source, filename)):
        if isinstance(node, ast.Import):
            found |= {a.name.removeprefix("omnican.") for a in node.names
                      if a.name.startswith("omnican.")}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "omnican":
                for alias in node.names:
                    home = homes.get(alias.name)
                    if home is not None:
                        found.add(home)
                    elif _known(alias.name):
                        found.add(alias.name)
            elif node.module.startswith("omnican."):
                found.add(node.module.removeprefix("omnican."))
    return found
