"""Helpers shared by the tests."""

from __future__ import annotations

import fcntl
import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from omnican import WHEEL_EDS, Chassis, ChassisConfig, WheelConfig, default_config
from omnican.clock import REAL_TIME, Clock, SimClock
from omnican.config import ChassisSettings
from omnican.protocol.cia402 import Mode
from omnican.sim import SimulatedBase

#: The repository's root, and the real drives' EDS files shipped as examples.
ROOT = Path(__file__).resolve().parents[2]
VENDOR_EDS = ROOT / "examples" / "eds"


@contextmanager
def locked(path: Path) -> Iterator[None]:
    """One pytest run at a time builds what ``path`` (a lock file) stands for: a cached
    venv, an npm install."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def wait_for(pred: Callable[[], bool], timeout: float = 2.0, step: float = 0.005,
             clock: Clock = REAL_TIME) -> bool:
    """``pred()`` became true within ``timeout`` s (of ``clock``'s time: on a lock-step
    clock, waiting runs the simulation)."""
    if clock.lockstep:
        assert isinstance(clock, SimClock)
        return clock.run_until(pred, timeout, step)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(step)
    return pred()


def drive_for(base: Any, seconds: float, vx: float = 0.0, vy: float = 0.0, wz: float = 0.0,
              every: float = 0.02) -> None:
    """Keep commanding a velocity (the watchdog wants fresh commands), on the base's clock."""
    clock = base.clock
    end = clock.now() + seconds
    while clock.now() < end:
        base.set_velocity(vx, vy, wz)
        clock.sleep(every)


def sim_config(channel: str, **chassis: Any) -> ChassisConfig:
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    return replace(cfg, chassis=replace(cfg.chassis, **chassis)) if chassis else cfg


def vendor_config(channel: str, layout: str, **chassis: Any) -> ChassisConfig:
    """Three wheels on vendor drives: two axes of one node plus one more node where the
    drive has two axes (ZLAC8015D, Roboteq), or three single-axis nodes (EPOS4)."""
    files = {"zlac": "zlac8015d.eds", "roboteq": "roboteq_v80_21.eds", "epos4": "maxon_epos4.eds",
             "bundled": None}
    eds: Path = VENDOR_EDS / files[layout] if files[layout] else WHEEL_EDS
    if layout in ("zlac", "roboteq"):
        slots = [(1, 0), (1, 1), (2, 0)]
    else:
        slots = [(1, 0), (2, 0), (3, 0)]
    # 1000 drive velocity units per m/s, 10000 counts per m (10 counts per unit per s).
    wheels = tuple(WheelConfig(node_id=n, axis=a, eds=eds, velocity_scale=1000.0,
                               position_scale=10000.0, mode=Mode.PROFILE_VELOCITY)
                   for n, a in slots)
    settings = replace(ChassisSettings(), **chassis)
    return ChassisConfig(chassis=settings, wheels=wheels,
                         bus={"interface": "virtual", "channel": channel})


def one_error_line(err: str) -> str:
    """The single line a bad invocation may print on stderr (never a traceback)."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def still(sim: Any) -> bool:
    """The simulated base stands still (its true twist, not the odometry)."""
    t = sim.true_twist
    return bool(math.hypot(t.vx, t.vy) < 1e-3 and abs(t.wz) < 1e-2)


@contextmanager
def lockstep_rig(channel: str) -> Iterator[tuple[SimClock, SimulatedBase, Chassis]]:
    """The demo base (:func:`sim_config`) and its simulated drives, in lock-step."""
    cfg = sim_config(channel)
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        yield clock, sim, base


@contextmanager
def with_truth(base: Chassis, sim: SimulatedBase) -> Iterator[None]:
    """The simulator's ground truth in the base's telemetry while the block runs, as a
    command's session puts it there (:func:`omnican.telemetry.attach.add_truth`)."""
    from omnican.telemetry.attach import add_truth

    add_truth(base, sim)
    yield
