"""The docs site builds offline with warnings as errors, and shows what the code has: every
configuration key of the schema, every subcommand, the pictures made from the code."""

from __future__ import annotations

import importlib.util
import os
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
    """The guard the site is built under refuses what only the tests install (in the
    program and in those it starts) and lets the docs extra's own packages through."""
    env = guarded_env(tmp_path, "omnican", ["docs"], {**os.environ, "PYTHONPATH": str(ROOT)})
    probe = ("import subprocess, sys\n"
             "import sphinx, myst_parser, furo, sphinxarg, matplotlib, rich, omnican.layers\n"
             "for name in ('pytest', 'hypothesis', 'xdist', 'mcap', 'ruff', 'tests.test_layers'):\n"
             "    try:\n"
             "        __import__(name)\n"
             "    except ModuleNotFoundError as exc:\n"
             "        print('refused', name, exc.name)\n"
             "    else:\n"
             "        print('imported', name)\n")
    inner = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                           env=env, cwd=ROOT, timeout=120, check=False)
    assert inner.returncode == 0, inner.stderr
    assert inner.stdout.split("\n")[:-1] == [
        "refused pytest pytest", "refused hypothesis hypothesis", "refused xdist xdist",
        "refused mcap mcap", "refused ruff ruff", "refused tests.test_layers pytest"]
    # a program started by one under the guard is guarded too (the docs build starts
    # tools/gen_docs_pictures.py, which starts omnican plot)
    nested = subprocess.run(
        [sys.executable, "-c", "import subprocess, sys; sys.exit(subprocess.run("
         "[sys.executable, '-c', 'import pytest']).returncode)"],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120, check=False)
    assert nested.returncode == 1 and "refused" in nested.stderr, nested.stderr
