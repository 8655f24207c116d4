"""Sphinx extension: the pages made from the code at every build.

- ``_generated/config.md``: the configuration reference, every key of
  :data:`omnican.config.SCHEMA` with its default, meaning, type and range, and per table
  the values the configurations the repository ships give (``examples/*.toml``);
- ``_generated/modules.md``: every module of the package, folder by folder, with the
  first sentence of its docstring (the architecture page's map of the tree);
- :func:`cli_parser`: omnican's argument parser for the CLI reference
  (sphinx-argparse), its texts made literal for reStructuredText (they are written for
  a terminal: python-can's help has an unclosed backtick, the descriptions indented
  tables);
- ``_generated/*.svg|png``: the pictures of ``tools/gen_docs_pictures.py`` (the wheel
  geometry of each preset, the teleop dashboard, a plot, the layers).

Written under ``docs/_generated/`` (not in git) before Sphinx reads the sources, so a
page that includes them always shows what the code does now.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx

if sys.version_info >= (3, 11):
    import tomllib
else:  # the package depends on tomli there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]


def _type_text(types: tuple[type, ...]) -> str:
    names = {int: "integer", float: "number", str: "string", bool: "boolean", list: "array",
             dict: "table"}
    if set(types) >= {int, float}:
        rest = [names.get(t, t.__name__) for t in types if t not in (int, float)]
        return " or ".join(["number", *rest])
    return " or ".join(names.get(t, t.__name__) for t in types)


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isinf(value):
            return "inf"
        return f"{value:g}"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return str(value)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _examples() -> dict[str, Any]:
    """``table.key`` -> the first value a shipped example config gives it."""
    found: dict[str, Any] = {}
    for path in sorted((ROOT / "examples").glob("*.toml")):
        data = tomllib.loads(path.read_text())
        for table, body in data.items():
            rows = body if isinstance(body, list) else [body]
            for row in rows:
                if not isinstance(row, dict):
                    continue
                for key, value in row.items():
                    if key == "sdo" and isinstance(value, list):
                        for sdo in value:
                            for k, v in sdo.items():
                                found.setdefault(f"{table}.sdo.{k}", v)
                    elif not isinstance(value, dict):
                        found.setdefault(f"{table}.{key}", value)
    return found


#: The [bus] table's keys omnican does not read itself, passed to ``can.Bus`` as they are.
BUS_PASSED = {
    "interface": ("string", "python-can's interface: socketcan (Linux), virtual, remote "
                  "(omnican sim's hub), pcan, kvaser, slcan ...; -i on the command line"),
    "channel": ("string", "the interface's channel: can0, vcan0, ws://127.0.0.1:54701/ "
                "...; -c on the command line"),
}


def bus_reference(examples: dict[str, Any]) -> list[str]:
    """The [bus] table: free-form (every key goes to ``can.Bus``), the keys omnican reads
    itself checked as :data:`omnican.config.schema.BUS_KEYS` says."""
    from omnican.config.schema import BUS_KEYS

    out = ["## `[bus]`", "",
           "The bus, as python-can opens it: every key is passed to `can.Bus` as it is "
           "(`bitrate`, `fd`, `receive_own_messages` and whatever the interface takes), so "
           "the table is free-form; omit it to use python-can's own configuration "
           "(`~/.canrc`, `CAN_INTERFACE`). The command line's bus arguments (`-i`, `-c`, "
           "`-b`, `--bus-kwargs`) override it. omnican reads the bitrates itself (the bus "
           "load) and checks them; under `--sim` the simulated bus has the nominal "
           "`bitrate` given here (500 kbit/s without one). `sync` and `sync_counter` are "
           "omnican's alone (who sends SYNC, and its counter: "
           "[how SYNC is timed](../architecture.md#how-sync-is-timed)) and never reach "
           "`can.Bus`.", "",
           "| key | default | meaning |", "|---|---|---|"]
    shown: list[str] = []
    for name, (kind, doc) in BUS_PASSED.items():
        out.append(f"| `{name}` | - | {_cell(doc)} *({kind})* |")
    for name, key in BUS_KEYS.items():
        what = _type_text(key.types)
        if key.range is not None:
            what += ", " + key.range_text()
        default = "-" if key.default is None else f"`{_toml(key.default)}`"
        out.append(f"| `{name}` | {default} | {_cell(key.doc)} *({_cell(what)})* |")
    for name in (*BUS_PASSED, *BUS_KEYS):
        example = examples.get(f"bus.{name}")
        if example is not None:
            shown.append(f"{name} = {_toml(example)}")
    if shown:
        out += ["", "From the shipped examples:", "", "```toml", "[bus]", *shown, "```"]
    return [*out, ""]


def config_reference() -> str:
    from omnican.config import SCHEMA

    examples = _examples()
    out = ["<!-- made from omnican.config.SCHEMA at every docs build: do not edit -->", ""]
    out += bus_reference(examples)
    for table, keys in SCHEMA.items():
        heading = {"wheel": "[[wheel]]", "wheel.sdo": "[[wheel.sdo]]",
                   "sim.slip.surface": "[[sim.slip.surface]]"}.get(table, f"[{table}]")
        out += [f"## `{heading}`", "", "| key | default | meaning |", "|---|---|---|"]
        shown: list[str] = []
        for name, key in keys.items():
            if key.required:
                default = "required"
            elif key.scaled is not None:
                other, factor = key.scaled
                default = f"{factor:g} x `{other}`"
            elif key.default is None:
                default = "-"
            else:
                default = f"`{_toml(key.default)}`"
            what = _type_text(key.types)
            if key.range is not None or key.inf_ok:
                what += ", " + key.range_text()
            out.append(f"| `{name}` | {default} | {_cell(key.doc)} *({_cell(what)})* |")
            example = examples.get(f"{table}.{name}")
            if example is not None:
                shown.append(f"{name} = {_toml(example)}")
        if shown:
            out += ["", "From the shipped examples:", "", "```toml", heading, *shown, "```"]
        out.append("")
    return "\n".join(out)


def module_map() -> str:
    """Every module of the package, folder by folder, with the first sentence of its
    docstring: the tree as the code has it."""
    import ast

    package = ROOT / "omnican"
    out = ["<!-- made from the package's modules at every docs build: do not edit -->", ""]
    folders = sorted({p.parent for p in package.rglob("*.py") if "__pycache__" not in p.parts})
    for folder in folders:
        rel = folder.relative_to(ROOT).as_posix()
        rows = []
        for path in sorted(folder.glob("*.py")):
            doc = ast.get_docstring(ast.parse(path.read_text())) or ""
            first = " ".join(doc.split("\n\n", 1)[0].split())
            first = first.split(". ", 1)[0].rstrip(".")
            first = re.sub(r":[a-z]+:`~?([^`]+)`", r"`\1`", first).replace("``", "`")
            name = path.name if path.name != "__init__.py" else "(the folder)"
            lines = path.read_text().count("\n")
            rows.append(f"| `{name}` | {lines} | {_cell(first)} |")
        out += [f"### `{rel}/`", "", "| module | lines | what it holds |", "|---|---|---|",
                *rows, ""]
    return "\n".join(out)


def _literal(text: str) -> str:
    """``text`` as reStructuredText reads it literally: every mark escaped, one line."""
    return re.sub(r"([^A-Za-z0-9\s])", r"\\\1", " ".join(text.split()))


def _literal_blocks(text: str) -> str:
    """A terminal description as reStructuredText: its paragraphs of prose escaped, those
    laid out by hand (indented lines: key maps, command lists, formulas) as literal
    blocks, as the terminal shows them."""
    import textwrap

    out = []
    for para in re.split(r"\n\s*\n", textwrap.dedent(text).strip("\n")):
        lines = para.splitlines()
        if any(line[:1].isspace() for line in lines[1:]) or \
                (len(lines) > 1 and lines[0].rstrip().endswith(":")):
            block = textwrap.indent(textwrap.dedent(para), "    ")
            out.append(f".. code-block:: text\n\n{block}")
        else:
            out.append(_literal(para))
    return "\n\n".join(out)


def cli_parser() -> Any:
    """omnican's argument parser with its texts as reStructuredText reads them literally
    (for sphinx-argparse, which parses every help text and description as
    reStructuredText): a help text escaped, a description's laid-out paragraphs as
    literal blocks. The terminal's ``--help`` is not touched (a parser of its own)."""
    import argparse

    from omnican.cli import build_parser

    def fix(parser: argparse.ArgumentParser) -> None:
        if parser.description:
            parser.description = _literal_blocks(parser.description)
        if parser.epilog:
            parser.epilog = _literal_blocks(parser.epilog)
        for group in parser._action_groups:
            if group.description:
                group.description = _literal(group.description)
        for action in parser._actions:
            if action.help and action.help != argparse.SUPPRESS:
                # sphinx-argparse fills %(default)s and the like first: keep a % a %
                action.help = _literal(action.help % {**vars(action), "prog": parser.prog}
                                       if "%(" in action.help else action.help)
                action.help = action.help.replace("%", "%%")
            if isinstance(action, argparse._SubParsersAction):
                for choice in action._choices_actions:
                    if choice.help:
                        choice.help = _literal(choice.help).replace("%", "%%")
                for sub in action.choices.values():
                    fix(sub)

    parser = build_parser()
    fix(parser)
    return parser


def generate(app: Sphinx) -> None:
    out = Path(app.srcdir) / "_generated"
    out.mkdir(exist_ok=True)
    for name, text in (("config.md", config_reference()), ("modules.md", module_map())):
        target = out / name
        if not target.exists() or target.read_text() != text:
            target.write_text(text)
    subprocess.run([sys.executable, str(ROOT / "tools" / "gen_docs_pictures.py"), str(out)],
                   check=True, cwd=ROOT)


def setup(app: Sphinx) -> dict[str, Any]:
    app.connect("builder-inited", generate)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
