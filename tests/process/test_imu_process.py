"""The CAN IMU across processes: the simulated base and its gyro in this process behind a
loopback hub (python-can-remote), ``omnican drive`` in another: the gyro's 29-bit frames
cross the hub and reach that base's IMU inbox; a gyro gone silent is counted as silent
there, and the base drives on regardless."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from omnican.config import ImuSettings, SimGyro, SimTruth
from omnican.config.imu import BUNDLED_DBC
from omnican.io.hub import LoopbackHub
from omnican.sim import SimulatedBase
from tests.config.test_imu_config import FOUR_LINES
from tests.support.helpers import sim_config

ROOT = Path(__file__).resolve().parents[2]


def _drive(toml: Path) -> dict[str, object]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "omnican", "drive", "--config", str(toml),
                           "--wz", "0.3", "--duration", "1", "--json"],
                          check=False, capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    out: dict[str, object] = json.loads(done.stdout)
    return out


def test_the_gyro_reaches_a_base_in_another_process(channel: str, tmp_path: Path) -> None:
    imu = ImuSettings("can", dbc=BUNDLED_DBC / "openimu300ri.dbc", message="ARI",
                      yaw_rate="AngularRateZ")
    cfg = replace(sim_config(channel), imu=imu, sim=SimTruth(gyro=SimGyro(rate_hz=100.0)))
    with SimulatedBase.from_config(cfg) as sim, LoopbackHub(channel, port=0) as hub:
        assert sim.gyro is not None
        toml = tmp_path / "robot.toml"
        toml.write_text(
            f'[bus]\ninterface = "remote"\nchannel = "{hub.url}"\n\n'
            "[chassis]\nlayout = \"b21\"\nbase_radius = 0.19\n\n" +
            "".join(f"[[wheel]]\nnode_id = {n}\ngear_ratio = 16\nencoder_cpr = 4096\n"
                    "wheel_radius = 0.05\n\n" for n in (1, 2, 3)) + FOUR_LINES)
        imu_seen = _drive(toml)["imu"]
        assert isinstance(imu_seen, dict)
        assert imu_seen["source"] == "can" and imu_seen["samples"] >= 50  # 100 Hz, 1 s+
        assert imu_seen["silent_s"] is not None and imu_seen["silent_s"] < 0.5
        sim.gyro.silence()
        out = _drive(toml)
        assert out["imu"] == {"source": "can", "samples": 0, "silent_s": None}
        assert "pose" in out  # it drove without its IMU
