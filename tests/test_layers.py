"""The layers of the package, read from its imports: data flows one way.

The order is the package's own (:mod:`omnican.layers`); these tests hold every module
to it, and the architecture page's table to the same order.
"""

from __future__ import annotations

import ast
import keyword
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

import omnican
from omnican.layers import (
    FACE,
    LAYERS,
    SHARED,
    UnlayeredModuleError,
    crossing,
    imports_in,
    layer_of,
)

PACKAGE = Path(omnican.__file__).resolve().parent


def modules() -> list[tuple[str, Path]]:
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        out.append((".".join(rel.parts), path))
    return out


def upward_imports() -> list[str]:
    problems = []
    for name, path in modules():
        for target in sorted(imports_in(path.read_text(), omnican._HOMES, str(path))):
            kind = crossing(name, target)
            if kind == "above":
                problems.append(f"omnican.{name} imports omnican.{target}, a layer above it")
            elif kind == "sibling":
                problems.append(f"omnican.{name} imports omnican.{target}, a sibling")
    return problems


#: Folders held free of import cycles, type-only ones (under TYPE_CHECKING) included: a
#: module that names its owner's type for a type checker is read with it all the same.
#: A small protocol of what the part needs of its owner breaks such a cycle. None: the
#: whole package (since issue 39: live/control and live/services were the last pair).
ACYCLIC: tuple[str, ...] | None = None


def submodule_imports(path: Path, known: set[str]) -> set[str]:
    """The modules of ``known`` that the module at ``path`` imports (under TYPE_CHECKING
    too): ``from omnican.chassis import realtime`` is omnican.chassis.realtime."""
    found = imports_in(path.read_text(), omnican._HOMES, str(path))
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and \
                node.module.startswith("omnican."):
            package = node.module.removeprefix("omnican.")
            subs = {f"{package}.{a.name}" for a in node.names} & known
            if subs and len(subs) == len(node.names):  # only submodules: not the package
                found.discard(package)
            found |= subs
    return found & known


def import_cycles(folders: tuple[str, ...] | None = ACYCLIC) -> list[str]:
    """The cycles among the modules of ``folders`` (``omnican.a -> omnican.b ->
    omnican.a``): each module's shortest way back to itself, but for modules a cycle
    already named holds."""
    paths = {name.removesuffix(".__init__"): path for name, path in modules()
             if folders is None or name.split(".")[0] in folders}
    graph = {name: submodule_imports(path, set(paths)) for name, path in paths.items()}
    cycles = []
    seen: set[str] = set()
    for start in sorted(graph):
        if start in seen:
            continue
        # The shortest way from start back to itself, if there is one.
        way: dict[str, str] = {}
        todo = [start]
        while todo and start not in way:
            here = todo.pop(0)
            for there in sorted(graph[here]):
                if there not in way:
                    way[there] = here
                    todo.append(there)
        if start not in way:
            continue
        path = [start]
        while len(path) == 1 or path[-1] != start:
            path.append(way[path[-1]])
        path.reverse()
        seen.update(path)
        cycles.append(" -> ".join(f"omnican.{m}" for m in path))
    return cycles


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


def test_no_import_cycle_in_the_package() -> None:
    cycles = import_cycles()
    assert not cycles, "\n".join(cycles)


def test_the_check_sees_a_type_only_cycle(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                          ) -> None:
    """The check itself: two modules of a folder that import each other, one of them only
    for a type checker, are named; a one-way import is not."""
    fake = tmp_path / "omnican"
    (fake / "io").mkdir(parents=True)
    (fake / "io" / "__init__.py").write_text("")
    (fake / "io" / "bus.py").write_text("from omnican.io.part import Part\n")
    (fake / "io" / "part.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
        "    from omnican.io.bus import Bus\n")
    (fake / "io" / "alone.py").write_text("from omnican.io.bus import Bus\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    assert import_cycles() == ["omnican.io.bus -> omnican.io.part -> omnican.io.bus"]


def test_the_public_names_are_one_table() -> None:
    """``__all__``, the lazy imports and the names type checkers see are one list."""
    assert set(omnican.__all__) == {"__version__", *omnican._HOMES}
    source = (PACKAGE / "__init__.py").read_text()
    [typing_block] = [node for node in ast.parse(source).body if isinstance(node, ast.If)
                      and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"]
    checking = {a.asname or a.name for node in ast.walk(typing_block)
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
    drawn = tuple(frozenset(name.strip("`").removesuffix(".py").rstrip("/")
                            for name in row.split("|")[2].replace(",", " ").split())
                  for row in rows)
    assert drawn == LAYERS


def test_the_layer_order_imports_nothing_but_the_standard_library() -> None:
    """tools/gen_docs_pictures.py reads the order with only the docs extra installed: the
    module that holds it must import nothing of the package, of the tests or of an
    extra."""
    source = (PACKAGE / "layers.py").read_text()
    assert imports_in(source, omnican._HOMES) == set()
    stdlib = set(sys.stdlib_module_names)
    tops = {a.name.split(".")[0] for node in ast.walk(ast.parse(source))
            if isinstance(node, ast.Import) for a in node.names}
    tops |= {node.module.split(".")[0] for node in ast.walk(ast.parse(source))
             if isinstance(node, ast.ImportFrom) and node.module}
    assert tops <= stdlib | {"__future__"}, tops - stdlib


# -- the order's properties ------------------------------------------------------------

NAMES = sorted(set().union(*LAYERS))
rest = st.lists(st.from_regex(r"[a-z_][a-z0-9_]{0,8}", fullmatch=True), max_size=3)


@given(st.sampled_from(NAMES), rest)
def test_a_module_is_in_the_layer_of_its_top_folder(top: str, tail: list[str]) -> None:
    rank, found = layer_of(".".join([top, *tail])) or (None, None)
    assert found == top
    assert rank is not None and top in LAYERS[rank]


@given(st.sampled_from(sorted(FACE)), rest)
def test_the_face_is_in_no_layer(top: str, tail: list[str]) -> None:
    assert layer_of(".".join([top, *tail])) is None


@given(st.from_regex(r"[a-z_][a-z0-9_]{0,12}", fullmatch=True))
def test_an_unknown_top_is_refused_by_name(top: str) -> None:
    if top in NAMES or top in FACE:
        return
    with pytest.raises(UnlayeredModuleError, match=f"omnican.{top} is in no layer"):
        layer_of(top)


@given(st.sampled_from(NAMES), st.sampled_from(NAMES))
def test_a_crossing_follows_the_ranks(a: str, b: str) -> None:
    ra, rb = layer_of(a), layer_of(b)
    assert ra is not None and rb is not None
    kind = crossing(f"{a}.x", f"{b}.y")
    if a == b:
        assert kind is None
    elif ra[0] < rb[0]:
        assert kind == "above"
    elif ra[0] == rb[0]:
        assert kind == "sibling"
    else:
        assert kind == "below"
    # one-way: an import that is fine one way is a problem the other way
    if kind == "below":
        assert crossing(f"{b}.y", f"{a}.x") == "above"


def test_every_layer_may_use_the_shared_modules() -> None:
    for layer in LAYERS[1:]:
        for name in layer:
            for shared in SHARED:
                assert crossing(name, shared) == "below"


module_path = st.lists(st.from_regex(r"[a-z][a-z0-9_]{0,8}", fullmatch=True)
                       .filter(lambda name: not keyword.iskeyword(name)),  # "in", "as"
                       min_size=1, max_size=3).map(".".join)


@given(st.lists(module_path, max_size=4), st.lists(module_path, max_size=4),
       st.sampled_from(sorted(omnican._HOMES)))
def test_every_form_of_import_is_read(plain: list[str], froms: list[str], public: str
                                      ) -> None:
    source = "\n".join(
        [f"import omnican.{m}" for m in plain]
        + [f"from omnican.{m} import thing" for m in froms]
        + ["import os", "from collections import abc",
           f"from omnican import {public}, core",
           "if TYPE_CHECKING:\n    from omnican.chassis import Chassis",
           "def f():\n    import omnican.sim.base as b"])
    assert imports_in(source, omnican._HOMES) == {
        *plain, *froms, omnican._HOMES[public], "core", "chassis", "sim.base"}
