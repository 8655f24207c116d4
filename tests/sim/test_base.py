"""The simulated base: one drive per node of a config, ground truth from wheel motion."""

from __future__ import annotations

import math
from typing import Any

import pytest

from omnican import Twist, default_config
from omnican.clock import SimClock
from omnican.io.lockstep import LockstepBus
from omnican.io.network import Network
from omnican.sim import SimulatedBase


def drive_wheels(sim: SimulatedBase, twist: Twist, seconds: float) -> None:
    """Command wheel speeds from a plain canopen master on the simulator's lock-step
    channel and clock: targets on the bundled drive's SYNC RPDO, so one SYNC starts (and
    stops) every wheel at once. Lock-step: the SDO answers come inside the requests'
    sends, whatever the machine's load, and the wheels turn for exactly ``seconds``."""
    cfg = sim.cfg
    clock = sim.clock
    assert isinstance(clock, SimClock)
    speeds = cfg.kinematics().to_wheel_speeds(twist)
    master = Network()
    master.bus = LockstepBus(str(cfg.bus["channel"]), clock)
    master.bus.set_receiver(master.lockstep_receiver())
    try:
        nodes = []
        for w in cfg.wheels:
            node = master.add_node(w.node_id, str(w.eds))
            node.sdo[0x6060].raw = 3
            node.sdo[0x6083].raw = 10**9
            node.sdo[0x6084].raw = 10**9
            for cw in (6, 7, 15):
                node.sdo[0x6040].raw = cw
            node.rpdo.read()
            nodes.append(node)
        master.nmt.state = "OPERATIONAL"
        clock.sleep(0.02)
        for scale in (1.0, 0.0):
            for w, node, v in zip(cfg.wheels, nodes, speeds, strict=True):
                node.rpdo[2]["Target velocity"].raw = round(scale * v * w.velocity_scale)
                node.rpdo[2].transmit()
            clock.sleep(0.01)
            master.sync.transmit()
            clock.sleep(seconds * scale + 0.2 * (1 - scale))
    finally:
        master.bus.shutdown()


def lockstep_sim(channel: str, **options: Any) -> SimulatedBase:
    """The demo base's simulated drives on a lock-step channel of their own."""
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    return SimulatedBase.from_config(cfg, clock=SimClock(), **options)


def test_truth_follows_wheel_motion(channel: str) -> None:
    with lockstep_sim(channel) as sim:
        assert len(sim.drives) == 3
        assert sim.true_pose.x == 0.0
        drive_wheels(sim, Twist(0.5, 0.0, 0.0), 0.4)
        pose = sim.true_pose
        # 0.41 s at 0.5 m/s between the SYNC that starts and the one that stops them.
        assert pose.x == pytest.approx(0.205, abs=1e-3)
        assert abs(pose.y) < 1e-3 and abs(pose.theta) < 1e-3


def test_spin_has_no_translation(channel: str) -> None:
    with lockstep_sim(channel) as sim:
        drive_wheels(sim, Twist(0.0, 0.0, 2.0), 0.3)
        twist = sim.true_twist
        pose = sim.true_pose
        assert pose.theta == pytest.approx(2.0 * 0.31, abs=1e-3)
        # In lock-step every drive takes the SYNC at the same instant: nothing but
        # rounding translates the base (a kinematics error would move it by centimetres).
        assert math.hypot(pose.x, pose.y) < 1e-6
        assert abs(twist.vx) < 1e-6


def test_true_scale_and_slip_change_truth_not_encoders(channel: str) -> None:
    with lockstep_sim(channel, true_scale=2.0, slip=0.5) as sim:
        drive_wheels(sim, Twist(0.5, 0.0, 0.0), 0.4)
        assert sim.true_pose.x == pytest.approx(0.205 / 4, abs=1e-3)
        drive, axis = sim.wheel_drive(1)
        assert drive.node_id == 2 and axis == 0
