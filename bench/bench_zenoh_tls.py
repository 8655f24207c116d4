"""What the fleet's credentials cost: a base on Zenoh over plain TCP against the same over
mutual TLS with the access control of a base and a router (``omnican zenoh
credentials``' files), on one loopback router in this process.

Per round and per mode (rounds interleave the two): the time to open the base's session
(its link to the router: TCP, or the TLS handshake both ways), the time from that open to
the first ``base_summary`` a viewer's session receives through the router (the simulated
base, its front end and the viewer already up), and the round trip of a small message
through the router and back (an operator's put on a base's cmd_vel key, answered by a
session under the base's certificate on a key of its namespace; median and 95th
percentile of ``--calls``): what every message pays for TLS and the access-control
checks at the router, both ways.

Run: ``python bench/bench_zenoh_tls.py`` (``--rounds``, ``--calls``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench_chassis import config, emit
from bench_fleet import free_port

from omnican import Chassis
from omnican.sim import SimulatedBase
from omnican.zenoh import rmw
from omnican.zenoh.bridge import SUMMARY, ZenohBridge, open_session
from omnican.zenoh.credentials import make
from omnican.zenoh.security import Identity
from omnican.zenoh.settings import ZenohSettings


@contextlib.contextmanager
def closing_all() -> Iterator[list[Any]]:
    opened: list[Any] = []
    try:
        yield opened
    finally:
        for session in reversed(opened):
            session.close()


def one_round(mode: str, creds: Path, calls: int) -> dict[str, Any]:
    tls = mode == "mtls"
    endpoint = f"{'tls' if tls else 'tcp'}/127.0.0.1:{free_port()}"

    def settings(identity: str, **kw: Any) -> ZenohSettings:
        extra = {"credentials": str(creds), "identity": identity} if tls else {}
        return ZenohSettings(**kw, **extra)

    cfg = config(100.0)
    with closing_all() as opened, SimulatedBase.from_config(cfg) as sim, \
            Chassis.open(cfg) as base:
        opened.append(open_session(settings("router/router", mode="router",
                                            listen=(endpoint,))))
        viewer = open_session(settings("viewer/bob", mode="client", connect=(endpoint,)))
        opened.append(viewer)
        base_settings = settings("base/robot1", mode="client", connect=(endpoint,),
                                 namespace="/robot1")
        first = threading.Event()
        summary_key = rmw.data_key(0, "/robot1/base_summary", "std_msgs/msg/String",
                                   rmw.type_hash("std_msgs/msg/String"))
        sub = viewer.declare_subscriber(summary_key, lambda s: first.set())
        t0 = time.perf_counter()
        session = open_session(base_settings)
        opened.append(session)
        t_open = time.perf_counter() - t0
        with ZenohBridge(base, base_settings, session, sim=sim) as bridge:
            assert bridge.publishers[SUMMARY].key == summary_key
            if not first.wait(60.0):
                raise RuntimeError(f"{mode}: no summary within 60 s")
            t_summary = time.perf_counter() - t0
        operator = open_session(settings("operator/alice", mode="client",
                                         connect=(endpoint,)))
        echo = open_session(settings("base/robot1", mode="client", connect=(endpoint,),
                                     namespace="/robot1"))
        opened += [operator, echo]
        ping, pong = "0/robot1/cmd_vel/bench", "0/robot1/bench_pong"
        answer = echo.declare_publisher(pong)
        got = threading.Event()
        subs = [echo.declare_subscriber(ping, lambda s: answer.put(s.payload.to_bytes())),
                operator.declare_subscriber(pong, lambda s: got.set())]
        sender = operator.declare_publisher(ping)
        while not (sender.matching_status.matching and answer.matching_status.matching):
            time.sleep(0.01)
        times = []
        for _ in range(calls):
            got.clear()
            start = time.perf_counter()
            sender.put(b"x" * 48)  # a Twist's size
            if not got.wait(5.0):
                raise RuntimeError(f"{mode}: no answer")
            times.append(time.perf_counter() - start)
        for sub_ in subs:
            sub_.undeclare()
        sub.undeclare()
    times.sort()
    return {"mode": mode, "open_s": round(t_open, 4), "first_summary_s": round(t_summary, 3),
            "rtt_ms_median": round(1e3 * statistics.median(times), 3),
            "rtt_ms_p95": round(1e3 * times[int(0.95 * (len(times) - 1))], 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--calls", type=int, default=1000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        creds = Path(tmp) / "fleet"
        make(creds, [Identity("router", "router"), Identity("base", "robot1"),
                     Identity("viewer", "bob"), Identity("operator", "alice")])
        results: dict[str, list[dict[str, Any]]] = {"tcp": [], "mtls": []}
        for _ in range(args.rounds):
            for mode, rows in results.items():
                result = one_round(mode, creds, args.calls)
                rows.append(result)
                emit(event="round", **result)
    for mode, rows in results.items():
        emit(event="summary", mode=mode, **{
            key: [row[key] for row in rows] for key in rows[0] if key != "mode"})
    print(json.dumps({"rounds": args.rounds, "calls": args.calls}))


if __name__ == "__main__":
    main()
