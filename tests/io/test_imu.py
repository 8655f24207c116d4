"""A CAN IMU end to end on the virtual bus: frames of the OpenIMU300RI's DBC (29-bit J1939
ids) decoded into the base's inbox, in SI units, in the base's frame; the simulator's
gyro sending them as that IMU would; a silent IMU's last sample time standing still."""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import can
import cantools
import pytest

from omnican import Chassis
from omnican.clock import SimClock
from omnican.config import ChassisConfig, ImuSettings, SimGyro, SimTruth
from omnican.config.imu import BUNDLED_DBC
from omnican.core.imu import ImuInbox
from omnican.io.bus import CanBus
from omnican.io.imu import CanImu
from omnican.sim import SimulatedBase
from tests.cli.test_first_use import EXAMPLE, run_main
from tests.config.test_imu_config import FOUR_LINES
from tests.support.helpers import drive_for, sim_config, wait_for

OPENIMU = BUNDLED_DBC / "openimu300ri.dbc"
ARI_ID, ACCS_ID = 0x18F02A80, 0x18F02D80
CAN_IMU = ImuSettings("can", dbc=OPENIMU, message="ARI", yaw_rate="AngularRateZ",
                      accel_message="ACCS", accel_x="AccelerationX", accel_y="AccelerationY")
DEG = math.pi / 180
LSB = 1 / 128 * DEG  # the ARI's yaw rate resolution, rad/s


def _ari(yaw_deg_s: float) -> bytes:
    db = cantools.database.load_file(str(OPENIMU))
    return bytes(db.get_message_by_name("ARI").encode(
        {"AngularRateX": 0, "AngularRateY": 0, "AngularRateZ": yaw_deg_s,
         "FiguresOfMerit": 0, "Latency": 0}))


def _accs(x: float, y: float) -> bytes:
    db = cantools.database.load_file(str(OPENIMU))
    return bytes(db.get_message_by_name("ACCS").encode(
        {"AccelerationX": x, "AccelerationY": y, "AccelerationZ": 9.81,
         "FiguresOfMerit": 0, "Latency": 0}))


def test_the_dbc_is_the_openimu_j1939_layout() -> None:
    db = cantools.database.load_file(str(OPENIMU))
    ari, accs = db.get_message_by_name("ARI"), db.get_message_by_name("ACCS")
    assert (ari.frame_id, ari.is_extended_frame) == (ARI_ID, True)
    assert (accs.frame_id, accs.is_extended_frame) == (ACCS_ID, True)
    # 1/128 deg/s per bit from -250 deg/s, little-endian: raw 0x7D00 is 0 deg/s
    assert _ari(0.0)[4:6] == bytes([0x00, 0x7D])
    assert ari.decode(_ari(-12.5))["AngularRateZ"] == -12.5
    assert accs.decode(_accs(1.25, -0.5))["AccelerationY"] == pytest.approx(-0.5)


def test_frames_on_the_bus_become_samples_in_si_and_the_base_frame(channel: str) -> None:
    """Through the bus owner's Notifier: 29-bit frames of the IMU's ids in, samples out;
    the same id as an 11-bit frame and another source address are not the IMU's."""
    imu = replace(CAN_IMU, upside_down=True, mount_yaw_deg=90.0)
    with CanBus({"interface": "virtual", "channel": channel}) as bus, \
            CanImu(imu).attach(bus) as reader, \
            can.Bus(interface="virtual", channel=channel) as imu_bus:
        inbox = reader.inbox
        assert (reader.frame_id, reader.is_extended_id) == (ARI_ID, True)
        imu_bus.send(can.Message(arbitration_id=ACCS_ID, data=_accs(2.0, 0.5)))
        imu_bus.send(can.Message(arbitration_id=ARI_ID + 1, data=_ari(90.0)))  # address 0x81
        imu_bus.send(can.Message(arbitration_id=ARI_ID & 0x7FF, is_extended_id=False,
                                 data=_ari(90.0)))
        for rate in (10.0, -20.0, 30.0):
            imu_bus.send(can.Message(arbitration_id=ARI_ID, data=_ari(rate)))
        assert wait_for(lambda: inbox.received == 3, timeout=10.0)
        got = inbox.drain()
        # upside down: the base's yaw rate is the IMU's negated, in rad/s
        assert [s.yaw_rate for s in got] == pytest.approx([-10 * DEG, 20 * DEG, -30 * DEG])
        # turned a quarter left and over: its x is the base's y, its y the base's x
        assert got[0].accel_x == pytest.approx(0.5) and got[0].accel_y == pytest.approx(2.0)
        assert [s.t for s in got] == sorted(s.t for s in got)
        assert reader.frames == 3 and reader.bad_frames == 0
        imu_bus.send(can.Message(arbitration_id=ARI_ID, data=b"\x00"))  # too short
        assert wait_for(lambda: reader.bad_frames == 1, timeout=10.0)
        assert inbox.received == 3
    assert reader.inbox.received == 3


def _imu_config(channel: str, gyro: SimGyro, **imu: object) -> ChassisConfig:
    return replace(sim_config(channel), imu=replace(CAN_IMU, **imu),  # type: ignore[arg-type]
                   sim=SimTruth(gyro=gyro))


@contextmanager
def _lockstep(cfg: ChassisConfig) -> Iterator[tuple[SimClock, SimulatedBase, Chassis]]:
    clock = SimClock()
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock) as base:
        base._loop.imu = None  # the source alone: the loop's fusion would drain the inbox
        yield clock, sim, base


def test_the_simulated_gyro_reaches_the_inbox_at_its_rate_in_its_units(channel: str) -> None:
    """sim gyro -> bus (29-bit ARI frames, deg/s as the DBC says) -> decoder -> inbox:
    50 samples a second, the true yaw rate plus the bias in rad/s, a silent IMU's last
    sample time standing still while the base runs on, and moving again after."""
    cfg = _imu_config(channel, SimGyro(rate_hz=50.0, bias_deg_s=0.5))
    frames: list[can.Message] = []
    with _lockstep(cfg) as (clock, sim, base):
        inbox = base.imu
        assert isinstance(inbox, ImuInbox)
        assert sim.gyro is not None
        tap = can.BufferedReader()
        base._bus.add_listener(tap)
        inbox.drain()
        start, received = clock.now(), inbox.received
        drive_for(base, 2.0, wz=0.5)
        rate = (inbox.received - received) / (clock.now() - start)
        assert 48 <= rate <= 52
        got = inbox.drain()
        steady = got[len(got) // 2:]  # turning at 0.5 rad/s by then
        mean = sum(s.yaw_rate for s in steady) / len(steady)
        assert mean == pytest.approx(0.5 + 0.5 * DEG, abs=0.01)
        assert all(a.t < b.t for a, b in itertools.pairwise(got))
        assert got[-1].t <= clock.now()
        while (msg := tap.get_message(0)) is not None:
            frames.append(msg)

        drive_for(base, 1.0)  # at rest: the bias alone
        rest = inbox.drain()[-10:]
        assert sum(s.yaw_rate for s in rest) / len(rest) == pytest.approx(0.5 * DEG,
                                                                         abs=LSB)

        sim.gyro.silence()
        drive_for(base, 0.2)
        inbox.drain()
        silent_since = inbox.last_t
        received = inbox.received
        drive_for(base, 1.0)
        assert inbox.received == received and inbox.last_t == silent_since
        assert clock.now() - silent_since > cfg.imu.stale_s  # type: ignore[union-attr,operator]
        sim.gyro.resume()
        drive_for(base, 0.2)
        assert inbox.received > received and inbox.last_t > silent_since  # type: ignore[operator]
    imu_frames = [m for m in frames if m.arbitration_id == ARI_ID]
    assert imu_frames and all(m.is_extended_id and len(m.data) == 8 for m in imu_frames)


def test_an_upside_down_imu_reads_the_right_way_round(channel: str) -> None:
    """The simulated IMU mounted upside down sends the yaw rate negated; the base's
    [imu] upside_down turns it back."""
    cfg = _imu_config(channel, SimGyro(rate_hz=100.0), upside_down=True)
    db = cantools.database.load_file(str(OPENIMU))
    raw: list[float] = []
    with _lockstep(cfg) as (_clock, _sim, base):
        inbox = base.imu
        assert inbox is not None
        tap = can.BufferedReader()
        base._bus.add_listener(tap)
        drive_for(base, 1.5, wz=-0.8)
        got = inbox.drain()[-20:]
        assert sum(s.yaw_rate for s in got) / len(got) == pytest.approx(-0.8, abs=0.02)
        while (msg := tap.get_message(0)) is not None:
            if msg.arbitration_id == ARI_ID:
                raw.append(db.decode_message(ARI_ID, msg.data)["AngularRateZ"])
    assert sum(raw[-20:]) / 20 == pytest.approx(0.8 / DEG, abs=2.0)  # deg/s, negated


def test_a_base_without_imu_has_no_inbox_and_no_gyro(channel: str) -> None:
    cfg = sim_config(channel)
    with _lockstep(cfg) as (_clock, sim, base):
        assert base.imu is None and sim.gyro is None


def test_a_noisy_drifting_gyro_repeats_with_its_noise_stream(channel: str) -> None:
    runs = []
    for _ in range(2):
        cfg = _imu_config(channel, SimGyro(rate_hz=100.0, drift_deg_s=0.5, noise_deg_s=0.2,
                                           noise_stream=3))
        with _lockstep(cfg) as (_clock, _sim, base):
            assert base.imu is not None
            drive_for(base, 0.5)
            runs.append([s.yaw_rate for s in base.imu.drain()])
    assert runs[0] == runs[1]
    assert len(set(runs[0])) > 10  # noise: not one value


def test_drive_sim_with_an_imu_table_gets_samples_end_to_end(tmp_path: Path,
                                                             channel: str) -> None:
    """`omnican drive --sim --json` with the four lines of a CAN IMU: the simulated gyro's
    frames reach the base (``"imu"``); ``[sim.gyro] enabled = false``: none, ever."""
    path = tmp_path / "robot.toml"
    text = (EXAMPLE.read_text().replace('channel = "can0"', f'channel = "{channel}"')
            .replace('interface = "socketcan"', 'interface = "virtual"'))
    path.write_text(text + FOUR_LINES)
    code, out, err = run_main(["drive", "--sim", "--fast", "--config", str(path), "--wz", "0.5",
                               "--duration", "1", "--json"])
    assert code == 0, err
    imu = json.loads(out)["imu"]
    assert imu["source"] == "can" and imu["samples"] >= 90  # 100 Hz for a second and more
    assert imu["silent_s"] is not None and imu["silent_s"] < 0.5
    path.write_text(text + FOUR_LINES + "\n[sim.gyro]\nenabled = false\n")
    code, out, err = run_main(["drive", "--sim", "--fast", "--config", str(path), "--wz", "0.5",
                               "--duration", "1", "--json"])
    assert code == 0, err
    assert json.loads(out)["imu"] == {"source": "can", "samples": 0, "silent_s": None}
