"""A front end is its own folder plus a few files elsewhere: its extra, its registry
line and its own subcommands (issue 39). Counted from the code, for every registered
front end: the package files outside its folder that name it in code.

A file names a front end in code when it imports a module of its folder, when an
identifier (a name, an attribute, a function's, class's or argument's name, a keyword)
contains the front end's name, or when a string that is not a docstring and holds no
space (a key, a flag, a table's, an extra's or a module's name; not a sentence of help
or of an error) contains its name or its package (``omnican.live``). Comments and
docstrings are prose. The ROS 2 message format, which every front end speaks (CDR types
with ``ros2msg`` schemas, rmw_zenoh's ``@ros2_lv`` tokens), shares its name with the
ROS 2 front end and is not it: :data:`FORMAT` lists its names.

A subcommand of its own in several modules (a package, ``omnican/cli/<command>/``) counts
once. ``python -m tests.test_front_end_files [ROOT]`` prints the files for each front end.
"""

from __future__ import annotations

import ast
import functools
import sys
from pathlib import Path

import omnican
from omnican.layers import FRONT_ENDS, imports_in

ROOT = Path(omnican.__file__).resolve().parents[1]

#: The most package files outside its folder that may name a front end.
TARGET = 4

#: The names of the ROS 2 message format (not of the ROS 2 front end): telemetry's kind of
#: message (``ROS2 = "ros2"``, MCAP's profile too), rosbags' type store, the schemas'
#: encoding, rmw_zenoh's liveliness key space.
FORMAT = frozenset({"ROS2", "ROS2_JAZZY", "ros2msg", "@ros2_lv"})


def _words(source: str) -> tuple[list[str], set[str]]:
    """The identifiers and the one-word strings of ``source`` (not its docstrings, not
    the strings the format's own names are given), and the modules it imports."""
    tree = ast.parse(source)
    skip: set[int] = set()
    nodes = list(ast.walk(tree))
    for node in nodes:
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                             ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                skip.add(id(first.value))
        elif isinstance(node, ast.Assign):  # ROS2, JSON = "ros2", "json"
            for target in node.targets:
                pairs = (zip(target.elts, node.value.elts, strict=False)
                         if isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple)
                         else [(target, node.value)])
                skip |= {id(value) for name, value in pairs
                         if isinstance(name, ast.Name) and name.id in FORMAT}
    words: list[str] = []
    for node in nodes:
        if isinstance(node, ast.Name):
            words.append(node.id)
        elif isinstance(node, ast.Attribute):
            words.append(node.attr)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            words.append(node.name)
        elif isinstance(node, ast.arg) or (isinstance(node, ast.keyword) and node.arg):
            words.append(node.arg)  # type: ignore[arg-type]
        elif isinstance(node, ast.alias):
            words += [w for w in (node.name, node.asname) if w]
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
              and id(node) not in skip and not any(c.isspace() for c in node.value)):
            words.append(node.value)
    return words, imports_in(source, omnican._HOMES)


@functools.cache
def _read(path: Path) -> tuple[list[str], set[str]]:
    return _words(path.read_text())


def _names(words: list[str], imports: set[str], name: str, folder: str) -> list[str]:
    word, package = name.lower(), f"omnican.{folder}"
    hits = [f"import {m}" for m in sorted(imports) if m == folder or m.startswith(f"{folder}.")]
    return hits + [w for w in words if w not in FORMAT and (
        word in w.lower() or package in w or f"omnican/{folder}/" in w)]


def names_in(source: str, name: str, folder: str) -> list[str]:
    """What in ``source`` names the front end ``name`` (its folder ``folder``)."""
    return _names(*_words(source), name, folder)


def files_naming(name: str, root: Path = ROOT) -> dict[str, list[str]]:
    """Package file (relative to ``omnican/``) -> what in it names the front end, for
    every file outside the front end's folder that does."""
    folder = FRONT_ENDS[name].folder
    package = root / "omnican"
    out = {}
    for path in sorted(package.rglob("*.py")):
        rel = path.relative_to(package)
        if rel.parts[0] == folder:
            continue
        hits = _names(*_read(path), name, folder)
        if hits:
            out[rel.as_posix()] = hits
    return out


def own_subcommands(name: str) -> dict[str, str]:
    """The modules of a front end's own subcommands (``cli/zenoh.py``), or their packages
    (``cli/fleet/``: a subcommand in several modules is one), by command."""
    out = {}
    for command, _ in FRONT_ENDS[name].commands:
        module = command.replace("-", "_")
        package = ROOT / "omnican" / "cli" / module
        out[command] = f"cli/{module}/" if package.is_dir() else f"cli/{module}.py"
    return out


def units(name: str, files: list[str]) -> set[str]:
    """``files``, a subcommand's package counted once."""
    packages = [p for p in own_subcommands(name).values() if p.endswith("/")]
    return {next((p for p in packages if f.startswith(p)), f) for f in files}


def test_a_front_end_is_its_folder_and_at_most_four_files_elsewhere() -> None:
    too_many = {name: sorted(found) for name in FRONT_ENDS
                if len(found := units(name, list(files_naming(name)))) > TARGET}
    assert not too_many, too_many


def test_those_files_are_its_extra_its_registry_line_and_its_own_subcommands() -> None:
    for name in FRONT_ENDS:
        allowed = {"extras.py", "layers.py", *own_subcommands(name).values()}
        assert units(name, list(files_naming(name))) <= allowed, name


def test_the_count_sees_each_way_of_naming_a_front_end() -> None:
    """The check itself: an import, an identifier, a key and a module's name are seen;
    prose, a docstring and the ROS 2 format's names are not."""
    seen = names_in('"""Foxglove and Zenoh in prose."""\n'
                    "import omnican.live.view\n"
                    "from omnican.zenoh.bridge import open_session\n"
                    "def add_zenoh(foxglove_control: bool) -> None:\n"
                    "    '''a docstring naming zenoh'''\n"
                    "    # a comment naming zenoh\n"
                    "    print('the Zenoh front end, in a sentence')\n"
                    "    table = cfg.front_ends['zenoh']\n"
                    "    load('omnican.zenoh.front_end:ZenohFrontEnd')\n", "zenoh", "zenoh")
    assert sorted(seen) == ["add_zenoh", "import zenoh.bridge",
                            "omnican.zenoh.front_end:ZenohFrontEnd", "zenoh"]
    assert sorted(names_in("import omnican.live.view\nx.foxglove_control = 1\n",
                           "foxglove", "live")) == [
        "foxglove_control", "import live.view", "omnican.live.view"]
    assert names_in('ROS2, JSON = "ros2", "json"\nSTORE = Stores.ROS2_JAZZY\n'
                    'ENCODING = "ros2msg"\n', "ros2", "ros2") == []
    assert names_in('PROFILE = "ros2"\ncfg.ros2\n', "ros2", "ros2") == ["ros2", "ros2"]


if __name__ == "__main__":  # pragma: no cover
    where = Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else ROOT
    for front_end in FRONT_ENDS:
        found = files_naming(front_end, where)
        print(f"{front_end}: {len(found)} files outside omnican/{FRONT_ENDS[front_end].folder}/")
        for file, hits in found.items():
            print(f"  {file}: {', '.join(sorted(set(hits))[:6])}")
