"""Commissioning benchmark: how long three simulated drives without node ids (FFh, one
vendor and product) take to get the node ids the config names for their serials, with
``omnican.analysis.commission.commission`` (fast scan, configure, store, reset, read
back); issue 38 wants under 10 s. Prints one JSON object per line.

Two buses: the simulator in this process on a virtual channel, and ``omnican sim
--unconfigured`` in another process behind its loopback hub (``-i remote``), where every
LSS answer crosses a WebSocket. Figures per LSS answer timeout (``--lss-timeout``): the
fast scan waits one timeout for each 1 bit of each identity.

Run: ``python bench/bench_commission.py`` (about a minute; ``--quick``: one run each).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import replace
from pathlib import Path
from typing import Any

from omnican import default_config
from omnican.analysis.commission import commission
from omnican.config import ChassisConfig
from omnican.sim import SimulatedBase

ROOT = Path(__file__).resolve().parents[1]
SERIALS = (0x00012345, 0x00012346, 0x00012347)


def emit(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


def config(bus: dict[str, Any]) -> ChassisConfig:
    cfg = default_config(bus=bus)
    return replace(cfg, wheels=tuple(replace(w, serial=s)
                                     for w, s in zip(cfg.wheels, SERIALS, strict=True)))


def timed(cfg: ChassisConfig, lss_timeout_s: float) -> tuple[float, bool]:
    start = time.monotonic()
    result = commission(cfg, lss_timeout_s=lss_timeout_s)
    took = time.monotonic() - start
    ok = result.ok and all(r.after == r.wanted for r in result.drives)
    if not ok:
        emit(problems=list(result.problems), drives=[
            {"serial": r.serial, "after": r.after, "wanted": r.wanted, "note": r.note}
            for r in result.drives])
    return took, ok


def in_process(lss_timeout_s: float) -> tuple[float, bool]:
    channel = f"bench-commission-{uuid.uuid4().hex[:8]}"
    cfg = config({"interface": "virtual", "channel": channel})
    with SimulatedBase.from_config(cfg, unconfigured=True):
        return timed(cfg, lss_timeout_s)


def across_processes(lss_timeout_s: float) -> tuple[float, bool]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with tempfile.TemporaryDirectory() as tmp:
        toml = Path(tmp) / "robot.toml"
        toml.write_text('[chassis]\nlayout = "b21"\nbase_radius = 0.19\n\n' + "".join(
            f"[[wheel]]\nnode_id = {n}\nserial = {s}\nvelocity_scale = -4772.44\n"
            "position_scale = 48000.0\n\n" for n, s in zip((1, 2, 3), SERIALS, strict=True)))
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        proc = subprocess.Popen(
            [sys.executable, "-m", "omnican", "sim", "--config", str(toml), "--unconfigured",
             "--serve", f"127.0.0.1:{port}"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL, text=True, env=env)
        try:
            assert proc.stdout is not None
            while not proc.stdout.readline().startswith("type a command"):
                pass
            cfg = config({"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"})
            return timed(cfg, lss_timeout_s)
        finally:
            proc.kill()
            proc.communicate(timeout=10)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="one run each")
    args = parser.parse_args()
    runs = 1 if args.quick else 3
    for where, run in (("in process (virtual)", in_process),
                       ("another process (omnican sim, remote hub)", across_processes)):
        for timeout in (0.05, 0.2):
            figures = [run(timeout) for _ in range(runs)]
            emit(bench="commission three drives", bus=where, lss_timeout_s=timeout,
                 seconds=[round(s, 2) for s, _ in figures],
                 all_given_their_ids=all(ok for _, ok in figures))


if __name__ == "__main__":
    main()
