"""omnican.record.replay: decoding recordings offline (synthetic frames; one real recording)."""

from __future__ import annotations

import functools
import json
import random
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from omnican import ChassisConfig, Odometry, default_config
from omnican.cli import main
from omnican.core.wheel_odometry import (
    CounterSampleSlot,
    EncoderCounters,
    WheelOdometry,
    fold_counter,
)
from omnican.plan.codec import PdoCodec
from omnican.plan.node import NodeLayout, node_layouts
from omnican.protocol.cia402 import State
from omnican.record.replay import (
    RecordingError,
    decode,
    load,
    read_frames,
    window_speeds,
)
from tests.support.helpers import vendor_config

CFG = default_config()
LAYOUTS = node_layouts(CFG)
PS = CFG.wheels[0].position_scale
VS = CFG.wheels[0].velocity_scale
NODES = (1, 2, 3)


@dataclass(frozen=True)
class F:
    """A frame as python-can's LogReader yields them (the attributes decode reads)."""

    timestamp: float
    arbitration_id: int
    data: bytes


def raw32(value: int) -> bytes:
    return (value % (1 << 32)).to_bytes(4, "little")


def cycle(t: float, raws: list[int], drop: int | None = None) -> list[F]:
    """One control cycle: the SYNC, then each node's position TPDO (node ``drop`` silent)."""
    out = [F(t, 0x80, b"")]
    out += [F(t + 0.0005 * (k + 1), 0x280 + node, raw32(raw))
            for k, (node, raw) in enumerate(zip(NODES, raws, strict=True)) if k != drop]
    return out


def statusword(t: float, node: int, sw: int) -> F:
    return F(t, 0x180 + node, sw.to_bytes(2, "little") + b"\x03\x00\x00")


def odometry_poses(travel: np.ndarray) -> np.ndarray:
    odo = Odometry(CFG.kinematics())
    return np.array([[p.x, p.y, p.theta] for p in (odo.update(row) for row in travel)])


# ---------------------------------------------------------------- decoding


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_decode_matches_the_chassis_rule(data: st.DataObject) -> None:
    """Per-SYNC positions across a 32-bit wrap, some SYNCs incomplete, frames out of order:
    travel at the complete sets is exact and the trajectory is Odometry's."""
    n_cycles = data.draw(st.integers(2, 40))
    offsets = data.draw(st.lists(st.integers(-(1 << 31), (1 << 31) - 1), min_size=3,
                                 max_size=3))
    steps = data.draw(st.lists(st.lists(st.integers(-3000, 3000), min_size=3, max_size=3),
                               min_size=n_cycles, max_size=n_cycles))
    drops = data.draw(st.lists(st.sampled_from([None, None, None, 0, 1, 2]),
                               min_size=n_cycles, max_size=n_cycles))
    drops[0] = None
    true = np.cumsum(np.array(steps, dtype=np.int64), axis=0)
    frames: list[F] = []
    for k in range(n_cycles):
        raws = [int(offsets[w] + true[k, w]) for w in range(3)]
        frames += cycle(0.01 * k, raws, drops[k])
    random.Random(n_cycles).shuffle(frames)  # decode orders by timestamp
    rep = decode(frames, CFG, LAYOUTS)
    complete = [k for k in range(n_cycles) if drops[k] is None]
    assert rep.syncs == n_cycles
    assert rep.complete_syncs == len(complete)
    np.testing.assert_allclose(rep.sync_t, [0.01 * k for k in complete], atol=1e-12)
    expected = (true[complete] - true[0]).astype(float)
    np.testing.assert_array_equal(rep.counts, expected)
    np.testing.assert_allclose(rep.travel, expected / PS, rtol=1e-12)
    np.testing.assert_allclose(rep.poses, odometry_poses(expected / PS), atol=1e-12)


def test_targets_states_emcy_and_reboot() -> None:
    frames = [
        F(0.000, 0x000, bytes([0x82, 0])),  # NMT reset communication, all nodes
        *(F(0.001, 0x700 + n, b"\x00") for n in NODES),  # boot-ups the host asked for
        statusword(0.002, 1, 0x0040),  # SWITCH ON DISABLED
        statusword(0.003, 1, 0x0021),  # READY TO SWITCH ON
        statusword(0.004, 1, 0x0023),
        statusword(0.005, 1, 0x0027),  # OPERATION ENABLED
        statusword(0.006, 1, 0x0427),  # same state, another bit: no new entry
        # RPDO1: the target, then the controlword (enable operation), every cycle
        F(0.010, 0x201, (int(0.25 * VS)).to_bytes(4, "little", signed=True) + b"\x0f\x00"),
        F(0.010, 0x202, (int(-0.5 * VS)).to_bytes(4, "little", signed=True) + b"\x0f\x00"),
        *cycle(0.011, [100, 200, 300]),
        *cycle(0.021, [150, 150, 350]),
        F(0.025, 0x81, bytes([0x10, 0x23, 0x03, 0, 0, 0, 0, 0])),  # EMCY 0x2310
        statusword(0.026, 1, 0x000F),  # FAULT REACTION ACTIVE
        statusword(0.027, 1, 0x0008),  # FAULT
        F(0.030, 0x702, b"\x00"),  # node 2 reboots by itself: its counter restarts
        *cycle(0.031, [170, 5000, 400]),
        *cycle(0.041, [170, 5010, 400]),
        F(0.045, 0x81, bytes(8)),  # error reset
        F(0.046, 0x201, b"\x01"),  # too short for the PDO: ignored, as the chassis does
    ]
    rep = decode(frames, CFG, LAYOUTS)
    assert rep.target_t[0].tolist() == [0.010]
    assert rep.target_speed[0][0] == pytest.approx(0.25, abs=1 / VS)
    assert rep.target_speed[1][0] == pytest.approx(-0.5, abs=1 / VS)
    assert rep.target_t[2].size == 0
    node1 = rep.stages[0]
    assert node1.label == "node 1 (wheel 0)"
    assert [c.state for c in node1.changes] == [
        State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON, State.SWITCHED_ON,
        State.OPERATION_ENABLED, State.FAULT_REACTION_ACTIVE, State.FAULT]
    assert [c.t for c in node1.changes][3] == 0.005
    assert [(e.node_id, e.code, e.register) for e in rep.emcy] == [(1, 0x2310, 3), (1, 0, 0)]
    assert rep.emcy[0].text == "0x2310 continuous over-current"
    assert rep.emcy[1].text == "error reset"
    assert rep.reboots == ((0.030, 2),)
    # Node 2's travel continues across its reboot without a jump.
    assert rep.counts.tolist() == [[0, 0, 0], [50, -50, 50], [70, -50, 100], [70, -40, 100]]
    assert rep.duration == pytest.approx(0.046)
    assert rep.frames == len(frames)


@functools.cache
def _vendor(kind: str) -> tuple[ChassisConfig, tuple[NodeLayout, ...]]:
    cfg = vendor_config("unused", kind)
    return cfg, tuple(node_layouts(cfg))


@settings(max_examples=30, deadline=None)
@given(kind=st.sampled_from(["bundled", "zlac", "roboteq", "epos4"]), data=st.data())
def test_replay_reads_what_the_loops_codec_packs(kind: str, data: st.DataObject) -> None:
    """Two cycles of every planned PDO of a vendor drive's plan, packed by the codec the
    control loop uses: replay reads each wheel's target and travel and each stage's
    statusword from the fields the loop would."""
    cfg, layouts = _vendor(kind)
    first: list[F] = []
    second: list[F] = []
    sent: dict[tuple[int, int, int], list[int]] = {}  # (node, index, sub) -> value per cycle
    for layout in layouts:
        for pdo in (*layout.plan.rpdos, *layout.plan.tpdos):
            codec = PdoCodec(pdo)
            for k, frames in enumerate((first, second)):
                values = [data.draw(st.integers(lo, hi)) for lo, hi in codec.ranges]
                for f, v in zip(codec.fields, values, strict=True):
                    key = (layout.node_id, f.entry.index, f.entry.subindex)
                    sent.setdefault(key, []).append(v)
                frames.append(F(0.01 * k + 0.001, codec.cob_id, codec.pack(values)))
    frames = [F(0.0, 0x80, b""), *first, F(0.01, 0x80, b""), *second]
    rep = decode(frames, cfg, list(layouts))
    assert rep.complete_syncs == 2
    stage_base = 0
    for layout in layouts:
        for axis in layout.axes:
            w = axis.wheel_index
            vs = cfg.wheels[w].velocity_scale
            targets = sent[(layout.node_id, axis.target.index, axis.target.subindex)]
            np.testing.assert_allclose(rep.target_speed[w] * vs, targets, rtol=1e-12)
            raws = sent[(layout.node_id, axis.position.index, axis.position.subindex)]
            expected = fold_counter(0.0, raws[0], raws[1], axis.position.bits)
            assert rep.counts[:, w].tolist() == [0.0, expected]
        for k, stage in enumerate(layout.stages):
            sw = sent[(layout.node_id, stage.statusword.index,
                       stage.statusword.subindex)][0] & 0xFFFF
            assert rep.stages[stage_base + k].changes[0].statusword == sw
        stage_base += len(layout.stages)


def test_positions_before_the_first_sync_are_ignored() -> None:
    frames = [F(0.0, 0x281, raw32(5)), F(0.0, 0x282, raw32(5)), F(0.0, 0x283, raw32(5)),
              *cycle(0.01, [10, 10, 10]), *cycle(0.02, [20, 30, 40])]
    rep = decode(frames, CFG, LAYOUTS)
    assert rep.counts.tolist() == [[0, 0, 0], [10, 20, 30]]


def test_frames_of_other_nodes_are_not_counted() -> None:
    frames = [F(0.0, 0x80, b""), F(0.001, 0x28A, raw32(1)), F(0.002, 0x70A, b"\x05")]
    rep = decode(frames, CFG, LAYOUTS)
    assert rep.node_frames == 0
    assert rep.complete_syncs == 0
    assert rep.poses.shape == (0, 3)


@given(speed=st.floats(-2.0, 2.0), jitter=st.lists(st.floats(0.0, 0.004), min_size=3,
                                                   max_size=60))
def test_window_speeds_of_constant_motion(speed: float, jitter: list[float]) -> None:
    t = np.arange(len(jitter)) * 0.01 + np.array(jitter)
    travel = np.column_stack([speed * t, -speed * t])
    out = window_speeds(t, travel)
    assert out[0].tolist() == [0.0, 0.0]
    np.testing.assert_allclose(out[1:, 0], speed, atol=1e-9)
    np.testing.assert_allclose(out[1:, 1], -speed, atol=1e-9)


def test_window_speeds_average_over_the_window() -> None:
    t = np.array([0.0, 0.0625, 0.125, 0.1875, 0.25])  # exact in binary
    travel = np.array([[0.0], [1.0], [1.0], [1.0], [3.0]])
    # The reference is the latest sample at least 0.125 s older (else the first).
    assert window_speeds(t, travel, 0.125)[:, 0].tolist() == [0, 16, 8, 0, 16]


@given(t_steps=st.lists(st.integers(1, 64), min_size=1, max_size=40),
       counts=st.lists(st.integers(-5000, 5000), min_size=41, max_size=41))
def test_window_speeds_are_the_loops_window(t_steps: list[int], counts: list[int]) -> None:
    """window_speeds, the window over a whole recording at once, gives each set the
    speeds the loop's WheelOdometry measured when that set came (times and window
    exact in binary: the two compare the same differences)."""
    t = np.cumsum([0.0, *t_steps]) / 1024
    travel = np.cumsum(counts[:len(t)]).astype(float)[:, None] / PS
    samples = [CounterSampleSlot() for _ in range(3)]
    odo = WheelOdometry(Odometry(CFG.kinematics()),
                        EncoderCounters(samples, [32] * 3, [PS] * 3), window_s=0.125)
    live = []
    for k, c in enumerate(np.cumsum(counts[:len(t)])):
        for s in samples:
            s.raw, s.epoch = int(c) % (1 << 32), k
        assert odo.integrate(k, float(t[k]))
        live.append(odo.speeds()[0])
    np.testing.assert_allclose(window_speeds(t, travel, 0.125)[:, 0], live, rtol=1e-12,
                               atol=1e-12)


# ---------------------------------------------------------------- files


def test_read_frames_errors(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="recording not found"):
        read_frames(tmp_path / "missing.log")
    (tmp_path / "x.weird").write_text("1")
    with pytest.raises(RecordingError, match="unknown log format"):
        read_frames(tmp_path / "x.weird")
    (tmp_path / "empty.log").write_text("")
    with pytest.raises(RecordingError, match="no CAN frames"):
        read_frames(tmp_path / "empty.log")
    (tmp_path / "bad.blf").write_bytes(b"not a blf file at all")
    with pytest.raises(RecordingError, match=r"bad\.blf: not a readable \.blf recording"):
        read_frames(tmp_path / "bad.blf")


@pytest.mark.parametrize("suffix", [".log", ".blf"])
def test_a_real_recording_replays_to_the_chassis_pose(
        tmp_path: Path, suffix: str, capsys: pytest.CaptureFixture[str]) -> None:
    # In simulated time: the point is the replay, not the machine's scheduling (a loaded
    # machine leaves real-time SYNCs without their samples now and then).
    rec = tmp_path / f"run{suffix}"
    assert main(["drive", "--sim", "--fast", "--vx", "0.3", "--wz", "0.8", "--duration", "0.5",
                 "--record", str(rec), "--json"]) == 0
    pose = json.loads(capsys.readouterr().out)["pose"]
    rep = load(rec, CFG)
    assert rep.complete_syncs > 40
    assert rep.complete_syncs >= rep.syncs - 2
    x, y, theta = rep.poses[-1]
    assert (x, y, theta) == pytest.approx((pose["x"], pose["y"], pose["theta"]), abs=2e-6)
    assert [s.changes[-1].state for s in rep.stages] == [State.SWITCH_ON_DISABLED] * 3
    assert all(State.OPERATION_ENABLED in [c.state for c in s.changes] for s in rep.stages)
    assert max(float(np.max(v)) for v in rep.target_speed) > 0.2
    assert float(np.max(np.abs(rep.actual_speed))) > 0.2
