"""Instructions omnican's host side executes per control cycle: the same number on every
run, so the figure to compare two commits by (timings on a shared VM move by a third).

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
import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path
from typing import Any

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


def child(rate_hz: float, cycles: int) -> None:
    """Runs under callgrind: drive the lock-step base, counting only the host side."""
    import cgtoggle  # type: ignore[import-not-found]  # built by the parent
    from bench_chassis import config

    from omnican import Chassis
    from omnican.clock import SimClock
    from omnican.sim import SimulatedBase

    owners: list[str] = []

    def wrap(owner: str, fn: Any) -> Any:
        def run(*args: Any, **kwargs: Any) -> Any:
            before = bool(owners) and owners[-1] == "host"
            owners.append(owner)
            if (owner == "host") != before:
                cgtoggle.toggle()
            try:
                return fn(*args, **kwargs)
            finally:
                owners.pop()
                after = bool(owners) and owners[-1] == "host"
                if after != (owner == "host"):
                    cgtoggle.toggle()
        return run

    cfg = config(rate_hz)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        clock.sleep(0.3)
        sim_bus, host_bus = sim.network.bus, base.bus.network.bus
        sim_bus.set_receiver(wrap("sim", sim_bus._receiver))  # type: ignore[union-attr]
        host_bus.set_receiver(wrap("host", host_bus._receiver))  # type: ignore[union-attr]
        ticks = sim.scheduler._ticks
        ticks[:] = [wrap("sim", tick) for tick in ticks]
        base._runner.cycle = wrap("host", base._runner.cycle)
        cycles0 = base.status.cycles
        cgtoggle.zero()
        for k in range(max(cycles // 10, 1)):
            base.set_velocity(0.3 * math.sin(k * 0.01), 0.1, 0.2)
            clock.sleep(10 / rate_hz)
        cgtoggle.dump()
        print(json.dumps({"cycles": base.status.cycles - cycles0}))


def measure(rate_hz: float, cycles: int, toggle_dir: Path, out_dir: Path) -> dict[str, Any]:
    env = dict(os.environ)
    here = Path(__file__).resolve().parent
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(toggle_dir), str(here),
                                                      env.get("PYTHONPATH")]))
    prefix = out_dir / f"cg-{int(rate_hz)}"
    done = subprocess.run(
        ["valgrind", "--tool=callgrind", "--collect-atstart=no",
         f"--callgrind-out-file={prefix}.%p", sys.executable, str(Path(__file__).resolve()),
         "--child", str(rate_hz), str(cycles)],
        check=False, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise SystemExit(f"bench_instructions: the run under valgrind failed:\n{done.stderr[-2000:]}")
    n = json.loads(done.stdout.strip().splitlines()[-1])["cycles"]
    # The client request's dump (suffix .1) holds exactly the measured cycles.
    dumps = sorted(out_dir.glob(f"{prefix.name}.*.1"))
    total = 0
    for line in dumps[0].read_text().splitlines():
        if line.startswith("summary:"):
            total = int(line.split()[1])
    return {"bench": "host_instructions", "rate_hz": rate_hz, "cycles": n,
            "instructions_per_cycle": round(total / max(n, 1))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rates", default="100,1000", help="comma-separated rates in Hz")
    parser.add_argument("--cycles", type=int, default=1000, help="cycles counted per rate")
    parser.add_argument("--child", nargs=2, metavar=("RATE", "CYCLES"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(float(args.child[0]), int(args.child[1]))
        return
    with tempfile.TemporaryDirectory() as tmp:
        why = build_toggle(Path(tmp))
        if why is not None:
            print(f"bench_instructions: cannot count instructions here: {why}", file=sys.stderr)
            raise SystemExit(2)
        for rate in (float(r) for r in args.rates.split(",")):
            print(json.dumps(measure(rate, args.cycles, Path(tmp), Path(tmp))), flush=True)


if __name__ == "__main__":
    main()
