"""What a base on Zenoh costs and what a fleet of them does, on one loopback router.

``--part loop`` (in one process): the simulated base at 100 Hz with its Zenoh front end
(every topic published to an in-process router on 127.0.0.1, a cmd_vel publisher at
20 Hz driving it) against the same base driven directly with no front end; rounds
interleave. Per run: the control loop's CPU per cycle and its longest gap between cycles
(the front end is a telemetry sink: nothing of it runs on the loop thread), the CPU of
every thread by name, and what one base puts on the network: messages and bytes per
second per topic (key, payload and attachment, as a subscriber to every key of another
session receives them).

``--part fleet``: ``--bases`` (10) ``omnican zenoh --sim`` processes, clients of one
router, and ``omnican.zenoh.fleet.Fleet`` in this process: the time from each base's
start (its process spawned; its front end up) to its row in the fleet view; each base
driven at 0.3 m/s by a cmd_vel publisher of its own, then the fleet stop: from the call
to every reply, and to the last base's wheels at rest on the simulators' truth (each
base's ``sim/true_pose``: at rest once it no longer moves); one base killed with SIGKILL:
the time until the fleet view shows it lost; messages and bytes per second per base; the
CPU of each base's process.

``--part view``: one fleet view against 100 and ``--view-bases`` (1,000) stand-in bases
in another process (their summaries at 2 Hz, their stop services answering at once).

``--part hostile``: ``--hostile-bases`` (3) ``omnican zenoh --sim`` processes and a
stranger's process that declares 0, 1,000 and 5,000 (``--spoofed``) liveliness tokens
announcing bases that do not exist (no summary, no service). For each count: discovery
in this process (a :class:`~omnican.zenoh.fleet.Fleet` from its creation to every real
base listed, and to :meth:`~omnican.zenoh.fleet.Fleet.settled`, with what it ignored)
and as a user runs it (``omnican fleet --once --json`` from its spawn to its exit, and
whether it listed the real bases and only them); then, every base driven at 0.2 m/s by a
cmd_vel publisher that keeps sending, ``omnican fleet --stop all`` as a process: from its
spawn to the last base's wheels at rest on the simulators' truth, and to its exit.

Run: ``python bench/bench_fleet.py`` (every part; ``--part loop|fleet|view|hostile``,
``--seconds``, ``--rounds``, ``--bases``).
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from bench_chassis import config, cycle_starts, emit
from bench_ros2 import thread_cpu_s

from omnican import Chassis
from omnican.sim import SimulatedBase
from omnican.telemetry import cdr
from omnican.telemetry.attach import add_truth
from omnican.zenoh import rmw
from omnican.zenoh.bridge import open_session
from omnican.zenoh.settings import ZenohSettings

RATE_HZ = 100.0
CMD_HZ = 20.0
TWIST = "geometry_msgs/msg/Twist"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextmanager
def router() -> Iterator[str]:
    """A Zenoh router in this process on tcp/127.0.0.1:<free port>, multicast scouting
    off; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohSettings(mode="router", listen=(endpoint,)))
    try:
        yield endpoint
    finally:
        session.close()


def client(endpoint: str) -> Any:
    """A client session of the router at ``endpoint`` (multicast scouting off)."""
    return open_session(ZenohSettings(mode="client", connect=(endpoint,)))


class Wire:
    """Counts what one session receives on every key: messages and bytes (key, payload,
    attachment) per key."""

    def __init__(self, session: Any, selector: str = "**") -> None:
        self.messages: dict[str, int] = defaultdict(int)
        self.bytes: dict[str, int] = defaultdict(int)
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(selector, self._on)

    def _on(self, sample: Any) -> None:
        key = str(sample.key_expr)
        size = len(key) + len(sample.payload.to_bytes())
        if sample.attachment is not None:
            size += len(sample.attachment.to_bytes())
        with self._lock:
            self.messages[key] += 1
            self.bytes[key] += size

    def take(self) -> tuple[dict[str, int], dict[str, int]]:
        """What came since the last take: (messages, bytes) per key."""
        with self._lock:
            out = dict(self.messages), dict(self.bytes)
            self.messages.clear()
            self.bytes.clear()
        return out

    def close(self) -> None:
        self._sub.undeclare()


class CmdVel:
    """A cmd_vel publisher in rmw_zenoh's format (what a ROS 2 node on rmw_zenoh sends)."""

    def __init__(self, session: Any, topic: str, gid: bytes) -> None:
        self.key = rmw.data_key(0, topic, TWIST, rmw.type_hash(TWIST))
        self._pub = session.declare_publisher(self.key)
        self._gid = gid
        self._seq = 0

    def send(self, vx: float) -> None:
        self._seq += 1
        data = cdr.encode(TWIST, {"linear": {"x": vx, "y": 0.0, "z": 0.0},
                                  "angular": {"x": 0.0, "y": 0.0, "z": 0.0}})
        self._pub.put(data, attachment=rmw.Attachment(self._seq, time.time_ns(),
                                                      self._gid).encode())

    def close(self) -> None:
        self._pub.undeclare()


# ------------------------------------------------------------ one base: the loop's share


def loop_run(seconds: float, bridge_on: bool) -> dict[str, Any]:
    from omnican.zenoh.bridge import ZenohBridge

    cfg = config(RATE_HZ)
    with router() as endpoint, SimulatedBase.from_config(cfg) as sim, \
            Chassis.open(cfg) as base:
        starts = cycle_starts(base)
        watcher = client(endpoint)
        wire = Wire(watcher)
        session = bridge = cmd = None
        try:
            if bridge_on:
                settings = ZenohSettings(mode="client", connect=(endpoint,))
                session = open_session(settings)
                add_truth(base, sim)  # as a command's session does
                bridge = ZenohBridge(base, settings, session, sim=sim).start()
                cmd = CmdVel(watcher, bridge.cmd_topic, bytes(range(16)))
            time.sleep(1.0)  # the sessions meet, the base reaches speed
            wire.take()
            cpu0, cycles0, n0 = base.loop_cpu_s, base.status.cycles, len(starts)
            threads0 = thread_cpu_s()
            t0 = time.monotonic()
            while (now := time.monotonic()) < t0 + seconds:
                if cmd is not None:
                    cmd.send(0.3)
                else:
                    base.set_velocity(0.3, 0.0, 0.0)
                time.sleep(max(0.0, 1.0 / CMD_HZ - (time.monotonic() - now)))
            elapsed = time.monotonic() - t0
            messages, sizes = wire.take()
            threads = {k: v - threads0.get(k, 0.0) for k, v in thread_cpu_s().items()}
            window = starts[n0:]
            gaps = [b - a for a, b in itertools.pairwise(window)]
            cycles = base.status.cycles - cycles0
            out: dict[str, Any] = {
                "bench": "fleet.loop", "zenoh": bridge_on, "seconds": round(elapsed, 2),
                "true_vx": round(sim.true_twist.vx, 3),
                "loop_cpu_us_per_cycle": round((base.loop_cpu_s - cpu0) / max(1, cycles)
                                               * 1e6, 1),
                "loop_longest_gap_ms": round(max(gaps, default=0.0) * 1e3, 1),
                "cpu_percent_by_thread": {
                    k: round(v / elapsed * 100, 2)
                    for k, v in sorted(threads.items(), key=lambda kv: -kv[1])
                    if v / elapsed >= 0.001},
            }
            if bridge_on:
                per_topic: dict[str, list[float]] = {}
                for key, n in messages.items():
                    if key == cmd.key if cmd is not None else False:
                        continue
                    per_topic[rmw.topic_of(key)] = [round(n / elapsed, 1),
                                              round(sizes[key] / elapsed)]
                out["per_topic_msgs_bytes_per_s"] = dict(sorted(per_topic.items()))
                out["msgs_per_s"] = round(sum(v[0] for v in per_topic.values()), 1)
                out["bytes_per_s"] = round(sum(v[1] for v in per_topic.values()))
            return out
        finally:
            if cmd is not None:
                cmd.close()
            if bridge is not None:
                bridge.close()
            if session is not None:
                session.close()
            wire.close()
            watcher.close()


def loop_part(seconds: float, rounds: int) -> None:
    runs: dict[bool, list[dict[str, Any]]] = {False: [], True: []}
    for _ in range(rounds):
        for on in (False, True):
            result = loop_run(seconds, on)
            emit(**result)
            runs[on].append(result)
    off, on = runs[False], runs[True]
    emit(bench="fleet.loop.summary",
         loop_cpu_us_per_cycle_without=round(statistics.median(
             r["loop_cpu_us_per_cycle"] for r in off), 1),
         loop_cpu_us_per_cycle_with=round(statistics.median(
             r["loop_cpu_us_per_cycle"] for r in on), 1),
         loop_longest_gap_ms_without=max(r["loop_longest_gap_ms"] for r in off),
         loop_longest_gap_ms_with=max(r["loop_longest_gap_ms"] for r in on),
         msgs_per_s=statistics.median(r["msgs_per_s"] for r in on),
         bytes_per_s=statistics.median(r["bytes_per_s"] for r in on))


# ------------------------------------------------------------ ten bases, one router


class BaseProcess:
    """One ``omnican zenoh --sim`` process, a client of the router, in namespace ``ns``."""

    def __init__(self, ns: str, endpoint: str) -> None:
        self.ns = ns
        self.name = f"{ns}/omnican"
        self.spawned = time.monotonic()
        self.ready: float | None = None  # its front end up ("Ctrl-C to stop")
        self.seen: float | None = None  # its row in the fleet view
        self.token_at: float | None = None  # its liveliness token heard
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "omnican", "zenoh", "--sim", "--namespace", ns,
             "--zenoh-mode", "client", "--zenoh-connect", endpoint],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())
            if self.ready is None and "Ctrl-C to stop" in line:
                self.ready = time.monotonic()

    def cpu_s(self) -> float:
        with open(f"/proc/{self.proc.pid}/stat") as f:
            stat = f.read()
        fields = stat[stat.rindex(")") + 2:].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def quit(self) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(OSError):
                assert self.proc.stdin is not None
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def tcp_bytes_sent(pids: dict[int, str]) -> dict[str, int]:
    """Bytes each process has sent over its TCP sockets (``ss -tinp``'s bytes_sent)."""
    out = dict.fromkeys(pids.values(), 0)
    text = subprocess.run(["ss", "-tinpH"], capture_output=True, text=True,
                          check=False).stdout
    owner: str | None = None
    for line in text.splitlines():
        if not line.startswith((" ", "\t")):
            owner = None
            for pid, name in pids.items():
                if f"pid={pid}," in line:
                    owner = name
        elif owner is not None:
            for word in line.split():
                if word.startswith("bytes_sent:"):
                    out[owner] += int(word.split(":", 1)[1])
    return out


class Truth:
    """Each base's ``sim/true_pose`` as it arrives: (arrival, x, y) per base."""

    def __init__(self, session: Any, names: list[str]) -> None:
        ptype = "geometry_msgs/msg/PoseStamped"
        self.poses: dict[str, list[tuple[float, float, float]]] = {n: [] for n in names}
        self._subs = []
        for name in names:
            ns = name.rsplit("/", 1)[0]
            key = rmw.data_key(0, f"{ns}/sim/true_pose", ptype, rmw.type_hash(ptype))
            self._subs.append(session.declare_subscriber(key, self._on(name)))

    def _on(self, name: str) -> Any:
        def on(sample: Any) -> None:
            pos = cdr.decode("geometry_msgs/msg/PoseStamped",
                             sample.payload.to_bytes())["pose"]["position"]
            self.poses[name].append((time.monotonic(), pos["x"], pos["y"]))
        return on

    def moving(self, name: str, since: float) -> bool:
        recent = [p for p in self.poses[name] if p[0] >= since]
        return len(recent) > 1 and math.dist(recent[0][1:], recent[-1][1:]) > 0.01

    def at_rest_since(self, name: str, after: float, still_m: float = 1e-4) -> float | None:
        """When the base's last motion after ``after`` ended (the arrival of the first
        pose of the final still run), None if it never moved after then."""
        poses = [p for p in self.poses[name] if p[0] >= after]
        last_move = None
        for a, b in itertools.pairwise(poses):
            if math.dist(a[1:], b[1:]) > still_m:
                last_move = b[0]
        return last_move

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def fleet_part(count: int, seconds: float) -> None:
    from omnican.zenoh.fleet import Fleet

    with router() as endpoint:
        view_session, watcher = client(endpoint), client(endpoint)
        bases: list[BaseProcess] = []
        fleet = Fleet(view_session, 0)
        cmds: list[CmdVel] = []
        truth: Truth | None = None
        try:
            t0 = time.monotonic()
            bases = [BaseProcess(f"/robot{i}", endpoint) for i in range(count)]
            deadline = t0 + 120
            while time.monotonic() < deadline and any(b.seen is None for b in bases):
                rows = {v.name: v for v in fleet.bases()}
                now = time.monotonic()
                for b in bases:
                    row = rows.get(b.name)
                    if b.seen is None and row is not None and row.summary is not None:
                        b.seen = now
                time.sleep(0.01)
            tokens = fleet._discovery  # when each base's token came, and its first summary
            with tokens.lock:
                found = {e.name: e.found_at for e in tokens.entries.values()}
            for b in bases:
                b.token_at = found.get(b.name)
            from_spawn = [b.seen - b.spawned for b in bases if b.seen is not None]
            from_ready = [b.seen - b.ready for b in bases
                          if b.seen is not None and b.ready is not None]
            emit(bench="fleet.discovery", bases=count, seen=len(from_spawn),
                 all_seen_s_after_first_spawn=round(max(b.seen or math.inf for b in bases)
                                                    - t0, 2),
                 from_spawn_s={"median": round(statistics.median(from_spawn), 2),
                               "max": round(max(from_spawn), 2)},
                 from_front_end_up_s={"median": round(statistics.median(from_ready), 3),
                                      "max": round(max(from_ready), 3)},
                 token_from_front_end_up_s=[round(b.token_at - b.ready, 3) for b in bases
                                            if b.token_at is not None and b.ready],
                 seen_from_front_end_up_s=[round(b.seen - b.ready, 3) for b in bases
                                           if b.seen is not None and b.ready])

            # What each base sends while only the fleet view listens (its summaries), and
            # while another session takes every key (the whole telemetry).
            pids = {b.proc.pid: b.name for b in bases}
            for label in ("fleet view only", "every key"):
                wire = Wire(watcher) if label == "every key" else None
                sent0, cpu0 = tcp_bytes_sent(pids), {b.name: b.cpu_s() for b in bases}
                if wire is not None:
                    time.sleep(1.0)
                    wire.take()
                    sent0 = tcp_bytes_sent(pids)
                t1 = time.monotonic()
                time.sleep(seconds)
                elapsed = time.monotonic() - t1
                sent = tcp_bytes_sent(pids)
                cpu = {b.name: (b.cpu_s() - cpu0[b.name]) / elapsed * 100 for b in bases}
                fields: dict[str, Any] = {
                    "bench": "fleet.wire", "listening": label,
                    "tcp_bytes_per_s_per_base": round(statistics.median(
                        (sent[n] - sent0[n]) / elapsed for n in sent)),
                    "cpu_percent_per_base": {"median": round(statistics.median(cpu.values()),
                                                             1),
                                             "max": round(max(cpu.values()), 1)},
                    "load": [round(x, 1) for x in os.getloadavg()]}
                if wire is not None:
                    messages, sizes = wire.take()
                    wire.close()
                    per_base_msgs: dict[str, int] = defaultdict(int)
                    per_base_bytes: dict[str, int] = defaultdict(int)
                    for key, n in messages.items():
                        per_base_msgs[key.split("/")[1]] += n
                        per_base_bytes[key.split("/")[1]] += sizes[key]
                    fields["received_msgs_per_s_per_base"] = round(statistics.median(
                        per_base_msgs.values()) / elapsed, 1)
                    fields["received_bytes_per_s_per_base"] = round(statistics.median(
                        per_base_bytes.values()) / elapsed)
                emit(**fields)

            # The fleet stop: every base driven at 0.3 m/s by a cmd_vel publisher that
            # keeps sending (a navigation stack does), then one call.
            names = [b.name for b in bases]
            truth = Truth(watcher, names)
            cmds = [CmdVel(watcher, f"{b.ns}/cmd_vel", bytes([i + 1] * 16))
                    for i, b in enumerate(bases)]
            sending = threading.Event()
            sending.set()

            def drive() -> None:
                while sending.is_set():
                    for c in cmds:
                        c.send(0.3)
                    time.sleep(1.0 / CMD_HZ)

            driver = threading.Thread(target=drive, daemon=True)
            driver.start()
            since = time.monotonic()
            deadline = since + 60
            time.sleep(1.0)
            while time.monotonic() < deadline and not all(
                    truth.moving(n, time.monotonic() - 0.5) for n in names):
                time.sleep(0.05)
            moving = sum(truth.moving(n, time.monotonic() - 0.5) for n in names)
            key = time.monotonic()
            answers = fleet.stop_all()
            answered = time.monotonic()
            time.sleep(3.0)  # the ramps end; cmd_vel still arrives
            rest = [truth.at_rest_since(n, key) for n in names]
            still_moving = sum(truth.moving(n, time.monotonic() - 0.5) for n in names)
            sending.clear()
            driver.join()
            emit(bench="fleet.stop", bases=count, moving_before=moving,
                 answered_ok=sum(a.answered and a.success for a in answers),
                 every_answer_s=round(answered - key, 3),
                 last_wheels_at_rest_s=round(max(r for r in rest if r is not None) - key, 3)
                 if any(r is not None for r in rest) else None,
                 median_at_rest_s=round(statistics.median(
                     r - key for r in rest if r is not None), 3)
                 if any(r is not None for r in rest) else None,
                 moving_3s_later=still_moving,
                 answers=[str(a) for a in answers[:2]])

            # A base killed: how long until the fleet view says it is lost.
            victim = bases[0]
            victim.proc.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            lost_at = None
            while time.monotonic() < killed + 30:
                row = next((v for v in fleet.bases() if v.name == victim.name), None)
                if row is None or row.lost:
                    lost_at = time.monotonic()
                    break
                time.sleep(0.005)
            emit(bench="fleet.lost", killed=victim.name,
                 shown_lost_s=round(lost_at - killed, 3) if lost_at else None)
        finally:
            for c in cmds:
                c.close()
            if truth is not None:
                truth.close()
            fleet.close()
            for b in bases:
                b.quit()
            view_session.close()
            watcher.close()


# ------------------------------------------------------------ one view, many bases


def stand_ins(endpoint: str, count: int, seconds: float) -> None:
    """The other process of ``--part view``: ``count`` stand-in bases in one session, each
    with its summary publisher's liveliness token, their summaries at 2 Hz each."""
    from omnican.zenoh.bridge import STRING, string_cdr
    from omnican.zenoh.services import service_key, trigger_response

    session = client(endpoint)
    hash_ = rmw.type_hash(STRING)
    pubs, tokens, queryables = [], [], []
    stopped = trigger_response(True, "stopped: held until recover")

    def answer(query: Any) -> None:
        asked = rmw.Attachment.decode(query.attachment.to_bytes())
        query.reply(query.key_expr, stopped, attachment=rmw.Attachment(
            asked.sequence, time.time_ns(), asked.gid).encode())

    zid = str(session.info.zid())
    gids = []
    for i in range(count):
        node = rmw.RosNode(0, zid, i, "omnican", namespace=f"/robot{i}")
        fq = f"/robot{i}/base_summary"
        token = node.endpoint_token(1, rmw.Kind.PUBLISHER, fq, STRING, hash_, rmw.Qos())
        gids.append(rmw.gid_of(token))  # what a base's summaries carry: its token's GID
        tokens.append(session.liveliness().declare_token(token))
        pubs.append(session.declare_publisher(rmw.data_key(0, fq, STRING, hash_)))
        # ~/stop answered at once, as a base's poll would (the time of the network alone)
        queryables.append(session.declare_queryable(service_key(node, "stop"), answer,
                                                    complete=True))
    print("ready", flush=True)
    period = 0.5
    start = time.monotonic()
    n = 0
    while time.monotonic() < start + seconds:
        for i, pub in enumerate(pubs):
            text = json.dumps({
                "node": f"/robot{i}/omnican", "state": "RUNNING", "stopped_reason": "",
                "enabled": True, "estop": False,
                "pose": {"x": 1.0 + i, "y": 2.0, "theta": 0.5},
                "speed": {"vx": 0.2, "vy": 0.0, "wz": 0.1}, "battery_v": 24.0, "faults": [],
                "driver": "Zenoh cmd_vel publisher 000102030405060708090a0b0c0d0e0f",
                "stamp": time.time(), "period_s": period}).encode()
            pub.put(string_cdr(text), attachment=rmw.Attachment(
                n + 1, time.time_ns(), gids[i]).encode())
        n += 1
        time.sleep(max(0.0, start + n * period - time.monotonic()))
    print(json.dumps({"rounds": n, "bytes_per_summary": len(string_cdr(text))}), flush=True)
    for token in tokens:
        token.undeclare()
    for queryable in queryables:
        queryable.undeclare()
    session.close()


def view_part(count: int, seconds: float) -> None:
    from omnican.zenoh.fleet import Fleet

    with router() as endpoint:
        view_session = client(endpoint)
        fleet = Fleet(view_session, 0)
        child = subprocess.Popen([sys.executable, __file__, "--stand-ins", endpoint,
                                  str(count), str(seconds)], stdout=subprocess.PIPE, text=True,
                                 env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            assert child.stdout is not None
            assert child.stdout.readline().strip() == "ready"
            t0 = time.monotonic()
            while time.monotonic() < t0 + 60 and sum(
                    v.summary is not None for v in fleet.bases()) < count:
                time.sleep(0.05)
            found_s = time.monotonic() - t0
            cpu0, t1 = thread_cpu_s(), time.monotonic()
            calls = 0
            while time.monotonic() < t1 + min(seconds / 2, 10):
                views = fleet.bases()  # what a dashboard asks four times a second
                calls += 1
                time.sleep(0.25)
            elapsed = time.monotonic() - t1
            cpu = {k: v - cpu0.get(k, 0.0) for k, v in thread_cpu_s().items()}
            t2 = time.perf_counter()
            for _ in range(10):
                fleet.bases()
            bases_ms = (time.perf_counter() - t2) / 10 * 1e3
            t3 = time.monotonic()
            answers = fleet.stop_all(timeout_s=10.0)  # the network's share of a fleet stop
            stop_s = time.monotonic() - t3
            tail = json.loads(child.stdout.readline() or "{}")
            child.wait(timeout=60)
            emit(bench="fleet.view", bases=count, summaries_per_s=2 * count,
                 all_summarized_s=round(found_s, 2), seen=len(views),
                 cpu_percent_process=round(sum(cpu.values()) / elapsed * 100, 1),
                 cpu_percent_by_thread={k: round(v / elapsed * 100, 1)
                                        for k, v in sorted(cpu.items(), key=lambda kv: -kv[1])
                                        if v / elapsed >= 0.005},
                 fleet_bases_call_ms=round(bases_ms, 2),
                 stop_all_answered=sum(a.answered and a.success for a in answers),
                 stop_all_every_answer_s=round(stop_s, 3), **tail)
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
            fleet.close()
            view_session.close()


# ------------------------------------------------------------ a stranger's tokens


def spoofer(endpoint: str, count: int) -> None:
    """The other process of ``--part hostile``: ``count`` liveliness tokens that announce
    a base (``/spoof<i>/omnican``'s base_summary publisher), nothing behind them; until
    stdin closes."""
    from omnican.zenoh.bridge import STRING

    session = client(endpoint)
    zid, hash_ = str(session.info.zid()), rmw.type_hash(STRING)
    tokens = [session.liveliness().declare_token(
        rmw.RosNode(0, zid, i, "omnican", namespace=f"/spoof{i}").endpoint_token(
            1, rmw.Kind.PUBLISHER, f"/spoof{i}/base_summary", STRING, hash_, rmw.Qos()))
        for i in range(count)]
    print("ready", flush=True)
    sys.stdin.read()
    for token in tokens:
        token.undeclare()
    session.close()


def omnican_fleet(endpoint: str, *argv: str) -> tuple[float, subprocess.CompletedProcess[str]]:
    """``omnican fleet ARGV`` as a client of ``endpoint``: (seconds from spawn to exit, it)."""
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "omnican", "fleet", "--zenoh-connect",
                           endpoint, *argv], capture_output=True, text=True, timeout=300,
                          check=False)
    return time.monotonic() - t0, done


def hostile_part(counts: list[int], nbases: int) -> None:
    from omnican.zenoh.fleet import Fleet

    with router() as endpoint:
        watcher = client(endpoint)
        bases = [BaseProcess(f"/robot{i}", endpoint) for i in range(1, nbases + 1)]
        names = [b.name for b in bases]
        truth = Truth(watcher, names)
        cmds = [CmdVel(watcher, f"{b.ns}/cmd_vel", bytes([i + 1] * 16))
                for i, b in enumerate(bases)]
        sending = threading.Event()

        def drive() -> None:
            while True:
                if sending.is_set():
                    for c in cmds:
                        c.send(0.2)
                if stopping.wait(1.0 / CMD_HZ):
                    return

        stopping = threading.Event()
        driver = threading.Thread(target=drive, daemon=True)
        driver.start()
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and any(b.ready is None for b in bases):
                time.sleep(0.1)
            for count in counts:
                spoof = subprocess.Popen([sys.executable, __file__, "--spoof", endpoint,
                                          str(count)], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True)
                try:
                    assert spoof.stdout is not None
                    assert spoof.stdout.readline().strip() == "ready"
                    time.sleep(1.0)  # the router has them all
                    hostile_round(endpoint, count, names, truth, sending, Fleet)
                finally:
                    if spoof.stdin is not None:
                        spoof.stdin.close()
                    spoof.wait(timeout=60)
        finally:
            stopping.set()
            driver.join()
            for c in cmds:
                c.close()
            truth.close()
            for b in bases:
                b.quit()
            watcher.close()


def hostile_round(endpoint: str, count: int, names: list[str], truth: Truth,
                  sending: threading.Event, fleet_type: Any) -> None:
    """One count of spoofed tokens: discovery in process and as a process, the stop."""
    session = client(endpoint)
    t0 = time.monotonic()
    listed = settled = None
    with fleet_type(session, 0) as fleet:
        while time.monotonic() < t0 + 60 and settled is None:
            if listed is None and sorted(v.name for v in fleet.bases()) == names:
                listed = time.monotonic() - t0
            if fleet.settled():
                settled = time.monotonic() - t0
            time.sleep(0.01)
        ignored = fleet.ignored()
        shown = sorted(v.name for v in fleet.bases())
        # the bases recovered from the last round's stop (cmd_vel quiet: it may be)
        sending.clear()
        time.sleep(1.2)
        for answer in fleet.request("recover", fleet.bases(), 30.0).wait():
            if not answer.success:
                print(f"# recover {answer}", file=sys.stderr)
    session.close()
    once_s, once = omnican_fleet(endpoint, "--once", "--json", "--wait", "30")
    got = json.loads(once.stdout) if once.returncode == 0 else {}
    once_names = sorted(b["name"] for b in got.get("bases", []))

    sending.set()  # every base driven, a navigation stack that keeps sending
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not all(
            truth.moving(n, time.monotonic() - 0.5) for n in names):
        time.sleep(0.05)
    moving = sum(truth.moving(n, time.monotonic() - 0.5) for n in names)
    key = time.monotonic()
    stop_s, stop = omnican_fleet(endpoint, "--stop", "all", "--wait", "10", "--timeout", "10")
    time.sleep(2.0)  # the ramps end; cmd_vel still arrives
    rest = [truth.at_rest_since(n, key) for n in names]
    emit(bench="fleet.hostile", spoofed=count, bases=len(names),
         discovery_listed_s=None if listed is None else round(listed, 3),
         discovery_settled_s=None if settled is None else round(settled, 3),
         listed_only_the_bases=shown == names, ignored=ignored,
         once_process_s=round(once_s, 2), once_exit=once.returncode,
         once_listed_only_the_bases=once_names == names,
         once_ignored=got.get("ignored_tokens"),
         moving_before_stop=moving, stop_exit=stop.returncode,
         stop_process_s=round(stop_s, 2),
         stop_last_wheels_at_rest_s=round(max(r for r in rest if r is not None) - key, 2)
         if all(r is not None for r in rest) else None,
         stop_answers=stop.stdout.splitlines(),
         load=[round(x, 1) for x in os.getloadavg()])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--part", choices=("loop", "fleet", "view", "hostile", "all"),
                        default="all")
    parser.add_argument("--view-bases", type=int, default=1000,
                        help="stand-in bases for --part view (default 1000)")
    parser.add_argument("--stand-ins", nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--spoof", nargs=2, help=argparse.SUPPRESS)
    parser.add_argument("--hostile-bases", type=int, default=3)
    parser.add_argument("--spoofed", type=int, nargs="+", default=[0, 1000, 5000],
                        help="tokens the stranger declares, one round each (--part hostile)")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--bases", type=int, default=10)
    args = parser.parse_args()
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    if args.stand_ins:
        stand_ins(args.stand_ins[0], int(args.stand_ins[1]), float(args.stand_ins[2]))
        return
    if args.spoof:
        spoofer(args.spoof[0], int(args.spoof[1]))
        return
    if args.part in ("loop", "all"):
        loop_part(args.seconds, args.rounds)
    if args.part in ("fleet", "all"):
        fleet_part(args.bases, args.seconds)
    if args.part in ("view", "all"):
        for count in (100, args.view_bases):
            view_part(count, max(args.seconds, 20.0))
    if args.part in ("hostile", "all"):
        hostile_part(args.spoofed, args.hostile_bases)


if __name__ == "__main__":
    main()
