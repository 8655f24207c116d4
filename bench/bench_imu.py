"""IMU sources benchmark: prints one JSON object per line.

Figures: what decoding one CAN IMU frame costs the thread that receives it (the
Notifier's, or the control loop's while it polls: cantools' decode, the units and the
mounting, the inbox), the simulated gyro's encode and send per reading, and the rate the
simulated gyro's samples reach the inbox in lock-step (simulated time: exact).

Run: ``python bench/bench_imu.py`` (a few seconds).
"""

from __future__ import annotations

import json
import time
import uuid
from dataclasses import replace
from typing import Any

import can

from omnican import Chassis, default_config
from omnican.clock import SimClock
from omnican.config import ImuSettings, SimGyro, SimTruth
from omnican.config.imu import BUNDLED_DBC, dbc_imu
from omnican.io.imu import CanImu
from omnican.sim import SimulatedBase

IMU = ImuSettings("can", dbc=BUNDLED_DBC / "openimu300ri.dbc", message="ARI",
                  yaw_rate="AngularRateZ", mount_yaw_deg=30.0, upside_down=True)


def emit(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


def decode_cost(n: int = 20000) -> None:
    reader = CanImu(IMU)
    ari = dbc_imu(IMU).rate_message
    msg = can.Message(arbitration_id=ari.frame_id, is_extended_id=True,
                      data=ari.encode({"AngularRateX": 0, "AngularRateY": 0,
                                       "AngularRateZ": 12.5, "FiguresOfMerit": 0,
                                       "Latency": 0}), timestamp=time.time())
    other = can.Message(arbitration_id=0x181, data=bytes(5))
    for label, frame in (("imu_frame", msg), ("other_frame", other)):
        t0 = time.perf_counter()
        for _ in range(n):
            reader.on_message_received(frame)
            if label == "imu_frame" and reader.inbox.received % 1000 == 0:
                reader.inbox.drain()
        emit(bench="can_imu_receive", frame=label, us_per_frame=round(
            (time.perf_counter() - t0) / n * 1e6, 2))


def gyro_rate(seconds: float = 10.0) -> None:
    channel = f"bench-imu-{uuid.uuid4().hex[:8]}"
    cfg = default_config(bus={"interface": "virtual", "channel": channel})
    for rate in (50.0, 100.0, 200.0):
        for loop_hz in (100.0, 1000.0):
            c = replace(cfg, chassis=replace(cfg.chassis, rate_hz=loop_hz), imu=IMU,
                        sim=SimTruth(gyro=SimGyro(rate_hz=rate)))
            clock = SimClock()
            with SimulatedBase.from_config(c, clock=clock) as sim, \
                    Chassis.open(c, clock=clock) as base:
                assert base.imu is not None and sim.gyro is not None
                base.imu.drain()
                start, got = clock.now(), base.imu.received
                w0 = time.perf_counter()
                sent0 = sim.gyro.sent
                clock.sleep(seconds)
                wall = time.perf_counter() - w0
                emit(bench="sim_gyro_rate", gyro_hz=rate, loop_hz=loop_hz,
                     samples_per_s=round((base.imu.received - got) / (clock.now() - start), 2),
                     frames_sent=sim.gyro.sent - sent0, wall_s=round(wall, 2))


if __name__ == "__main__":
    decode_cost()
    gyro_rate()
