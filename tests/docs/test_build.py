"""The docs site builds offline with warnings as errors, and shows what the code has: every
configuration key of the schema, every subcommand, the pictures made from the code."""

from __future__ import annotations

import importlib.util
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from omnican.cli import COMMANDS
from omnican.config import SCHEMA
from tests.docs.extra_only import guarded_env
from tests.support.helpers import ROOT

MISSING = [m for m in ("sphinx", "myst_parser", "furo", "sphinxarg", "matplotlib")
           if importlib.util.find_spec(m) is None]


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if MISSING:
        pytest.skip(f"the docs extra is not installed (no {', '.join(MISSING)}): "
                    "pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site")
    # Built with what the docs extra installs and nothing else (README: "pip install
    # '.[docs]'"), although the tests' venv has more: tests/docs/extra_only.py says why.
    env = guarded_env(tmp_path_factory.mktemp("docs-only"), "omnican", ["docs"],
                      {**os.environ, "PYTHONPATH": str(ROOT)})
    result = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q",
                             "-b", "html", str(ROOT / "docs"), str(out)],
                            capture_output=True, text=True, env=env, cwd=ROOT, timeout=900,
                            check=False)
    assert result.returncode == 0, result.stderr[-4000:]
    return out


@pytest.mark.timeout(900)
def test_every_configuration_key_is_in_the_reference(site: Path) -> None:
    page = (site / "reference" / "config.html").read_text()
    for table, keys in SCHEMA.items():
        for key in keys:
            assert f"<code class=\"docutils literal notranslate\"><span class=\"pre\">{key}" \
                   f"</span></code>" in page, f"{table}.{key} is not in the reference"


@pytest.mark.timeout(900)
def test_every_subcommand_is_in_the_cli_reference(site: Path) -> None:
    page = (site / "reference" / "cli.html").read_text()
    for command in COMMANDS:
        assert f"omnican {command}" in page, command


@pytest.mark.timeout(900)
def test_the_pictures_are_made_and_shown(site: Path) -> None:
    images = {p.name for p in (site / "_images").iterdir()}
    for name in ("geometry-b21.svg", "geometry-a12.svg", "teleop.svg", "plot.png",
                 "layers.svg"):
        assert name in images, f"{name} is not on any page"


def test_the_docs_build_can_import_only_what_the_docs_extra_installs(tmp_path: Path) -> None:
    """The guard the site is built under hides what only the tests install (in the
    program and in those it starts) and lets the docs extra's own packages through."""
    env = guarded_env(tmp_path, "omnican", ["docs"], {**os.environ, "PYTHONPATH": str(ROOT)})
    probe = ("import subprocess, sys\n"
             "import sphinx, myst_parser, furo, sphinxarg, matplotlib, rich, omnican.layers\n"
             "for name in ('pytest', 'hypothesis', 'xdist', 'mcap', 'ruff', 'tests.test_layers'):\n"
             "    try:\n"
             "        __import__(name)\n"
             "    except ModuleNotFoundError as exc:\n"
             "        print('hidden', name, exc.name)\n"
             "    else:\n"
             "        print('imported', name)\n")
    inner = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                           env=env, cwd=ROOT, timeout=120, check=False)
    assert inner.returncode == 0, inner.stderr
    assert inner.stdout.split("\n")[:-1] == [
        "hidden pytest pytest", "hidden hypothesis hypothesis", "hidden xdist xdist",
        "hidden mcap mcap", "hidden ruff ruff", "hidden tests.test_layers pytest"]
    # a program started by one under the guard is guarded too (the docs build starts
    # tools/gen_docs_pictures.py, which starts omnican plot)
    nested = subprocess.run(
        [sys.executable, "-c", "import subprocess, sys; sys.exit(subprocess.run("
         "[sys.executable, '-c', 'import pytest']).returncode)"],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120, check=False)
    assert nested.returncode == 1 and "No module named 'pytest'" in nested.stderr, \
        nested.stderr
    # as a missing package looks to omnican.extras: not there
    extras = subprocess.run(
        [sys.executable, "-c", "from omnican.extras import missing; "
         "print(missing('ros2'), missing('plot'))"],
        capture_output=True, text=True, env=env, cwd=ROOT, timeout=120, check=True)
    assert extras.stdout.split() == ["cyclonedds", "None"]


@pytest.mark.timeout(900)
def test_the_cli_reference_shows_the_help_texts_as_they_are(site: Path) -> None:
    """sphinx-argparse reads every help text as reStructuredText: python-can's unclosed
    backtick made 9 broken '#id1' links, and '--bus-kwargs' came out with an en-dash."""
    page = (site / "reference" / "cli.html").read_text()
    assert 'class="problematic"' not in page and 'href="#id' not in page
    assert "\u2013" not in page and "\u2014" not in page  # no en or em dash anywhere
    assert page.count("-i vector -c 1 --bus-kwargs app_name=MyCanApp serial=1234") >= 5
    assert "--key-timeout" in page and "--no-foxglove-control" in page
    # teleop's key map laid out as in the terminal, not run into one paragraph
    assert re.search(r"u +i +o +forward-left +forward +forward-right", page)


@pytest.mark.timeout(900)
def test_the_configuration_reference_has_the_bus_table(site: Path) -> None:
    from omnican.config.schema import BUS_KEYS

    page = (site / "reference" / "config.html").read_text()
    assert '<span class="pre">[bus]</span>' in page
    section = page.split('<span class="pre">[bus]</span>', 1)[1].split("<h2>", 1)[0]
    for key in ("interface", "channel", *BUS_KEYS):
        assert f'<span class="pre">{key}</span>' in section, key
    assert "can.Bus" in section and "--sim" in section


@pytest.mark.timeout(900)
def test_the_teleop_picture_is_the_80x24_screen(site: Path) -> None:
    """As rich draws an 80-column terminal, at most 24 lines high (it was 100 wide)."""
    from rich.console import Console

    def box(lines: int) -> tuple[float, float]:
        console = Console(record=True, width=80, force_terminal=True, file=io.StringIO())
        console.print("\n".join(["x"] * lines))
        m = re.search(r'viewBox="0 0 ([0-9.]+) ([0-9.]+)"', console.export_svg())
        assert m is not None
        return float(m[1]), float(m[2])

    svg = (site / "_images" / "teleop.svg").read_text()
    m = re.search(r'viewBox="0 0 ([0-9.]+) ([0-9.]+)"', svg)
    assert m is not None
    width, height = float(m[1]), float(m[2])
    assert width == box(1)[0]
    assert box(12)[1] < height <= box(24)[1]
