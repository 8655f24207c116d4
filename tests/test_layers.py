"""The layers of the package, read from its imports: data flows one way.

A module may import from the layers below its own and from its own folder, never from a
layer above, and never from a sibling of its own layer (the command sources, recordings
and analyses know nothing of each other; neither do the front ends, below the CLI that
starts them). The order is written once, here, and drawn in docs/architecture.md.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

import omnican

PACKAGE = Path(omnican.__file__).resolve().parent

#: Lowest first. A set is one layer of siblings.
LAYERS: list[frozenset[str]] = [frozenset(s) for s in (
    {"errors", "clock", "extras", "log_throttle"},  # what every layer may use
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
    {"ros2", "live", "gamepad", "zenoh"},  # front ends
    {"cli"},             # the command line, which starts the others
)]
#: The package's public face: it may name any layer (lazily), and old names kept for a
#: release point at their new homes.
FACE = {"__init__", "__main__", "motion", "teleop_model"}


def layer_of(module: str) -> tuple[int, str] | None:
    """(rank, top folder or module) of ``omnican.<module...>``; None for the face."""
    top = module.split(".", maxsplit=1)[0]
    if top in FACE:
        return None
    for rank, layer in enumerate(LAYERS):
        if top in layer:
            return rank, top
    raise AssertionError(f"omnican.{top} is in no layer: add it to LAYERS (and to "
                         "docs/architecture.md)")


def imported(path: Path) -> set[str]:
    """The omnican modules ``path`` imports (below ``omnican.``), wherever the import is
    (under TYPE_CHECKING too: a type is a dependency a reader follows)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name.removeprefix("omnican.") for a in node.names
                      if a.name.startswith("omnican.")}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "omnican":
                for alias in node.names:
                    home = omnican._HOMES.get(alias.name)
                    if home is not None:
                        found.add(home)
                    elif (PACKAGE / alias.name).is_dir() or (
                            PACKAGE / f"{alias.name}.py").is_file():
                        found.add(alias.name)
            elif node.module.startswith("omnican."):
                found.add(node.module.removeprefix("omnican."))
    return found


def modules() -> list[tuple[str, Path]]:
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        out.append((".".join(rel.parts), path))
    return out


def upward_imports() -> list[str]:
    problems = []
    for name, path in modules():
        own = layer_of(name)
        if own is None:
            continue
        for target in sorted(imported(path)):
            theirs = layer_of(target)
            if theirs is None or theirs[1] == own[1]:
                continue
            if theirs[0] > own[0]:
                problems.append(f"omnican.{name} imports omnican.{target}, a layer above it")
            elif theirs[0] == own[0]:
                problems.append(f"omnican.{name} imports omnican.{target}, a sibling")
    return problems


def test_every_module_is_in_a_layer() -> None:
    for name, _ in modules():
        layer_of(name)


def test_no_module_imports_from_a_layer_above_its_own() -> None:
    problems = upward_imports()
    assert not problems, "\n".join(problems)


def test_the_check_sees_an_upward_import(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                         ) -> None:
    """The check itself: a pure module that imports the chassis is named."""
    fake = tmp_path / "omnican"
    (fake / "core").mkdir(parents=True)
    (fake / "core" / "bad.py").write_text("from omnican.chassis import Chassis\n"
                                          "from omnican import Twist\n")
    (fake / "chassis").mkdir()
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    assert upward_imports() == [
        "omnican.core.bad imports omnican.chassis, a layer above it"]


def test_the_public_names_are_one_table() -> None:
    """``__all__``, the lazy imports and the names type checkers see are one list."""
    assert set(omnican.__all__) == {"__version__", *omnican._HOMES}
    source = (PACKAGE / "__init__.py").read_text()
    checking = {a.asname or a.name for node in ast.walk(ast.parse(source))
                if isinstance(node, ast.ImportFrom) for a in node.names
                if node.module and node.module.startswith("omnican.")}
    assert checking == set(omnican._HOMES)
    for name, home in omnican._HOMES.items():
        assert getattr(omnican, name).__module__.startswith(f"omnican.{home}") or name in {
            "WHEEL_EDS"}, name


def test_the_architecture_page_draws_the_same_layers() -> None:
    """docs/architecture.md's table of layers names the folders of LAYERS, in order."""
    page = (PACKAGE.parent / "docs" / "architecture.md").read_text()
    rows = page.split("| layer (lowest first) |", 1)[1].split("\n\n", 1)[0].splitlines()[2:]
    drawn = [frozenset(name.strip("`").removesuffix(".py").rstrip("/")
                       for name in row.split("|")[2].replace(",", " ").split())
             for row in rows]
    assert drawn == LAYERS
