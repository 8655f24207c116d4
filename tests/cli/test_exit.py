"""The process's own command ends past the interpreter's finalization once Zenoh is
imported: a Zenoh thread calling into Python during it aborted the process now and then
("FATAL: exception not rethrown", exit -6: `fleet --once --json` 2 runs in 120, and a
fleet view interrupted during discovery). Its output is all there, its exit code its own.

Without Zenoh it ends as the interpreter would, its exit handlers run, but without
tearing down its modules and objects one by one (the command closed what it opened);
a thread still running that is not a daemon keeps the interpreter's own exit."""

from __future__ import annotations

import json
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
sys.argv = ["omnican", *{words!r}]
sys.exit(main())
"""

# A thread that is no daemon, still running when the command returns.
THREAD = """
import threading, time
def late():
    time.sleep(0.5)
    print("thread done", flush=True)
threading.Thread(target=late, name="late").start()
"""


def run(imports: str, words: tuple[str, ...] = ("check-config", "no-such-config.toml")
        ) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", SCRIPT.format(imports=imports,
                                                               words=list(words))],
                          capture_output=True, text=True, env=env, timeout=120, check=False)


def test_with_zenoh_imported_the_command_ends_without_finalization() -> None:
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    done = run("import zenoh")
    assert done.returncode == 2, done.stderr  # the command's own code
    assert "no-such-config.toml" in done.stderr  # its output flushed
    assert "finalized" not in done.stdout  # no interpreter finalization ran


def test_without_zenoh_the_exit_handlers_run() -> None:
    done = run("")
    assert done.returncode == 2, done.stderr
    assert "no-such-config.toml" in done.stderr and done.stdout == "finalized\n"


def test_a_command_run_to_its_end_has_its_output_and_its_exit_handlers() -> None:
    """Its output whole (piped: flushed at the end), its exit code, its exit handlers
    run."""
    done = run("", ("drive", "--sim", "--fast", "--vx", "0.1", "--duration", "0.2",
                           "--json"))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert json.loads(lines[0])["duration_s"] == pytest.approx(0.2, abs=0.05)
    assert lines[1:] == ["finalized"]


def test_a_thread_still_running_keeps_the_interpreters_exit() -> None:
    """A thread that is no daemon (a program calling main()) is waited for: the
    interpreter's own exit."""
    done = run(THREAD)
    assert done.returncode == 2, done.stderr
    assert done.stdout.splitlines() == ["thread done", "finalized"]
