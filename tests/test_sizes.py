"""Sizes that need no apology (issue 39, step 5): no module of the package over
MODULE_LINES lines, no class over CLASS_LINES; a module that grows past them is split
by concern, as zenoh/fleet.py (discovery, calls) and cli/fleet/ were."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "omnican"
MODULE_LINES = 450
CLASS_LINES = 300


def test_no_module_or_class_is_over_its_size() -> None:
    over = []
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_text()
        name = path.relative_to(PACKAGE).as_posix()
        lines = text.count("\n")
        if lines > MODULE_LINES:
            over.append(f"{name}: {lines} lines")
        for node in ast.walk(ast.parse(text, name)):
            if isinstance(node, ast.ClassDef):
                size = (node.end_lineno or node.lineno) - node.lineno + 1
                if size > CLASS_LINES:
                    over.append(f"{name}: class {node.name} {size} lines")
    assert not over, "\n".join(over)
