"""The simulated base: one drive per node of a config, ground truth from wheel motion."""

from __future__ import annotations

import math
import time

import canopen
import pytest

from omnican import Twist, default_config
from omnican.sim import SimulatedBase


def drive_wheels(sim: SimulatedBase, twist: Twist, seconds: float) -> None:
    """Command wheel speeds from a plain canopen master: targets on the bundled
    drive's SYNC RPDO, so one SYNC starts (and stops) every wheel at once."""
    cfg = sim.cfg
    speeds = cfg.kinematics().to_wheel_speeds(twist)
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    master.connect(**cfg.bus)  # type: ignore[arg-type]
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
        time.sleep(0.02)
        for scale in (1.0, 0.0):
            for w, node, v in zip(cfg.wheels, nodes, speeds, strict=True):
                node.rpdo[2]["Target velocity"].raw = round(scale * v * w.velocity_scale)
                node.rpdo[2].transmit()
            time.sleep(0.01)
            master.sync.transmit()
            time.sleep(seconds * scale + 0.2 * (1 - scale))
    finally:
        master.disconnect()


def test_truth_follows_wheel_motion(channel: str) -> None:
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    with SimulatedBase.from_config(cfg) as sim:
        assert len(sim.drives) == 3
        assert sim.true_pose.x == 0.0
        drive_wheels(sim, Twist(0.5, 0.0, 0.0), 0.4)
        pose = sim.true_pose
        assert pose.x == pytest.approx(0.2, abs=0.03)
        assert abs(pose.y) < 1e-3 and abs(pose.theta) < 1e-3


def test_spin_has_no_translation(channel: str) -> None:
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    with SimulatedBase.from_config(cfg) as sim:
        drive_wheels(sim, Twist(0.0, 0.0, 2.0), 0.3)
        twist = sim.true_twist
        pose = sim.true_pose
        assert pose.theta == pytest.approx(0.6, abs=0.1)
        # Each drive handles the SYNC a little after the previous one, like real drives
        # do: that skew is the only translation. A few microseconds on an idle machine
        # (well under 0.1 mm); on a loaded one the simulator's thread can be held up for
        # a millisecond between two drives (0.4 mm at this spin). A kinematics error
        # would move the base by centimetres.
        assert math.hypot(pose.x, pose.y) < 1e-3
        assert abs(twist.vx) < 1e-6


def test_true_scale_and_slip_change_truth_not_encoders(channel: str) -> None:
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    with SimulatedBase.from_config(cfg, true_scale=2.0, slip=0.5) as sim:
        drive_wheels(sim, Twist(0.5, 0.0, 0.0), 0.4)
        assert sim.true_pose.x == pytest.approx(0.2 / 4, abs=0.01)
        drive, axis = sim.wheel_drive(1)
        assert drive.node_id == 2 and axis == 0
