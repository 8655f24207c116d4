"""``omnican drive --sim`` as a process of its own, beside a Foxglove client that
subscribes to everything and never reads, and programs that keep every core busy: its
simulated drives are as steady as the base's loop, which runs them. Their heartbeats
never fall further behind than the host's own (the loop's); a drive reacts to a lost
host heartbeat (EMCY 8130h) only after the loop itself stalled past the drives'
consumer time, as real drives would; and where it never did, the base runs to the end.

How long a loaded machine stalls the loop is the machine's (bench/bench_sim_steady.py
measures it); what this test holds is that the simulator adds no stall of its own: before
the drives ran on the loop, beside a busy desktop they missed heartbeats while the loop
kept its rate."""

from __future__ import annotations

import importlib.util
import itertools
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
HOST_NODE_ID = 127  # [chassis] host_node_id's default
PERIOD_S = 0.1  # [chassis] heartbeat_ms's default
CONSUMER_S = 3.5 * PERIOD_S  # heartbeat_timeout_factor 3 and half a period
SLACK_S = 0.03  # a few cycles of the 100 Hz loop
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


def gaps(times: list[float]) -> list[float]:
    return [b - a for a, b in itertools.pairwise(times)] or [0.0]


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
    seen = frames(log)
    host = [t for t, i, _ in seen if i == HEARTBEAT_BASE + HOST_NODE_ID]
    assert len(host) >= 2, "the host's heartbeats are in the recording"
    host_gap = max(gaps(host))
    for node in (1, 2, 3):
        beats = [t for t, i, _ in seen if i == HEARTBEAT_BASE + node]
        assert len(beats) >= 2, f"node {node}'s heartbeats are in the recording"
        # The drives run on the loop: a drive's heartbeat is late only when the loop is.
        assert max(gaps(beats)) <= host_gap + PERIOD_S + SLACK_S, (node, host_gap, err)
    emcys = [(t, i - EMCY_BASE) for t, i, d in seen if EMCY_BASE < i < EMCY_BASE + 0x80
             and int(d[2:4] + d[0:2], 16) == EMCY_HEARTBEAT]
    if emcys:  # the drives lost the host: only after the loop stalled past their time
        first = emcys[0][0]
        before = [t for t in host if t <= first]
        stalled = max(gaps([*before, first]))
        assert stalled > CONSUMER_S - SLACK_S, (emcys, stalled, err)
        assert drive.returncode == 1 and "base stopped" in err, err
    elif host_gap < CONSUMER_S - SLACK_S:  # the loop never stalled that long: no stop
        assert drive.returncode == 0, err
        assert "heartbeat lost" not in err
        assert "pose x=" in out
