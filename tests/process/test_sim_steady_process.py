"""``omnican drive --sim`` as a process of its own, beside a Foxglove client that
subscribes to everything and never reads, and programs that keep every core busy: its
simulated drives keep their heartbeats and the base keeps running to the end."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from omnican.protocol.cia301 import EMCY_BASE, EMCY_HEARTBEAT, HEARTBEAT_BASE

ROOT = Path(__file__).resolve().parents[2]
DURATION_S = 8.0  # 80 of the drives' heartbeat periods
HOG = "while True: pass"


@contextmanager
def processes(*argvs: list[str]) -> Iterator[list[subprocess.Popen[str]]]:
    procs = [subprocess.Popen(a, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                              stdin=subprocess.DEVNULL, text=True, cwd=ROOT) for a in argvs]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
            p.wait()
            if p.stdout is not None:
                p.stdout.close()


def frames(log: Path) -> list[tuple[float, int, str]]:
    """(time, id, data hex) of every frame of a candump-format log."""
    out = []
    for line in log.read_text().splitlines():
        m = re.match(r"\((\d+\.\d+)\) \S+ ([0-9A-F]+)#([0-9A-F]*)", line)
        if m:
            out.append((float(m[1]), int(m[2], 16), m[3]))
    return out


@pytest.mark.skipif(importlib.util.find_spec("foxglove") is None, reason="needs foxglove-sdk")
def test_sim_drives_keep_up_beside_a_stalled_foxglove_client_and_busy_cores(
        tmp_path: Path) -> None:
    log = tmp_path / "bus.log"
    drive = subprocess.Popen(
        [sys.executable, "-m", "omnican", "drive", "--sim", "--foxglove", "127.0.0.1:0",
         "--speed", "0.2", "--omega", "0.5", "--duration", str(DURATION_S),
         "--record", str(log)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
        cwd=tmp_path)
    try:
        assert drive.stderr is not None
        url = None
        for line in drive.stderr:  # its first lines: where the live view listens
            m = re.search(r"open a connection to (ws://\S+)", line)
            if m:
                url = m[1]
                break
        assert url is not None, "no Foxglove address announced"
        hogs = [[sys.executable, "-c", HOG]] * (os.cpu_count() or 2) * 2
        with processes([sys.executable, "-m", "tests.support.stalled_foxglove_client", url],
                       *hogs) as (client, *_):
            assert client.stdout is not None
            assert client.stdout.readline().startswith("subscribed")
            out, err = drive.communicate(timeout=DURATION_S + 60)
    finally:
        if drive.poll() is None:
            drive.kill()
            drive.communicate()
    assert drive.returncode == 0, err
    assert "heartbeat lost" not in err
    seen = frames(log)
    emcys = [(i - EMCY_BASE, d) for _, i, d in seen if EMCY_BASE < i < EMCY_BASE + 0x80]
    assert not [e for e in emcys if int(e[1][2:4] + e[1][0:2], 16) == EMCY_HEARTBEAT], emcys
    for node in (1, 2, 3):
        assert any(i == HEARTBEAT_BASE + node for _, i, _ in seen)
    assert "pose x=" in out
