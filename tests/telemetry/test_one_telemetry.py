"""One truth for every front end: the ROS 2 bridge, the Foxglove live view and an MCAP
recording of the same run carry the same messages, field by field, stamps included;
under simulated time they all carry the simulated clock, at the documented rates."""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import pytest

from omnican import Chassis
from omnican.clock import SimClock
from omnican.record.recording import FileRecording
from omnican.sim import SimulatedBase
from tests.ros2.test_bridge import MemoryTransport
from tests.support.foxglove_client import FoxgloveClient
from tests.support.helpers import drive_for, sim_config, wait_for, with_truth

COMPARED = {"/odom": "nav_msgs/msg/Odometry", "/tf": "tf2_msgs/msg/TFMessage",
            "/joint_states": "sensor_msgs/msg/JointState",
            "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
            "/sim/true_pose": "geometry_msgs/msg/PoseStamped"}


def decoder(schema: str) -> Any:
    """An independent CDR decoder (mcap_ros2's) for ``schema``."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    from omnican.telemetry import cdr

    return DecoderFactory().decoder_for("cdr", Schema(
        id=1, name=schema, encoding="ros2msg", data=cdr.msgdef(schema).encode()))


def plain(value: Any, like: Any) -> Any:
    """``value`` (a decoded message) as the plain values of ``like``'s shape."""
    if isinstance(like, dict):
        return {k: plain(getattr(value, k), v) for k, v in like.items()}
    if isinstance(like, list):
        return [plain(a, b) for a, b in zip(value, like, strict=True)]
    if isinstance(like, int) and isinstance(value, bytes):
        return value[0]  # a ROS byte
    return value


def stamp_of(msg: dict[str, Any]) -> tuple[int, int]:
    header = msg["transforms"][0]["header"] if "transforms" in msg else msg["header"]
    return header["stamp"]["sec"], header["stamp"]["nanosec"]


def test_bridge_live_view_and_recording_say_the_same(channel: str, tmp_path: Path) -> None:
    pytest.importorskip("cyclonedds")
    pytest.importorskip("foxglove")
    from mcap.reader import make_reader

    from omnican.live import watch
    from omnican.ros2.bridge import Bridge
    from omnican.ros2.settings import Ros2Settings

    cfg = sim_config(channel)
    clock = SimClock(speed=4.0)  # paced, so a viewer on a loaded machine keeps up
    record = tmp_path / "run.mcap"
    transport = MemoryTransport()
    live: list[tuple[str, int, bytes]] = []
    with SimulatedBase.from_config(cfg, clock=clock) as sim, \
            Chassis.open(cfg, clock=clock, record=FileRecording(record)) as base, \
            with_truth(base, sim), watch(base, sim, "127.0.0.1:0") as view, \
            Bridge(base, Ros2Settings(), transport, sim=sim):
        assert view is not None
        client = FoxgloveClient(view.url)
        stop = threading.Event()
        try:
            client.wait_for_topics(COMPARED)
            client.subscribe(list(COMPARED))
            time.sleep(0.3)  # the subscription reaches the server

            def collect() -> None:
                while not stop.is_set():
                    live.extend(client.messages(timeout=0.2))

            reader = threading.Thread(target=collect, name="test-foxglove-reader")
            reader.start()
            try:
                # Motion, a fault, a recover, motion again.
                drive_for(base, 1.0, vx=0.2, wz=0.3)
                sim.drives[1].inject_fault(0x2310)
                clock.sleep(0.5)
                assert base.status.stopped_reason is not None
                base.recover()
                drive_for(base, 0.6, vy=0.15)
                base.stop()
                clock.sleep(0.4)
                last = transport.last("/odom").header.stamp
                assert wait_for(lambda: any(
                    t == "/odom" and ns == last.sec * 1_000_000_000 + last.nanosec
                    for t, ns, _ in live[-50:]), 20.0), "the live view never caught up"
            finally:
                stop.set()
                reader.join()
        finally:
            client.close()

    ros: dict[str, dict[tuple[int, int], dict[str, Any]]] = {}
    for topic in COMPARED:
        dds = "/omnican/sim/true_pose" if topic == "/sim/true_pose" else topic
        for msg in transport.published[dds]:
            data = asdict(msg) if is_dataclass(msg) else msg
            if topic == "/diagnostics":  # the bridge's own status comes after the base's
                assert data["status"][-1]["name"] == "omnican: ros2 bridge"
                data["status"] = data["status"][:-1]
            ros.setdefault(topic, {})[stamp_of(data)] = data
    viewed: dict[str, dict[tuple[int, int], Any]] = {}
    for topic, _, payload in live:
        msg = decoder(COMPARED[topic])(payload)
        viewed.setdefault(topic, {})[(msg.header.stamp.sec, msg.header.stamp.nanosec)
                                     if topic != "/tf" else
                                     (msg.transforms[0].header.stamp.sec,
                                      msg.transforms[0].header.stamp.nanosec)] = msg
    recorded: dict[str, dict[tuple[int, int], Any]] = {}
    with record.open("rb") as f:
        for schema, channel_, message in make_reader(f).iter_messages(topics=list(COMPARED)):
            msg = decoder(schema.name)(message.data)
            key = (msg.transforms[0].header.stamp if channel_.topic == "/tf"
                    else msg.header.stamp)
            recorded.setdefault(channel_.topic, {})[(key.sec, key.nanosec)] = msg
            assert message.log_time == key.sec * 1_000_000_000 + key.nanosec

    # The same samples in each, and each sample the same, field by field.
    for topic in COMPARED:
        assert ros.get(topic), f"the bridge published no {topic}"
        # The recording began before the bridge subscribed and ends after it left.
        span = min(ros[topic]), max(ros[topic])
        assert {k for k in recorded[topic] if span[0] <= k <= span[1]} == set(ros[topic]), topic
        missed = set(ros[topic]) - set(viewed.get(topic, {}))
        assert len(missed) <= len(ros[topic]) // 20, f"the viewer missed {len(missed)} {topic}"
        for stamp, data in ros[topic].items():
            assert plain(recorded[topic][stamp], data) == data, (topic, stamp)
            if stamp in viewed.get(topic, {}):
                assert plain(viewed[topic][stamp], data) == data, (topic, stamp)
    # The scenario is in them: the fault went ERROR at once, the recover back to OK.
    levels = [max(s["level"] for s in d["status"]) for _, d in sorted(ros["/diagnostics"].items())]
    assert 2 in levels and levels[-1] == 0
    # One clock: the simulated one (its epoch is a fixed date in 2026), at 50 Hz.
    stamps = sorted(ros["/odom"])
    first, last_ = stamps[0][0] + stamps[0][1] / 1e9, stamps[-1][0] + stamps[-1][1] / 1e9
    assert abs(first - clock.epoch) < 5.0
    assert len(stamps) == pytest.approx(50 * (last_ - first) + 1, abs=2)


def test_a_fast_recording_has_state_and_frames_on_one_time_base(tmp_path: Path) -> None:
    pytest.importorskip("mcap")
    import json
    import subprocess
    import sys

    from mcap.reader import make_reader

    record = tmp_path / "fast.mcap"
    run = subprocess.run([sys.executable, "-m", "omnican", "drive", "--sim", "--fast",
                          "--square", "0.5", "--json", "--record", str(record)],
                         capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    simulated_s = json.loads(run.stdout)["duration_s"]
    times: dict[str, list[int]] = {}
    with record.open("rb") as f:
        for _, channel_, message in make_reader(f).iter_messages():
            times.setdefault(channel_.topic, []).append(message.log_time)
    odom, frames = sorted(times["/odom"]), sorted(times["/from_can_bus"] + times["/to_can_bus"])
    span = (odom[-1] - odom[0]) / 1e9
    assert simulated_s <= span <= simulated_s + 2.0  # seconds of simulated time, not months
    assert abs(frames[0] - odom[0]) / 1e9 < 1.0 and abs(frames[-1] - odom[-1]) / 1e9 < 0.5
    assert len(odom) == pytest.approx(50 * span, rel=0.02)  # the documented 50 Hz
    assert {"/can/TPDO2_node1", "/can/SYNC", "/sim/true_pose"} <= set(times)
