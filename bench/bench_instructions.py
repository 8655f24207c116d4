"""Instructions omnican's host side executes per control cycle: the same number on every
run, so the figure to compare two commits by (timings on a shared VM move by a third);
beside it the same count for bench_cycle's minimal hand-written loop (the floor) and its
plain canopen loop, run unchanged on the same simulated clock and drives, for 3 wheels
(and ``--wheels 3,6,12``), and what the simulated drives themselves cost per cycle.

The base and three simulated drives run in lock-step on one thread (as bench_cycle's
lock-step row) under ``valgrind --tool=callgrind``, which counts only while the host
side runs: the control cycle, its sends, and its receive handlers, not the simulated
drives answering inside them. Collection is switched by a ten-line C extension built
here on the fly (valgrind's client requests have no Python binding).

Needs valgrind, a C compiler and Python's headers; says so and exits 2 otherwise.
The lock-step bus delivers frames directly, so python-can's virtual-bus cost (and the
threaded loop's wake-ups) are not in this figure: bench_cycle measures those.

Run: ``python bench/bench_instructions.py`` (about a minute per rate under valgrind);
``--rates 1000``; ``--cycles 500``. Prints one JSON object per line.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can

TOGGLE_C = r"""
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <valgrind/callgrind.h>
static PyObject *toggle(PyObject *m, PyObject *a) { CALLGRIND_TOGGLE_COLLECT; Py_RETURN_NONE; }
static PyObject *zero(PyObject *m, PyObject *a) { CALLGRIND_ZERO_STATS; Py_RETURN_NONE; }
static PyObject *dump(PyObject *m, PyObject *a) { CALLGRIND_DUMP_STATS; Py_RETURN_NONE; }
static PyMethodDef methods[] = {{"toggle", toggle, METH_NOARGS, ""},
    {"zero", zero, METH_NOARGS, ""}, {"dump", dump, METH_NOARGS, ""}, {NULL}};
static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "cgtoggle", NULL, -1, methods};
PyMODINIT_FUNC PyInit_cgtoggle(void) { return PyModule_Create(&module); }
"""


def build_toggle(where: Path) -> str | None:
    """Build the cgtoggle extension into ``where``; None, or why it could not be built."""
    if shutil.which("valgrind") is None:
        return "valgrind is not installed"
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return "no C compiler (cc)"
    src = where / "cgtoggle.c"
    src.write_text(TOGGLE_C)
    out = where / f"cgtoggle{sysconfig.get_config_var('EXT_SUFFIX')}"
    done = subprocess.run([cc, "-O2", "-shared", "-fPIC", f"-I{sysconfig.get_paths()['include']}",
                           str(src), "-o", str(out)], check=False, capture_output=True,
                          text=True)
    if done.returncode != 0:
        return f"building the collection switch failed: {done.stderr.strip().splitlines()[-1]}"
    return None


def _toggler() -> Any:
    """``wrap(owner, fn)``: ``fn`` counted when ``owner`` is the side counted (the host,
    or with OMNICAN_COUNT_SIDE=sim the simulated drives), however the calls nest (a host
    send answered inside by the simulated drives)."""
    import cgtoggle  # type: ignore[import-not-found]  # built by the parent

    side = os.environ.get("OMNICAN_COUNT_SIDE", "host")
    owners: list[str] = []

    def wrap(owner: str, fn: Any) -> Any:
        def run(*args: Any, **kwargs: Any) -> Any:
            before = bool(owners) and owners[-1] == side
            owners.append(owner)
            if (owner == side) != before:
                cgtoggle.toggle()
            try:
                return fn(*args, **kwargs)
            finally:
                owners.pop()
                after = bool(owners) and owners[-1] == side
                if after != (owner == side):
                    cgtoggle.toggle()
        return run

    return wrap


def _counted(wrap: Any, clock: Any, sim: Any, rate_hz: float, cycles: int,
             command: Any, count: Any) -> None:
    """Run ``cycles`` cycles with the collection on for the host side only (``wrap``: the
    one toggler the host's functions are wrapped with too); print them."""
    import cgtoggle

    sim_bus = sim.network.bus
    sim_bus.set_receiver(wrap("sim", sim_bus._receiver))
    ticks = sim.scheduler._ticks
    ticks[:] = [wrap("sim", tick) for tick in ticks]
    cycles0 = count()
    cgtoggle.zero()
    for k in range(max(cycles // 10, 1)):
        command(k)
        clock.sleep(10 / rate_hz)
    cgtoggle.dump()
    print(json.dumps({"cycles": count() - cycles0}))


def child(rate_hz: float, cycles: int, kind: str, wheels: int) -> None:
    """Runs under callgrind: one kind of loop against lock-step simulated drives,
    counting only the host side."""
    from bench_chassis import config

    from omnican import Chassis
    from omnican.clock import SimClock
    from omnican.sim import SimulatedBase

    cfg = config(rate_hz, wheels)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim:
        if kind == "omnican":
            with Chassis.open(cfg, clock=clock) as base:
                clock.sleep(0.3)
                knockout = os.environ.get("OMNICAN_KNOCKOUT")
                if knockout:  # bench_checks: one check replaced, the base up and enabled
                    from bench_checks import KNOCKOUTS

                    KNOCKOUTS[knockout][1](base)
                wrap = _toggler()
                host_bus = base.bus.network.bus
                host_bus.set_receiver(wrap("host", host_bus._receiver))  # type: ignore[union-attr]
                base._runner.cycle = wrap("host", base._runner.cycle)
                _counted(wrap, clock, sim, rate_hz, cycles,
                         lambda k: base.set_velocity(0.3 * math.sin(k * 0.01), 0.1, 0.2),
                         lambda: base._loop.cycles)  # (the snapshot's may be frozen)
            return
        with _hand_loop(cfg, clock, kind) as (step, count):
            wrap = _toggler()
            task = clock.every(1.0 / rate_hz, wrap("host", step))
            clock.sleep(0.3)
            _counted(wrap, clock, sim, rate_hz, cycles, lambda k: None, count)
            clock.cancel(task)


@contextlib.contextmanager
def _hand_loop(cfg: Any, clock: Any, kind: str) -> Iterator[tuple[Any, Any]]:
    """bench_cycle's hand-written loops ("minimal", "canopen"), unchanged in what a cycle
    does, on the lock-step clock: (the cycle, a function giving the cycles run)."""
    import struct

    import canopen

    from omnican.io.lockstep import LockstepBus, listeners_receiver

    channel = str(cfg.bus["channel"])
    net = canopen.Network()
    bus = LockstepBus(channel, clock)
    bus.set_receiver(listeners_receiver(net.listeners))
    net.bus = bus
    nodes = []
    for w in cfg.wheels:
        node = canopen.RemoteNode(w.node_id, str(w.eds))
        net.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 0.01  # answers come inside the request's send
        node.sdo[0x6060].raw = 3
        node.tpdo.read()
        node.rpdo.read()
        nodes.append(node)
    net.nmt.state = "OPERATIONAL"
    clock.sleep(0.05)
    for cw in (6, 7, 15):
        for node in nodes:
            node.rpdo[1]["Controlword"].raw = cw
            node.rpdo[1].transmit()
        clock.sleep(0.01)
    kin = cfg.kinematics()
    counters = {"cycles": 0}
    if kind == "canopen":
        import numpy as np

        last: list[Any] = [None]

        def step(now: float) -> None:
            speeds = kin.to_wheel_speeds_array(np.array([[0.2, 0.1, 0.3]]))[0]
            for node, w, v in zip(nodes, cfg.wheels, speeds, strict=True):
                node.rpdo[2]["Target velocity"].raw = round(v * w.velocity_scale)
                node.rpdo[2].transmit()
            net.sync.transmit()
            pos = [node.tpdo[2]["Position actual value"].raw for node in nodes]
            travel = np.array(pos) / cfg.wheels[0].position_scale
            if last[0] is not None:
                kin.to_twist(travel - last[0])
            last[0] = travel
            counters["cycles"] += 1
    else:
        bus.set_receiver(None)  # frames queue for recv(), read on the loop's thread
        rows, fwd = kin.rows, kin.forward_rows
        targets = []
        slots: dict[int, tuple[int, int, float]] = {}
        pack = struct.Struct("<i").pack
        for i, (node, w) in enumerate(zip(nodes, cfg.wheels, strict=True)):
            var = node.rpdo[2]["Target velocity"]
            msg = can.Message(arbitration_id=node.rpdo[2].cob_id, is_extended_id=False,
                              data=bytes(node.rpdo[2].data))
            targets.append((msg, pack, var.offset // 8, w.velocity_scale,
                            bytearray(node.rpdo[2].data)))
            pos = node.tpdo[2]["Position actual value"]
            slots[node.tpdo[2].cob_id] = (i, pos.offset // 8, w.position_scale)
        unpack = struct.Struct("<i").unpack_from
        sync_msg = can.Message(arbitration_id=0x80, is_extended_id=False, data=b"")
        pose = [0.0, 0.0, 0.0]
        travel = [0.0] * len(nodes)
        previous: list[list[float] | None] = [None]
        recv, send = bus.recv, bus.send

        def step(now: float) -> None:
            while (m := recv(0)) is not None:
                slot = slots.get(m.arbitration_id)
                if slot is not None:
                    travel[slot[0]] = unpack(m.data, slot[1])[0] / slot[2]
            last_ = previous[0]
            if last_ is not None:
                dx = dy = dw = 0.0
                for k, (t, t0) in enumerate(zip(travel, last_, strict=True)):
                    d = t - t0
                    dx += fwd[0][k] * d
                    dy += fwd[1][k] * d
                    dw += fwd[2][k] * d
                c, s_ = math.cos(pose[2]), math.sin(pose[2])
                pose[0] += c * dx - s_ * dy
                pose[1] += s_ * dx + c * dy
                pose[2] += dw
            previous[0] = list(travel)
            for (msg, pack_, off, scale, buf), (a, b, c_) in zip(targets, rows, strict=True):
                buf[off:off + 4] = pack_(round((a * 0.2 + b * 0.1 + c_ * 0.3) * scale))
                msg.data = bytes(buf)  # type: ignore[assignment]  # copied for free
                send(msg)
            send(sync_msg)
            counters["cycles"] += 1
    try:
        yield step, lambda: counters["cycles"]
    finally:
        bus.shutdown()


def measure(rate_hz: float, cycles: int, toggle_dir: Path, out_dir: Path, kind: str = "omnican",
            wheels: int = 3, side: str = "host") -> dict[str, Any]:
    env = dict(os.environ)
    env["OMNICAN_COUNT_SIDE"] = side
    here = Path(__file__).resolve().parent
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(toggle_dir), str(here),
                                                      env.get("PYTHONPATH")]))
    prefix = out_dir / f"cg-{kind}-{wheels}-{int(rate_hz)}-{side}"
    done = subprocess.run(
        ["valgrind", "--tool=callgrind", "--collect-atstart=no",
         f"--callgrind-out-file={prefix}.%p", sys.executable, str(Path(__file__).resolve()),
         "--child", str(rate_hz), str(cycles), kind, str(wheels)],
        check=False, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise SystemExit(f"bench_instructions: the run under valgrind failed:\n{done.stderr[-2000:]}")
    n = json.loads(done.stdout.strip().splitlines()[-1])["cycles"]
    # The client request's dump (suffix .1) holds exactly the measured cycles.
    dumps = sorted(out_dir.glob(f"{prefix.name}.*.1"), key=lambda p: p.stat().st_mtime,
                   reverse=True)  # this run's (a kept directory may hold older ones)
    total = 0
    for line in dumps[0].read_text().splitlines():
        if line.startswith("summary:"):
            total = int(line.split()[1])
    return {"bench": f"{side}_instructions", "loop": kind, "wheels": wheels, "rate_hz": rate_hz,
            "cycles": n, "instructions_per_cycle": round(total / max(n, 1))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rates", default="100,1000", help="comma-separated rates in Hz")
    parser.add_argument("--cycles", type=int, default=1000, help="cycles counted per rate")
    parser.add_argument("--loops", default="omnican,minimal,canopen",
                        help="which loops to count: omnican, minimal, canopen")
    parser.add_argument("--wheels", default="3", help="comma-separated wheel counts (3,6,12)")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help="keep callgrind's output files in DIR (read them with "
                             "callgrind_annotate: the top functions per cycle)")
    parser.add_argument("--child", nargs=4, metavar=("RATE", "CYCLES", "LOOP", "WHEELS"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(float(args.child[0]), int(args.child[1]), args.child[2], int(args.child[3]))
        return
    with tempfile.TemporaryDirectory() as tmp:
        why = build_toggle(Path(tmp))
        if why is not None:
            print(f"bench_instructions: cannot count instructions here: {why}", file=sys.stderr)
            raise SystemExit(2)
        out = Path(tmp)
        if args.keep is not None:
            args.keep.mkdir(parents=True, exist_ok=True)
            out = args.keep
        counts: dict[tuple[str, int, float], int] = {}
        for wheels in (int(w) for w in args.wheels.split(",")):
            for rate in (float(r) for r in args.rates.split(",")):
                for kind in args.loops.split(","):
                    row = measure(rate, args.cycles, Path(tmp), out, kind, wheels)
                    counts[(kind, wheels, rate)] = row["instructions_per_cycle"]
                    print(json.dumps(row), flush=True)
        _summary(counts)
        if "omnican" in args.loops.split(","):  # what the simulated drives cost per cycle
            for rate in (float(r) for r in args.rates.split(",")):
                row = measure(rate, args.cycles, Path(tmp), out, "omnican", 3, "sim")
                row["host"] = counts.get(("omnican", 3, rate))
                print(json.dumps(row), flush=True)


def _summary(counts: dict[tuple[str, int, float], int]) -> None:
    """omnican against the minimal loop (the floor) and plain canopen, per rate and wheel
    count; and what each wheel beyond three adds to each."""
    for (kind, wheels, rate), n in sorted(counts.items()):
        if kind != "omnican":
            continue
        row: dict[str, Any] = {"bench": "host_instructions.ratio", "wheels": wheels,
                               "rate_hz": rate, "omnican": n}
        for other in ("minimal", "canopen"):
            m = counts.get((other, wheels, rate))
            if m:
                row[other] = m
                row[f"omnican_per_{other}"] = round(n / m, 3)
        base_o, base_m = counts.get(("omnican", 3, rate)), counts.get(("minimal", 3, rate))
        if wheels != 3 and base_o and base_m and ("minimal", wheels, rate) in counts:
            added_o = (n - base_o) / (wheels - 3)
            added_m = (counts[("minimal", wheels, rate)] - base_m) / (wheels - 3)
            row["added_per_wheel"] = {"omnican": round(added_o), "minimal": round(added_m),
                                      "ratio": round(added_o / added_m, 2) if added_m else None}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
