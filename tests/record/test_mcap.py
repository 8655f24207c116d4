"""MCAP recordings (``--record run.mcap``): read back with the mcap reader and an
independent ROS 2 decoder (mcap_ros2), replayed through omnican.record.replay."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import cantools
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from omnican import Chassis, Pose2D, default_config
from omnican.cli import main
from omnican.record import replay
from omnican.record.can_log import mcap_frames as read_frames
from omnican.record.mcap import McapRecorder
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from tests.support.helpers import drive_for, one_error_line


def read_all(path: Path) -> tuple[dict[str, list[Any]], dict[str, Any], Any]:
    """Decoded messages per topic, channel info per topic, and the reader's extras."""
    topics: dict[str, list[Any]] = {}
    info: dict[str, Any] = {}
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        for schema, channel, message in reader.iter_messages():
            info[channel.topic] = ((schema.name, schema.encoding) if schema else (None, None)) \
                + (channel.message_encoding,)
            if channel.message_encoding == "json":
                value = json.loads(message.data)
            else:
                value = None
            topics.setdefault(channel.topic, []).append((message.log_time, value))
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(
                topics=[t for t, i in info.items() if i[2] == "cdr"]):
            topics.setdefault(f"{channel.topic}#", []).append((message.log_time, decoded))
        attachments = {a.name: a for a in reader.iter_attachments()}
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    return topics, info, (header, attachments, metadata)


def test_drive_records_frames_and_ros2_state(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "run.mcap"
    # In simulated time: the point is the file, and a stall of this process beside busy
    # ones cannot cost the drives the host's heartbeat (seen once).
    assert main(["drive", "--sim", "--fast", "--vx", "0.2", "--vy", "0.1", "--wz", "0.4",
                 "--duration", "1.0", "--json", "--record", str(path)]) == 0
    result = json.loads(capsys.readouterr().out)
    topics, info, (header, attachments, metadata) = read_all(path)
    assert header.profile == "ros2"
    assert info["/odom"] == ("nav_msgs/msg/Odometry", "ros2msg", "cdr")
    assert info["/tf"] == ("tf2_msgs/msg/TFMessage", "ros2msg", "cdr")
    assert info["/joint_states"] == ("sensor_msgs/msg/JointState", "ros2msg", "cdr")
    assert info["/diagnostics"] == ("diagnostic_msgs/msg/DiagnosticArray", "ros2msg", "cdr")
    assert info["/from_can_bus"] == ("can_msgs/msg/Frame", "ros2msg", "cdr")
    assert info["/to_can_bus"] == ("can_msgs/msg/Frame", "ros2msg", "cdr")
    # The last odometry is the pose the command printed; the truth went along under --sim.
    _, odo = topics["/odom#"][-1]
    assert odo.pose.pose.position.x == pytest.approx(result["pose"]["x"], abs=1e-3)
    assert odo.pose.pose.position.y == pytest.approx(result["pose"]["y"], abs=1e-3)
    _, true = topics["/sim/true_pose#"][-1]
    assert true.pose.position.x == pytest.approx(result["true_pose"]["x"], abs=1e-3)
    assert any(abs(o.twist.twist.angular.z - 0.4) < 0.04 for _, o in topics["/odom#"])
    # Joint angles are rim travel over the wheel radius (50 mm on the demo base).
    _, js = topics["/joint_states#"][-1]
    _, wheels = topics["/wheels"][-1]
    assert list(js.position) == pytest.approx([w["travel"] / 0.05 for w in wheels["wheels"]],
                                              abs=0.05)
    _, diag = topics["/diagnostics#"][-1]
    assert [s.name for s in diag.status] == ["omnican: chassis", "omnican: CAN bus",
                                             "omnican: wheel 0",
                                             "omnican: wheel 1",
                                             "omnican: wheel 2"]
    # Frames both ways, decodable with the DBC that came along.
    db = cantools.database.load_string(attachments["omnican.dbc"].data.decode(), "dbc")
    tx = {f.id for _, f in topics["/to_can_bus#"]}
    rx = [f for _, f in topics["/from_can_bus#"]]
    assert {0x80, 0x201, 0x202, 0x203, 0x77F} <= tx
    tpdo2 = next(f for f in rx if f.id == 0x281)
    assert "PositionActual" in db.decode_message(0x281, bytes(tpdo2.data)[:tpdo2.dlc])
    assert metadata["omnican"]["dropped_frames"] == "0"
    assert int(metadata["omnican"]["frames"]) == len(topics["/to_can_bus"]) + len(rx)
    assert info["/wheels"] == (None, None, "json")  # schemaless JSON: see the next test


def test_a_ros2_bag_reader_reads_the_recording(tmp_path: Path) -> None:
    """rosbags (a ROS 2 bag library) opens the file and decodes the robot's state."""
    from rosbags.highlevel import AnyReader

    path = tmp_path / "run.mcap"
    # In simulated time: a stall of this process on a loaded machine cannot cost the
    # drives the host's heartbeat (seen once), and the point here is the file.
    assert main(["drive", "--sim", "--fast", "--vx", "0.2", "--duration", "0.5",
                 "--record", str(path)]) == 0
    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/odom"] == "nav_msgs/msg/Odometry"
        assert types["/to_can_bus"] == "can_msgs/msg/Frame"
        odometry = [reader.deserialize(raw, conn.msgtype) for conn, _, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == "/odom"])]
        frames = [reader.deserialize(raw, conn.msgtype) for conn, _, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == "/to_can_bus"])]
    assert odometry[-1].pose.pose.position.x > 0.05
    assert {f.id for f in frames} >= {0x80, 0x201}


def test_mcap_replays_like_a_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """plot/calibrate read .mcap through replay: the same decode as from a .log."""
    mcap_path, log_path = tmp_path / "a.mcap", tmp_path / "a.log"
    cfg = default_config(bus={"interface": "virtual", "channel": f"mcap-{tmp_path.name}"})
    with SimulatedBase.from_config(cfg), Chassis.open(cfg, record=FileRecording(mcap_path)) as base:
        drive_for(base, 0.8, vx=0.3, wz=0.5)
        base.stop()
        drive_for(base, 0.4)
        pose = base.pose
    frames = read_frames(mcap_path)
    assert all(f.timestamp > 1e9 for f in frames)  # wall-clock times, as a .log has
    rep = replay.load(mcap_path, cfg)
    assert rep.complete_syncs > 10  # ~100 at 100 Hz; fewer when the machine is busy
    x, y, theta = rep.poses[-1]
    assert math.hypot(x - pose.x, y - pose.y) < 0.002
    assert theta == pytest.approx(pose.theta, abs=0.002)
    assert main(["plot", str(mcap_path), "-o", str(tmp_path / "a.png")]) == 0
    assert "complete SYNCs" in capsys.readouterr().out
    # The same run through the .log path gives the same figure input.
    import can

    with can.Logger(str(log_path)) as log:
        for f in frames:
            log.on_message_received(f)
    rep_log = replay.load(log_path, cfg)
    assert rep_log.complete_syncs == rep.complete_syncs
    assert rep_log.poses[-1] == pytest.approx(rep.poses[-1], abs=1e-6)


def test_unreadable_mcap_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    assert main(["plot", str(bad), "-o", str(tmp_path / "x.png")]) == 2
    assert "bad.mcap: not a readable .mcap recording" in one_error_line(capsys.readouterr().err)


def test_a_recording_drops_instead_of_blocking(tmp_path: Path) -> None:
    """Frames go into a bounded tap that drops (and counts) when full; samples queue for a
    front end that is slow and the oldest go: offering never waits for it."""
    import threading

    import can

    from omnican.clock import REAL_TIME
    from omnican.telemetry import Feed, TelemetrySettings
    from omnican.telemetry.feed import QUEUE_SAMPLES
    from omnican.telemetry.frames import FrameTap

    tap = FrameTap(size=0)
    for i in range(100):
        tap.on_message_received(can.Message(arbitration_id=0x181, data=bytes([i])))
    assert tap.dropped == 100 and not tap.queue

    cfg = default_config()
    feed = Feed(TelemetrySettings.from_config(cfg), cfg.kinematics(), REAL_TIME,
                has_base=False)
    release = threading.Event()

    class Stuck:
        def wants(self, topic: str) -> bool:
            return True

        def publish(self, messages: list) -> None:  # type: ignore[type-arg]
            release.wait(10)

    feed.truth = type("Truth", (), {"true_pose": Pose2D(), "true_twist": None})()
    feed.add(Stuck())
    try:
        for _ in range(QUEUE_SAMPLES + 50):
            feed.offer(None)  # returns at once, the front end stuck or not
        assert feed.dropped >= 49
    finally:
        release.set()
        feed.close()
    rec = McapRecorder(tmp_path / "q.mcap")
    rec.close(dropped_frames=tap.dropped)
    with (tmp_path / "q.mcap").open("rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["omnican"]["dropped_frames"] == "100"


def test_unwritable_record_path_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:  # refused as the arguments are parsed
        raise SystemExit(main(["drive", "--sim", "--vx", "0.1", "--record",
                               "/nonexistent/dir/run.mcap"]))
    assert info.value.code == 2
    assert "cannot record to /nonexistent/dir/run.mcap" in one_error_line(
        capsys.readouterr().err)


def test_diagnostics_once_a_second_and_at_once_on_a_fault(tmp_path: Path) -> None:
    """The state topics go at the state rate; diagnostics once a second (as ROS expects
    them), at once when a level changes, and in the final sample."""
    path = tmp_path / "diag.mcap"
    cfg = default_config(bus={"interface": "virtual", "channel": f"mcap-{tmp_path.name}"})
    with SimulatedBase.from_config(cfg) as sim, Chassis.open(cfg, record=FileRecording(path)) as base:
        drive_for(base, 2.3, vx=0.2)
        sim.drives[0].inject_fault(0x2310)
        drive_for(base, 0.3, vx=0.2)
        assert base.status.stopped_reason is not None
    topics, _, _ = read_all(path)
    diag = topics["/diagnostics#"]
    statuses = topics["/status"]
    assert len(statuses) > 40  # ~130 at 50 Hz; fewer on a busy machine
    # The drives coming up, 1 and 2 s, the fault, the last sample: a handful, not one
    # per state sample.
    assert 3 <= len(diag) <= 12, [t for t, _ in diag]
    assert len(statuses) >= 5 * len(diag)
    # Unchanged diagnostics are a second apart.
    for (t0, d0), (t1, d1) in itertools.pairwise(diag):
        same = [(s.level, s.message) for s in d0.status] == [(s.level, s.message)
                                                              for s in d1.status]
        assert not same or t1 - t0 >= 999_000_000 or (t1, d1) == diag[-1]
    levels = [max(s.level for s in d.status) for _, d in diag]
    first_error = next(i for i, level in enumerate(levels) if level == 2)
    fault_at = next(t for t, s in statuses if s["stopped_reason"])
    # The diagnostics that say ERROR come with the first state sample that shows the fault.
    assert diag[first_error][0] == fault_at
    assert diag[-1][0] == statuses[-1][0]  # the final sample carries them too
