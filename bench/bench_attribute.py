"""Instructions per control cycle by part: which of the host side's calls costs what,
counted as bench_instructions counts the whole (valgrind's callgrind, lock-step, the
host side only), in one run: a first stretch of cycles with everything counted, then
one stretch per part with that part's calls left out of the count. A part's cost is
the difference (its calls and everything they call, per cycle, with the collector
off; the wrapper that leaves
it out adds a few hundred instructions per call, so small parts read a little high).

Run: ``python bench/bench_attribute.py`` (100 Hz, 200 cycles per stretch, a few
minutes); ``--rate 1000``. Prints one JSON object per part, then the total.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_instructions import _toggler, build_toggle


def _parts(base: Any) -> list[tuple[str, Any, str]]:
    """(name, owner, attribute) of each part: the attribute on the owner is wrapped."""
    from omnican.chassis.checks import ChassisChecks
    from omnican.core.limits import VelocityLimiter
    from omnican.core.odometry import Odometry
    from omnican.core.wheel_odometry import WheelOdometry
    from omnican.drive.power_state import StageDriver
    from omnican.io.bus_watch import BusWatch

    loop = base._loop
    bus = base.bus
    parts: list[tuple[str, Any, str]] = [
        ("receive (every frame's handlers)", bus.network.bus, "_receiver"),
        ("bus.poll", bus, "poll"),
        ("supervisor.check", loop._sup, "check"),
        ("chassis checks (10 Hz)", ChassisChecks, "check"),
        ("wheel_odometry.integrate", WheelOdometry, "integrate"),
        ("odometry.step", Odometry, "step"),
        ("limiter.step_xyz", VelocityLimiter, "step_xyz"),
        ("stage.step", StageDriver, "step"),
        ("bus.send_prepared (each frame)", bus, "send_prepared"),
        ("bus.sync", bus, "sync"),
        ("bus.send (heartbeat)", bus, "send"),
        ("watch.check", BusWatch, "check"),
        ("_make_snapshot", loop, "_make_snapshot"),
    ]
    for node in loop.nodes:
        parts.append((f"node {node.node_id} cyclic_frames", node, "cyclic_frames"))
    return parts


def _sim_parts(sim: Any) -> list[tuple[str, Any, str]]:
    """The simulated drives' parts (``--side sim``)."""
    from omnican.sim import motor
    from omnican.sim.axis import Motion
    from omnican.sim.device import Device
    from omnican.sim.heartbeat import Heartbeat
    from omnican.sim.node import SimNode
    from omnican.sim.process_data import ProcessData
    from omnican.sim.transmit import Transmitter

    return [
        ("SimNode._on_sync (a SYNC, each node)", SimNode, "_on_sync"),
        ("SimNode._on_rpdo", SimNode, "_on_rpdo"),
        ("SimNode.tick (housekeeping)", SimNode, "tick"),
        ("Device.advance", Device, "advance"),
        ("Motion.advance", Motion, "advance"),
        ("motor.advance", motor, "advance"),
        ("ProcessData.sync", ProcessData, "sync"),
        ("ProcessData.apply (RPDO writes)", ProcessData, "apply"),
        ("ProcessData.events (event TPDO checks)", ProcessData, "events"),
        ("Motion.status_bits", Motion, "status_bits"),
        ("Heartbeat.expired", Heartbeat, "expired"),
        ("Transmitter.send (each frame)", Transmitter, "send"),
    ]


def child(rate_hz: float, cycles: int, side: str) -> None:
    import cgtoggle  # type: ignore[import-not-found]
    from bench_chassis import config

    from omnican import Chassis
    from omnican.clock import SimClock
    from omnican.sim import SimulatedBase

    cfg = config(rate_hz, 3)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        clock.sleep(0.3)
        wrap = _toggler()
        host_bus = base.bus.network.bus
        host_bus.set_receiver(wrap("host", host_bus._receiver))
        base._runner.cycle = wrap("host", base._runner.cycle)
        sim_bus = sim.network.bus
        sim_bus.set_receiver(wrap("sim", sim_bus._receiver))
        ticks = sim.scheduler._ticks
        ticks[:] = [wrap("sim", tick) for tick in ticks]

        def stretch(name: str) -> None:
            # The same commands each stretch (bench_instructions'), from a standstill.
            base.set_velocity(0.0, 0.0, 0.0)
            clock.sleep(1.0)
            c0 = base.status.cycles
            cgtoggle.zero()
            for k in range(max(cycles // 10, 1)):
                base.set_velocity(0.3 * math.sin(k * 0.01), 0.1, 0.2)
                clock.sleep(10 / rate_hz)
            cgtoggle.dump()
            print(json.dumps({"part": name, "cycles": base.status.cycles - c0}), flush=True)

        # The collector off: whether a collection falls in a stretch would otherwise move
        # a stretch's count by more than most parts cost (bench_instructions keeps it on).
        gc.collect()
        gc.disable()
        stretch("all")
        other = "sim" if side == "host" else "host"
        for name, owner, attr in (_parts(base) if side == "host" else _sim_parts(sim)):
            had = attr in vars(owner) if isinstance(owner, type) else \
                attr in getattr(owner, "__dict__", {})
            old = getattr(owner, attr) if not isinstance(owner, type) else vars(owner)[attr]
            setattr(owner, attr, wrap(other, old))
            try:
                stretch(name)
            finally:
                if had or isinstance(owner, type):
                    setattr(owner, attr, old)
                else:
                    delattr(owner, attr)
            stretch("all")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--cycles", type=int, default=200)
    parser.add_argument("--side", choices=("host", "sim"), default="host",
                        help="the host side's parts, or the simulated drives'")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(float(args.child[0]), int(args.child[1]), args.child[2])
        return
    with tempfile.TemporaryDirectory() as tmp:
        why = build_toggle(Path(tmp))
        if why is not None:
            print(f"bench_attribute: cannot count instructions here: {why}", file=sys.stderr)
            raise SystemExit(2)
        env = dict(os.environ, OMNICAN_COUNT_SIDE=args.side)
        here = Path(__file__).resolve().parent
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [tmp, str(here),
                                                          env.get("PYTHONPATH")]))
        done = subprocess.run(
            ["valgrind", "--tool=callgrind", "--collect-atstart=no",
             f"--callgrind-out-file={tmp}/cg.%p", sys.executable, str(Path(__file__).resolve()),
             "--child", str(args.rate), str(args.cycles), args.side],
            check=False, capture_output=True, text=True, env=env)
        if done.returncode != 0:
            raise SystemExit(f"bench_attribute: the run under valgrind failed:\n"
                             f"{done.stderr[-2000:]}")
        rows = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
        dumps = sorted(Path(tmp).glob("cg.*.*"), key=lambda p: int(p.name.rsplit(".", 1)[1]))
        totals = []
        for d in dumps:
            for line in d.read_text().splitlines():
                if line.startswith("summary:"):
                    totals.append(int(line.split()[1]))
        per = [t / max(r["cycles"], 1) for t, r in zip(totals, rows, strict=False)]
        # Stretches alternate: everything counted, a part left out, everything, ...: each
        # part against the mean of the whole cycle's stretches on either side of it.
        wholes = per[0::2]
        whole = sum(wholes) / len(wholes)
        for i in range(1, len(per) - 1, 2):
            around = (per[i - 1] + per[i + 1]) / 2
            print(json.dumps({"bench": f"{args.side}_instructions.part", "rate_hz": args.rate,
                              "part": rows[i]["part"],
                              "instructions_per_cycle": round(around - per[i]),
                              "share": round((around - per[i]) / around, 3)}), flush=True)
        print(json.dumps({"bench": f"{args.side}_instructions.part", "rate_hz": args.rate,
                          "part": "whole cycle", "instructions_per_cycle": round(whole),
                          "spread": [round(min(wholes)), round(max(wholes))]}), flush=True)


if __name__ == "__main__":
    main()
