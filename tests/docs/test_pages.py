"""The pages hold together: README is the front door, links land, every fence says its
language, TOML examples parse, and the safety page names every stop the code latches."""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

from tests.docs.test_snippets import PAGES, ROOT, all_blocks, fenced_blocks

DOCS = ROOT / "docs"
README = ROOT / "README.md"
#: what a fence may say: code the tests run or parse, or plain text
LANGS = {"python", "sh", "console", "toml", "ini", "text", "", "{toctree}", "{include}"}
#: pages the docs build generates (from the schema, the parsers, the docstrings)
GENERATED = ("docs/reference/", "docs/_generated/")  # made by the docs build


def test_readme_is_a_front_door() -> None:
    text = README.read_text()
    assert len(text.encode()) < 15_000
    for marker in ("<!-- main-command -->", "<!-- test-command -->"):
        assert text.count(marker) == 1, marker
    # One click from the front page: the sim console, the stop reasons, the config keys.
    for target in ("docs/getting-started.md#a-second-terminal-against-simulated-drives",
                   "docs/safety.md#what-stops-the-base-and-how-to-recover",
                   "docs/reference/config.md"):
        assert f"]({target})" in text, target
    assert "QEMU" in text and "apt-get" in text and "root" in text


def _test_command(text: str) -> str:
    """The fenced block after <!-- test-command -->, as .ci/run reads it."""
    after = text.split("<!-- test-command -->", 1)[1]
    return fenced_blocks(after, "README.md")[0].body.strip()


def test_the_test_command_builds_the_docs_and_the_contributing_page_quotes_it() -> None:
    command = _test_command(README.read_text())
    assert "pip install '.[test,docs]'" in command and "tools/socketcan-tests" in command
    page = (DOCS / "contributing.md").read_text()
    assert f"```console\n{command}\n```" in page


def test_every_fence_says_its_language() -> None:
    blocks = all_blocks()
    assert len(blocks) > 30
    for block in blocks:
        assert block.lang in LANGS, (block.id, block.lang)


def test_toml_examples_parse() -> None:
    if sys.version_info >= (3, 11):
        import tomllib
    else:
        import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]

    tables = [b for b in all_blocks() if b.lang == "toml"]
    assert len(tables) >= 5
    for block in tables:
        try:
            tomllib.loads(block.body)
        except tomllib.TOMLDecodeError as exc:
            pytest.fail(f"{block.id}: {exc}\n{block.body}")


def _slug(heading: str) -> str:
    """A heading's anchor as GitHub and MyST (myst_heading_anchors) make it."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = page.read_text()
    # headings outside fences
    for block in fenced_blocks(text, page.name):
        text = text.replace(block.body, "")
    return {_slug(m[1]) for m in re.finditer(r"^#{1,6} (.+)$", text, re.M)}


def test_links_land() -> None:
    checked = 0
    for page in PAGES:
        text = page.read_text()
        for block in fenced_blocks(text, page.name):
            text = text.replace(block.body, "")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue  # https:, mailto:
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            rel = dest.relative_to(ROOT).as_posix()
            if rel.startswith(GENERATED):
                continue  # made by the docs build, which checks its own links
            assert dest.exists(), f"{page.name}: {target}"
            checked += 1
            if anchor:
                assert anchor in _anchors(dest), f"{page.name}: {target}"
    assert checked > 40


def test_the_index_lists_every_page() -> None:
    text = (DOCS / "index.md").read_text()
    listed = [line.strip() for b in fenced_blocks(text, "index.md") if b.lang == "{toctree}"
              for line in b.body.splitlines() if line.strip() and not line.startswith(":")]
    assert listed[:11] == ["getting-started", "driving", "python-api", "bring-up", "safety",
                           "ros2", "zenoh", "fleet", "foxglove", "mcap", "calibration"]
    pages = {p.stem for p in DOCS.glob("*.md")} - {"index"}
    assert pages <= set(listed), pages - set(listed)


# ---------------------------------------------------------------- facts the code holds


def _stop_fragments() -> list[tuple[str, str]]:
    """(where, text) of every literal part of a stop's reason: the argument of each
    latch call in omnican/chassis, and the reasons made for one (describe(),
    cutoff_reason(), a ``reason``/``held``/``bus_off`` assignment)."""
    files = [*sorted((ROOT / "omnican" / "chassis").glob("*.py")),
             ROOT / "omnican" / "core" / "tracking.py", ROOT / "omnican" / "core" / "lift.py"]
    out: list[tuple[str, str]] = []

    def literal(node: ast.AST, where: str) -> None:
        parts = [node] if isinstance(node, ast.Constant) else \
            [v for v in node.values if isinstance(v, ast.Constant)] \
            if isinstance(node, ast.JoinedStr) else []
        out.extend((where, str(p.value)) for p in parts if isinstance(p.value, str))

    for path in files:
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            where = f"{path.name}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
                    node.func.attr in ("latch", "latch_cause", "latch_also") and node.args:
                literal(node.args[0], where)
            elif isinstance(node, ast.FunctionDef) and node.name in ("describe",
                                                                     "cutoff_reason"):
                for sub in ast.walk(node):
                    if isinstance(sub, ast.JoinedStr):
                        literal(sub, f"{path.name}:{sub.lineno}")
            elif isinstance(node, ast.Assign) and any(
                    (isinstance(t, ast.Name) and t.id in ("reason", "held")) or
                    (isinstance(t, ast.Attribute) and t.attr == "bus_off")
                    for t in node.targets):
                for sub in ast.walk(node.value):
                    if isinstance(sub, ast.JoinedStr):
                        literal(sub, where)
    return out


def test_the_stop_table_names_every_stop_the_code_latches() -> None:
    page = (DOCS / "safety.md").read_text()
    fragments = [(w, f.strip()) for w, f in _stop_fragments() if len(f.strip()) >= 5]
    assert len(fragments) >= 20
    missing = [(w, f) for w, f in fragments if f not in page]
    assert not missing, missing


def _halts() -> list[tuple[str, str]]:
    """(where, text) of every literal part of the reason each ``halt(...)`` call in the
    package gives: the held stops the front ends make (a Zenoh ``~/stop``, the fleet's)."""
    out: list[tuple[str, str]] = []
    for path in sorted((ROOT / "omnican").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
                    node.func.attr == "halt" and node.args:
                arg = node.args[0]
                parts = [arg] if isinstance(arg, ast.Constant) else \
                    [v for v in arg.values if isinstance(v, ast.Constant)] \
                    if isinstance(arg, ast.JoinedStr) else []
                out.extend((f"{path.relative_to(ROOT)}:{node.lineno}", str(p.value).strip())
                           for p in parts if isinstance(p.value, str))
    return out


def test_the_stop_table_names_every_held_stop_a_front_end_makes() -> None:
    """Issue 36 item 12: a stop from Zenoh, ROS 2 (over rmw_zenoh) or the fleet holds
    until recover (Chassis.halt); the table had no row for it, and its stop() row said
    the next command moves again. Each halt's reason is in the table, with the reason
    the Zenoh ~/stop gives whole, and which stops hold and which do not."""
    from omnican.zenoh.services import SOURCE

    page = (DOCS / "safety.md").read_text()
    halts = _halts()
    assert halts, "no halt() call found: the test reads the wrong tree"
    missing = [(w, f) for w, f in halts if f and f not in page]
    assert not missing, missing
    rows = [line for line in page.splitlines() if line.startswith("| ")]
    held = next((r for r in rows if "`halt(reason)`" in r), None)
    assert held is not None, "no row for Chassis.halt"
    assert f"`stopped by {SOURCE} <gid>`" in held
    for front_end in ("`~/stop`", "ros2 service call", "fleet"):
        assert front_end in held, front_end
    assert "`recover()`" in held.rsplit("|", 2)[1]
    plain = next(r for r in rows if "`stop()`" in r and r is not held)
    assert "`/omnican/stop`" in plain and "let go" in plain


def test_the_sim_console_commands_are_on_the_getting_started_page() -> None:
    from omnican.sim.console import COMMANDS

    page = (DOCS / "getting-started.md").read_text()
    section = page.split("## A second terminal against simulated drives", 1)[1]
    for syntax, _ in COMMANDS:
        verb = syntax.split()[0]
        assert re.search(rf"`{verb}( [^`]*)?`", section), verb


def test_one_version_for_the_command_the_package_and_the_changelog() -> None:
    import subprocess

    import omnican

    if sys.version_info >= (3, 11):
        import tomllib
    else:
        import tomli as tomllib  # type: ignore[import-not-found,unused-ignore]

    out = subprocess.run([sys.executable, "-m", "omnican", "--version"], text=True,
                         capture_output=True, check=True, env={"PYTHONPATH": str(ROOT)},
                         cwd=ROOT).stdout
    assert out.strip() == f"omnican {omnican.__version__}"
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project.get("version", omnican.__version__) == omnican.__version__
    changelog = (ROOT / "CHANGELOG.md").read_text()
    first = re.search(r"^## \[([^\]]+)\]", changelog, re.M)
    assert first is not None and first[1] in ("Unreleased", omnican.__version__)
    assert f"## [{omnican.__version__}]" in changelog
