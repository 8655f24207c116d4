"""The process's own command ends past the interpreter's finalization once Zenoh is
imported: a Zenoh thread calling into Python during it aborted the process now and then
("FATAL: exception not rethrown", exit -6: `fleet --once --json` 2 runs in 120, and a
fleet view interrupted during discovery). Its output is all there, its exit code its own."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import atexit, sys
{imports}
atexit.register(lambda: print("finalized", flush=True))
from omnican.cli import main
sys.argv = ["omnican", "check-config", "no-such-config.toml"]
sys.exit(main())
"""


def run(imports: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", SCRIPT.format(imports=imports)],
                          capture_output=True, text=True, env=env, timeout=120, check=False)


def test_with_zenoh_imported_the_command_ends_without_finalization() -> None:
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    done = run("import zenoh")
    assert done.returncode == 2, done.stderr  # the command's own code
    assert "no-such-config.toml" in done.stderr  # its output flushed
    assert "finalized" not in done.stdout  # no interpreter finalization ran


def test_without_zenoh_the_interpreter_ends_as_usual() -> None:
    done = run("")
    assert done.returncode == 2, done.stderr
    assert "no-such-config.toml" in done.stderr and done.stdout == "finalized\n"
