"""``omnican sim`` serving another process: its drives take the control loop's real-time
class where the process may, and say how to keep them steady where it may not."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest


@pytest.mark.skipif(shutil.which("setpriv") is None or os.geteuid() != 0,
                    reason="needs root and util-linux's setpriv (to run without CAP_SYS_NICE)")
def test_sim_says_how_to_keep_its_drives_steady_without_real_time_priority() -> None:
    done = subprocess.run(["setpriv", "--bounding-set", "-sys_nice", sys.executable, "-m",
                           "omnican", "sim", "--serve", "127.0.0.1:0", "--duration", "0.5"],
                          capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
                          check=False)
    assert done.returncode == 0, done.stderr
    notes = [line for line in done.stdout.splitlines() if line.startswith("note:")]
    assert len(notes) == 1, done.stdout
    assert "simulated drives at normal priority" in notes[0]
    assert "not permitted (run as root, give the program CAP_SYS_NICE" in notes[0]
    assert "--sim" in notes[0]

