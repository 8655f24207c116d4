"""docs/architecture.md's "Where a change goes" names the files a change really touches
(issue 39): for a front end, the files outside its folder that name it are those the
page names; for a health field, the files that name an existing field in code (the
temperature, end to end: its entry, its config keys, the wheel's fields, the simulator,
scan) are those the page names."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import omnican
from omnican.layers import FRONT_ENDS
from omnican.plan.health_fields import BY_QUANTITY
from tests.test_front_end_files import files_naming

ROOT = Path(omnican.__file__).resolve().parents[1]
PACKAGE = ROOT / "omnican"

#: Files where the word "temperature" means something else than what a drive reports:
#: CiA 301's EMCY error class (protocol), and sensor_msgs/BatteryState's field (the ROS 2
#: message's declaration and the telemetry that fills it with NaN: not measured).
OTHER_MEANINGS = {"protocol/cia402.py", "ros2/msgs.py", "telemetry/messages.py"}


def bullet(title: str) -> str:
    page = (ROOT / "docs" / "architecture.md").read_text()
    section = page.split("## Where a change goes", 1)[1]
    found = re.search(rf"^- \*\*{re.escape(title)}\*\*(.*?)(?=^- \*\*|\Z)", section,
                      re.S | re.M)
    assert found, title
    return found.group(1)


def named_files(text: str) -> set[str]:
    """The package files a bullet names (``plan/health.py``, ``omnican/layers.py``),
    relative to ``omnican/``."""
    out = set()
    for name in re.findall(r"`([^`\s]+\.py)`", text):
        if not name.startswith("tests/"):
            out.add(name.removeprefix("omnican/"))
    return out


def code_words(source: str) -> set[str]:
    """The identifiers and the strings of ``source`` that are not docstrings."""
    tree = ast.parse(source)
    docs = {id(node.body[0].value) for node in ast.walk(tree)
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                 ast.AsyncFunctionDef)) and node.body
            and isinstance(node.body[0], ast.Expr)}
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            out.add(node.id)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, ast.arg) or (isinstance(node, ast.keyword) and node.arg):
            out.add(node.arg)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in docs:
            out.add(node.value)
    return out


def files_naming_field(quantity: str) -> set[str]:
    """The package files whose code names a health field: its name, its quantity (the
    config key of its object, the health plan's word) or its scale's key."""
    field = BY_QUANTITY[quantity]
    words = {field.name, quantity, f"{quantity}_scale"}
    return {path.relative_to(PACKAGE).as_posix() for path in PACKAGE.rglob("*.py")
            if code_words(path.read_text()) & words}


def test_a_front_end_touches_the_files_the_page_names() -> None:
    text = bullet("A front end.")
    named = named_files(text)
    assert {"layers.py", "extras.py", "<name>/front_end.py", "cli/<command>.py"} <= named
    for name, entry in FRONT_ENDS.items():
        own = {command.replace('-', '_') for command, _ in entry.commands}
        touched = set(files_naming(name))
        # its subcommand: a module of cli/, or a package of cli/ when it is several
        outside = {path for path in touched - {"layers.py", "extras.py"}
                   if not any(path == f"cli/{c}.py" or path.startswith(f"cli/{c}/")
                              for c in own)}
        assert not outside, (name, touched)
        assert "layers.py" in touched  # its registry line


def test_a_health_field_touches_the_files_the_page_names() -> None:
    named = named_files(bullet("A health field"))
    found = files_naming_field("temperature")
    assert found >= OTHER_MEANINGS  # the other meanings are there: set aside, by name
    for path in OTHER_MEANINGS:
        words = code_words((PACKAGE / path).read_text())
        assert not words & {"temperature_c", "temperature_scale"}, path
    # the temperature is read as the config says (no way of its own: plan/health.py)
    assert found - OTHER_MEANINGS == named - {"plan/health.py"}
    assert all((PACKAGE / path).is_file() for path in named)
