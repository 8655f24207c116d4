"""Sphinx extension: the pages made from the code at every build.

- ``_generated/config.md``: the configuration reference, every key of
  :data:`omnican.config.SCHEMA` with its default, meaning, type and range, and per table
  the values the configurations the repository ships give (``examples/*.toml``);
- ``_generated/modules.md``: every module of the package, folder by folder, with the
  first sentence of its docstring (the architecture page's map of the tree);
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


def config_reference() -> str:
    from omnican.config import SCHEMA

    examples = _examples()
    out = ["<!-- made from omnican.config.SCHEMA at every docs build: do not edit -->", ""]
    for table, keys in SCHEMA.items():
        heading = {"wheel": "[[wheel]]", "wheel.sdo": "[[wheel.sdo]]"}.get(table, f"[{table}]")
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
